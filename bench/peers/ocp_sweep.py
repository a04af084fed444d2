"""bflow's and nosnoc's default settings over the number of control stages N on the two optimal
control examples with exact optima: the turbo car (time-optimal, T* = 40/3) and the braking
block (J* of the continuous problem; at a finite N the error is the discretisation's, so there
the two tools are compared with each other).

Three configurations per (problem, formulation, N): bflow's defaults (`peer_problems` as the
default rows of peer_nosnoc.py call it), bflow's defaults with `--early-polish-sigma 0` (the
homotopy to its final sigma and one final polish) and nosnoc's defaults (peer_nosnoc.py's worker
with the default rows' case dictionaries, N changed). Every run is a process of its own with one
BLAS thread; CPU is the CPU time each program reports (cpu_s: the tool's calls, the harness's
reading of IPOPT's logs left out), and a row keeps the median over
every run of a configuration in the JSON (iterations and optima are the same in every run). The
JSON is written after every run and a later call resumes it (a sweep tags its runs), so --repeat
can be raised later. Usage (with the peers environment's Python):

    python bench/peers/ocp_sweep.py [--binary build/bench/peer_problems] [--repeat 3]
        [--out bench/results/peers/ocp_sweep.json] [--stop-at HH:MM] [--report-only]

The markdown table goes to stdout.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time

import peer_nosnoc
import peers_common as common

TURBO_CAR_T = 40.0 / 3.0
TURBO_CAR_N = tuple(range(3, 26))
BRAKING_BLOCK_N = tuple(range(4, 26))
FORMULATIONS = ("step", "stewart")
CONFIGS = ("bflow-default", "bflow-no-early-polish", "nosnoc-default")
# The configurations repeated up to --repeat times (median CPU kept); the other runs once.
REPEATED = ("bflow-default", "nosnoc-default")
# bflow's default optimum worse than nosnoc's by more than this (relative) is flagged.
WORSE_RELATIVE = 1e-6


def sweep_cases():
    """The default rows' case dictionaries of peer_nosnoc.py with N changed."""
    out = []
    for problem, sizes in (("turbo-car", TURBO_CAR_N), ("braking-block", BRAKING_BLOCK_N)):
        rho_h = 0.0 if problem == "turbo-car" else 1.0
        for formulation in FORMULATIONS:
            for n in sizes:
                out.append({"problem": problem, "formulation": formulation, "N_FE": 3,
                            "n_s": 2, "N": n, "rho_h": rho_h})
    return out


def case_key(case):
    return f"{case['problem']}/{case['formulation']}/N={case['N']}"


def bflow_command(binary, case, config):
    cmd = peer_nosnoc.bflow_command(binary, case, "default")
    if config == "bflow-no-early-polish":
        cmd += ["--early-polish-sigma", "0"]
    return cmd


def nosnoc_command(python, case):
    job = json.dumps({"case": case, "setting": "default"})
    return [python, os.path.abspath(peer_nosnoc.__file__), "--worker", job]


def command(config, case, binary, python):
    if config == "nosnoc-default":
        return nosnoc_command(python, case)
    return bflow_command(binary, case, config)


def optimum(case, result):
    key = "T" if case["problem"] == "turbo-car" else "objective"
    value = result.get(key)
    return float(value) if value is not None else None


def exact_optimum(case, result):
    if case["problem"] == "turbo-car":
        return TURBO_CAR_T
    if result.get("exact") is not None:
        return float(result["exact"])
    return 2 * math.sqrt(5) + math.asinh(2) - 4


