"""bflow's flow sensitivities beside heyoka, diffrax and SciPy (scripts/peers flow): x(T) and the
derivative of the flow dx(T)/dx0 on a smooth flow, through single events and through
simultaneous events, against an independent reference in long double; and the jump alone
(flow_jump.py). docs/peers.md explains what is measured.

Each tool runs in a process of its own (`peer_flow.py --worker JOB`, JOB a JSON object), over
every tolerance of the row, and prints one JSON object. The problems are flow_problems.py's.

How each tool gets the derivative (each the way its documentation shows):
  bflow     bench/peer_flow: simulate() with the d unit vectors (or the test directions) as
            tangents, dopri5 (the default), dop853 and CVODES Adams (forward sensitivities with
            root-finding); the jumps by the saltation matrix or Algorithm 2.1, automatic
            grouping (the defaults).
  heyoka    a Taylor integrator of the variational equations (var_ode_sys), one terminal event
            per surface, the sides as parameters; at each event the saltation matrix
            I + (F+ - F-) Dh^T / (Dh . F-) written by hand (F and Dh compiled by heyoka's cfunc),
            in the order the events fire.
  diffrax   jax.jit(jax.jacfwd(flow)), flow a chain of diffeqsolve calls (ForwardMode adjoint),
            each ending where its Event, the smallest margin min_j s_j h_j, reaches zero (root
            found by optimistix' Newton), the sides a traced array, so the derivative carries
            the event time's derivative; as many segments as the reference has events, plus one.
  SciPy     solve_ivp (DOP853) with one terminal event per surface (direction -1 on s_j h_j),
            restarted with the new field; the derivative by one-sided finite differences, step
            sqrt(rtol) max(1, |x0_i|): the full Jacobian by d + 1 runs, or (at simultaneous
            events, a second row) along each direction itself.
An event function restarted on its own surface starts a few ulps on the wrong side; diffrax
and SciPy would trigger at once, so their event functions carry the restart's residual as an
offset (2 max(0, -s_j h_j(x_start))), a shift of the crossing of the order of rounding.

The reference: heyoka 7.13.2 in long double (64-bit mantissa), tol = its epsilon 1.08e-19:
the variational equations with the hand-written saltation for the smooth flow and the single
events; at simultaneous events one-sided Richardson differences of the flow,
(8 D(a/4) - 6 D(a/2) + D(a)) / 3 with D(a) = (phi(x0 + a v) - phi(x0)) / a, a = 1e-4, each
direction labelled by the order in which its perturbed trajectory crosses the surfaces.
"""
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

import flow_problems as fp
import peers_common as common

NAME = "flow"
HERE = os.path.dirname(os.path.abspath(__file__))
SINGLE_THREAD_XLA = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"

TOLERANCES = [1e-4, 1e-6, 1e-8, 1e-10, 1e-12, 1e-13]
QUICK_TOLERANCES = [1e-6, 1e-10]
# atol = ATOL_PER_RTOL rtol for every tool that takes both (bflow's default); heyoka has one tol.
ATOL_PER_RTOL = 1e-2
# The setting of the simultaneous-event table.
TABLE_RTOL = 1e-10
RICHARDSON_STEP = 1e-4
# Directions at the simultaneous events (seeded Gaussian, unit length).
DIRECTIONS = {"biped": 16, "three": 36}
QUICK_DIRECTIONS = {"biped": 6, "three": 12}
# Each timed run is repeated until this much CPU time has passed.
MIN_CPU = 0.2
# Errors below this are "the right piece" in the simultaneous table (a wrong piece is off by
# tens of percent; a right one by the integration and difference error).
RIGHT_PIECE = 1e-3


def log(message):
    common.log(message)


# --------------------------------------------------------------------------------------------
# The tools (run inside a worker process)

class _Numpy:
    sin, cos, exp = np.sin, np.cos, np.exp


def initial_sides(name, x0):
    h = fp.surfaces(name, [float(v) for v in x0], _Numpy)
    if any(v == 0.0 for v in h):
        raise ValueError(f"{name}: x0 is on a surface (h = {h})")
    return [1.0 if v > 0 else -1.0 for v in h]


