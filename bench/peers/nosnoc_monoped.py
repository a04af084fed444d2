#!/usr/bin/env python3
"""The time-freezing hopping monoped of [F] Section 7.2 solved by nosnoc_py (PyPI nosnoc 0.2.0)
with IPOPT and MUMPS, stated as nosnoc's MATLAB files state it.

Two setups (--setup):

  example    nosnoc's MATLAB example examples/time_freezing_monoped_ocp/monoped_ocp.m (its last
             version in github.com/nurkanovic/nosnoc, commit c07d841, 2024-09-17; before
             2024-09-16 at examples/monoped_ocp/monoped_ocp.m): N = 50, no linear solver set
             (MUMPS), IPOPT tol = acceptable_tol = 1e-8, complementarity tolerance 1e-6,
             s in [0.99, 10], cross complementarity mode 3 (FE_STAGE), the reference a spline
             through x0, x_mid = (1.5, 0.6, 0, 0, 1, 0, 0, 0) and the target at t/T = 0, 1/2, 1.
  benchmark  the benchmark behind [F] Figure 10 (benchmarks/time_freezing_monoped_ocp/
             monoped_model.m, same commit) and bflow's `ocp --example monoped` defaults: N = 30,
             tol = acceptable_tol = 1e-5, complementarity tolerance 1e-5, s in [0.99, 100], cross
             complementarity FE_FE, the reference a spline through five knots (two hops); the
             file sets MA27, here MUMPS.

Common to both (the MATLAB files and nosnoc's option defaults at that commit): Radau IIA
n_s = 2, N_FE = 3, T = 3, Heaviside step formulation with the time-freezing lifting of
nosnoc.time_freezing.cls_inelastic_multicontact (theta = (a_q + a_n - b_1, b_2 a_t,
b_2 (1 - a_t)), b = (a_q a_n, (1 - a_q)(1 - a_n))), mu = 0.8, a_n = 200, e = 0, the speed of
time s per control stage multiplying every mode, the stage-wise clock constraint, the
equidistant control grid, step equilibration rho_h sum (h - h0)^2 with rho_h = 1, gamma_h = 1,
Q = diag(1, 1, 10, 1, 1e-6 x 4), Q_T = diag(1e3 x 4, 10 x 4), R = 0.1 I, least squares at the
stage ends weighted by T/N and the terminal term by T/N, |u| <= 100, x in
[-0.5, 3.5] x [0, 10] x [-pi, pi]^2 x [-100, 100]^4 at every stage point, Scholtes relaxation
(inequality) from sigma = 1 by factors 0.1, at most 5 NLPs, stop when the complementarity
residual is below the tolerance; IPOPT: max_iter 10000 per NLP, dual_inf_tol = compl_inf_tol =
1e-12, acceptable_iter 3, bound_relax_factor 0, mu_strategy adaptive, mu_oracle
quality-function, warm_start_init_point yes (each NLP from the previous primal point, every
multiplier 0), MUMPS.

The model is written out here from the MATLAB files' kinematics (robot_model_kinematics.m): the
hip at (q_x, q_z), links along (-sin, -cos) of their absolute angles; M(q) and the bias forces
by Lagrange. --check-model DIR compares them with the CasADi functions M_fun and h_forces_fun
the MATLAB example loads (files of that repository, read at run time only).

Where nosnoc_py 0.2.0's API cannot state the MATLAB problem exactly (printed at the start and
stored in the JSON under "differences"):
  * cross complementarity: nosnoc_py offers (sum of the element's lambdas) * alpha_j per stage
    point (--cross-comp sum, the default; MATLAB's STAGE_FE) and every pair of points
    (--cross-comp all, MATLAB's STAGE_STAGE); MATLAB's FE_STAGE (example) and FE_FE
    (benchmark) are not available.
  * least squares at the stage ends: nosnoc_py integrates its Lagrange term by the Radau
    quadrature. The stage-end error is carried by slack controls e_k (8 per stage) with the
    path constraint e_k = x(t_k)[:8] - x_ref,k at the stage end, and the Lagrange term
    e'Qe + u'Ru, constant on a stage, integrates to (T/N)(e'Qe + u'Ru) wherever sum h = T/N
    (a constraint). --tracking integrated instead integrates (x - x_ref)'Q(x - x_ref).
  * lambda at x(0): nosnoc_py fixes it to its value at x0 (0, all switching functions vanish
    at x0); MATLAB keeps lambda(0), alpha(0) as unknowns with their own complementarity.
  * the complementarity residual nosnoc_py stops on is the largest product over every pair of
    an element's points; MATLAB's is the largest product of its chosen cross-complementarity
    pairs. Both are printed (comp, comp_matlab).
  * the homotopy continues in MATLAB after an unsolved NLP even when the residual is met;
    nosnoc_py stops on the residual alone.

Outputs (--out DIR, --tag NAME): NAME.json (settings, differences, per-NLP table, final state,
hops, the IPOPT log's key lines, the trajectory at every stage point) and NAME_ipopt.log (IPOPT
at print level 5, every NLP).
"""