def summarise(case, config, result, load):
    """The fields of one run kept in the JSON."""
    nlps = result.get("nlps") or []
    value = optimum(case, result)
    exact = exact_optimum(case, result)
    run = {
        "status": result.get("status"),
        "message": result.get("message"),
        "iterations": (result.get("ipopt") or {}).get("iterations"),
        "nlps": len(nlps),
        "nlp_iterations": [n.get("iterations") for n in nlps],
        "nlp_sigma": [n.get("sigma") for n in nlps],
        "nlp_status": [n.get("status") for n in nlps],
        "cpu_s": result.get("cpu_s"),
        "wall_s": result.get("wall_s"),
        "solve_cpu_s": result.get("solve_cpu_s"),
        "optimum": value,
        "exact": exact,
        "error": abs(value - exact) if value is not None else None,
        "max_complementarity": result.get("max_complementarity"),
        "load_average_before": load,
    }
    if config != "nosnoc-default":
        run["polish"] = [bool(n.get("polish")) for n in nlps]
        run["polished"] = result.get("polished")
        run["switch_times"] = result.get("switch_times")
        for key in ("notes", "decisions", "homotopy_notes"):
            if key in result:
                run[key] = result[key]
    else:
        run["nosnoc_status"] = result.get("nosnoc_status")
        run["versions"] = result.get("versions")
    return run