class Heyoka:
    """One compiled Taylor integrator of a problem (the sides as parameters)."""

    def __init__(self, name, fp_type, tol, variational=True, events=True):
        import heyoka as hy
        self.hy = hy
        self.name = name
        self.fp_type = fp_type
        p = fp.PROBLEMS[name]
        self.d, self.n = p["d"], p["n"]
        xs = list(hy.make_vars(*[f"x{i}" for i in range(self.d)])) if self.d > 1 else \
            [hy.make_vars("x0")]
        pars = [hy.par[j] for j in range(self.n)]

        class M:
            sin, cos, exp = hy.sin, hy.cos, hy.exp
        f = fp.field(name, xs, pars, M)
        h = fp.surfaces(name, xs, M)
        sys_ = list(zip(xs, f))
        self.variational = variational
        if variational:
            sys_ = hy.var_ode_sys(sys_, hy.var_args.vars, order=1)
        t_events = [hy.t_event(hj, fp_type=fp_type) for hj in h] if events else []
        kwargs = {"fp_type": fp_type, "t_events": t_events}
        if tol is not None:
            kwargs["tol"] = fp_type(tol)
        if self.n:
            kwargs["pars"] = [fp_type(1.0)] * self.n
        self.ta = hy.taylor_adaptive(sys_, [fp_type(0.0)] * self.d, **kwargs)
        self.field = hy.cfunc(f, vars=xs, fp_type=fp_type)
        if self.n:
            self.gradients = hy.cfunc([hy.diff(hj, xi) for hj in h for xi in xs], vars=xs,
                                      fp_type=fp_type)

    def segment(self, x, t0, t1, sides):
        """x(t1) and the transition matrix from x at t0, with the sides fixed (no events)."""
        ta, d, T = self.ta, self.d, self.fp_type
        ta.time = T(t0)
        ta.state[:d] = np.asarray(x, dtype=T)
        ta.state[d:] = np.eye(d, dtype=T).ravel()
        if self.n:
            ta.pars[:] = np.asarray(sides, dtype=T)
        outcome = ta.propagate_until(T(t1))[0]
        if outcome != self.hy.taylor_outcome.time_limit:
            raise RuntimeError(f"heyoka stopped with {outcome} between {t0} and {t1}")
        return np.array(ta.state[:d]), np.array(ta.state[d:]).reshape(d, d)

    def run(self, x0, t, sides, backward=False):
        """x(t) from x0 (and the Jacobian with saltations at the events, in firing order)."""
        hy, ta, d, T = self.hy, self.ta, self.d, self.fp_type
        ta.time = T(0.0)
        state = ta.state
        state[:d] = np.asarray(x0, dtype=T)
        if self.variational:
            state[d:] = np.eye(d, dtype=T).ravel()
        if self.n:
            ta.pars[:] = np.asarray(sides, dtype=T)
        if ta.with_events:
            ta.reset_cooldowns()
        events = []
        while True:
            outcome = ta.propagate_until(T(-t if backward else t))[0]
            if outcome == hy.taylor_outcome.time_limit:
                break
            code = int(outcome)
            if code >= 0:
                raise RuntimeError(f"heyoka stopped with {outcome} at t = {float(ta.time)}")
            j = -code - 1
            rho = np.array(ta.state[:d])
            f_before = self.field(rho, pars=np.array(ta.pars))
            ta.pars[j] = -ta.pars[j]
            f_after = self.field(rho, pars=np.array(ta.pars))
            if self.variational:
                g = self.gradients(rho)[j * d:(j + 1) * d]
                salt = np.eye(d, dtype=T) + np.outer(f_after - f_before, g) / g.dot(f_before)
                phi = np.array(ta.state[d:]).reshape(d, d)
                ta.state[d:] = (salt @ phi).ravel()
            events.append([float(ta.time), j])
            if len(events) > 1000:
                raise RuntimeError("more than 1000 events")
        x = np.array(ta.state[:d])
        jac = np.array(ta.state[d:]).reshape(d, d) if self.variational else None
        return x, jac, events


def reference(job):
    """The long double reference of a problem: x(T), the Jacobian (no simultaneous event) or
    the Richardson differences along the directions, and the events."""
    name = job["problem"]
    L = np.longdouble
    p = fp.PROBLEMS[name]
    out = {"tool": "reference", "problem": name}
    x0 = job.get("x0")
    if name == "three":
        back = Heyoka(name, L, None, variational=False, events=False)
        x0_ld, _, _ = back.run(np.array(fp.THREE_RHO, dtype=L), fp.THREE_CROSSING_TIME,
                               [-1.0] * 3, backward=True)
        x0 = [float(v) for v in x0_ld]
        out["x0_long_double"] = [repr(v) for v in x0_ld]
    out["x0"] = x0
    sides = initial_sides(name, x0)
    x0_ld = np.array(x0, dtype=L)
    start = time.process_time()
    ref = Heyoka(name, L, None, variational=True)
    x, jac, events = ref.run(x0_ld, p["t"], sides)
    out["x"] = [float(v) for v in x]
    out["events"] = events
    if job.get("directions") is None:
        out["jacobian"] = jac.astype(float).tolist()
    else:
        plain = Heyoka(name, L, None, variational=False)
        base, _, _ = plain.run(x0_ld, p["t"], sides)
        images, orders = [], []
        for v in job["directions"]:
            v = np.array(v, dtype=L)
            quotients = []
            for a in (L(RICHARDSON_STEP), L(RICHARDSON_STEP) / 2, L(RICHARDSON_STEP) / 4):
                moved, _, ev = plain.run(x0_ld + a * v, p["t"], sides)
                quotients.append((moved - base) / a)
                if a == L(RICHARDSON_STEP) / 4:
                    orders.append([j for _, j in ev])
            r = (8 * quotients[2] - 6 * quotients[1] + quotients[0]) / 3
            images.append([float(c) for c in r])
        out["images"] = images
        out["orders"] = orders
        # The variational Jacobian with saltations in the nominal firing order: one piece.
        out["jacobian_one_order"] = jac.astype(float).tolist()
    out["cpu_s"] = time.process_time() - start
    out["settings"] = "heyoka long double, tol = epsilon (1.08e-19)"
    return out