import argparse
import json
import math
import os
import re
import sys
import time

import casadi as ca
import numpy as np
from scipy.interpolate import CubicSpline

import nosnoc as ns
from nosnoc.solver import get_results_from_primal_vector

# Robot parameters of the MATLAB files (robot_model_parameters.m).
M_HIP, M_THIGH, M_SHANK = 3.975, 1.782, 0.548
L_THIGH, L_SHANK = 0.2, 0.2
S_THIGH, S_SHANK = 0.016, 0.1
I_THIGH, I_SHANK = 0.001, 0.0032
GRAVITY = 9.81
MU, A_N = 0.8, 200.0
T_HORIZON = 3.0
Q_TARGET = np.array([3.0, 0.4, 0.0, 0.0])
X0 = np.array([0.0, 0.4, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])

SETUPS = {
    "example": dict(N=50, tol=1e-8, comp_tol=1e-6, s_max=10.0,
                    matlab_file="examples/time_freezing_monoped_ocp/monoped_ocp.m",
                    matlab_cross_comp="FE_STAGE (cross_comp_mode = 3)",
                    matlab_linear_solver="MUMPS (not set)"),
    "benchmark": dict(N=30, tol=1e-5, comp_tol=1e-5, s_max=100.0,
                      matlab_file="benchmarks/time_freezing_monoped_ocp/monoped_model.m",
                      matlab_cross_comp="FE_FE (cross_comp_mode = 7)",
                      matlab_linear_solver="MA27"),
}
MATLAB_COMMIT = "c07d841"  # github.com/nurkanovic/nosnoc, 2024-09-17


def link(theta):
    return ca.vertcat(-ca.sin(theta), -ca.cos(theta))


def kinematics(q):
    """Points of the MATLAB kinematics: hip (= base), thigh and shank centres, knee, foot."""
    hip = q[0:2]
    thigh = hip + S_THIGH * link(q[2])
    knee = hip + L_THIGH * link(q[2])
    shank = knee + S_SHANK * link(q[2] + q[3])
    foot = knee + L_SHANK * link(q[2] + q[3])
    return hip, thigh, shank, knee, foot


def dynamics(q, v, u):
    """M(q) and f_v(q, v, u) = bias forces + (0, 0, u) by Lagrange."""
    hip, thigh, shank, _, _ = kinematics(q)
    M = ca.SX.zeros(4, 4)
    for m, p in ((M_HIP, hip), (M_THIGH, thigh), (M_SHANK, shank)):
        J = ca.jacobian(p, q)
        M += m * J.T @ J
    e3 = ca.DM([0, 0, 1, 0])
    e34 = ca.DM([0, 0, 1, 1])
    M += I_THIGH * e3 @ e3.T + I_SHANK * e34 @ e34.T
    kinetic = 0.5 * v.T @ M @ v
    potential = GRAVITY * (M_HIP * hip[1] + M_THIGH * thigh[1] + M_SHANK * shank[1])
    coriolis = ca.jacobian(M @ v, q) @ v - ca.gradient(kinetic, q)
    bias = -coriolis - ca.gradient(potential, q)
    return M, bias + ca.vertcat(0, 0, u[0], u[1])


