"""The jump alone: bflow's JumpMap::apply (Algorithm 2.1 of [B], Figure 2.2) beside numpy (the
paper's Algorithm 2.2, one tangent at a time, and the same steps vectorised over a block of
tangents) and JAX (jax.jit of Algorithm 2.1: a lax.fori_loop over the n crossings, jax.vmap over
a block), on the same random cases. docs/peers.md explains what is measured.

As a comparison of scripts/peers: run(ctx) returns the rows, report(data, ctx) the markdown of
docs/peers.md's generated section (and draws its plot). ctx.jump_program is bflow's side
(bench/peer_jump.cc). Each case is written once as JSON (n, d, normals, limits table, tangents)
and read by every tool. Run by itself with --worker JOB (a JSON object) it times one case with
numpy or JAX and prints one JSON object: each tool has a process of its own (clean CPU time, JAX's
one-thread flags set before it is imported).
"""
import json
import os
import shutil
import sys
import tempfile
import time

import peers_common as common

NAME = "jump"

# Every timed run lasts at least this long (process CPU seconds).
MIN_RUN_S = 0.2
# Images compared with bflow's: the first IMAGES tangents of each case.
IMAGES = 100
# Largest relative difference from bflow's image (max norm, relative to bflow's) of an "ok" row.
AGREEMENT = 1e-12
# apply_block against apply() on the same tangents (relative to the largest image entry): for
# one surface the block sums eta . x in another order.
BLOCK_AGREEMENT = 1e-13
# JAX on one thread, double precision.
JAX_ENV = {"XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
           "JAX_PLATFORMS": "cpu"}
JAX_THREADS = "XLA_FLAGS=--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def cases(quick):
    """(n, d) of every case, and k, the tangents per case. n <= d: n surfaces meeting
    transversally need n independent normals in R^d (n = 8 is left out for d = 6)."""
    if quick:
        return [(n, 20) for n in (1, 3, 6)], 1000
    return [(n, d) for d in (6, 20, 64) for n in (1, 2, 3, 4, 6, 8) if n <= d], 10000


# ---------------------------------------------------------------------------------------------
# The data, as tests/support/random_jump.h builds it.

def make_case(n, d, k):
    """Gaussian normals eta (n x d); for every word b, Gamma(b) = P g(b) + K w(b) with P the
    pseudo-inverse of eta, K the projector onto its kernel, g_j(b) = |eta_j| U(0.2, 2) and w(b)
    Gaussian, so that eta_j . Gamma(b) = g_j(b) > 0; Gaussian tangents. limits[w] is Gamma(b) for
    the word whose bit j is set when b_j = +1 (bflow's Signs::bits())."""
    import numpy as np

    seed = 20250 + 1000 * n + d
    rng = np.random.default_rng(seed)
    eta = rng.standard_normal((n, d))
    pinv = eta.T @ np.linalg.inv(eta @ eta.T)
    kernel = np.eye(d) - pinv @ eta
    norms = np.linalg.norm(eta, axis=1)
    limits = np.empty((2 ** n, d))
    for w in range(2 ** n):
        g = norms * rng.uniform(0.2, 2.0, n)
        limits[w] = pinv @ g + kernel @ rng.standard_normal(d)
    transversality = limits @ eta.T
    if not (transversality > 0).all():
        raise ValueError(f"n = {n}, d = {d}: eta_j . Gamma(b) = {transversality.min():g} <= 0")
    tangents = rng.standard_normal((k, d))
    return {"n": n, "d": d, "k": k, "seed": seed, "normals": eta.tolist(),
            "limits": limits.tolist(), "tangents": tangents.tolist()}


def read_case(path):
    import numpy as np

    with open(path) as f:
        c = json.load(f)
    return (c["n"], c["d"], np.array(c["normals"]), np.array(c["limits"]),
            np.array(c["tangents"]))


# ---------------------------------------------------------------------------------------------
# The algorithms.