def _time(function, repeat):
    """Runs function() until MIN_CPU seconds and `repeat` runs have passed; the mean CPU time
    per run and the last result (after one untimed run: first calls import and allocate)."""
    function()
    runs, start = 0, time.process_time()
    while True:
        result = function()
        runs += 1
        elapsed = time.process_time() - start
        if runs >= repeat and elapsed >= MIN_CPU:
            return elapsed / runs, runs, result


def run_heyoka(job):
    name, p = job["problem"], fp.PROBLEMS[job["problem"]]
    x0, sides = job["x0"], initial_sides(job["problem"], job["x0"])
    out = []
    for tol in job["tolerances"]:
        start = time.process_time()
        integrator = Heyoka(name, float, tol)
        compile_s = time.process_time() - start
        try:
            cpu, runs, (x, jac, events) = _time(lambda: integrator.run(x0, p["t"], sides),
                                                job["repeat"])
            out.append({"tol": tol, "cpu_s": cpu, "runs": runs, "compile_s": compile_s,
                        "x": x.tolist(), "jacobian": jac.tolist(), "events": events,
                        "status": "solved"})
        except RuntimeError as e:
            out.append({"tol": tol, "status": "error", "message": str(e)})
    return out


def _scipy_flow(name, x0, t, sides, rtol, method):
    from scipy.integrate import solve_ivp
    p = fp.PROBLEMS[name]
    s = list(sides)
    x, t0, events = np.array(x0, dtype=float), 0.0, []
    while True:
        residual = [max(0.0, -sj * hj) for sj, hj in zip(s, fp.surfaces(name, list(x), _Numpy))]
        functions = []
        for j in range(p["n"]):
            def g(tt, y, j=j, sj=s[j], off=2.0 * residual[j]):
                return sj * fp.surfaces(name, y, _Numpy)[j] + off
            g.terminal, g.direction = True, -1
            functions.append(g)
        sol = solve_ivp(lambda tt, y, s=tuple(s): fp.field(name, y, s, _Numpy), (t0, t), x,
                        method=method, rtol=rtol, atol=ATOL_PER_RTOL * rtol,
                        events=functions or None)
        if sol.status < 0:
            raise RuntimeError(sol.message)
        x = sol.y[:, -1]
        if sol.status == 0:
            return x, events
        fired = [j for j in range(p["n"]) if sol.t_events[j].size]
        j = min(fired, key=lambda k: sol.t_events[k][0])
        t0 = float(sol.t_events[j][0])
        x = sol.y_events[j][0]
        s[j] = -s[j]
        events.append([t0, j])
        if len(events) > 1000:
            raise RuntimeError("more than 1000 events")


def run_scipy(job):
    name, p = job["problem"], fp.PROBLEMS[job["problem"]]
    x0, sides = np.array(job["x0"]), initial_sides(job["problem"], job["x0"])
    d = p["d"]
    along = job.get("along_directions", False)
    directions = np.array(job["directions"]) if job.get("directions") else np.eye(d)
    out = []
    for rtol in job["tolerances"]:
        def derivative():
            base, events = _scipy_flow(name, x0, p["t"], sides, rtol, "DOP853")
            if along:
                cols = []
                for v in directions:
                    step = math.sqrt(rtol) * max(1.0, float(np.max(np.abs(x0))))
                    moved, _ = _scipy_flow(name, x0 + step * v, p["t"], sides, rtol, "DOP853")
                    cols.append((moved - base) / step)
                return base, np.array(cols).T, events
            jac = np.empty((d, d))
            for i in range(d):
                step = math.sqrt(rtol) * max(1.0, abs(x0[i]))
                moved, _ = _scipy_flow(name, x0 + step * np.eye(d)[i], p["t"], sides, rtol,
                                       "DOP853")
                jac[:, i] = (moved - base) / step
            return base, jac, events
        try:
            cpu, runs, (x, jac, events) = _time(derivative, job["repeat"])
            row = {"tol": rtol, "cpu_s": cpu, "runs": runs, "x": x.tolist(), "events": events,
                   "status": "solved"}
            row["images" if along else "jacobian"] = jac.T.tolist() if along else jac.tolist()
            out.append(row)
        except RuntimeError as e:
            out.append({"tol": rtol, "status": "error", "message": str(e)})
    return out