def check_model(directory):
    """Largest differences of M and the bias forces against the MATLAB example's M_fun and
    h_forces_fun at random states."""
    M_ref = ca.Function.load(os.path.join(directory, "M_fun"))
    h_ref = ca.Function.load(os.path.join(directory, "h_forces_fun"))
    q, v = ca.SX.sym("q", 4), ca.SX.sym("v", 4)
    M, f = dynamics(q, v, ca.DM.zeros(2))
    fun = ca.Function("mine", [ca.vertcat(q, v)], [M, f])
    rng = np.random.default_rng(1)
    dm, dh = 0.0, 0.0
    for _ in range(200):
        x = np.concatenate((rng.uniform([-1, 0, -3, -3], [4, 1, 3, 3]), rng.uniform(-10, 10, 4)))
        Mm, fm = (np.array(a) for a in fun(x))
        dm = max(dm, float(np.max(np.abs(Mm - np.array(M_ref(x))))))
        dh = max(dh, float(np.max(np.abs(fm.flatten() - np.array(h_ref(x)).flatten()))))
    return {"M_max_abs_diff": dm, "h_forces_max_abs_diff": dh, "states": 200}


def reference(setup, N):
    """x_ref rows for the control stages 1..N (8 entries) and the terminal target."""
    x_target = np.concatenate((Q_TARGET, np.zeros(4)))
    if setup == "example":
        # interp1([0 0.5 1], [x0, x_mid, x_target]', linspace(0, 1, N), 'spline'): with three
        # knots MATLAB's spline is the parabola through them, as scipy's not-a-knot; stage k
        # (1-based) uses column k, i.e. the value at (k - 1) / (N - 1).
        x_mid = np.array([Q_TARGET[0] / 2, 0.6, 0, 0, Q_TARGET[0] / T_HORIZON, 0, 0, 0])
        spline = CubicSpline([0.0, 0.5, 1.0], np.vstack((X0, x_mid, x_target)),
                             bc_type="not-a-knot")
        return spline(np.linspace(0.0, 1.0, N)), x_target
    # benchmark: interp1([0 .25 .5 .75 1], ..., linspace(0, 1, N + 1), 'spline'), columns
    # 2..N+1: stage k uses the value at k / N.
    knots = [0.0, 0.25, 0.5, 0.75, 1.0]
    vx = Q_TARGET[0] / T_HORIZON
    pts = np.vstack((X0,
                     [Q_TARGET[0] / 4, 0.6, 0, 0, vx, 0, 0, 0],
                     [2 * Q_TARGET[0] / 4, 0.4, 0, 0, vx, 0, 0, 0],
                     [3 * Q_TARGET[0] / 4, 0.6, 0, 0, vx, 0, 0, 0],
                     x_target))
    spline = CubicSpline(knots, pts, bc_type="not-a-knot")
    return spline(np.linspace(0.0, 1.0, N + 1))[1:], x_target


