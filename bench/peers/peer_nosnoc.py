"""bflow against nosnoc (PyPI nosnoc 0.2.0, the Python nosnoc_py on CasADi and IPOPT): FESD
simulation and optimal control on bflow's examples with exact solutions, the same problems stated
in both, the same discretisation, homotopy and IPOPT options ("matched"), and each tool at its own
defaults ("default"). docs/peers.md explains what is measured.

As a comparison of scripts/peers: run(ctx) returns the rows, report(data, ctx) the markdown of
docs/peers.md's generated section (and draws its plots). Run by itself with --worker JOB (a JSON
object) it solves one problem with nosnoc and prints one JSON object: each nosnoc run has a
process of its own (clean CPU time; nosnoc's option dictionary is shared between instances).
"""
import json
import os
import sys
import tempfile
import time

import peers_common as common

NAME = "nosnoc"

# The common settings of the "matched" rows. nosnoc_py 0.2.0 solves every NLP from the previous
# one's primal point with IPOPT's own initialisation (no warm_start_init_point, mu_init 0.1), to
# tol = dual_inf_tol = compl_inf_tol = mu_target = comp_tol / 100, and stops at the first NLP
# whose largest complementarity product is below comp_tol (or at sigma_N); an NLP IPOPT does not
# solve hands its iterate on.
COMP_TOL = 1e-8
MATCHED = {
    "sigma_initial": 1.0,
    "sigma_factor": 0.1,
    "sigma_final": COMP_TOL,
    "complementarity_tolerance": COMP_TOL,
    "ipopt_tol": COMP_TOL * 1e-2,
    "cross_complementarity": "every product of two points of an element (and the previous "
                             "element's end) on its own row",
    "relaxation": "Scholtes, every product <= sigma",
    "polish": False,
    "warm_start": "previous primal point, IPOPT's own initialisation, mu_init 0.1",
    "ipopt": "mu_strategy adaptive, mu_oracle quality-function, bound_relax_factor 0, "
             "acceptable_tol 1e-6 after 15 iterations, max_iter 500, exact Hessian, MUMPS",
    "guess": "x = x0, u = 0, step a = lambda = 1/2 (Stewart theta = 1/2)",
    "state_bounds": "at every collocation stage point",
    "collocation": "the derivative form D (X - x_n) = h F (nosnoc's IrkRepresentation.INTEGRAL "
                   "default writes its rows so), the Jacobian and Hessian structure of the "
                   "entries that are not identically zero (CasADi's symbolic sparsity; bflow's "
                   "probe_sparsity)",
}


def matched_bflow_flags(rho_h, state_bounds=True):
    """state_bounds: the problem bounds its states (nosnoc then bounds them at every stage point,
    and so does bflow; bflow refuses the flag for a problem without state bounds)."""
    tol = MATCHED["ipopt_tol"]
    flags = [
        "--cross", "point-pairs", "--sigma-initial", "1", "--sigma-factor", "0.1",
        "--sigma-final", repr(COMP_TOL), "--complementarity-tolerance", repr(COMP_TOL),
        "--stop-at-complementarity", "--nlp-tolerance", repr(tol),
        "--intermediate-tolerance-factor", "0", "--step-deviation-weight", repr(rho_h),
        "--no-polish", "--warm-start", "cold", "--later-mu-init", "0.1",
        "--acceptable-tolerance", "1e-6", "--acceptable-iterations", "15",
        "--max-nlp-iterations", "500", "--continue-after-failure", "--nosnoc-guess",
        "--collocation-form", "derivative", "--probe-sparsity",
        f"--ipopt-num=dual_inf_tol={tol!r}", f"--ipopt-num=compl_inf_tol={tol!r}",
        f"--ipopt-num=mu_target={tol!r}", "--ipopt-str=mu_oracle=quality-function",
    ]
    return flags + (["--x-bounds-at-stage-points"] if state_bounds else [])


# The problems. rho_h: the weight of nosnoc's HEURISTIC_MEAN step equilibration,
# rho_h sum (h - h0)^2 with h in units of time, which bflow's step_deviation_weight states the
# same way; the time-optimal turbo car has none in the matched rows, because nosnoc's h are there
# fractions of the free horizon and bflow's physical lengths (the weights would differ by T^2).
def cases(quick):
    out = []

    def add(problem, formulation, **kw):
        c = {"problem": problem, "formulation": formulation, "N_FE": 3, "n_s": 2}
        c.update(kw)
        out.append(c)

    if quick:
        add("sliding-enter", "step", N_sim=4, T=1.0, rho_h=1.0)
        add("irma", "step", N_sim=10, T=50.0, rho_h=1.0)
        add("braking-block", "step", N=10, rho_h=1.0)
        add("turbo-car", "step", N=5, rho_h=0.0)
        return out
    for formulation in ("step", "stewart"):
        add("sliding-enter", formulation, N_sim=4, T=1.0, rho_h=1.0)
    add("irma", "step", N_sim=20, T=100.0, rho_h=1.0)
    for formulation in ("step", "stewart"):
        for n in (10, 20):
            add("braking-block", formulation, N=n, rho_h=1.0)
    for formulation in ("step", "stewart"):
        for n in (5, 10):
            add("turbo-car", formulation, N=n, rho_h=0.0)
    return out