def run_diffrax(job):
    import jax
    jax.config.update("jax_enable_x64", True)
    import diffrax
    import jax.numpy as jnp
    import optimistix as optx

    name, p = job["problem"], fp.PROBLEMS[job["problem"]]
    x0 = jnp.array(job["x0"])
    sides = initial_sides(job["problem"], job["x0"])
    segments = job["segments"]
    solver = {"Tsit5": diffrax.Tsit5, "Dopri8": diffrax.Dopri8}[job["solver"]]()

    class M:
        sin, cos, exp = jnp.sin, jnp.cos, jnp.exp

    def vector_field(t, y, args):
        s, _ = args
        return jnp.stack(fp.field(name, [y[i] for i in range(p["d"])], s, M))

    def margins(y, s, offset):
        return s * jnp.stack(fp.surfaces(name, [y[i] for i in range(p["d"])], M)) + offset

    def cond(t, y, args, **kwargs):
        # One condition, the smallest margin: diffrax takes, of several conditions that change
        # sign in one step, the first in its list (not the earliest in time; a list of one
        # condition per surface missed the biped's first touchdown at every tolerance).
        s, offset = args
        return jnp.min(margins(y, s, offset))

    def flow(x, rtol, atol):
        return trace(x, rtol, atol)[0]

    def trace(x, rtol, atol):
        """x(T) and, per segment, where it ended and which surfaces its event flagged."""
        s, t = jnp.array(sides), 0.0
        ends, masks = [], []
        for _ in range(segments):
            event = None
            offset = jnp.zeros(p["n"])
            if p["n"]:
                h = jnp.stack(fp.surfaces(name, [x[i] for i in range(p["d"])], M))
                # A constant of the segment: no derivative may flow through it.
                offset = jax.lax.stop_gradient(2.0 * jnp.maximum(0.0, -s * h))
                event = diffrax.Event(cond_fn=cond,
                                      root_finder=optx.Newton(rtol=1e-14, atol=1e-14))
            sol = diffrax.diffeqsolve(
                diffrax.ODETerm(vector_field), solver, t0=t, t1=p["t"], dt0=None, y0=x,
                args=(s, offset), event=event, adjoint=diffrax.ForwardMode(),
                stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
                max_steps=1_000_000)
            t, x = sol.ts[-1], sol.ys[-1]
            if p["n"]:
                # The surface that reached zero: the smallest margin among those falling there
                # (at a simultaneous crossing the margins tie, and the one just flipped rises).
                rates = jax.jvp(lambda y: margins(y, s, offset), (x,),
                                (vector_field(t, x, (s, offset)),))[1]
                hit = jnp.argmin(jnp.where(rates < 0.0, margins(x, s, offset), jnp.inf))
                mask = (jnp.arange(p["n"]) == hit) & sol.event_mask
                s = jnp.where(mask, -s, s)
                ends.append(t)
                masks.append(mask)
        return x, ends, masks

    start = time.process_time()
    value = jax.jit(trace)
    jacobian = jax.jit(jax.jacfwd(flow))
    jax.block_until_ready(value(x0, 1e-6, 1e-8))
    jacobian(x0, 1e-6, 1e-8).block_until_ready()
    compile_s = time.process_time() - start
    out = []
    for rtol in job["tolerances"]:
        atol = ATOL_PER_RTOL * rtol

        def both():
            x, ends, masks = value(x0, rtol, atol)
            jac = jacobian(x0, rtol, atol)
            return x.block_until_ready(), ends, masks, jac.block_until_ready()
        try:
            cpu, runs, (x, ends, masks, jac) = _time(both, job["repeat"])
            x, jac = np.asarray(x), np.asarray(jac)
            # The events as the other tools report them: (time, surface) per flagged surface.
            events = [[float(t), j] for t, mask in zip(ends, masks)
                      for j in np.flatnonzero(np.asarray(mask)).tolist()]
            status = "solved" if np.all(np.isfinite(jac)) else "error"
            out.append({"tol": rtol, "cpu_s": cpu, "runs": runs, "compile_s": compile_s,
                        "x": x.tolist(), "jacobian": jac.tolist(), "events": events,
                        "status": status})
        except Exception as e:  # an XLA runtime error is not a RuntimeError
            out.append({"tol": rtol, "status": "error", "message": str(e).splitlines()[0]})
    return out


def run_bflow(job):
    p = fp.PROBLEMS[job["problem"]]
    out = []
    for rtol in job["tolerances"]:
        command = [job["program"], "--problem", p["program"], "--t", repr(p["t"]),
                   "--x0", ",".join(repr(v) for v in job["x0"]), "--backend", job["backend"],
                   "--rtol", repr(rtol), "--atol", repr(ATOL_PER_RTOL * rtol),
                   "--min-cpu", repr(MIN_CPU)]
        if job.get("directions"):
            command += ["--directions",
                        ";".join(",".join(repr(c) for c in v) for v in job["directions"])]
        r = common.run_json(command, timeout=job.get("timeout"))
        row = {"tol": rtol, "status": r.get("status"), "message": r.get("message")}
        if r.get("status") == "solved":
            images = np.array(r["images"])  # k rows
            row.update({"cpu_s": r["cpu_s"], "runs": r["runs"], "x": r["x"],
                        "steps": r["steps"], "events": r["events"], "notices": r["notices"]})
            if job.get("directions"):
                row["images"] = images.tolist()
            else:
                row["jacobian"] = images.T.tolist()
        out.append(row)
    return out