def build(args):
    cfg = SETUPS[args.setup]
    N = args.N if args.N else cfg["N"]

    q, v, t = ca.SX.sym("q", 4), ca.SX.sym("v", 4), ca.SX.sym("t")
    x = ca.vertcat(q, v, t)
    torque, sot, e = ca.SX.sym("torque", 2), ca.SX.sym("s"), ca.SX.sym("e", 8)
    stage_end = args.tracking == "stage-end"
    u = ca.vertcat(torque, sot, e) if stage_end else ca.vertcat(torque, sot)

    M, f_v = dynamics(q, v, torque)
    inv_M = ca.inv(M)  # as the MATLAB files: model.invM = inv(M)
    foot = kinematics(q)[4]
    f_c = foot[1]
    J_n = ca.jacobian(f_c, q).T
    J_t = ca.jacobian(foot[0], q).T
    v_n, v_t = J_n.T @ v, J_t.T @ v
    f_ode = ca.vertcat(v, inv_M @ f_v, 1)
    f_aux_pos = ca.vertcat(ca.SX.zeros(4), inv_M @ (J_n - MU * J_t) * A_N, 0)  # v_t > 0
    f_aux_neg = ca.vertcat(ca.SX.zeros(4), inv_M @ (J_n + MU * J_t) * A_N, 0)  # v_t < 0
    c = [ca.vertcat(f_c, v_n, v_t)]

    x_ref, x_target = reference(args.setup, N)
    p_ref = ca.SX.sym("x_ref", 8)
    Q = np.diag([1.0, 1.0, 10.0, 1.0, 1e-6, 1e-6, 1e-6, 1e-6])
    Q_T = np.diag([1e3, 1e3, 1e3, 1e3, 10.0, 10.0, 10.0, 10.0])
    R = 0.1 * np.eye(2)
    h_stage = T_HORIZON / N

    common = dict(x=x, x0=np.concatenate((X0, [0.0])), u=u, p_time_var=p_ref,
                  p_time_var_val=x_ref, t_var=t)
    if args.formulation == "step":
        alpha = ca.SX.sym("alpha", 3)  # H(f_c), H(v_n), H(v_t)
        theta = ca.SX.sym("theta", 3)
        beta = ca.SX.sym("beta", 2)
        g_z = ca.vertcat(theta - ca.vertcat(alpha[0] + alpha[1] - beta[0],
                                            beta[1] * alpha[2],
                                            beta[1] * (1 - alpha[2])),
                         beta - ca.vertcat(alpha[0] * alpha[1],
                                           (1 - alpha[0]) * (1 - alpha[1])))
        f_x = sot * (theta[0] * f_ode + theta[1] * f_aux_pos + theta[2] * f_aux_neg)
        # z0 as cls_inelastic_multicontact at alpha = 0.5: beta = (1/4, 1/4),
        # theta = (3/4, 1/8, 1/8).
        model = ns.NosnocModel(f_x=[f_x], alpha=[alpha], c=c, z=ca.vertcat(theta, beta),
                               z0=np.array([0.75, 0.125, 0.125, 0.25, 0.25]), g_z=g_z, **common)
    else:
        F = [sot * ca.horzcat(*([f_ode] * 6), f_aux_pos, f_aux_neg)]
        S = [np.array([[1, 1, 1], [1, 1, -1], [1, -1, 1], [1, -1, -1],
                       [-1, 1, 1], [-1, 1, -1], [-1, -1, 1], [-1, -1, -1]])]
        model = ns.NosnocModel(F=F, S=S, c=c, **common)

    inf = np.inf
    lbx = np.array([-0.5, 0.0, -np.pi, -np.pi, -100, -100, -100, -100, -inf])
    ubx = np.array([Q_TARGET[0] + 0.5, 10.0, np.pi, np.pi, 100, 100, 100, 100, inf])
    lbu = [-100.0, -100.0, 0.99]
    ubu = [100.0, 100.0, cfg["s_max"]]
    u_guess = [0.0, 0.0, 1.0]
    x8 = ca.vertcat(q, v)
    if stage_end:
        lbu += [-inf] * 8
        ubu += [inf] * 8
        u_guess += [0.0] * 8
        f_q = e.T @ Q @ e + torque.T @ R @ torque
        g_path = e - (x8 - p_ref)
        path = dict(g_path=g_path, lbg=np.zeros(8), ubg=np.zeros(8))
    else:
        f_q = (x8 - p_ref).T @ Q @ (x8 - p_ref) + torque.T @ R @ torque
        path = {}
    f_T = h_stage * (x8 - x_target).T @ Q_T @ (x8 - x_target)
    ocp = ns.NosnocOcp(lbu=np.array(lbu), ubu=np.array(ubu), u_guess=np.array(u_guess),
                       lbx=lbx, ubx=ubx, f_q=f_q, f_terminal=f_T, **path)

    opts = ns.NosnocOpts()
    opts.pss_mode = ns.PssMode.STEP if args.formulation == "step" else ns.PssMode.STEWART
    opts.irk_scheme = ns.IrkSchemes.RADAU_IIA
    opts.n_s = 2
    opts.N_stages = N
    opts.N_finite_elements = 3
    opts.terminal_time = T_HORIZON
    opts.use_fesd = True
    opts.gamma_h = 1.0
    opts.step_equilibration = ns.StepEquilibrationMode.HEURISTIC_MEAN
    opts.rho_h = 1.0
    opts.cross_comp_mode = (
        ns.CrossComplementarityMode.SUM_LAMBDAS_COMPLEMENT_WITH_EVERY_THETA
        if args.cross_comp == "sum"
        else ns.CrossComplementarityMode.COMPLEMENT_ALL_STAGE_VALUES_WITH_EACH_OTHER)
    opts.mpcc_mode = (ns.MpccMode.ELASTIC_INEQ if args.mpcc_mode == "elastic-ineq"
                      else ns.MpccMode.SCHOLTES_INEQ)
    opts.sigma_0 = 1.0
    opts.homotopy_update_slope = 0.1
    opts.homotopy_update_rule = ns.HomotopyUpdateRule.LINEAR
    opts.max_iter_homotopy = 5
    opts.comp_tol = cfg["comp_tol"]
    opts.sigma_N = min(0.1 * cfg["comp_tol"], 1e-9)
    opts.time_freezing = True
    opts.time_freezing_tolerance = 0.0  # the clock constraint as an equality
    opts.equidistant_control_grid = True
    opts.speed_of_time_variables = ns.SpeedOfTimeVariableMode.NONE  # s is the control u[2]
    opts.initialization_strategy = ns.InitializationStrategy.ALL_XCURRENT_W0_START
    opts.print_level = 0
    ip = opts.opts_casadi_nlp["ipopt"]
    ip.update({"tol": cfg["tol"], "acceptable_tol": cfg["tol"], "acceptable_iter": 3,
               "dual_inf_tol": 1e-12, "compl_inf_tol": 1e-12, "max_iter": args.max_iter,
               "bound_relax_factor": 0.0, "mu_strategy": "adaptive",
               "mu_oracle": "quality-function", "warm_start_init_point": "yes",
               "linear_solver": "mumps", "print_level": 0, "sb": "yes",
               "output_file": args.ipopt_log, "file_print_level": 5})
    opts.opts_casadi_nlp["print_time"] = 0
    return opts, model, ocp, x_ref, N, cfg


