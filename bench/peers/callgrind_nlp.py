"""Instructions per IPOPT iteration of both tools on the matched optimal-control rows of
peer_nosnoc.py, counted by callgrind inside IPOPT's solves (IpoptApplication::OptimizeTNLP, so
neither process's start nor Python's setup counts): the whole NLP solve, MUMPS (dmumps_c with
the BLAS it calls) and each callback IPOPT makes (objective, gradient, constraints, Jacobian,
Hessian; nosnoc's are CasADi's IpoptUserClass, bflow's its TNLP). Instruction counts repeat
from run to run on a loaded machine, where CPU times move by a tenth; both tools run the same
IPOPT 3.14.19 and MUMPS 5.8.2 here. Usage (the peers environment's Python; valgrind on PATH):

    python bench/peers/callgrind_nlp.py [--binary build/bench/peer_problems]
        [--rows braking-block-stewart-20,...] [--bflow-flag=--jet-derivatives]
        [--out bench/results/peers/nosnoc_callgrind.json]

About a minute per row and tool. Writes the counts to the JSON and a markdown table to stdout.
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

import peer_nosnoc
import peers_common as common

TOGGLE = "--toggle-collect=Ipopt::IpoptApplication::OptimizeTNLP*"
CALLBACKS = ("eval_f", "eval_grad_f", "eval_g", "eval_jac_g", "eval_h")


def row_name(case):
    return f"{case['problem']}-{case['formulation']}-{case['N']}"


def inclusive(out_file):
    """{function name: inclusive instructions} of a callgrind output, and the total."""
    text = subprocess.run(["callgrind_annotate", "--threshold=100", "--inclusive=yes", out_file],
                          capture_output=True, text=True, check=True).stdout
    counts = {}
    total = None
    for line in text.splitlines():
        m = re.match(r"\s*([\d,]+)\s+\(\s*[\d.]+%\)\s+(.*)$", line)
        if not m:
            continue
        value = int(m.group(1).replace(",", ""))
        name = m.group(2)
        if "PROGRAM TOTALS" in name:
            total = value
            continue
        counts[name] = max(counts.get(name, 0), value)
    return counts, total


def split(counts, total, tool):
    """Instructions of the solve, MUMPS and each callback."""
    owner = "casadi::IpoptUserClass::" if tool == "nosnoc" else "Forward::"
    out = {"total": total, "mumps": 0}
    for name, value in counts.items():
        if re.search(r"\?\?\?:dmumps_c\b", name):
            out["mumps"] = max(out["mumps"], value)
        for cb in CALLBACKS:
            if owner + cb + "(" in name:
                out[cb] = max(out.get(cb, 0), value)
    for cb in CALLBACKS:
        out.setdefault(cb, 0)
    out["callbacks"] = sum(out[cb] for cb in CALLBACKS)
    out["rest"] = total - out["mumps"] - out["callbacks"]
    return out


def measure(cmd, tool, workdir):
    handle, path = tempfile.mkstemp(prefix=f"callgrind_{tool}_", suffix=".out", dir=workdir)
    os.close(handle)
    run = subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={path}", TOGGLE]
                         + cmd, capture_output=True, text=True, timeout=3600)
    result = json.loads(run.stdout)
    counts, total = inclusive(path)
    os.remove(path)
    parts = split(counts, total, tool)
    parts["iterations"] = result["ipopt"]["iterations"]
    parts["status"] = result.get("status")
    key = "T" if result.get("problem") == "turbo-car" else "objective"
    parts["optimum"] = result.get(key)
    return parts


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--binary", default="build/bench/peer_problems")
    ap.add_argument("--rows", default="", help="comma-separated row names (default: all)")
    ap.add_argument("--bflow-flag", action="append", default=[],
                    help="a further flag of bflow's runs (repeatable)")
    ap.add_argument("--out", default="bench/results/peers/nosnoc_callgrind.json")
    a = ap.parse_args()
    binary = os.path.abspath(a.binary)
    cases = [c for c in peer_nosnoc.cases(False) if not peer_nosnoc.is_simulation(c)]
    wanted = [r for r in a.rows.split(",") if r]
    if wanted:
        cases = [c for c in cases if row_name(c) in wanted]
    rows = []
    with tempfile.TemporaryDirectory() as workdir:
        for case in cases:
            print(f"  {row_name(case)}", file=sys.stderr, flush=True)
            job = json.dumps({"case": case, "setting": "matched"})
            nosnoc = measure([sys.executable, os.path.abspath(peer_nosnoc.__file__), "--worker",
                              job], "nosnoc", workdir)
            bflow = measure(peer_nosnoc.bflow_command(binary, case, "matched") + a.bflow_flag,
                            "bflow", workdir)
            rows.append({"row": row_name(case), "case": case, "bflow": bflow, "nosnoc": nosnoc})
            out = {"description": __doc__.split("\n\n")[0], "bflow_flags": a.bflow_flag,
                   "machine": common.machine(os.path.dirname(os.path.dirname(binary))),
                   "rows": rows}
            with open(a.out, "w") as f:
                json.dump(out, f, indent=1)
    per = lambda p, k: p[k] / p["iterations"] / 1e6  # noqa: E731
    print("| row | tool | iterations | per iteration | MUMPS | Hessian | Jacobian | constraints |"
          " gradient and objective | IPOPT's rest |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for r in rows:
        for tool in ("bflow", "nosnoc"):
            p = r[tool]
            print(f"| {r['row'] if tool == 'bflow' else ''} | {tool} | {p['iterations']} | "
                  f"{per(p, 'total'):.2f} | {per(p, 'mumps'):.2f} | {per(p, 'eval_h'):.3f} | "
                  f"{per(p, 'eval_jac_g'):.3f} | {per(p, 'eval_g'):.3f} | "
                  f"{(p['eval_grad_f'] + p['eval_f']) / p['iterations'] / 1e6:.3f} | "
                  f"{per(p, 'rest'):.2f} |")
    print("\n(millions of instructions per IPOPT iteration)")


if __name__ == "__main__":
    main()