def run_hybrid_tools(job):
    """hybrid-tools 0.1.0 at simultaneous events: its simulator's loop (HybridSimulator.
    simulate_timestep: solve_ivp with the guards as events, the first guard in its order that
    fired taken, then the next mode from there) with the table's tolerances, and its saltation
    matrices (compute_saltation_matrix, identity resets) composed in the order its guards fire.
    hybrid-tools has no variational flow (its filter linearises by the user's discrete A), so
    the transition matrices between its events come from the long double reference along its
    mode sequence and event times: what differs from the reference is the jump alone."""
    import heyoka as hy
    import hybrid_tools as ht
    from hybrid_tools import hybrid_helper_functions as hh
    from scipy.integrate import solve_ivp

    name, p = job["problem"], fp.PROBLEMS[job["problem"]]
    d, n, T = p["d"], p["n"], p["t"]
    rtol = job["tolerances"][0]
    x0 = np.array(job["x0"])
    xs = list(hy.make_vars(*[f"x{i}" for i in range(d)]))

    class M:
        sin, cos, exp = hy.sin, hy.cos, hy.exp
    grad = hy.cfunc([hy.diff(hj, xi) for hj in fp.surfaces(name, xs, M) for xi in xs], vars=xs)

    def word(s):
        return "".join("+" if v > 0 else "-" for v in s)

    def signs(w):
        return [1.0 if c == "+" else -1.0 for c in w]

    words = ["".join("+" if (b >> j) & 1 else "-" for j in range(n)) for b in range(2 ** n)]
    offsets = {}  # (word, j) -> the restart's residual (see the module's docstring)
    dynamics, guards, resets, noises = {}, {}, {}, {}
    unused = lambda *args: None  # noqa: E731  (the filter's matrices)
    for w in words:
        s = signs(w)
        dynamics[w] = ht.ModeDynamics(
            f_cont=lambda x, u, dt, par, s=s: np.array(fp.field(name, list(x), s, _Numpy)),
            A_disc=unused, B_disc=unused, y=unused, C=unused)
        guards[w], resets[w] = {}, {}
        for j in range(n):
            target = list(w)
            target[j] = "+" if w[j] == "-" else "-"
            target = "".join(target)
            guards[w][target] = ht.ModeGuard(
                g=lambda x, u, dt, par, s=s, j=j, w=w: np.array(
                    [s[j] * fp.surfaces(name, list(x), _Numpy)[j] + offsets.get((w, j), 0.0)]),
                G=lambda x, u, dt, par, s=s, j=j: s[j] * grad(np.asarray(x, dtype=float))[
                    j * d:(j + 1) * d])
            resets[w][target] = ht.ModeReset(r=lambda x, u, dt, par: np.array(x),
                                             R=lambda x, u, dt, par: np.eye(d))
        noises[w] = ht.ModeNoise(W=np.zeros((1, 1)), V=np.zeros((1, 1)))
    system = ht.HybridDynamicalSystem(dynamics=dynamics, resets=resets, guards=guards,
                                      noises=noises)
    inputs, params = np.zeros(1), np.zeros(0)

    def set_offsets(w, x):
        h = fp.surfaces(name, list(x), _Numpy)
        for j, sj in enumerate(signs(w)):
            offsets[(w, j)] = 2.0 * max(0.0, -sj * h[j])

    mode, state, t = word(initial_sides(name, x0)), x0.copy(), 0.0
    fired = []  # (time, state, mode before, mode after, saltation)
    for _ in range(100):
        set_offsets(mode, state)
        f = hh.solve_ivp_dynamics_func(system.dynamics, mode, inputs, T, params)
        g, targets = hh.solve_ivp_guard_funcs(system.guards, mode, inputs, T, params)
        sol = solve_ivp(f, [t, T], state, events=g, rtol=rtol, atol=ATOL_PER_RTOL * rtol)
        event_state, event_time, new_mode = hh.solve_ivp_extract_hybrid_events(sol, targets)
        if new_mode is None:
            state = sol.y[:, -1]
            break
        salt = hh.compute_saltation_matrix(event_state, inputs, T, params, mode, new_mode,
                                           system)
        fired.append((float(event_time), event_state, mode, new_mode, salt))
        mode, state, t = new_mode, np.array(event_state), float(event_time)
    # The derivative: reference transition matrices between its events, its saltations.
    L = np.longdouble
    ref = Heyoka(name, L, None, variational=True, events=False)
    sides = initial_sides(name, x0)
    x, t0, jac = np.array(x0, dtype=L), 0.0, np.eye(d)
    for event_time, _, before, after, salt in fired:
        x, phi = ref.segment(x, t0, event_time, signs(before))
        jac = salt @ (phi.astype(float) @ jac)
        t0 = event_time
    x, phi = ref.segment(x, t0, T, signs(mode) if fired else sides)
    jac = phi.astype(float) @ jac
    events = [[t_, [j for j in range(n) if a[j] != b[j]][0]] for t_, _, a, b, _ in fired]
    return [{"tol": rtol, "status": "solved", "cpu_s": None, "x": state.tolist(),
             "jacobian": jac.tolist(), "events": events}]


