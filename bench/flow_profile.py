"""Where the flow engine's time goes: bench/peer_flow's problems (chain, ball, biped-tilt) under
callgrind at several tolerances and both Runge-Kutta backends, the instructions of one
simulate() call split into the field's evaluations (Jets, all tangent directions), the error
norm, event location (the crossing's root on the step), the jump (the event's saltation or
B-derivative map), the steppers' construction and the rest (the stages' linear combinations of
Jets, step control, dense output), and apart the share of malloc and free in all of them. Counts repeat from run to run on a
loaded machine. Usage:

    python3 bench/flow_profile.py [--binary build/bench/peer_flow] [--out FILE.json]

About a minute. Prints a markdown table (docs/flow.md, "Where the time goes").
"""
import argparse
import json
import os
import re
import subprocess
import tempfile

PROBLEMS = {
    "chain": ("chain", "0.1,0.2,0.3,0.4,0.5,0.6,0.3,0.2,0.1,0.0,-0.1,-0.2", 10.0),
    "ball": ("ball", "1.0,0.0", 2.5),
    "biped-tilt": ("biped", "0.0,1.0,0.2,0.0,0.0,0.0", 0.6),
}
TOLERANCES = (1e-5, 1e-8, 1e-11)
BACKENDS = ("dopri5", "dop853")
# name -> regular expression of the functions whose inclusive counts make the part (the parts
# but malloc are disjoint by construction of the engine's calls; malloc and free are counted
# wherever they run).
PARTS = {
    "simulate": r"\?\?\?:bflow::simulate\(",
    "field": r"ModelAdapter<.*>::field\(ceres::Jet",
    "error_norm": r"Stepper<.*>::error_norm\(",
    "locate": r"Stepper<.*>::locate_crossing\(",
    "jump": r"make_event\(",
    "setup": r"Stepper<.*>::Stepper\(",
    "malloc": r"malloc\.c:(malloc|free) ",
}


def inclusive(path):
    text = subprocess.run(["callgrind_annotate", "--threshold=100", "--inclusive=yes", path],
                          capture_output=True, text=True, check=True).stdout
    rows = []
    for line in text.splitlines():
        m = re.match(r"\s*([\d,]+)\s+\(\s*[\d.]+%\)\s+(.*)$", line)
        if m:
            rows.append((int(m.group(1).replace(",", "")), m.group(2)))
    return rows


def parts_of(rows):
    out = {}
    for part, pattern in PARTS.items():
        hits = [v for v, name in rows if re.search(pattern, name)]
        # Several instantiations (Jet widths, chunks) add up; malloc and free add up.
        out[part] = sum(hits) if part in ("field", "error_norm", "locate", "setup", "malloc") \
            else max(hits, default=0)
    # malloc and free run inside the other parts too: reported apart, not in the sum.
    out["rest"] = out["simulate"] - sum(out[p] for p in PARTS if p not in ("simulate", "malloc"))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--binary", default="build/bench/peer_flow")
    ap.add_argument("--out", default="")
    a = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as work:
        for name, (program, x0, t) in PROBLEMS.items():
            for backend in BACKENDS:
                for tol in TOLERANCES:
                    out = os.path.join(work, "cg.out")
                    run = subprocess.run(
                        ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                         a.binary, "--problem", program, "--x0", x0, "--t", repr(t),
                         "--backend", backend, "--rtol", repr(tol), "--atol", repr(tol * 1e-2),
                         "--min-cpu", "0"],
                        capture_output=True, text=True, check=True)
                    info = json.loads(run.stdout)
                    # peer_flow repeats its run (at least 3 times, after an untimed one): the
                    # counts are per run.
                    runs = info["runs"] + 1
                    p = {k: v / runs for k, v in parts_of(inclusive(out)).items()}
                    results.append({"problem": name, "backend": backend, "rtol": tol,
                                    "runs": runs,
                                     "steps": info["steps"],
                                     "field_evaluations": info["field_evaluations"], **p})
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"description": __doc__.split("\n\n")[0], "rows": results}, f, indent=1)
    print("| problem | backend | rtol | steps | field evaluations | simulate (10³ instructions) |"
          " field | error norm | event location | jump | steppers' setup | the rest |"
          " of which malloc, free | per step (10³) | per field evaluation (10³) |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
          " ---: | ---: | ---: |")
    for r in results:
        s = r["simulate"]
        pct = lambda k: f"{100.0 * r[k] / s:.0f} %"  # noqa: E731
        print(f"| {r['problem']} | {r['backend']} | {r['rtol']:g} | {r['steps']} | "
              f"{r['field_evaluations']} | {s / 1e3:.0f} | {pct('field')} | "
              f"{pct('error_norm')} | {pct('locate')} | {pct('jump')} | {pct('setup')} | "
              f"{pct('rest')} | {pct('malloc')} | {s / max(r['steps'], 1) / 1e3:.1f} | "
              f"{r['field'] / max(r['field_evaluations'], 1) / 1e3:.2f} |")


if __name__ == "__main__":
    main()