def differences(args, cfg):
    d = [
        "cross complementarity: MATLAB " + cfg["matlab_cross_comp"] + "; here nosnoc_py's " +
        ("SUM_LAMBDAS_COMPLEMENT_WITH_EVERY_THETA ((sum of the element's lambdas incl. the "
         "previous end) * alpha_j at each stage point, MATLAB's STAGE_FE)"
         if args.cross_comp == "sum" else
         "COMPLEMENT_ALL_STAGE_VALUES_WITH_EACH_OTHER (every pair, MATLAB's STAGE_STAGE)"),
        "lambda(0) fixed to its value at x0 (0) instead of unknowns lambda(0), alpha(0) with "
        "their own complementarity",
        "stopping residual: nosnoc_py's max over every pair of an element's points (column "
        "comp); MATLAB's max over its cross-complementarity pairs (column comp_matlab)",
        "an unsolved NLP whose residual meets the tolerance ends the homotopy here; MATLAB "
        "would continue",
        "IPOPT 3.14.19 / MUMPS 5.8.2 as bundled by CasADi 3.8.2's wheel; the MATLAB runs used "
        "the CasADi MATLAB build of their day",
    ]
    if args.tracking == "stage-end":
        d.append("stage-end least squares through 8 slack controls per stage, an equality path "
                 "constraint at the stage end and the Radau quadrature of a per-stage constant "
                 "(equal to MATLAB's (T/N) l(x_k, u_k) where sum h = T/N holds)")
    else:
        d.append("least squares integrated by the Radau quadrature over every stage point "
                 "instead of MATLAB's (T/N) l(x_k, u_k) at the stage ends")
    if args.formulation == "stewart":
        d.append("Stewart's formulation with the dense 8-mode sign matrix (nosnoc_py's hopper "
                 "example) instead of the lifted Heaviside step formulation")
    if cfg["matlab_linear_solver"] != "MUMPS (not set)":
        d.append("linear solver MUMPS instead of " + cfg["matlab_linear_solver"])
    return d