WORKERS = {"reference": reference, "heyoka": run_heyoka, "scipy": run_scipy,
           "diffrax": run_diffrax, "bflow": run_bflow, "hybrid-tools": run_hybrid_tools}


def worker(job):
    result = WORKERS[job["tool"]](job)
    print(json.dumps(result))


# --------------------------------------------------------------------------------------------
# The run

def _versions(python):
    code = ("import json, importlib.metadata as m\n"
            "print(json.dumps({k: m.version(k) for k in "
            "['heyoka', 'diffrax', 'jax', 'jaxlib', 'equinox', 'optimistix', 'scipy', "
            "'numpy', 'hybrid-tools']}))")
    done = subprocess.run([python, "-c", code], capture_output=True, text=True, check=False)
    try:
        return json.loads(done.stdout)
    except ValueError:
        return {}


def _spawn(job, ctx):
    env = {"XLA_FLAGS": SINGLE_THREAD_XLA, "JAX_PLATFORMS": "cpu"}
    result = common.run_json([sys.executable, os.path.join(HERE, "peer_flow.py"), "--worker",
                              json.dumps(job)], timeout=ctx.timeout * 4, env=env)
    if isinstance(result, dict) and result.get("status") == "error":
        log(f"  {job['tool']} on {job['problem']}: {result.get('message')}")
        return None
    return result


def _directions(name, count, d):
    rng = np.random.default_rng(20261127 + d)
    v = rng.standard_normal((count, d))
    return (v / np.linalg.norm(v, axis=1, keepdims=True)).tolist()


def _relative(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(b)))))


def _direction_errors(images, ref_images):
    return [float(np.linalg.norm(np.subtract(a, b)) / np.linalg.norm(b))
            for a, b in zip(images, ref_images)]


def _tools(simultaneous):
    """(tool, label, extra job fields) in the order of the tables."""
    tools = [("bflow", "bflow dopri5", {"backend": "dopri5"}),
             ("bflow", "bflow dop853", {"backend": "dop853"}),
             ("bflow", "bflow CVODES Adams", {"backend": "cvodes-adams"}),
             ("heyoka", "heyoka", {}),
             ("diffrax", "diffrax Tsit5", {"solver": "Tsit5"}),
             ("scipy", "SciPy DOP853 + FD", {})]
    if simultaneous:
        tools.append(("scipy", "SciPy DOP853 + FD along v", {"along_directions": True}))
        tools.append(("hybrid-tools", "hybrid-tools", {}))
    return tools


def run(ctx):
    ctx.flow_program = os.path.join(os.path.dirname(ctx.bflow), "peer_flow")
    versions = _versions(sys.executable)
    tolerances = QUICK_TOLERANCES if ctx.quick else TOLERANCES
    problems = ["chain", "ball", "biped-tilt", "biped", "three"]
    if ctx.quick:
        problems = ["chain", "ball", "three"]
    rows = []
    for name in problems:
        p = fp.PROBLEMS[name]
        simultaneous = name in DIRECTIONS
        directions = None
        if simultaneous:
            count = (QUICK_DIRECTIONS if ctx.quick else DIRECTIONS)[name]
            directions = _directions(name, count, p["d"])
        log(f"flow: {name}: the long double reference")
        ref = _spawn({"tool": "reference", "problem": name, "x0": p["x0"],
                      "directions": directions}, ctx)
        if ref is None:
            continue
        x0 = ref["x0"]
        rows.append({"comparison": "flow", "problem": name, "tool": "reference",
                     "version": f"heyoka {versions.get('heyoka', '?')}", **ref})
        for tool, label, extra in _tools(simultaneous):
            job = {"tool": tool, "problem": name, "x0": x0, "tolerances": tolerances,
                   "repeat": ctx.repeat, "directions": directions, **extra}
            if tool == "hybrid-tools":
                job["tolerances"] = [TABLE_RTOL]
            if tool == "bflow":
                job.update(program=ctx.flow_program, timeout=ctx.timeout)
                version = ctx.bflow_version
            elif tool == "diffrax":
                job["segments"] = len(ref["events"]) + 1
                version = f"diffrax {versions.get('diffrax')}, jax {versions.get('jax')}"
            elif tool == "heyoka":
                version = f"heyoka {versions.get('heyoka')}"
            elif tool == "hybrid-tools":
                version = f"hybrid-tools {versions.get('hybrid-tools')}"
            else:
                version = f"scipy {versions.get('scipy')}"
            log(f"flow: {name}: {label}")
            start = time.time()
            result = _spawn(job, ctx)
            log(f"  {time.time() - start:.1f} s")
            if result is None:
                rows.append({"comparison": "flow", "problem": name, "tool": label,
                             "version": version, "status": "error"})
                continue
            for r in result:
                row = {"comparison": "flow", "problem": name, "tool": label, "version": version,
                       "settings": _settings(tool, extra, r["tol"]), **r}
                if r.get("status") == "solved":
                    row["x_error"] = _relative(r["x"], ref["x"])
                    if simultaneous:
                        images = r.get("images")
                        if images is None:
                            images = (np.array(r["jacobian"]) @ np.array(directions).T).T
                        row["direction_errors"] = _direction_errors(images, ref["images"])
                        row["error"] = max(row["direction_errors"])
                    else:
                        row["error"] = _relative(r["jacobian"], ref["jacobian"])
                rows.append(row)
    import flow_jump
    ctx.jump_program = os.path.join(os.path.dirname(ctx.bflow), "peer_jump")
    rows += flow_jump.run(ctx)
    for r in rows:
        r.setdefault("comparison", "flow")
    return rows