def algorithm_2_2(dx, e, G):
    """[B] Algorithm 2.2 as printed (np.int, gone from numpy, is int): tangent dx (d,), normals
    e (n, d), G(b) the limit for b in {-1, +1}^n."""
    import numpy as np

    dt = 0
    dx = np.array(dx)
    b = -np.ones(len(e), dtype=int)
    while np.any(b < 0):
        tau = -np.dot(e, dx) / np.dot(e, G(b))
        tau[b > 0] = np.inf
        j = np.argmin(tau)
        dt += tau[j]
        dx += tau[j] * G(b)
        b[j] = +1
    return dx - dt * G(b)  # b == [+1, ..., +1]


def table_function(limits):
    """G(b) for Algorithm 2.2: the table's row whose index has bit j set where b_j = +1."""
    import numpy as np

    weights = 1 << np.arange(limits.shape[0].bit_length() - 1)

    def G(b):
        return limits[int(np.dot(b > 0, weights))]

    return G


def algorithm_2_1_block(X, e, limits):
    """Algorithm 2.1 on every row of X (k, d) at once: per crossing, each tangent's Gamma(b)
    gathered from the table, eta . dx and eta . Gamma(b) as two (k, d) x (d, n) products."""
    import numpy as np

    k, n = X.shape[0], e.shape[0]
    X = X.copy()
    rows = np.arange(k)
    dt = np.zeros(k)
    bits = np.zeros(k, dtype=np.int64)
    crossed = np.zeros((k, n), dtype=bool)
    for _ in range(n):
        G = limits[bits]
        tau = -(X @ e.T) / (G @ e.T)
        tau[crossed] = np.inf
        j = np.argmin(tau, axis=1)
        t = tau[rows, j]
        dt += t
        X += t[:, None] * G
        crossed[rows, j] = True
        bits |= np.int64(1) << j
    return X - dt[:, None] * limits[bits]


def jax_algorithm_2_1():
    """Algorithm 2.1 for jax.jit: one tangent, a lax.fori_loop over the n crossings."""
    import jax.numpy as jnp
    from jax import lax

    def B(dx, e, limits):
        n = e.shape[0]
        powers = jnp.left_shift(1, jnp.arange(n, dtype=jnp.int64))

        def crossing(_, state):
            x, dt, bits = state
            g = limits[bits]
            tau = -(e @ x) / (e @ g)
            tau = jnp.where((bits & powers) != 0, jnp.inf, tau)
            j = jnp.argmin(tau)
            t = tau[j]
            return x + t * g, dt + t, bits | powers[j]

        start = (dx, jnp.zeros((), dx.dtype), jnp.zeros((), jnp.int64))
        x, dt, bits = lax.fori_loop(0, n, crossing, start)
        return x - dt * limits[bits]

    return B


# ---------------------------------------------------------------------------------------------
# Timing (runs in the worker process).

def time_runs(body, repeat):
    """body(calls) doubled from 1 call until a run takes MIN_RUN_S, then `repeat` runs of that
    many calls: (CPU seconds per call of each run, calls per run)."""
    calls = 1
    while True:
        start = time.process_time()
        body(calls)
        if time.process_time() - start >= MIN_RUN_S:
            break
        calls *= 2
    per_call = []
    for _ in range(repeat):
        start = time.process_time()
        body(calls)
        per_call.append((time.process_time() - start) / calls)
    return per_call, calls


def timing(per_call, calls, tangents_per_call):
    ns = [1e9 * s / tangents_per_call for s in per_call]
    return {"ns_per_tangent": common.median(ns), "runs_ns_per_tangent": ns,
            "calls_per_run": calls, "cpu_s_per_run": common.median(per_call) * calls}


