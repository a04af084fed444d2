"""Runs bflow beside other tools on the same problems (scripts/peers runs this in its virtual
environment; docs/peers.md explains the comparisons).

  peers.py --bflow BUILD/bench/peer_problems [--quick] [--repeat K] [--report-only]
           [--problems P,...] [--tools T,...] [NAME ...]

A comparison is a module of this directory named in COMPARISONS, with
  run(ctx) -> list of rows (dicts: problem, tool, version, settings, cpu_s, wall_s, iterations,
              error, status, ...), one per problem, setting and tool
  report(data, ctx) -> the markdown of its section of docs/peers.md (it may draw PNGs into docs/)
A full run writes bench/results/peers/NAME.json ({"machine": ..., "rows": [...]}) and replaces the
comparison's generated section of docs/peers.md; --quick writes out/peers/NAME.json and prints
the section instead, leaving docs/ alone; --report-only rebuilds the section and plots from the
stored JSON.
"""
import argparse
import importlib
import json
import os
import sys
import time

import peers_common as common

# name -> module (bench/peers/<module>.py). A new comparison is a new module and a line here.
COMPARISONS = {
    "nosnoc": "peer_nosnoc",
    "flow": "peer_flow",
}


class Context:
    pass


def main():
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"comparisons to run (default: all of {', '.join(COMPARISONS)})")
    parser.add_argument("--bflow", help="bflow's problem program (bench/peer_problems)")
    parser.add_argument("--build-dir", default=None, help="its build directory (machine info)")
    parser.add_argument("--quick", action="store_true",
                        help="a small subset, results in out/peers/")
    parser.add_argument("--repeat", type=int, default=None,
                        help="runs per row, the median CPU time kept (default 3, --quick 1)")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per run")
    parser.add_argument("--report-only", action="store_true",
                        help="rebuild docs/peers.md's sections and plots from the stored JSON")
    parser.add_argument("--problems", default=None,
                        help="only these problems, comma-separated (results in out/peers/)")
    parser.add_argument("--tools", default=None,
                        help="only these tools, comma-separated (results in out/peers/)")
    args = parser.parse_args()
    names = args.names or list(COMPARISONS)
    unknown = [n for n in names if n not in COMPARISONS]
    if unknown:
        parser.error(f"unknown comparison {', '.join(unknown)}; known: {', '.join(COMPARISONS)}")
    if args.repeat is not None and args.repeat < 1:
        parser.error(f"--repeat {args.repeat}: the runs per row must be at least 1")
    if not args.timeout > 0:
        parser.error(f"--timeout {args.timeout}: the seconds per run must be > 0")

    ctx = Context()
    ctx.quick = args.quick
    ctx.problems = args.problems.split(",") if args.problems else None
    ctx.tools = args.tools.split(",") if args.tools else None
    subset = args.quick or ctx.problems is not None or ctx.tools is not None
    ctx.repeat = args.repeat or (1 if args.quick else 3)
    ctx.timeout = args.timeout
    ctx.bflow = args.bflow
    ctx.plots = not subset
    build_dir = args.build_dir or (os.path.dirname(os.path.dirname(args.bflow))
                                   if args.bflow else None)
    results = os.path.join(common.ROOT, "out" if subset else "bench/results", "peers")
    stored = {}
    if args.report_only:
        # Every stored file is read before any section is rewritten.
        for name in names:
            path = os.path.join(results, f"{name}.json")
            try:
                with open(path) as f:
                    stored[name] = json.load(f)
            except (OSError, UnicodeDecodeError, ValueError) as e:
                parser.error(f"--report-only: cannot read {path}: {str(e)[:200]}")
            rows = stored[name].get("rows") if isinstance(stored[name], dict) else None
            if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
                parser.error(f"--report-only: {path} is not the results of a comparison (an "
                             "object whose \"rows\" is a list of objects)")
    for name in names:
        module = importlib.import_module(COMPARISONS[name])
        for kind, chosen in (("problems", ctx.problems), ("tools", ctx.tools)):
            known = getattr(module, "SUBSETS", {}).get(kind)
            if chosen is not None and known is None:
                parser.error(f"--{kind}: the {name} comparison runs as a whole")
            unknown = [c for c in chosen or [] if c not in known]
            if unknown:
                parser.error(f"--{kind}: {', '.join(unknown)} not in the {name} comparison; "
                             f"known: {', '.join(known)}")
        path = os.path.join(results, f"{name}.json")
        if args.report_only:
            data = stored[name]
        else:
            if not ctx.bflow or not os.access(ctx.bflow, os.X_OK):
                parser.error(f"--bflow: {ctx.bflow} is not an executable")
            ctx.bflow_version = "bflow " + (common.machine(build_dir).get("git") or "?")
            start = time.time()
            common.log(f"peers: {name}{' (quick)' if ctx.quick else ''}, "
                       f"{ctx.repeat} run(s) per row")
            data = {"comparison": name, "quick": ctx.quick, "repeat": ctx.repeat,
                    "machine": common.machine(build_dir)}
            data["rows"] = module.run(ctx)
            data["minutes"] = round((time.time() - start) / 60.0, 2)
            data["machine"]["load_average_after"] = os.getloadavg()[0]
            os.makedirs(results, exist_ok=True)
            with open(path, "w") as f:
                json.dump(data, f, indent=1)
            common.log(f"peers: {name} took {data['minutes']} min; wrote {path}")
        text = module.report(data, ctx)
        if subset:
            print(text)
        else:
            common.replace_section(name, text)
            common.log(f"peers: updated the {name} section of {common.PEERS_MD}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