def is_simulation(case):
    return case["problem"] in ("irma", "sliding-enter")


def case_label(case):
    size = f"N_sim = {case['N_sim']}, T = {case['T']:g}" if is_simulation(case) \
        else f"N = {case['N']}"
    return f"{case['problem']} ({case['formulation']}, {size})"


def bflow_command(binary, case, setting):
    cmd = [binary, "--problem", case["problem"], "--formulation", case["formulation"],
           "--elements", str(case["N_FE"]), "--collocation-stages", str(case["n_s"])]
    if is_simulation(case):
        cmd += ["--steps", str(case["N_sim"]), "--horizon", repr(case["T"])]
    else:
        cmd += ["--stages", str(case["N"])]
    if setting == "matched":
        # The braking block has no state bounds.
        cmd += matched_bflow_flags(case["rho_h"], case["problem"] != "braking-block")
    elif is_simulation(case):
        cmd += ["--solver", "fesd"]  # fesd_simulate with its own rules (Newton first)
    return cmd


# ---------------------------------------------------------------------------------------------
# The nosnoc side (runs in the worker process).

def nosnoc_model(case):
    """The problem in nosnoc's terms: (model, ocp or None, terminal_time, exact data)."""
    import casadi as ca
    import numpy as np
    import nosnoc

    p = case["problem"]
    if p == "braking-block":
        # v' in u - sign(v): f1 for v > 0, f2 for v < 0 (bflow: v' = u + 1 - 2a, a in step(v)).
        x = ca.SX.sym("x", 2)
        u = ca.SX.sym("u", 1)
        F = [ca.horzcat(ca.vertcat(x[1], u - 1), ca.vertcat(x[1], u + 1))]
        model = nosnoc.NosnocModel(x=x, F=F, c=[x[1]], S=[np.array([[1], [-1]])],
                                   x0=np.array([0.0, 2.0]), u=u, name="braking_block")
        ocp = nosnoc.NosnocOcp(f_q=x[1] ** 2 + u ** 2)
        return model, ocp, 3.0
    if p == "turbo-car":
        # Time-optimal by time scaling, as bflow: T a global unknown, the dynamics T f on the
        # unit horizon (nosnoc 0.2.0's GLOBAL speed of time does not build: add_variables).
        x = ca.SX.sym("x", 2)
        u = ca.SX.sym("u", 1)
        T = ca.SX.sym("T", 1)
        F = [ca.horzcat(T * ca.vertcat(x[1], u), T * ca.vertcat(x[1], 3 * u))]
        model = nosnoc.NosnocModel(x=x, F=F, c=[x[1] - 10], S=[np.array([[-1], [1]])],
                                   x0=np.array([0.0, 0.0]), u=u, v_global=T, name="turbo_car")
        ocp = nosnoc.NosnocOcp(lbu=np.array([-5.0]), ubu=np.array([5.0]),
                               lbx=np.array([-ca.inf, -20.0]), ubx=np.array([ca.inf, 20.0]),
                               g_terminal=ca.vertcat(x[0] - 200, x[1]), f_terminal=T,
                               lbv_global=np.array([15.0 * 1e-9]), ubv_global=np.array([ca.inf]),
                               v_global_guess=np.array([15.0]))
        return model, ocp, 1.0
    if p == "irma":
        # [F] (50) as a general step inclusion in alpha (nosnoc's examples/Acary2014/irma.py
        # without its lifting, switch on), as bflow's Irma.
        x = ca.SX.sym("x", 5)
        a = ca.SX.sym("alpha", 7)
        c = [ca.vertcat(x[0] - 0.01, x[1] - 0.01, x[1] - 0.06, x[1] - 0.08, x[2] - 0.035,
                        x[3] - 0.04, x[4] - 0.01)]
        f = ca.vertcat(-0.05 * x[0] + 1.1e-4 + 9e-4 * a[5],
                       -0.04 * x[1] + 3e-4 + 0.15 * a[0],
                       -0.05 * x[2] + 6e-4 + 0.018 * a[2],
                       -0.02 * x[3] + 5e-4 * a[1] + 0.03 * a[1] * (1 - a[4]),
                       -0.6 * x[4] + 7.5e-4 + 0.015 * a[3])
        model = nosnoc.NosnocModel(x=x, f_x=[f], alpha=[a], c=c,
                                   x0=np.array([0.011, 0.09, 0.04, 0.05, 0.015]), name="irma")
        return model, None, case["T"] / case["N_sim"]
    if p == "sliding-enter":
        # x' in -sign(x) + 0.2 sin 5t with the clock t as a state.
        x = ca.SX.sym("x", 2)
        drift = 0.2 * ca.sin(5 * x[1])
        F = [ca.horzcat(ca.vertcat(-1 + drift, 1), ca.vertcat(1 + drift, 1))]
        model = nosnoc.NosnocModel(x=x, F=F, c=[x[0]], S=[np.array([[1], [-1]])],
                                   x0=np.array([0.5, 0.0]), name="sliding_enter")
        return model, None, case["T"] / case["N_sim"]
    raise ValueError(p)