def worker_numpy(job):
    import numpy as np

    _, _, eta, limits, tangents = read_case(job["case"])
    k, repeat = tangents.shape[0], job["repeat"]
    G = table_function(limits)
    shown = min(k, IMAGES)
    out = {"tool": "numpy", "version": f"numpy {np.__version__}"}
    out["images_single"] = [algorithm_2_2(tangents[t], eta, G).tolist() for t in range(shown)]
    out["images_block"] = algorithm_2_1_block(tangents, eta, limits)[:shown].tolist()
    rows = list(tangents)

    def single(calls):
        t = 0
        for _ in range(calls):
            algorithm_2_2(rows[t], eta, G)
            t = t + 1 if t + 1 < k else 0

    def loop(calls):
        for _ in range(calls):
            for dx in rows:
                algorithm_2_2(dx, eta, G)

    def block(calls):
        for _ in range(calls):
            algorithm_2_1_block(tangents, eta, limits)

    out["single"] = timing(*time_runs(single, repeat), 1)
    out["loop"] = timing(*time_runs(loop, repeat), k)
    out["block"] = timing(*time_runs(block, repeat), k)
    out["harness"] = timing(*time_runs(_empty, repeat), 1)
    return out


def _empty(calls):
    """The timing loop with nothing in it: the harness's own cost per call."""
    t = 0
    for _ in range(calls):
        t = t + 1


def worker_jax(job):
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import jaxlib
    import numpy as np

    _, _, eta, limits, tangents = read_case(job["case"])
    k, repeat = tangents.shape[0], job["repeat"]
    B = jax_algorithm_2_1()
    single_fn = jax.jit(B)
    block_fn = jax.jit(jax.vmap(B, in_axes=(0, None, None)))
    e, table = jnp.asarray(eta), jnp.asarray(limits)
    rows = [jax.device_put(tangents[t]) for t in range(k)]
    block_in = jnp.asarray(tangents)
    out = {"tool": "jax", "version": f"JAX {jax.__version__}, jaxlib {jaxlib.__version__}",
           "backend": jax.default_backend(), "x64": bool(jax.config.jax_enable_x64)}
    # The first call traces and compiles.
    compile_s = {}
    for name, fn, arg in (("single", single_fn, rows[0]), ("block", block_fn, block_in)):
        cpu, wall = time.process_time(), time.perf_counter()
        fn(arg, e, table).block_until_ready()
        compile_s[name] = {"cpu_s": time.process_time() - cpu, "wall_s": time.perf_counter() - wall}
    out["first_call"] = compile_s
    shown = min(k, IMAGES)
    images = [np.asarray(single_fn(rows[t], e, table)) for t in range(shown)]
    if images[0].dtype != np.float64:
        raise RuntimeError(f"JAX computed in {images[0].dtype}, not float64")
    out["images_single"] = [x.tolist() for x in images]
    out["images_block"] = np.asarray(block_fn(block_in, e, table))[:shown].tolist()

    def single(calls):
        t = 0
        for _ in range(calls):
            single_fn(rows[t], e, table).block_until_ready()
            t = t + 1 if t + 1 < k else 0

    def block(calls):
        for _ in range(calls):
            block_fn(block_in, e, table).block_until_ready()

    out["single"] = timing(*time_runs(single, repeat), 1)
    out["block"] = timing(*time_runs(block, repeat), k)
    out["harness"] = timing(*time_runs(_empty, repeat), 1)
    return out


def worker(job):
    # Anything a library prints goes to stderr; stdout carries this process's JSON.
    stdout, sys.stdout = sys.stdout, sys.stderr
    try:
        out = worker_jax(job) if job["tool"] == "jax" else worker_numpy(job)
        out["status"] = "ok"
    finally:
        sys.stdout = stdout
    print(json.dumps(out))


# ---------------------------------------------------------------------------------------------
# The driver side.

def max_rel_diff(images, reference):
    """max over tangents of |image - bflow's|_inf / |bflow's|_inf, or None."""
    import numpy as np

    if not images or not reference or len(images) != len(reference):
        return None
    a, b = np.asarray(images), np.asarray(reference)
    if a.shape != b.shape:
        return None
    scale = np.maximum(np.abs(b).max(axis=1), np.finfo(float).tiny)
    return float((np.abs(a - b).max(axis=1) / scale).max())


