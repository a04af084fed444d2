"""How far the matched rows' IPOPT iterations are a property of the NLP: each matched
optimal-control row of peer_nosnoc.py run by both tools again with one IPOPT option changed in a
way that leaves the NLP and its solution as they are (the cap on the gradient-based scaling
1e-6 relative off its default 100, which moves the scaling factors of the rows whose gradients
exceed 100 by 1e-6; MUMPS's pivot tolerance 1e-7 or 1.0001e-6 instead of 1e-6, which changes
pivoting and so the factorisations' rounding). A row whose iteration count moves with them in
nosnoc itself follows the rounding of its KKT solves, not its NLP, and the two tools' counts on
it can agree only by chance. Usage (with the peers environment's Python):

    python bench/peers/perturb_paths.py [--binary build/bench/peer_problems]
        [--out bench/results/peers/nosnoc_perturbed.json]

Writes the iterations and optima of every run to the JSON and a markdown table to stdout.
"""
import argparse
import json
import os
import sys

import peer_nosnoc
import peers_common as common

PERTURBATIONS = (
    {},
    {"nlp_scaling_max_gradient": 99.9999},
    {"nlp_scaling_max_gradient": 100.0001},
    {"mumps_pivtol": 1e-7},
    {"mumps_pivtol": 1.0001e-6},
)


def label(perturbation):
    return ", ".join(f"{k} {v!r}" for k, v in perturbation.items()) or "as in the matched rows"


def run(case, perturbation, binary):
    job = json.dumps({"case": case, "setting": "matched", "ipopt": perturbation})
    nosnoc = common.run_json([sys.executable, os.path.abspath(peer_nosnoc.__file__), "--worker",
                              job], timeout=600)
    flags = [f"--ipopt-num={k}={v!r}" for k, v in perturbation.items()]
    bflow = common.run_json(peer_nosnoc.bflow_command(binary, case, "matched") + flags,
                            timeout=600)
    key = "T" if case["problem"] == "turbo-car" else "objective"
    return {tool: {"status": r.get("status"), "iterations": (r.get("ipopt") or {}).get("iterations"),
                   "optimum": r.get(key)} for tool, r in (("bflow", bflow), ("nosnoc", nosnoc))}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--binary", default="build/bench/peer_problems")
    ap.add_argument("--out", default="bench/results/peers/nosnoc_perturbed.json")
    a = ap.parse_args()
    binary = os.path.abspath(a.binary)
    cases = [c for c in peer_nosnoc.cases(False) if not peer_nosnoc.is_simulation(c)]
    rows = []
    for case in cases:
        name = f"{case['problem']} ({case['formulation']}, N = {case['N']})"
        row = {"case": case, "name": name, "runs": []}
        for perturbation in PERTURBATIONS:
            print(f"  {name}: {label(perturbation)}", file=sys.stderr, flush=True)
            row["runs"].append({"ipopt": perturbation, **run(case, perturbation, binary)})
        rows.append(row)
        out = {"description": __doc__.split("\n\n")[0], "perturbations": list(PERTURBATIONS),
               "machine": common.machine(os.path.dirname(os.path.dirname(binary))),
               "rows": rows}
        with open(a.out, "w") as f:
            json.dump(out, f, indent=1)
    print("| row | " + " | ".join(label(p) for p in PERTURBATIONS) + " |")
    print("| --- |" + " ---: |" * len(PERTURBATIONS))
    for row in rows:
        cells = [f"{r['bflow']['iterations']} / {r['nosnoc']['iterations']}" for r in row["runs"]]
        print(f"| {row['name']} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