def median_run(runs):
    """The run with the median CPU time (an error run if any failed)."""
    for r in runs:
        if r.get("status") == "error":
            return r
    ordered = sorted(runs, key=lambda r: r.get("cpu_s") or 0.0)
    return ordered[(len(ordered) - 1) // 2]


def rows_of(data):
    """One row per case: the kept run of each configuration and the comparisons."""
    rows = []
    for case in sweep_cases():
        entry = data["runs"].get(case_key(case))
        if not entry:
            continue
        row = {"case": case, "key": case_key(case)}
        for config in CONFIGS:
            runs = entry.get(config) or []
            if runs:
                kept = dict(median_run(runs))
                kept["runs_cpu_s"] = [r.get("cpu_s") for r in runs]
                kept["median_cpu_s"] = common.median([r.get("cpu_s") for r in runs])
                row[config] = kept
        b, e, n = (row.get(c) for c in CONFIGS)
        flags = []
        if b is not None and b.get("status") != "solved":
            flags.append(f"bflow status {b.get('status')}")
        if b and n and b.get("median_cpu_s") and n.get("median_cpu_s"):
            row["cpu_ratio"] = b["median_cpu_s"] / n["median_cpu_s"]
            by_sweep = {}
            for sweep in sorted({r.get("sweep") for c in REPEATED for r in entry[c]
                                 if r.get("sweep") is not None}):
                cb = common.median([r["cpu_s"] for r in entry["bflow-default"]
                                    if r.get("sweep") == sweep])
                cn = common.median([r["cpu_s"] for r in entry["nosnoc-default"]
                                    if r.get("sweep") == sweep])
                if cb and cn:
                    by_sweep[str(sweep)] = cb / cn
            if by_sweep:
                row["cpu_ratio_by_sweep"] = by_sweep
            if b.get("iterations") and n.get("iterations"):
                row["cpu_per_iteration_ratio"] = row["cpu_ratio"] * n["iterations"] / \
                    b["iterations"]
        if b and n and b.get("optimum") is not None and n.get("optimum") is not None:
            diff = b["optimum"] - n["optimum"]
            row["optimum_distance"] = abs(diff)
            row["optimum_relative"] = diff / abs(n["optimum"])
            row["lower"] = "equal" if diff == 0 else ("bflow" if diff < 0 else "nosnoc")
            if row["optimum_relative"] > WORSE_RELATIVE:
                flags.append(f"bflow's optimum {row['optimum_relative']:.2e} (relative) above "
                             f"nosnoc's")
        if b and e and b.get("iterations") is not None and e.get("iterations") is not None:
            row["iterations_saved_by_early_polish"] = e["iterations"] - b["iterations"]
            if e.get("median_cpu_s") and b.get("median_cpu_s"):
                row["cpu_ratio_default_to_no_early_polish"] = \
                    b["median_cpu_s"] / e["median_cpu_s"]
            if b.get("optimum") is not None and e.get("optimum") is not None:
                row["optimum_distance_to_no_early_polish"] = abs(b["optimum"] - e["optimum"])
        row["flags"] = flags
        rows.append(row)
    return rows


def _cells(run, case):
    if run is None:
        return ["—"] * 5
    status = run.get("status") or "—"
    its = f"{run.get('iterations')} ({run.get('nlps')})" if run.get("iterations") is not None \
        else "—"
    cpu = common.fmt(run.get("median_cpu_s"))
    digits = 9 if case["problem"] == "turbo-car" else 8
    value = common.fmt(run.get("optimum"), digits)
    return [status, its, cpu, value, common.fmt(run.get("error"))]


def markdown(data):
    rows = rows_of(data)
    lines = []
    names = {"bflow-default": "bflow", "bflow-no-early-polish": "bflow σ_ep = 0",
             "nosnoc-default": "nosnoc"}
    for problem, title in (("turbo-car", "Turbo car (T* = 40/3 = 13.333333333)"),
                           ("braking-block", "Braking block (J* of the continuous problem)")):
        header = ["N", "form."]
        for config in CONFIGS:
            n = names[config]
            header += [f"{n} status", f"{n} it. (NLPs)", f"{n} CPU s", f"{n} optimum",
                       f"{n} error"]
        header += ["CPU bflow / nosnoc", "per iteration", "distance bflow − nosnoc (lower)",
                   "flags"]
        align = ["---:", "---"] + ["---", "---:", "---:", "---:", "---:"] * 3 + \
            ["---:", "---:", "---:", "---"]
        body = []
        for row in rows:
            case = row["case"]
            if case["problem"] != problem:
                continue
            cells = [str(case["N"]), case["formulation"]]
            for config in CONFIGS:
                cells += _cells(row.get(config), case)
            ratio = f"{row['cpu_ratio']:.2f}" if row.get("cpu_ratio") else "—"
            per_it = f"{row['cpu_per_iteration_ratio']:.2f}" \
                if row.get("cpu_per_iteration_ratio") else "—"
            dist = "—"
            if row.get("optimum_distance") is not None:
                dist = f"{common.fmt(row['optimum_distance'])} ({row['lower']})"
            cells += [ratio, per_it, dist, "; ".join(row["flags"]) or ""]
            body.append(cells)
        lines.append(f"### {title}")
        lines.append("")
        lines.append(common.table(header, body, align))
        lines.append("")
    flagged = [r for r in rows if r["flags"]]
    lines.append("Flagged rows (bflow's default optimum more than 1e-6 relative above nosnoc's, "
                 "or bflow's status not solved):")
    lines.append("")
    if flagged:
        for r in flagged:
            lines.append(f"- {r['key']}: " + "; ".join(r["flags"]))
    else:
        lines.append("- none")
    lines.append("")
    ratios = [r["cpu_ratio"] for r in rows if r.get("cpu_ratio")]
    if ratios:
        geo = math.exp(sum(math.log(x) for x in ratios) / len(ratios))
        lines.append(f"CPU bflow default / nosnoc default (median CPU of the runs, the tools' "
                     f"work without the harness's; 'per iteration': that ratio per IPOPT "
                     f"iteration): at most 1 on "
                     f"{sum(x <= 1 for x in ratios)} of {len(ratios)} rows, geometric mean "
                     f"{geo:.2f}, range {min(ratios):.2f} to {max(ratios):.2f}.")
        lines.append("")
    saved = [r["iterations_saved_by_early_polish"] for r in rows
             if r.get("iterations_saved_by_early_polish") is not None]
    if saved:
        lines.append(f"IPOPT iterations the early polish saved against --early-polish-sigma 0 "
                     f"(σ_ep = 0 minus default, per row): total {sum(saved)}, median "
                     f"{common.median(saved)}, min {min(saved)}, max {max(saved)} over "
                     f"{len(saved)} rows.")
        lines.append("")
    return "\n".join(lines)


def save(data, path):
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(data, f, indent=1)
        f.write("\n")
    os.replace(tmp, path)


def binary_info(binary):
    info = {"path": os.path.abspath(binary)}
    try:
        info["mtime_utc"] = time.strftime("%Y-%m-%d %H:%M:%S UTC",
                                          time.gmtime(os.path.getmtime(binary)))
    except OSError:
        pass
    src = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(binary))))
    try:
        info["source_git"] = subprocess.run(
            ["git", "-C", src, "describe", "--always", "--dirty"], capture_output=True,
            text=True, check=False).stdout.strip() or None
    except OSError:
        pass
    return info