def _row(n, d, k, tool, version, settings, result, part, images=None, reference=None):
    row = {"comparison": NAME, "problem": f"n={n} d={d}", "n": n, "d": d, "k": k, "tool": tool,
           "version": version, "settings": settings, "ns_per_tangent": None, "cpu_s": None,
           "max_rel_diff_vs_bflow": None, "status": "error"}
    if result.get("status") != "ok":
        row["message"] = result.get("message", "no result")
        return row
    t = result.get(part) or {}
    row["ns_per_tangent"] = t.get("ns_per_tangent")
    # The timing loop's own cost per call (an empty call), part of ns_per_tangent at k = 1.
    row["harness_ns_per_call"] = (result.get("harness") or {}).get("ns_per_tangent")
    row["runs_ns_per_tangent"] = t.get("runs_ns_per_tangent")
    row["calls_per_run"] = t.get("calls_per_run")
    # The CPU time of the row's k tangents.
    if row["ns_per_tangent"] is not None:
        row["cpu_s"] = 1e-9 * row["ns_per_tangent"] * k
    row["status"] = "ok"
    if reference is not None:
        diff = max_rel_diff(images, reference)
        row["max_rel_diff_vs_bflow"] = diff
        if diff is None or not diff <= AGREEMENT:
            row["status"] = "error"
            row["message"] = ("no images to compare" if diff is None else
                              f"max relative difference from bflow {diff:.3g} > {AGREEMENT:g}")
    return row


def run_worker(path, tool, repeat, timeout):
    job = json.dumps({"case": path, "tool": tool, "repeat": repeat})
    env = JAX_ENV if tool == "jax" else None
    return common.run_json([sys.executable, os.path.abspath(__file__), "--worker", job],
                           timeout=timeout, env=env)