def _settings(tool, extra, tol):
    if tool == "bflow":
        return f"{extra['backend']}, rtol {tol:g}, atol {ATOL_PER_RTOL * tol:g}, defaults"
    if tool == "heyoka":
        return f"double, tol {tol:g}, variational equations, saltation by hand"
    if tool == "hybrid-tools":
        return (f"its simulator's loop with solve_ivp (RK45) rtol {tol:g} atol "
                f"{ATOL_PER_RTOL * tol:g}, its saltation matrices in its firing order, the "
                "reference's transition matrices between them")
    if tool == "diffrax":
        return (f"{extra['solver']}, PIDController rtol {tol:g} atol {ATOL_PER_RTOL * tol:g}, "
                "jit(jacfwd), ForwardMode, Event + optimistix Newton 1e-14")
    how = "along each direction" if extra.get("along_directions") else "d + 1 runs"
    return (f"DOP853 rtol {tol:g} atol {ATOL_PER_RTOL * tol:g}, one-sided FD ({how}), "
            f"step sqrt(rtol) max(1, |x0|)")


# --------------------------------------------------------------------------------------------
# The report

def _front(points):
    """The lower-left front of (error, cpu) points, sorted by error descending."""
    pts = sorted((e, c) for e, c in points if e and c and e > 0)
    front, best = [], math.inf
    for e, c in pts:
        if c < best:
            front.append((e, c))
            best = c
    return sorted(front, reverse=True)


def cpu_at(points, target):
    """CPU time to reach `target` error, interpolated in log-log on the tool's front; None when
    the tool does not reach it."""
    front = _front(points)
    if not front or min(e for e, _ in front) > target:
        return None
    if front[0][0] <= target:
        return front[0][1]
    for (e1, c1), (e2, c2) in zip(front, front[1:]):
        if e2 <= target <= e1:
            w = (math.log(target) - math.log(e1)) / (math.log(e2) - math.log(e1))
            return math.exp(math.log(c1) + w * (math.log(c2) - math.log(c1)))
    return None


TARGETS = [1e-5, 1e-8, 1e-11]


def report(data, ctx):
    import flow_jump
    rows = data["rows"]
    flow_rows = [r for r in rows if r.get("comparison") == "flow"]
    jump_rows = [r for r in rows if r.get("comparison") == "jump"]
    m = data.get("machine", {})
    out = []
    out.append(f"Measured {m.get('date', '?')} on {m.get('cpu', '?')} ({m.get('cores', '?')} "
               f"cores, load {m.get('load_average_before', '?')} before the run), "
               f"{m.get('git', '?')}, {data.get('minutes', '?')} minutes"
               f"{' (quick)' if data.get('quick') else ''}. Versions: "
               + "; ".join(sorted({r['version'] for r in flow_rows if r.get('version')})) + ".")
    problems = [p for p in fp.PROBLEMS if any(r["problem"] == p for r in flow_rows)]
    # The ratio table.
    header = ["problem", "error", "bflow CPU (backend)"]
    tools = [t for t in ["bflow CVODES Adams", "heyoka", "diffrax Tsit5", "SciPy DOP853 + FD",
                         "SciPy DOP853 + FD along v"]
             if any(r["tool"] == t for r in flow_rows)]
    header += [f"{t} / bflow" for t in tools]
    table = []
    for name in problems:
        def points(tool):
            return [(r.get("error"), r.get("cpu_s")) for r in flow_rows
                    if r["problem"] == name and r["tool"] == tool and r.get("status") == "solved"]
        for target in TARGETS:
            candidates = [(cpu_at(points(b), target), b.split()[1])
                          for b in ("bflow dopri5", "bflow dop853")]
            candidates = [(c, b) for c, b in candidates if c]
            base, backend = min(candidates) if candidates else (None, None)
            line = [name, f"{target:g}", f"{common.fmt(base)} s ({backend})" if base else "—"]
            for t in tools:
                c = cpu_at(points(t), target)
                line.append(common.fmt(c / base) if c and base else
                            ("not reached" if points(t) else "—"))
            table.append(line)
    out.append("\n**Peer CPU / bflow CPU at equal error** (error of the derivative: the largest "
               "entry of dx(T)/dx0 off, over max(1, the largest entry), or at simultaneous "
               "events the largest relative error over the test directions; each tool's CPU "
               "interpolated in log-log between its tolerances; bflow's CPU is the faster of its "
               "two Runge-Kutta backends there; \"not reached\": no tolerance of the tool got "
               "there; > 1: bflow is faster).\n")
    out.append(common.table(header, table, ["---", "---:"] + ["---:"] * (len(header) - 2)))
    # Per problem: the work-precision numbers.
    for name in problems:
        ref = next((r for r in flow_rows if r["problem"] == name and r["tool"] == "reference"),
                   None)
        out.append(f"\n### {fp.PROBLEMS[name]['title']}\n")
        if ref:
            out.append(f"Reference: {ref.get('settings')}, {len(ref.get('events', []))} events "
                       f"({common.fmt(ref.get('cpu_s'))} s).\n")
        lines = []
        for r in flow_rows:
            if r["problem"] != name or r["tool"] == "reference":
                continue
            lines.append([r["tool"], f"{r.get('tol', 0):g}", r.get("status"),
                          common.fmt(r.get("cpu_s")), common.fmt(r.get("x_error")),
                          common.fmt(r.get("error")),
                          str(len(r["events"])) if r.get("events") is not None else "—"])
        out.append(common.table(["tool", "tol", "status", "CPU s", "x(T) error",
                                 "derivative error", "events"], lines,
                                ["---", "---:", "---", "---:", "---:", "---:", "---:"]))
        if name in DIRECTIONS and ref:
            out.append(_piece_table(name, ref, flow_rows))
    if ctx.plots:
        _plots(flow_rows, problems)
        out.append("\n![work-precision](peers_flow_smooth.png)\n"
                   "![work-precision](peers_flow_events.png)\n"
                   "![work-precision](peers_flow_simultaneous.png)")
    if jump_rows:
        out.append("\n### The jump alone\n")
        out.append(flow_jump.report(jump_rows, ctx))
    return "\n".join(out)