def past(stop_at):
    if not stop_at:
        return False
    hh, mm = (int(x) for x in stop_at.split(":"))
    now = time.gmtime()
    return (now.tm_hour, now.tm_min) >= (hh, mm)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--binary", default=os.path.join(common.ROOT, "build", "bench",
                                                         "peer_problems"))
    parser.add_argument("--python", default=sys.executable,
                        help="the Python with nosnoc for the worker (default: this one)")
    parser.add_argument("--out", default=os.path.join(common.ROOT, "bench", "results", "peers",
                                                      "ocp_sweep.json"))
    parser.add_argument("--repeat", type=int, default=1,
                        help="runs of bflow's and nosnoc's defaults per case (median CPU kept); "
                             "--early-polish-sigma 0 runs once")
    parser.add_argument("--timeout", type=float, default=600.0)
    parser.add_argument("--stop-at", help="HH:MM UTC after which no run is started")
    parser.add_argument("--report-only", action="store_true")
    args = parser.parse_args()

    data = None
    if os.path.exists(args.out):
        with open(args.out) as f:
            data = json.load(f)
    if data is None:
        data = {"description": __doc__.split("\n\n")[0].replace("\n", " "),
                "configurations": {
                    "bflow-default": "peer_problems at its defaults (peer_nosnoc.py's default "
                                     "rows)",
                    "bflow-no-early-polish": "the same with --early-polish-sigma 0",
                    "nosnoc-default": "peer_nosnoc.py --worker with setting default"},
                "exact": {"turbo-car": "T* = 40/3", "braking-block":
                          "J* = 2 sqrt 5 + asinh 2 - 4 (peer_problems' exact field), the "
                          "continuous optimum"},
                "flag_rule": f"bflow's default optimum above nosnoc's by more than "
                             f"{WORSE_RELATIVE:g} relative, or bflow's status not solved",
                "runs": {}, "commands": {}}
    build_dir = os.path.dirname(os.path.dirname(os.path.abspath(args.binary)))
    if not args.report_only:
        data.setdefault("machine", common.machine(build_dir))
        data["binary"] = binary_info(args.binary)
        data["environment"] = dict(common.SINGLE_THREAD)
        sweeps = data.setdefault("sweeps", [])
        sweep = {"index": len(sweeps) + 1, "date": time.strftime("%Y-%m-%d %H:%M:%S UTC",
                                                                  time.gmtime()),
                 "command": " ".join([os.path.basename(args.python)] + sys.argv),
                 "load_average_before": os.getloadavg()[0], "runs": 0}
        sweeps.append(sweep)
        todo = []
        # The first pass runs every configuration once, later passes add the repeats.
        for rep in range(max(args.repeat, 1)):
            for case in sweep_cases():
                for config in CONFIGS:
                    if rep > 0 and config not in REPEATED:
                        continue
                    todo.append((rep, case, config))
        for rep, case, config in todo:
            key = case_key(case)
            entry = data["runs"].setdefault(key, {})
            runs = entry.setdefault(config, [])
            if len(runs) > rep:
                continue
            if past(args.stop_at):
                common.log(f"stop at {args.stop_at} reached, {key} {config} not run")
                break
            cmd = command(config, case, args.binary, args.python)
            shown = [os.path.basename(cmd[0])] + cmd[1:] if config != "nosnoc-default" else \
                ["python", "bench/peers/peer_nosnoc.py"] + cmd[2:]
            data["commands"].setdefault(key, {})[config] = " ".join(
                c if " " not in c else f"'{c}'" for c in shown)
            load = os.getloadavg()[0]
            common.log(f"{key} {config} (run {rep + 1}), load {load:.2f}")
            result = common.run_json(cmd, timeout=args.timeout)
            run = summarise(case, config, result, load)
            run["sweep"] = sweep["index"]
            runs.append(run)
            common.log(f"  {run['status']} {run['iterations']} it {run['nlps']} NLPs "
                       f"{common.fmt(run['cpu_s'])} s optimum {run['optimum']}")
            sweep["runs"] += 1
            sweep["load_average_after"] = os.getloadavg()[0]
            data["rows"] = rows_of(data)
            save(data, args.out)
    data["rows"] = rows_of(data)
    if data["runs"]:
        save(data, args.out)
    print(markdown(data))


if __name__ == "__main__":
    main()