def run(ctx):
    program = getattr(ctx, "jump_program", None)
    bflow_version = getattr(ctx, "bflow_version", None) or "bflow"
    shapes, k = cases(ctx.quick)
    rows = []
    scratch = tempfile.mkdtemp(prefix="flow_jump_")
    try:
        for n, d in shapes:
            label = f"n = {n}, d = {d}, k = {k}"
            path = os.path.join(scratch, f"jump_n{n}_d{d}.json")
            try:
                with open(path, "w") as f:
                    json.dump(make_case(n, d, k), f)
                problem = None
            except (ValueError, ArithmeticError) as e:  # numpy's LinAlgError is a ValueError
                problem = {"status": "error", "message": f"the case: {e}"}
            common.log(f"  {label}: bflow")
            if problem:
                b = npy = jx = problem
            elif program and os.access(program, os.X_OK):
                b = common.run_json([program, "--case", path, "--repeat", str(ctx.repeat)],
                                    timeout=ctx.timeout)
            else:
                b = {"status": "error", "message": f"bflow's program {program} is not an "
                                                   f"executable"}
            if not problem:
                common.log(f"  {label}: numpy")
                npy = run_worker(path, "numpy", ctx.repeat, ctx.timeout)
                common.log(f"  {label}: jax")
                jx = run_worker(path, "jax", ctx.repeat, ctx.timeout)
            ref = b.get("images") if b.get("status") == "ok" else None

            rb1 = _row(n, d, 1, "bflow", bflow_version,
                       "JumpMap::apply, one call per tangent (cycling through the k tangents)",
                       b, "apply")
            rbk = _row(n, d, k, "bflow", bflow_version,
                       "JumpMap::apply_block on the d x k block", b, "apply_block")
            for r in (rb1, rbk):
                if r["status"] == "ok":
                    r["max_rel_diff_vs_bflow"] = 0.0
                    r["construct_ns"] = (b.get("construct") or {}).get("ns_per_call")
            rbk["block_vs_apply_max_rel_diff"] = b.get("block_vs_apply_max_rel_diff")
            if (b.get("block_vs_apply_max_rel_diff") or 0.0) > BLOCK_AGREEMENT:
                rbk["status"] = "error"
                rbk["message"] = (f"apply_block differs from apply by "
                                  f"{b['block_vs_apply_max_rel_diff']:.3g} (relative)")
            nv = npy.get("version", "numpy")
            jv = jx.get("version", "JAX")
            rows += [
                rb1,
                _row(n, d, 1, "numpy", nv, "Algorithm 2.2 as printed, one call per tangent",
                     npy, "single", npy.get("images_single"), ref),
                _row(n, d, 1, "jax", jv, "jax.jit of Algorithm 2.1 (lax.fori_loop over the n "
                     "crossings), float64, one call per tangent with block_until_ready; "
                     + JAX_THREADS, jx, "single", jx.get("images_single"), ref),
                rbk,
                _row(n, d, k, "numpy", nv, "Algorithm 2.2 as printed, a Python loop over the k "
                     "tangents", npy, "loop", npy.get("images_single"), ref),
                _row(n, d, k, "numpy", nv, "Algorithm 2.1 vectorised over the k x d block "
                     "(n steps of (k, d) x (d, n) products)", npy, "block",
                     npy.get("images_block"), ref),
                _row(n, d, k, "jax", jv, "jax.jit(jax.vmap(...)) on the k x d block, float64, "
                     "block_until_ready; " + JAX_THREADS, jx, "block",
                     jx.get("images_block"), ref),
            ]
            first = jx.get("first_call") or {}
            for r in rows[-7:]:
                if r["tool"] == "jax":
                    part = "single" if r["k"] == 1 else "block"
                    r["jit_compile_s"] = (first.get(part) or {}).get("cpu_s")
                    r["jit_compile_wall_s"] = (first.get(part) or {}).get("wall_s")
            by_k = {1: rb1, k: rbk}
            for r in rows[-7:]:
                ref_row = by_k[r["k"]]
                if r["tool"] != "bflow" and r["ns_per_tangent"] and ref_row["ns_per_tangent"]:
                    r["ratio_vs_bflow"] = r["ns_per_tangent"] / ref_row["ns_per_tangent"]
            common.log("    " + ", ".join(
                f"{r['tool']} k={r['k']} {common.fmt(r['ns_per_tangent'])} ns {r['status']}"
                for r in rows[-7:]))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return rows


# ---------------------------------------------------------------------------------------------
# The report.

# (tool, k is 1, settings prefix) -> column label, in the table's order.
MODES = [
    ("bflow", True, "JumpMap::apply", "bflow apply"),
    ("bflow", False, "JumpMap::apply_block", "bflow apply_block"),
    ("numpy", True, "Algorithm 2.2 as printed, one call", "numpy, one call"),
    ("numpy", False, "Algorithm 2.2 as printed, a Python loop", "numpy, loop"),
    ("numpy", False, "Algorithm 2.1 vectorised", "numpy, vectorised"),
    ("jax", True, "jax.jit of", "JAX jit, one call"),
    ("jax", False, "jax.jit(jax.vmap", "JAX jit(vmap)"),
]


def mode(row):
    for tool, single, prefix, label in MODES:
        if row["tool"] == tool and (row["k"] == 1) == single and row["settings"].startswith(prefix):
            return label
    return None


def _ns(x):
    """ns below 10^4 (whole ns from 100 on), µs above."""
    if x is None:
        return "—"
    if x >= 1e4:
        return f"{x / 1e3:.3g} µs"
    return f"{x:.0f}" if x >= 100 else f"{x:.3g}"