class RecordingSolver:
    """Stands in for the CasADi solver inside NosnocSolver and keeps, for every NLP, IPOPT's
    statistics and the complementarity residual (nosnoc keeps only the last NLP's)."""

    def __init__(self, solver, problem, sigma_of_p):
        self.solver = solver
        self.problem = problem
        self.sigma_of_p = sigma_of_p
        self.nlps = []
        self.step = 0

    def __call__(self, **kw):
        sol = self.solver(**kw)
        st = self.solver.stats()
        w = sol["x"]
        self.nlps.append({
            "step": self.step,
            "sigma": float(self.sigma_of_p(kw["p"])),
            "iterations": int(st["iter_count"]),
            "status": st["return_status"],
            "complementarity": float(self.problem.comp_res(w, kw["p"])),
            "nlp_objective": float(sol["f"]),
            "cpu_s": float(st["t_proc_total"]),
            "wall_s": float(st["t_wall_total"]),
            "callbacks_cpu_s": float(sum(st.get(f"t_proc_nlp_{k}", 0.0)
                                         for k in ("f", "g", "grad_f", "jac_g", "hess_l"))),
        })
        return sol

    def stats(self):
        return self.solver.stats()


def nosnoc_options(case, setting, log_path):
    import nosnoc

    o = nosnoc.NosnocOpts()
    o.n_s = case["n_s"]
    o.N_finite_elements = case["N_FE"]
    o.irk_scheme = nosnoc.IrkSchemes.RADAU_IIA
    o.pss_mode = nosnoc.PssMode.STEP if case["formulation"] == "step" else nosnoc.PssMode.STEWART
    o.N_stages = 1 if is_simulation(case) else case["N"]
    o.print_level = 0
    if setting == "matched":
        modes = nosnoc.CrossComplementarityMode
        o.cross_comp_mode = modes.COMPLEMENT_ALL_STAGE_VALUES_WITH_EACH_OTHER
        o.mpcc_mode = nosnoc.MpccMode.SCHOLTES_INEQ
        o.step_equilibration = nosnoc.StepEquilibrationMode.HEURISTIC_MEAN
        o.rho_h = case["rho_h"]
        o.comp_tol = COMP_TOL
        o.sigma_0 = MATCHED["sigma_initial"]
        o.sigma_N = MATCHED["sigma_final"]
        o.homotopy_update_slope = MATCHED["sigma_factor"]
        o.homotopy_update_rule = nosnoc.HomotopyUpdateRule.LINEAR
        o.do_polishing_step = False
        o.nlp_max_iter = 500
    ipopt = o.opts_casadi_nlp["ipopt"]
    ipopt["output_file"] = log_path
    ipopt["file_print_level"] = 6
    ipopt["print_timing_statistics"] = "yes"
    return o


def step_penalty(opts, h, terminal_time):
    """The step equilibration term of nosnoc's objective at the element lengths h."""
    import nosnoc

    n, nfe = opts.N_stages, opts.N_finite_elements
    if opts.step_equilibration == nosnoc.StepEquilibrationMode.HEURISTIC_MEAN:
        h0 = terminal_time / (n * nfe)
        return opts.rho_h * sum((hi - h0) ** 2 for hi in h)
    if opts.step_equilibration == nosnoc.StepEquilibrationMode.HEURISTIC_DELTA:
        return opts.rho_h * sum((h[k * nfe + i] - h[k * nfe + i - 1]) ** 2
                                for k in range(n) for i in range(1, nfe))
    raise ValueError(opts.step_equilibration)


