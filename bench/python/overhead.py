#!/usr/bin/env python3
"""What a call from Python costs over the same call in C++: one JumpMap.apply of a d = 6 jump
(n = 2 surfaces) and one flow derivative of the biped (d = 6, to t = 0.6, rtol 1e-6, atol 1e-9,
one event of two surfaces), each timed in this process, beside the C++ benchmarks of the same
problems (bench/jump_benchmark BM_JumpApply/2/6, bench/flow_benchmark BM_FlowFull/6), run as
subprocesses when their build directory is given.

    python bench/python/overhead.py [--cpp-build build-bench] [--json out.json]

Prints a table (median of repeated timings; the Python column through the package's public call,
"out=" the same into a preallocated array, the native column through the extension's method
alone) and, with --json, writes it.
"""

import argparse
import json
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np

import bflow


def median_seconds(call, inner, repeats=15):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(inner):
            call()
        times.append((time.perf_counter() - start) / inner)
    return statistics.median(times)


def random_jump(n, d, seed=1):
    rng = np.random.default_rng(seed)
    eta = rng.standard_normal((n, d))
    # Limits that every normal crosses positively: a common part along eta's rows plus noise.
    base = eta.T @ np.ones(n)
    limits = np.empty((d, 2 ** n))
    for bits in range(2 ** n):
        limits[:, bits] = base * 3.0 + 0.3 * rng.standard_normal(d)
    for j in range(n):
        assert np.all(eta[j] @ limits > 0)
    return bflow.JumpMap.from_limits(eta, limits)


def cpp_median_us(binary, name):
    out = subprocess.run([binary, f"--benchmark_filter=^{name}$", "--benchmark_repetitions=5",
                          "--benchmark_report_aggregates_only=true", "--benchmark_format=json"],
                         check=True, capture_output=True, text=True).stdout
    for row in json.loads(out)["benchmarks"]:
        if row.get("aggregate_name") == "median":
            scale = {"ns": 1e-3, "us": 1.0, "ms": 1e3, "s": 1e6}[row["time_unit"]]
            return row["real_time"] * scale
    raise RuntimeError(f"no median for {name} in {binary}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cpp-build", help="a build directory with bench/jump_benchmark and "
                        "bench/flow_benchmark (BFLOW_BUILD_BENCHMARKS=ON)")
    parser.add_argument("--json", help="write the rows to this file")
    args = parser.parse_args()

    jump = random_jump(2, 6)
    dx = np.random.default_rng(2).standard_normal(6)
    native = jump._native
    out = np.empty(6)
    rows = {
        "jump apply n=2 d=6": {
            "python_us": median_seconds(lambda: jump.apply(dx), 20000) * 1e6,
            "native_us": median_seconds(lambda: native._apply_vector(dx), 20000) * 1e6,
            "python_out_us": median_seconds(lambda: jump.apply(dx, out=out), 20000) * 1e6,
            "cpp": ("jump_benchmark", "BM_JumpApply/2/6"),
        },
    }
    model, x0 = bflow.biped(), bflow.biped_initial_state()
    options = bflow.flow_options(rtol=1e-6, atol=1e-9)
    rows["biped flow_derivative t=0.6 rtol=1e-6"] = {
        "python_us": median_seconds(
            lambda: bflow.flow_derivative(model, x0, 0.6, rtol=1e-6, atol=1e-9), 50) * 1e6,
        "native_us": median_seconds(
            lambda: bflow._bflow._flow_derivative(model, x0, 0.6, options), 50) * 1e6,
        "cpp": ("flow_benchmark", "BM_FlowFull/6"),
    }
    for name, row in rows.items():
        binary, bench = row.pop("cpp")
        if args.cpp_build:
            row["cpp_us"] = cpp_median_us(str(Path(args.cpp_build) / "bench" / binary), bench)
            row["overhead_us"] = row["python_us"] - row["cpp_us"]
    print(f"{'call':40} {'Python us':>10} {'out= us':>8} {'native us':>10} {'C++ us':>10} "
          f"{'overhead us':>12}")
    for name, row in rows.items():
        cpp = row.get("cpp_us")
        print(f"{name:40} {row['python_us']:10.3f} {row.get('python_out_us', float('nan')):8.3f} "
              f"{row['native_us']:10.3f} {cpp if cpp is not None else float('nan'):10.3f} "
              f"{row.get('overhead_us', float('nan')):12.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