def report(data, ctx):
    rows = data["rows"] if isinstance(data, dict) else data
    m = data.get("machine", {}) if isinstance(data, dict) else {}
    lines = []
    if m:
        lines.append(f"Run of {m.get('date')} ({'quick' if data.get('quick') else 'full'}, "
                     f"{data.get('minutes')} min; {data.get('repeat')} timed run(s) per number, "
                     f"the median kept) on {m.get('cpu')}, {m.get('cores')} cores, {m.get('os')};"
                     f" bflow {m.get('git')} built by {m.get('compiler')} "
                     f"({m.get('build_type')}); Python {m.get('python')}; load average "
                     f"{m.get('load_average_before'):.2f} before the run. JSON: "
                     f"`{'out' if data.get('quick') else 'bench/results'}/peers/{NAME}.json`.")
        lines.append("")
    versions = []
    for tool in ("numpy", "jax"):
        v = next((r["version"] for r in rows if r["tool"] == tool and r.get("status") == "ok"),
                 None)
        if v:
            versions.append(v)
    k_big = max((r["k"] for r in rows), default=0)
    lines.append(
        "B(dx) at a point where n surfaces meet in R^d, nothing else: bflow's `JumpMap::apply` "
        "(Algorithm 2.1 of [B]) beside the paper's own numpy code (Algorithm 2.2, typed in as "
        "printed with `np.int` as `int`; `G(b)` looks the word's row up in the table) and "
        "`jax.jit` of Algorithm 2.1 written the obvious way (a `lax.fori_loop` over the n "
        "crossings, `jax.vmap` over a block, float64). Every tool reads the same case: Gaussian "
        "normals eta (n x d), the full table of 2^n limits Gamma(b) = P g(b) + K w(b) (P the "
        "pseudo-inverse of eta, K the kernel projector, g_j(b) = |eta_j| U(0.2, 2), w Gaussian, "
        "as tests/support/random_jump.h; a seed per (n, d)) and "
        f"{k_big} Gaussian tangents."
        + (" n surfaces meet transversally only for n <= d, so d = 6 stops at n = 6."
           if any(r["d"] < 8 for r in rows) else ""))
    lines.append("")
    lines.append(
        "Times are process CPU time per tangent on one thread "
        "(numpy and OpenBLAS with OMP_NUM_THREADS=1, JAX with "
        "`--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1`), each timed run at "
        f"least {MIN_RUN_S} s: k = 1 is the latency of one call (one Python call per tangent "
        "for numpy and JAX, cycling through the tangents, each JAX result waited for), "
        f"k = {k_big} the cost per tangent of the whole block (bflow `apply_block`, a Python "
        "loop of Algorithm 2.2 calls, the vectorised numpy version, one jitted `vmap` call). "
        "bflow's table constructor computes eta . Gamma(b) for every word once (its cost is the "
        "last column, not in the times) and then keeps eta . dx up to date, O(n d + n^2) per "
        "tangent; the paper's code and the JAX version recompute eta . dx and eta . Gamma(b) at "
        "every crossing, O(n^2 d). The ratios are peer CPU / bflow CPU for the same k. The "
        "images of the first "
        f"{IMAGES} tangents of every tool are compared with bflow's (max norm, relative to "
        f"bflow's); a row above {AGREEMENT:g} is an error.")
    lines.append("")
    if versions:
        lines.append("Peers: " + "; ".join(versions) + ".")
        lines.append("")
    harness = [r["harness_ns_per_call"] for r in rows if r.get("harness_ns_per_call")]
    if harness:
        lines.append(f"The Python harness's own cost (the same timing loop around an empty call): "
                     f"{_ns(min(harness))}–{_ns(max(harness))} ns per call, included in the "
                     "numpy and JAX times at k = 1.")
        lines.append("")

    groups = []
    for r in rows:
        key = (r["n"], r["d"], r["k"])
        if key not in groups:
            groups.append(key)
    header = ["n", "d", "k", "bflow [ns]", "numpy [ns]", "numpy vectorised [ns]", "JAX jit [ns]",
              "numpy / bflow", "numpy vect. / bflow", "JAX / bflow", "max rel. diff numpy, "
              "vect., JAX", "JAX first call [s]", "bflow construction"]
    align = ["---:"] * len(header)
    body = []
    errors = []
    for n, d, k in sorted(groups, key=lambda g: (g[1], g[0], g[2])):
        by = {mode(r): r for r in rows if (r["n"], r["d"], r["k"]) == (n, d, k)}
        single = k == 1
        b = by.get("bflow apply" if single else "bflow apply_block") or {}
        npy = by.get("numpy, one call" if single else "numpy, loop") or {}
        vec = {} if single else by.get("numpy, vectorised") or {}
        jx = by.get("JAX jit, one call" if single else "JAX jit(vmap)") or {}

        def cell(r):
            if not r:
                return "—"
            if r.get("status") != "ok" and r.get("ns_per_tangent") is None:
                return "error"
            return _ns(r.get("ns_per_tangent")) + ("" if r.get("status") == "ok" else " (error)")

        def ratio(r):
            return f"{r['ratio_vs_bflow']:.3g}" if r.get("ratio_vs_bflow") else "—"

        diffs = ", ".join(common.fmt(r.get("max_rel_diff_vs_bflow")) for r in (npy, vec, jx))
        construct = b.get("construct_ns")
        body.append([n, d, k, cell(b), cell(npy), cell(vec), cell(jx), ratio(npy), ratio(vec),
                     ratio(jx), diffs, common.fmt(jx.get("jit_compile_s")),
                     _ns(construct) if construct is not None else "—"])
        for r in (b, npy, vec, jx):
            if r and r.get("status") != "ok":
                errors.append(f"n = {n}, d = {d}, k = {k}, {mode(r)}: {r.get('message')}")
    lines.append(common.table(header, body, align))
    lines.append("")
    lines.append(
        "ns per tangent (µs where marked). For k > 1 the numpy column is the Python loop of "
        "Algorithm 2.2 calls; JAX's first call (trace and compile, process CPU) is per function "
        "and case. bflow construction: one `JumpMap(normals, table)` in ns (µs where marked).")
    lines.append("")
    if errors:
        lines.append("Rows in error:")
        lines.append("")
        lines += [f"- {e}" for e in errors]
        lines.append("")
    if getattr(ctx, "plots", False):
        name = _plot(rows)
        if name:
            lines.append(f"![{name}]({name})")
            lines.append("")
    return "\n".join(lines)