def worker(job):
    import casadi
    import numpy as np
    import nosnoc
    from importlib import metadata

    case, setting = job["case"], job["setting"]
    # nosnoc prints its warnings on stdout, which carries this process's JSON.
    stdout, sys.stdout = sys.stdout, sys.stderr
    handle, log_path = tempfile.mkstemp(prefix="nosnoc_ipopt_", suffix=".log")
    os.close(handle)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    model, ocp, terminal_time = nosnoc_model(case)
    opts = nosnoc_options(case, setting, log_path)
    # Further IPOPT options of the job's (perturb_paths.py), over nosnoc's and the harness's.
    opts.opts_casadi_nlp["ipopt"].update(job.get("ipopt") or {})
    opts.terminal_time = terminal_time
    solver = nosnoc.NosnocSolver(opts, model, ocp)
    problem = solver.problem
    n_p_stages = problem.model.p_val_ctrl_stages.size
    recorder = RecordingSolver(solver.solver, problem, lambda p: np.asarray(p).ravel()[n_p_stages])
    solver.solver = recorder
    setup_cpu = time.process_time() - cpu0
    out = {"tool": "nosnoc", "problem": case["problem"], "formulation": case["formulation"]}
    if is_simulation(case):
        looper = nosnoc.NosnocSimLooper(solver, model.x0, case["N_sim"], print_level=0)

        # Number the NLPs by integration step.
        original_solve = solver.solve

        def solve_step():
            result = original_solve()
            recorder.step += 1
            return result

        solver.solve = solve_step
        looper.run()
        res = looper.get_results()
        x_all = np.array(res["X_sim"])
        x_stages = x_all[::case["N_FE"]]
        out["x_T"] = x_all[-1].tolist()
        out["stage_times"] = [k * terminal_time for k in range(case["N_sim"] + 1)]
        statuses = [str(s) for s in res["status"]]
        out["objective"] = None
        out["T"] = case["T"]
    else:
        res = solver.solve()
        w = res["w_sol"]
        x_traj = np.array(res["x_traj"])
        x_stages = x_traj[::case["N_FE"]]
        p_val = solver.p_val
        h = np.asarray(w[problem.ind_h]).ravel()
        cost = float(problem.cost_fun(w, p_val))
        if case["problem"] == "turbo-car":
            T = float(np.asarray(res["v_global"]).ravel()[0])
            out["objective"] = T
            out["T"] = T
            out["stage_times"] = [T * t for t in res["t_grid_u"]]
        else:
            out["objective"] = cost - step_penalty(opts, h, terminal_time)
            out["T"] = terminal_time
            out["stage_times"] = list(map(float, res["t_grid_u"]))
        out["nlp_objective"] = cost
        out["u"] = [np.asarray(u).ravel().tolist() for u in res["u_list"]]
        statuses = [str(res["status"])]
    cpu = time.process_time() - cpu0
    wall = time.perf_counter() - wall0
    nlps = recorder.nlps
    out["x_stages"] = x_stages.tolist()
    last_per_step = {}
    for n in nlps:
        last_per_step[n["step"]] = n
    ok = all(n["status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
             for n in last_per_step.values())
    comp = max((n["complementarity"] for n in last_per_step.values()), default=None)
    if not ok:
        bad = [n for n in last_per_step.values()
               if n["status"] not in ("Solve_Succeeded", "Solved_To_Acceptable_Level")][0]
        out["status"] = "nlp_failed"
        out["message"] = f"step {bad['step']}: IPOPT {bad['status']} at sigma {bad['sigma']:g}"
    elif comp is not None and comp > opts.comp_tol:
        out["status"] = "complementarity_not_reached"
        out["message"] = f"complementarity {comp:.3g} above {opts.comp_tol:g}"
    elif any(n["status"] == "Solved_To_Acceptable_Level" for n in last_per_step.values()):
        # nosnoc counts it as solved; bflow's status says so (its KKT error above tol).
        out["status"] = "acceptable_only"
        out["message"] = "IPOPT solved the last NLP only to its acceptable level"
    else:
        out["status"] = "solved"
        out["message"] = ""
    out["nosnoc_status"] = statuses
    out["max_complementarity"] = comp
    out["nlps"] = nlps
    out["solve_cpu_s"] = sum(n["cpu_s"] for n in nlps)
    out["setup_cpu_s"] = setup_cpu
    out["cpu_s"] = cpu
    out["wall_s"] = wall
    harness0 = time.process_time()
    ipopt = common.read_ipopt_log(log_path)
    # Reading IPOPT's log is the harness's, outside cpu_s (as peer_problems' harness_cpu_s).
    out["harness_cpu_s"] = time.process_time() - harness0
    ipopt["iterations"] = sum(n["iterations"] for n in nlps)
    # CasADi times its callbacks to the microsecond; IPOPT's timing statistics print
    # milliseconds per NLP.
    ipopt["callbacks_cpu_s"] = sum(n["callbacks_cpu_s"] for n in nlps)
    out["ipopt"] = ipopt
    out["unknowns"] = int(problem.w.shape[0])
    out["constraints"] = int(problem.g.shape[0])
    out["versions"] = {"nosnoc": metadata.version("nosnoc"), "casadi": casadi.__version__,
                       "ipopt": ipopt["version"]}
    out["settings_applied"] = {
        "cross_comp_mode": opts.cross_comp_mode.name, "step_equilibration":
            opts.step_equilibration.name, "rho_h": opts.rho_h, "comp_tol": opts.comp_tol,
        "sigma_0": opts.sigma_0, "sigma_N": opts.sigma_N,
        "homotopy_update_slope": opts.homotopy_update_slope,
        "homotopy_update_rule": opts.homotopy_update_rule.name,
        "max_iter_homotopy": opts.max_iter_homotopy,
        "do_polishing_step": opts.do_polishing_step,
        "ipopt": {k: v for k, v in opts.opts_casadi_nlp["ipopt"].items()
                  if k not in ("output_file", "file_print_level", "print_timing_statistics")}}
    os.remove(log_path)
    sys.stdout = stdout
    print(json.dumps(out))


# ---------------------------------------------------------------------------------------------
# The driver side.

def run_nosnoc(case, setting, python, timeout):
    job = json.dumps({"case": case, "setting": setting})
    return common.run_json([python, os.path.abspath(__file__), "--worker", job], timeout=timeout)


def _row(case, setting, tool, version, settings, result, exact):
    row = {"problem": case["problem"], "case": case_label(case), "formulation": case["formulation"],
           "setting": setting, "tool": tool, "version": version, "settings": settings}
    row.update({k: case[k] for k in ("N", "N_sim", "T", "N_FE", "n_s") if k in case})
    for key in ("solver", "status", "message", "objective", "x_T", "max_complementarity",
                "stage_times", "x_stages", "u", "switch_times", "nlps", "unknowns", "constraints"):
        if key in result:
            row[key] = result[key]
    if not is_simulation(case):
        row["T"] = result.get("T")
    row["cpu_s"] = result.get("cpu_s")
    row["wall_s"] = result.get("wall_s")
    row["solve_cpu_s"] = result.get("solve_cpu_s")
    row["setup_cpu_s"] = result.get("setup_cpu_s")
    row["harness_cpu_s"] = result.get("harness_cpu_s")
    ipopt = result.get("ipopt", {})
    row["ipopt"] = ipopt
    row["iterations"] = ipopt.get("iterations")
    row["nlp_iterations"] = [n["iterations"] for n in result.get("nlps", [])]
    if row["iterations"] and row.get("solve_cpu_s"):
        row["cpu_per_iteration_s"] = row["solve_cpu_s"] / row["iterations"]
    row["split_ms_per_iteration"] = _split(row)
    # The error against the problem's exact solution: the optimum (turbo car: T) for an OCP,
    # max |x(T) - x*(T)| for a simulation.
    if result.get("status") == "error":
        row["error"] = None
    elif is_simulation(case):
        row["exact"] = exact["x"]
        xt = result.get("x_T")
        row["error"] = max(abs(a - b) for a, b in zip(xt, exact["x"])) \
            if xt and exact["x"] else None
    else:
        row["exact"] = exact["objective"]
        value = result.get("T") if case["problem"] == "turbo-car" else result.get("objective")
        row["error"] = abs(value - exact["objective"]) if value is not None else None
    return row


def run(ctx):
    rows = []
    for case in cases(ctx.quick):
        for setting in ("matched", "default"):
            label = f"{case_label(case)}, {setting}"
            bflow_runs, nosnoc_runs = [], []
            for rep in range(ctx.repeat):
                common.log(f"  {label}: bflow (run {rep + 1} of {ctx.repeat})")
                bflow_runs.append(common.run_json(bflow_command(ctx.bflow, case, setting),
                                                  timeout=ctx.timeout))
                common.log(f"  {label}: nosnoc (run {rep + 1} of {ctx.repeat})")
                nosnoc_runs.append(run_nosnoc(case, setting, sys.executable, ctx.timeout))
            b, n = _median_run(bflow_runs), _median_run(nosnoc_runs)
            if b.get("status") == "error":
                exact = None
            elif is_simulation(case):
                exact = {"x": b["exact"], "x_stages": b.get("exact_x_stages")}
            else:
                exact = {"objective": b["exact"]}
            if exact is None:
                exact = _exact_fallback(case)
            b_settings = {"flags": " ".join(bflow_command("peer_problems", case, setting)[1:])}
            n_settings = n.get("settings_applied", {})
            versions = n.get("versions", {})
            rb = _row(case, setting, "bflow", ctx.bflow_version, b_settings, b, exact)
            rn = _row(case, setting, "nosnoc",
                      f"nosnoc {versions.get('nosnoc')}, CasADi {versions.get('casadi')}, "
                      f"{versions.get('ipopt')}", n_settings, n, exact)
            rb["blas"] = b.get("blas")
            for r, runs in ((rb, bflow_runs), (rn, nosnoc_runs)):
                r["runs_cpu_s"] = [x.get("cpu_s") for x in runs]
            _compare(rb, rn, case)
            rows += [rb, rn]
            common.log(f"    bflow {rb.get('status')} {common.fmt(rb.get('cpu_s'))} s, "
                       f"nosnoc {rn.get('status')} {common.fmt(rn.get('cpu_s'))} s")
    return rows


def _median_run(runs):
    """The run whose CPU time is the median (iterations and results are the same in every run;
    the first failed run if any failed)."""
    for r in runs:
        if r.get("status") == "error":
            return r
    ordered = sorted(runs, key=lambda r: r.get("cpu_s") or 0.0)
    return ordered[len(ordered) // 2]


def _exact_fallback(case):
    import math
    if case["problem"] == "braking-block":
        return {"objective": 2 * math.sqrt(5) + math.asinh(2) - 4}
    if case["problem"] == "turbo-car":
        return {"objective": 40.0 / 3.0}
    return {"x": None}


def _compare(rb, rn, case):
    """Distances between the two solutions and the ratios bflow / nosnoc."""
    d = common.max_distance(rb.get("x_stages"), rn.get("x_stages"))
    for r in (rb, rn):
        r["distance_x"] = d
        if case["problem"] == "turbo-car" and rb.get("T") is not None and rn.get("T") is not None:
            r["distance_T"] = abs(rb["T"] - rn["T"])
    for key in ("cpu_s", "solve_cpu_s", "cpu_per_iteration_s"):
        if rb.get(key) and rn.get(key):
            rb[f"ratio_{key}"] = rb[key] / rn[key]
    if rb.get("iterations") and rn.get("iterations"):
        rb["ratio_iterations"] = rb["iterations"] / rn["iterations"]


# ---------------------------------------------------------------------------------------------
# The report.

def _split(row):
    """ms per IPOPT iteration: function and derivative evaluations (CasADi's callback timers for
    nosnoc, IPOPT's for bflow), KKT factorisations, back-solves and the rest of the NLP solves
    (IPOPT's own work and the caller's), and MUMPS factorisations per iteration."""
    ip = row.get("ipopt") or {}
    it = row.get("iterations") or 0
    if not it or row.get("solve_cpu_s") is None or "factorization_cpu_s" not in ip:
        return None
    evaluations = ip.get("callbacks_cpu_s", ip.get("functions_cpu_s", 0.0))
    parts = {"evaluations": evaluations, "factorization": ip["factorization_cpu_s"],
             "back_solves": ip.get("back_solve_cpu_s", 0.0)}
    parts["rest"] = row["solve_cpu_s"] - sum(parts.values())
    out = {k: 1e3 * v / it for k, v in parts.items()}
    out["factorizations"] = (ip.get("factorizations") or 0) / it
    out["ms_per_factorization"] = 1e3 * ip["factorization_cpu_s"] / ip["factorizations"] \
        if ip.get("factorizations") else None
    return out


def _iterations_text(r):
    its = r.get("nlp_iterations") or []
    if r.get("N_sim"):
        if r.get("solver") == "fesd" or (its and not any(n.get("sigma") for n in r["nlps"])):
            total = r.get("iterations") or 0
            return f"Newton, {total} IPOPT iterations" if total else "Newton, no NLP"
        return f"{len(its)} NLPs over {r['N_sim']} steps: {r.get('iterations')}"
    if not its:
        return "—"
    polish = any(n.get("polish") for n in r.get("nlps", []))
    return f"{len(its)}{' (the last a polish)' if polish else ''}: " + \
        ", ".join(str(i) for i in its)


def _value_text(r):
    if r["problem"] == "turbo-car":
        return f"T = {common.fmt(r.get('T'), 8)}"
    if r.get("objective") is not None:
        return f"J = {common.fmt(r.get('objective'), 7)}"
    if r.get("x_T"):
        return "x(T) = (" + ", ".join(common.fmt(v, 4) for v in r["x_T"]) + ")"
    return "—"


def _kkt_nonzeros(row):
    ip = row.get("ipopt") or {}
    if ip.get("jacobian_nonzeros") is None or ip.get("hessian_nonzeros") is None:
        return None
    return ip["jacobian_nonzeros"] + ip["hessian_nonzeros"]


def factorisation_fit(rows):
    """Per tool, the least-squares line ms per MUMPS factorisation = a + b nnz over every row with
    IPOPT solves, nnz the Jacobian's and the Hessian's nonzeros (IPOPT's count): the cost of one
    factorisation of a KKT matrix of a given size, whoever built it."""
    out = {}
    for tool in ("bflow", "nosnoc"):
        pts = [(_kkt_nonzeros(r), r["split_ms_per_iteration"]["ms_per_factorization"])
               for r in rows if r["tool"] == tool and r.get("split_ms_per_iteration")
               and r["split_ms_per_iteration"].get("ms_per_factorization")
               and _kkt_nonzeros(r)]
        if len(pts) < 2:
            continue
        n = len(pts)
        mx = sum(p[0] for p in pts) / n
        my = sum(p[1] for p in pts) / n
        sxx = sum((p[0] - mx) ** 2 for p in pts)
        if sxx == 0:
            continue
        b = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx
        a = my - b * mx
        rms = (sum((a + b * p[0] - p[1]) ** 2 for p in pts) / n) ** 0.5
        out[tool] = {"a_ms": a, "b_ms_per_1000": 1e3 * b, "points": pts, "rms_ms": rms}
    return out


def _group_labels(rows):
    """The problem and settings on the first row of each group of a table, blank below it."""
    last = [None]

    def labels(r):
        key = (r["case"], r["setting"])
        if key == last[0]:
            return ["", ""]
        last[0] = key
        return [r["case"], r["setting"]]

    return labels


def report(data, ctx):
    rows = data["rows"]
    m = data["machine"]
    lines = []
    lines.append(f"Run of {m.get('date')} ({'quick' if data.get('quick') else 'full'}, "
                 f"{data.get('minutes')} min; {data.get('repeat')} run(s) per row, the one with "
                 f"the median CPU time kept) on {m.get('cpu')}, {m.get('cores')} cores, "
                 f"{m.get('os')}; bflow {m.get('git')} built by {m.get('compiler')} "
                 f"({m.get('build_type')}), IPOPT {m.get('bflow_ipopt')} with "
                 f"{m.get('bflow_mumps')}; Python {m.get('python')}; load average "
                 f"{m.get('load_average_before'):.2f} before the run. "
                 f"JSON: `{'out' if data.get('quick') else 'bench/results'}/peers/{NAME}.json`.")
    lines.append("")
    nos = next((r for r in rows if r["tool"] == "nosnoc" and r.get("version")), None)
    if nos:
        lines.append(f"Peer: {nos['version']}.")
        lines.append("")
    header = ["problem", "settings", "tool", "status", "NLPs: IPOPT iterations each",
              "CPU total", "per iteration", "optimum", "error", "distance",
              "bflow / nosnoc CPU (per iteration)"]
    align = ["---"] * 5 + ["---:"] * 6
    body = []
    labels = _group_labels(rows)
    for r in rows:
        dist = common.fmt(r.get("distance_x"))
        if r.get("distance_T") is not None:
            dist += f", T: {common.fmt(r['distance_T'])}"
        ratio = ""
        if r["tool"] == "bflow" and r.get("ratio_cpu_s"):
            ratio = f"{r['ratio_cpu_s']:.2f}"
            if r.get("ratio_cpu_per_iteration_s"):
                ratio += f" ({r['ratio_cpu_per_iteration_s']:.2f})"
        per_it = r.get("cpu_per_iteration_s")
        body.append([
            *labels(r), r["tool"], r.get("status"), _iterations_text(r),
            f"{common.fmt(r.get('cpu_s'))} s",
            f"{common.fmt(1e3 * per_it)} ms" if per_it else "—", _value_text(r),
            common.fmt(r.get("error")), dist, ratio])
    lines.append(common.table(header, body, align))
    lines.append("")
    lines.append("The NLPs and where an iteration goes (ms per IPOPT iteration over the whole "
                 "run): function and derivative evaluations, KKT factorisations, back-solves, and "
                 "the rest of the NLP solves (IPOPT's own work and the caller's between "
                 "callbacks):")
    lines.append("")
    header = ["problem", "settings", "tool", "variables / constraints (IPOPT)",
              "Jacobian / Hessian nonzeros", "per iteration", "evaluations", "factorisations",
              "back-solves", "rest", "MUMPS factorisations per iteration",
              "ms per factorisation"]
    align = ["---"] * 3 + ["---:"] * 9
    body = []
    labels = _group_labels(rows)
    for r in rows:
        s = r.get("split_ms_per_iteration")
        ip = r.get("ipopt") or {}
        if s is None:
            continue
        cons = (ip.get("equalities") or 0) + (ip.get("inequalities") or 0)
        body.append([*labels(r), r["tool"],
                     f"{ip.get('variables')} / {cons}",
                     f"{ip.get('jacobian_nonzeros')} / {ip.get('hessian_nonzeros')}",
                     f"{common.fmt(1e3 * r['cpu_per_iteration_s'])} ms",
                     f"{common.fmt(s['evaluations'])}", f"{common.fmt(s['factorization'])}",
                     f"{common.fmt(s['back_solves'])}", f"{common.fmt(s['rest'])}",
                     common.fmt(s["factorizations"]), common.fmt(s["ms_per_factorization"])])
    lines.append(common.table(header, body, align))
    lines.append("")
    fit = factorisation_fit(rows)
    if len(fit) == 2:
        fb, fn = fit["bflow"], fit["nosnoc"]
        size = 3000
        at = {t: fit[t]["a_ms"] + fit[t]["b_ms_per_1000"] * size / 1e3 for t in fit}
        lines.append(
            "One MUMPS factorisation against the size of the KKT matrix (nnz: the Jacobian's and "
            "the Hessian's nonzeros as IPOPT counts them), least squares over every row above: "
            f"bflow's IPOPT {fb['a_ms']:.3f} ms + {fb['b_ms_per_1000']:.3f} ms per 1000 "
            f"nonzeros (RMS {fb['rms_ms']:.3f} ms, {len(fb['points'])} rows), nosnoc's "
            f"{fn['a_ms']:.3f} ms + {fn['b_ms_per_1000']:.3f} ms per 1000 (RMS "
            f"{fn['rms_ms']:.3f} ms, {len(fn['points'])} rows); at {size} nonzeros "
            f"{at['bflow']:.2f} against {at['nosnoc']:.2f} ms, "
            f"{at['bflow'] / at['nosnoc']:.1f} times.")
        lines.append("")
    if ctx.plots:
        for name in _plots(rows, ctx):
            lines.append(f"![{name}]({name})")
            lines.append("")
    return "\n".join(lines)


def _plots(rows, ctx):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    matched = [r for r in rows if r["setting"] == "matched" and r.get("split_ms_per_iteration")]
    cases_seen = []
    for r in matched:
        if r["case"] not in cases_seen:
            cases_seen.append(r["case"])
    names = []
    if cases_seen:
        fig, ax = plt.subplots(figsize=(10, 0.55 * len(cases_seen) * 2 + 1.5))
        y, labels = 0, []
        parts = ("evaluations", "factorization", "back_solves", "rest")
        colors = dict(zip(parts, ("#4c72b0", "#dd8452", "#55a868", "#a0a0a0")))
        for case in cases_seen:
            for tool in ("bflow", "nosnoc"):
                r = next((x for x in matched if x["case"] == case and x["tool"] == tool), None)
                if r is None:
                    continue
                s = r["split_ms_per_iteration"]
                left = 0.0
                for part in parts:
                    ax.barh(y, s[part], left=left, color=colors[part])
                    left += s[part]
                labels.append(f"{case} — {tool}")
                y += 1
            y += 0.5
        ticks = []
        t = 0.0
        for case in cases_seen:
            for tool in ("bflow", "nosnoc"):
                if any(x["case"] == case and x["tool"] == tool for x in matched):
                    ticks.append(t)
                    t += 1
            t += 0.5
        ax.set_yticks(ticks)
        ax.set_yticklabels(labels, fontsize=8)
        ax.invert_yaxis()
        ax.set_xlabel("CPU per IPOPT iteration [ms]")
        ax.set_title("Matched settings: where an IPOPT iteration goes")
        from matplotlib.patches import Patch
        ax.legend(handles=[Patch(color=colors[p], label=p.replace("_", "-")) for p in parts],
                  loc="lower right")
        fig.tight_layout()
        name = f"peers_{NAME}_iteration.png"
        fig.savefig(os.path.join(common.DOCS, name), dpi=110)
        plt.close(fig)
        names.append(name)
    fit = factorisation_fit(rows)
    if fit:
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for tool, color, marker in (("bflow", "#4c72b0", "o"), ("nosnoc", "#c44e52", "s")):
            if tool not in fit:
                continue
            f = fit[tool]
            xs = [p[0] for p in f["points"]]
            ax.plot(xs, [p[1] for p in f["points"]], marker, color=color, label=tool)
            grid = [0, max(xs)]
            ax.plot(grid, [f["a_ms"] + f["b_ms_per_1000"] * g / 1e3 for g in grid], "-",
                    color=color, alpha=0.6)
        ax.set_xlabel("KKT matrix: Jacobian + Hessian nonzeros")
        ax.set_ylabel("CPU per MUMPS factorisation [ms]")
        ax.set_title("One factorisation against the matrix's size")
        ax.grid(True, alpha=0.3)
        ax.legend()
        fig.tight_layout()
        name = f"peers_{NAME}_factorisation.png"
        fig.savefig(os.path.join(common.DOCS, name), dpi=110)
        plt.close(fig)
        names.append(name)
    # Error against CPU time, every row (a work-precision view): colour by problem, marker by
    # tool, filled for the matched settings; errors of 0 drawn at 1e-16.
    from matplotlib.lines import Line2D
    fig, ax = plt.subplots(figsize=(8, 5))
    markers = {"bflow": "o", "nosnoc": "s"}
    fill = {"matched": "full", "default": "none"}
    problems = []
    for r in rows:
        if r["problem"] not in problems:
            problems.append(r["problem"])
    palette = ["#4c72b0", "#c44e52", "#55a868", "#8172b2", "#ccb974", "#64b5cd"]
    color = {p: palette[i % len(palette)] for i, p in enumerate(problems)}
    for r in rows:
        if r.get("error") is None or not r.get("cpu_s"):
            continue
        ax.loglog(r["cpu_s"], max(r["error"], 1e-16), marker=markers[r["tool"]],
                  fillstyle=fill[r["setting"]], linestyle="none", color=color[r["problem"]],
                  markersize=7)
    handles = [Line2D([], [], marker="o", color=color[p], linestyle="none", label=p)
               for p in problems]
    handles += [Line2D([], [], marker=markers[t], color="black", fillstyle=fill[st],
                       linestyle="none", label=f"{t}, {st}")
                for t in ("bflow", "nosnoc") for st in ("matched", "default")]
    ax.legend(handles=handles, fontsize=8, ncol=2)
    ax.set_xlabel("CPU time of the run [s]")
    ax.set_ylabel("error against the exact solution (0 drawn at 1e-16)")
    ax.set_title("Error against CPU time, every row")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    name = f"peers_{NAME}_error.png"
    fig.savefig(os.path.join(common.DOCS, name), dpi=110)
    plt.close(fig)
    names.append(name)
    return names


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        worker(json.loads(sys.argv[2]))
    else:
        sys.exit(__doc__)