def _piece_table(name, ref, flow_rows):
    """Which piece each tool gives: its largest error per crossing order of the reference."""
    orders = [" → ".join(str(j) for j in o) for o in ref["orders"]]
    labels = sorted(set(orders))
    lines = []
    for r in flow_rows:
        if r["problem"] != name or r.get("tol") != TABLE_RTOL or not r.get("direction_errors"):
            continue
        cells, right = [], 0
        for label in labels:
            errs = [e for e, o in zip(r["direction_errors"], orders) if o == label]
            worst = max(errs)
            right += worst < RIGHT_PIECE
            cells.append(common.fmt(worst))
        lines.append([r["tool"]] + cells + [f"{right} of {len(labels)}"])
    counts = {label: orders.count(label) for label in labels}
    header = ["tool (tol 1e-10)"] + [f"order {label} ({counts[label]} dir.)" for label in labels]
    header.append(f"orders right (error < {RIGHT_PIECE:g})")
    return ("\nLargest relative error ‖D v − D_ref v‖ / ‖D_ref v‖ over the test directions of "
            "each crossing order (the order the reference's perturbed trajectory crosses the "
            "surfaces in):\n\n" + common.table(header, lines))


STYLE = {"bflow dopri5": ("C0", "o-"), "bflow dop853": ("C4", "P-"),
         "hybrid-tools": ("C5", "X"),
         "bflow CVODES Adams": ("C0", "s--"),
         "heyoka": ("C1", "^-"), "diffrax Tsit5": ("C2", "v-"),
         "SciPy DOP853 + FD": ("C3", "D-"), "SciPy DOP853 + FD along v": ("C3", "d:")}


def _plots(flow_rows, problems):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    groups = {"smooth": ["chain"], "events": ["ball", "biped-tilt"],
              "simultaneous": ["biped", "three"]}
    for group, names in groups.items():
        names = [n for n in names if n in problems]
        if not names:
            continue
        fig, axes = plt.subplots(1, len(names), figsize=(5.2 * len(names), 4.2), squeeze=False)
        for ax, name in zip(axes[0], names):
            for tool, (color, style) in STYLE.items():
                pts = sorted((r["error"], r["cpu_s"]) for r in flow_rows
                             if r["problem"] == name and r["tool"] == tool
                             and r.get("status") == "solved" and r.get("error")
                             and r.get("cpu_s"))
                if pts:
                    ax.loglog([e for e, _ in pts], [c for _, c in pts], style, color=color,
                              label=tool, ms=4)
            ax.set_xlabel("error of the derivative")
            ax.set_ylabel("CPU s per run")
            ax.set_title(name, fontsize=9)
            ax.grid(True, which="both", alpha=0.3)
            ax.invert_xaxis()
        axes[0][0].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(os.path.join(common.DOCS, f"peers_flow_{group}.png"), dpi=110)
        plt.close(fig)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        worker(json.loads(sys.argv[2]))
    else:
        sys.exit("usage: peer_flow.py --worker JOB (scripts/peers flow runs the comparison)")