def hops(foot_heights, threshold=1e-3):
    """Flight phases that start from the ground: height > threshold after <= threshold."""
    count, grounded = 0, False
    for z in foot_heights:
        if z <= threshold:
            grounded = True
        elif grounded:
            count += 1
            grounded = False
    return count


IPOPT_KEYS = ("This is Ipopt version", "Total number of variables",
              "Total number of equality constraints", "Total number of inequality constraints",
              "Number of nonzeros in equality constraint Jacobian",
              "Number of nonzeros in inequality constraint Jacobian",
              "Number of nonzeros in Lagrangian Hessian", "Number of Iterations",
              "Objective...", "Dual infeasibility", "Constraint violation",
              "Complementarity...", "Overall NLP error", "EXIT:", "Total seconds in IPOPT")


def ipopt_key_lines(path):
    """The key lines of every NLP in the IPOPT log, one list per NLP (split at the version
    line)."""
    blocks, current = [], None
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            s = line.rstrip("\n")
            if s.startswith("This is Ipopt version"):
                current = []
                blocks.append(current)
            if current is not None and any(s.strip().startswith(k) for k in IPOPT_KEYS):
                current.append(s.strip())
    return blocks


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--setup", choices=sorted(SETUPS), default="example")
    ap.add_argument("--N", type=int, default=0, help="control stages (default: the setup's)")
    ap.add_argument("--formulation", choices=["step", "stewart"], default="step")
    ap.add_argument("--cross-comp", choices=["sum", "all"], default="sum")
    ap.add_argument("--tracking", choices=["stage-end", "integrated"], default="stage-end")
    ap.add_argument("--mpcc-mode", choices=["scholtes", "elastic-ineq"], default="scholtes",
                    help="scholtes: products <= sigma; elastic-ineq: products <= s, s in [0, 10] "
                         "and s / sigma added to the cost (the package's l-infinity elastic mode)")
    ap.add_argument("--max-iter", type=int, default=10000, help="IPOPT iterations per NLP")
    ap.add_argument("--out", default=".")
    ap.add_argument("--tag", default="")
    ap.add_argument("--check-model", default="",
                    help="directory with the MATLAB example's M_fun and h_forces_fun")
    args = ap.parse_args()
    tag = args.tag or f"nosnoc_monoped_{args.setup}_{args.formulation}"
    os.makedirs(args.out, exist_ok=True)
    args.ipopt_log = os.path.join(args.out, tag + "_ipopt.log")
    if os.path.exists(args.ipopt_log):
        os.remove(args.ipopt_log)

    model_check = check_model(args.check_model) if args.check_model else None
    if model_check:
        print("model against the MATLAB example's M_fun / h_forces_fun:", model_check, flush=True)

    opts, model, ocp, x_ref, N, cfg = build(args)
    diffs = differences(args, cfg)
    print(f"setup {args.setup} ({cfg['matlab_file']} at {MATLAB_COMMIT}), N = {N}, "
          f"formulation {args.formulation}, cross comp {args.cross_comp}, tracking "
          f"{args.tracking}, IPOPT max_iter {args.max_iter} per NLP, MUMPS", flush=True)
    print("differences to the MATLAB file:", *("  - " + d for d in diffs), sep="\n", flush=True)

    t_build = time.process_time()
    solver = ns.NosnocSolver(opts, model, ocp)
    t_build = time.process_time() - t_build
    prob = solver.problem
    print(f"NLP: {prob.w.shape[0]} unknowns, {prob.g.shape[0]} constraints; built in "
          f"{t_build:.1f} s CPU", flush=True)
    if args.tracking == "stage-end":
        u0 = np.tile(ocp.u_guess, (N, 1))
        u0[:, 3:] = X0 - x_ref  # the slack consistent with the constant guess x = x0
        solver.set("u", u0)

    n_p_stages = model.p_val_ctrl_stages.size
    foot_fun = ca.Function("foot", [model.x], [kinematics(model.x[0:4])[4]])

    def summary(w):
        res = get_results_from_primal_vector(prob, w)
        xs = np.array(res["x_all_list"])
        feet = np.array(foot_fun(xs.T)).reshape(2, -1)[1] if xs.size else np.array([])
        qT = xs[-1, 0:4]
        return res, xs, feet, qT

    # Largest product of MATLAB's FE_STAGE / FE_FE pairs (step formulation only).
    def comp_matlab(w, p):
        if args.formulation != "step":
            return None
        lam00 = p[n_p_stages + 2:n_p_stages + 2 + 6]
        prev_n, prev_p = lam00[0:3], lam00[3:6]
        worst = 0.0
        for i in range(N):
            for j in range(3):
                a = [w[prob.ind_alpha[i][j][k][0]] for k in range(2)]
                ln = [w[prob.ind_lambda_n[i][j][k][0]] for k in range(2)]
                lp = [w[prob.ind_lambda_p[i][j][k][0]] for k in range(2)]
                sa, sna = a[0] + a[1], 2.0 - a[0] - a[1]
                if args.setup == "example":  # FE_STAGE: every lambda point * sum of alphas
                    for n_, p_ in [(prev_n, prev_p)] + list(zip(ln, lp)):
                        worst = max(worst, float(np.max(n_ * sa)), float(np.max(p_ * sna)))
                else:  # FE_FE: sums times sums
                    worst = max(worst, float(np.max((prev_n + ln[0] + ln[1]) * sa)),
                                float(np.max((prev_p + lp[0] + lp[1]) * sna)))
                prev_n, prev_p = ln[1], lp[1]
        return worst

    rows = []
    h_fe = T_HORIZON / (N * 3)

    class Recorder:
        """Stands in for the CasADi solver inside NosnocSolver.solve: records every NLP."""

        def __init__(self, nlp):
            self.nlp = nlp

        def stats(self):
            return self.nlp.stats()

        def __call__(self, **kw):
            sol = self.nlp(**kw)
            st = self.nlp.stats()
            w = np.array(sol["x"]).flatten()
            p = np.array(kw["p"]).flatten()
            sigma = float(p[n_p_stages])
            _, xs, feet, qT = summary(w)
            step_eq = float(np.sum((w[prob.ind_h] - h_fe) ** 2))
            f = float(sol["f"])
            it = st.get("iterations") or {}
            row = {
                "sigma": sigma,
                "comp": float(prob.comp_res(w, p)),
                "comp_matlab": comp_matlab(w, p),
                "ipopt_iterations": int(st["iter_count"]),
                "status": st["return_status"],
                "objective": f,
                "objective_without_step_equilibration": f - step_eq,
                "inf_pr": float(it["inf_pr"][-1]) if it.get("inf_pr") else None,
                "inf_du": float(it["inf_du"][-1]) if it.get("inf_du") else None,
                "cpu_s": float(st["t_proc_total"]),
                "wall_s": float(st["t_wall_total"]),
                "q_T": qT.tolist(),
                "q_T_max_abs_error": float(np.max(np.abs(qT - Q_TARGET))),
                "clock_T": float(xs[-1, 8]),
                "hops": hops(feet),
                "min_foot_height": float(np.min(feet)),
            }
            rows.append(row)
            cm = row["comp_matlab"]
            print(f"NLP {len(rows)}: sigma {sigma:.1e}  comp {row['comp']:.2e}  comp_matlab "
                  f"{cm if cm is None else format(cm, '.2e')}  iter {row['ipopt_iterations']}  "
                  f"{row['status']}  objective {f:.6g}  CPU {row['cpu_s']:.1f} s  "
                  f"|q(T)-target|max {row['q_T_max_abs_error']:.3g}  hops {row['hops']}",
                  flush=True)
            return sol

    solver.solver = Recorder(solver.solver)
    t0c, t0w = time.process_time(), time.time()
    results = solver.solve()
    cpu_total, wall_total = time.process_time() - t0c, time.time() - t0w

    w = np.array(results["w_sol"])
    res, xs, feet, qT = summary(w)
    target_err = qT - Q_TARGET
    out = {
        "tool": "nosnoc_py",
        "nosnoc_py_version": getattr(ns, "__version__", None) or "0.2.0",
        "casadi_version": ca.__version__,
        "matlab_reference": {"repository": "github.com/nurkanovic/nosnoc",
                             "commit": MATLAB_COMMIT, "file": cfg["matlab_file"]},
        "settings": {"setup": args.setup, "N": N, "N_FE": 3, "n_s": 2, "T": T_HORIZON,
                     "formulation": args.formulation, "cross_comp": args.cross_comp,
                     "tracking": args.tracking, "ipopt_max_iter_per_nlp": args.max_iter,
                     "ipopt_tol": cfg["tol"], "comp_tol": cfg["comp_tol"],
                     "sigma_0": 1.0, "sigma_factor": 0.1, "max_nlps": 5,
                     "s_bounds": [0.99, cfg["s_max"]], "linear_solver": "mumps",
                     "mu": MU, "a_n": A_N},
        "differences": diffs,
        "model_check": model_check,
        "nlp_size": {"unknowns": int(prob.w.shape[0]), "constraints": int(prob.g.shape[0])},
        "nlps": rows,
        "status": str(results["status"]),
        "final": {
            "sigma": rows[-1]["sigma"] if rows else None,
            "comp": rows[-1]["comp"] if rows else None,
            "objective": rows[-1]["objective"] if rows else None,
            "q_T": qT.tolist(),
            "target": Q_TARGET.tolist(),
            "q_T_max_abs_error": float(np.max(np.abs(target_err))),
            "q_T_euclidean_error": float(np.linalg.norm(target_err)),
            "v_T": xs[-1, 4:8].tolist(),
            "clock_T": float(xs[-1, 8]),
            "hops": hops(feet),
            "hop_rule": "foot height > 1e-3 after <= 1e-3, over every stage point",
            "min_foot_height": float(np.min(feet)),
            "max_foot_height": float(np.max(feet)),
        },
        "ipopt_iterations_total": int(sum(r["ipopt_iterations"] for r in rows)),
        "cpu_s_ipopt_total": float(sum(r["cpu_s"] for r in rows)),
        "cpu_s_total": cpu_total,
        "wall_s_total": wall_total,
        "cpu_s_build": t_build,
        "ipopt_log": args.ipopt_log,
        "ipopt_key_lines": ipopt_key_lines(args.ipopt_log),
        "trajectory": {"x_all_stage_points": xs.tolist(),
                       "u": [list(map(float, uk[:3])) for uk in res["u_list"]],
                       "h": list(map(float, res["time_steps"]))},
    }
    path = os.path.join(args.out, tag + ".json")
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(out, fh, indent=1)
    f = out["final"]
    print(f"final: q(T) = {np.array2string(qT, precision=4)}, |q(T) - target|max "
          f"{f['q_T_max_abs_error']:.3g} (euclidean {f['q_T_euclidean_error']:.3g}), clock(T) "
          f"{f['clock_T']:.4f}, hops {f['hops']}, foot height in "
          f"[{f['min_foot_height']:.3g}, {f['max_foot_height']:.3g}], objective "
          f"{f['objective']}, IPOPT iterations {out['ipopt_iterations_total']}, CPU "
          f"{out['cpu_s_ipopt_total']:.1f} s in IPOPT, {cpu_total:.1f} s in all", flush=True)
    print("wrote", path, "and", args.ipopt_log, flush=True)


if __name__ == "__main__":
    main()