def _plot(rows, d=20):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    picked = [r for r in rows if r["d"] == d and r.get("ns_per_tangent")]
    if not picked:
        return None
    style = {
        "bflow apply": ("#4c72b0", "o", "-"), "bflow apply_block": ("#4c72b0", "s", "--"),
        "numpy, one call": ("#dd8452", "o", "-"), "numpy, loop": ("#dd8452", "^", ":"),
        "numpy, vectorised": ("#dd8452", "s", "--"),
        "JAX jit, one call": ("#55a868", "o", "-"), "JAX jit(vmap)": ("#55a868", "s", "--"),
    }
    fig, ax = plt.subplots(figsize=(9.5, 4.8))
    for _, _, _, label in MODES:
        pts = sorted((r["n"], r["ns_per_tangent"], r["k"]) for r in picked if mode(r) == label)
        if not pts:
            continue
        color, marker, line = style[label]
        k = pts[0][2]
        ax.semilogy([p[0] for p in pts], [p[1] for p in pts], marker=marker, linestyle=line,
                    color=color, label=f"{label} (k = {k})")
    ax.set_xlabel("n, surfaces crossed at once")
    ax.set_ylabel("CPU per tangent [ns]")
    ax.set_title(f"The jump alone, d = {d}: B(dx) per tangent")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.tight_layout()
    name = "peers_flow_jump.png"
    fig.savefig(os.path.join(common.DOCS, name), dpi=110)
    plt.close(fig)
    return name


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        worker(json.loads(sys.argv[2]))
    else:
        sys.exit(__doc__)
