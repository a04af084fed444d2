"""bflow's flow sensitivities beside heyoka, diffrax and SciPy (scripts/peers flow): x(T) and the
derivative of the flow dx(T)/dx0 on a smooth flow, through single events and through
simultaneous events, against an independent reference in long double; and the jump alone
(flow_jump.py). docs/peers.md explains what is measured.

Each tool runs in a process of its own (`peer_flow.py --worker JOB`, JOB a JSON object), over
every tolerance of the row, and prints one JSON object. The problems are flow_problems.py's.

How each tool gets the derivative (each the way its documentation shows), every tool with each
of its methods, the tables taking each tool's fastest at every error:
  bflow     bench/peer_flow: simulate() with the d unit vectors (or the test directions) as
            tangents, dopri5, dop853, the defaults (backend auto: dopri5 or dop853 by the
            tolerance and the model, bflow::choose_backend) and CVODES Adams (forward sensitivities with
            root-finding); the jumps by the saltation matrix or Algorithm 2.1, automatic
            grouping and the default error control (the defaults); one untimed run first.
            From Python (bflow-python): the same call, bflow.simulate, in a Python process
            timed by the same harness as heyoka, diffrax and SciPy, on the problem written in
            SymPy (flow_problems' field with SymPy symbols, compiled before the timing).
  heyoka    a Taylor integrator of the variational equations (var_ode_sys), one terminal event
            per surface, the sides as parameters, compiled once per tolerance and re-set for
            every run; at each event the saltation matrix I + (F+ - F-) Dh^T / (Dh . F-)
            written by hand (F and Dh compiled by heyoka's cfunc), in the order the events fire.
            Timed twice: the whole run, and the CPU time inside propagate_until alone.
  diffrax   one jax.jit(jax.jacfwd(trace, has_aux=True)) call giving the Jacobian and x(T),
            trace a lax.while_loop of diffeqsolve calls (Tsit5 or Dopri8, ForwardMode adjoint),
            each ending where its Event, the smallest margin min_j s_j h_j, reaches zero (root
            found by optimistix' Newton) or at T, the sides a traced array, so the derivative
            carries the event time's derivative; the loop restarts after each event until T,
            not told how many events there are.
  SciPy     solve_ivp (DOP853, RK45, LSODA) with one terminal event per surface (direction -1
            on s_j h_j), restarted with the new field; the derivative by one-sided finite
            differences, step sqrt(rtol) max(1, |x0_i|): the full Jacobian by d + 1 runs, or (at
            simultaneous events, a second row, DOP853) along each direction itself.
Every Python tool's row also carries the harness's own cost per run (an empty call timed the
same way) and diffrax's the cost of one jitted call that does nothing (JAX's dispatch).
An event function restarted on its own surface starts a few ulps on the wrong side; diffrax
and SciPy would trigger at once, so their event functions carry the restart's residual as an
offset (2 max(0, -s_j h_j(x_start))), a shift of the crossing of the order of rounding.

The reference shares no code with any tool compared: bench/peer_flow.cc --reference, bflow's
examples::ReferenceFlow in long double (a fixed-step sixth-order Runge-Kutta method with
bisected crossings, independent of bflow's engine), x(T), its crossings and one-sided Richardson
differences (8 D(a/4) - 6 D(a/2) + D(a)) / 3 with D(a) = (phi(x0 + a v) - phi(x0)) / a,
a = 5e-5, along each unit vector or test direction, each direction labelled by the order in
which its a/4 trajectory crosses the surfaces; with its own accuracy (its step and a halved).
Cross-check: heyoka 7.13.2 in long double, tol = its epsilon 1.08e-19 (the variational
equations with the hand-written saltation, or the same differences at a = 1e-4 at
simultaneous events); every row's errors against it are stored too (heyoka_reference_*).
A row whose crossings differ from the reference's, or whose x(T) is off by more than X_OFF
times its tolerance, gets a failing status.
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
# diffrax's event loop stops with an error after this many events (none of the problems has
# more than 8).
MAX_EVENTS = 64
# The reference's Runge-Kutta step (ReferenceFlow, default 2^-9): the ball's contact spring
# (frequency 20/s) wants a finer one.
REFERENCE_STEP = {"ball": 2.0 ** -12}
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
        # CPU time spent inside propagate_until (heyoka's integration and its call), summed
        # over the calls since the last reset, and the number of calls.
        # With instrument set (run_heyoka's second timing only, so that the clock's own cost
        # stays out of the whole run's time).
        self.instrument = False
        self.integration_ns = 0
        self.integration_calls = 0
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
        clock = time.process_time_ns if self.instrument else None
        end = T(-t if backward else t)
        while True:
            if clock:
                before = clock()
                outcome = ta.propagate_until(end)[0]
                self.integration_ns += clock() - before
                self.integration_calls += 1
            else:
                outcome = ta.propagate_until(end)[0]
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


def reference_heyoka(job):
    """The second long double reference, a cross-check of the first (bench/peer_flow.cc
    --reference, which shares no code with heyoka): heyoka in long double, x(T), the Jacobian
    by the variational equations with the saltation matrices (no simultaneous event) or the
    Richardson differences along the directions, and the events."""
    name = job["problem"]
    L = np.longdouble
    p = fp.PROBLEMS[name]
    out = {"tool": "reference", "problem": name}
    x0 = job.get("x0")
    if name == "three":
        back = Heyoka(name, L, None, variational=False, events=False)
        x0_ld, _, _ = back.run(np.array(fp.THREE_RHO, dtype=L), fp.THREE_CROSSING_TIME,
                               [-1.0] * 3, backward=True)
        out["x0_from_crossing"] = [float(v) for v in x0_ld]
    out["x0"] = x0
    sides = initial_sides(name, x0)
    x0_ld = np.array(x0, dtype=L)
    start = time.process_time()
    if job.get("directions") is None:
        ref = Heyoka(name, L, None, variational=True)
        x, jac, events = ref.run(x0_ld, p["t"], sides)
        out["x"] = [float(v) for v in x]
        out["events"] = events
        out["jacobian"] = jac.astype(float).tolist()
    else:
        # The flow alone: no variational equations to compile (in long double that takes
        # minutes for the biped).
        plain = Heyoka(name, L, None, variational=False)
        base, _, events = plain.run(x0_ld, p["t"], sides)
        out["x"] = [float(v) for v in base]
        out["events"] = events
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
    out["cpu_s"] = time.process_time() - start
    out["settings"] = "heyoka long double, tol = epsilon (1.08e-19)"
    return out


def _bflow_reference(job):
    """The reference (bench/peer_flow.cc --reference): examples::ReferenceFlow in long double,
    independent of bflow's engine and of every peer."""
    p = fp.PROBLEMS[job["problem"]]
    x0 = job.get("x0")
    command = [job["program"], "--reference", "--problem", p["program"], "--t", repr(p["t"]),
               "--x0", "crossing" if x0 is None else ",".join(repr(v) for v in x0),
               "--reference-step", repr(REFERENCE_STEP.get(job["problem"], 2.0 ** -9))]
    if job.get("directions"):
        command += ["--directions",
                    ";".join(",".join(repr(c) for c in v) for v in job["directions"])]
    return common.run_json(command, timeout=job.get("timeout"))


def _time_empty(repeat):
    """The harness's own cost per run: an empty call timed the way every Python tool is."""
    return _time(lambda: None, repeat)[0]


def _time(function, repeat, after_warm_up=None):
    """Runs function() until MIN_CPU seconds and `repeat` runs have passed; the mean CPU time
    per run and the last result (after one untimed run: first calls import and allocate;
    after_warm_up() is called between the two)."""
    function()
    if after_warm_up:
        after_warm_up()
    runs, start = 0, time.process_time()
    while True:
        result = function()
        runs += 1
        elapsed = time.process_time() - start
        if runs >= repeat and elapsed >= MIN_CPU:
            return elapsed / runs, runs, result


def _clock_pair_ns():
    """What one pair of process_time_ns() calls adds to the interval it measures (the mean
    over many empty pairs)."""
    clock, total, count = time.process_time_ns, 0, 200000
    for _ in range(count):
        before = clock()
        total += clock() - before
    return total / count


def run_heyoka(job):
    """heyoka's whole run (x(T) and the Jacobian, the saltation matrices applied from Python)
    and, within it, heyoka's integration: the CPU time inside propagate_until, less what the
    clock around each call adds. The integrator is compiled once per tolerance and re-set
    (time, state, parameters, cooldowns) for every run."""
    name, p = job["problem"], fp.PROBLEMS[job["problem"]]
    x0, sides = job["x0"], initial_sides(job["problem"], job["x0"])
    harness = _time_empty(job["repeat"])
    pair_ns = _clock_pair_ns()
    out = []
    for tol in job["tolerances"]:
        start = time.process_time()
        integrator = Heyoka(name, float, tol)
        compile_s = time.process_time() - start

        def reset():
            integrator.integration_ns = 0
            integrator.integration_calls = 0
        try:
            cpu, runs, (x, jac, events) = _time(lambda: integrator.run(x0, p["t"], sides),
                                                job["repeat"])
            integrator.instrument = True
            _, instrumented_runs, _ = _time(lambda: integrator.run(x0, p["t"], sides),
                                            job["repeat"], after_warm_up=reset)
            integrator.instrument = False
            # One propagate_until that has nothing to do: the call's own cost, inside the
            # integration time (informative; not subtracted).
            integrator.ta.time = float(p["t"])
            empty = _time(lambda: integrator.ta.propagate_until(float(p["t"])), job["repeat"])[0]
            calls = integrator.integration_calls
            integration = (max(0.0, integrator.integration_ns - calls * pair_ns) * 1e-9
                           / instrumented_runs)
            calls /= instrumented_runs
            out.append({"tol": tol, "cpu_s": cpu, "integration_cpu_s": integration,
                        "propagate_calls": calls, "empty_propagate_s": empty,
                        "clock_pair_ns": pair_ns,
                        "harness_s": harness, "runs": runs, "compile_s": compile_s,
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
    method = job.get("method", "DOP853")
    harness = _time_empty(job["repeat"])
    out = []
    for rtol in job["tolerances"]:
        def derivative():
            base, events = _scipy_flow(name, x0, p["t"], sides, rtol, method)
            if along:
                cols = []
                for v in directions:
                    step = math.sqrt(rtol) * max(1.0, float(np.max(np.abs(x0))))
                    moved, _ = _scipy_flow(name, x0 + step * v, p["t"], sides, rtol, method)
                    cols.append((moved - base) / step)
                return base, np.array(cols).T, events
            jac = np.empty((d, d))
            for i in range(d):
                step = math.sqrt(rtol) * max(1.0, abs(x0[i]))
                moved, _ = _scipy_flow(name, x0 + step * np.eye(d)[i], p["t"], sides, rtol,
                                       method)
                jac[:, i] = (moved - base) / step
            return base, jac, events
        try:
            cpu, runs, (x, jac, events) = _time(derivative, job["repeat"])
            row = {"tol": rtol, "cpu_s": cpu, "runs": runs, "harness_s": harness,
                   "x": x.tolist(), "events": events, "status": "solved"}
            row["images" if along else "jacobian"] = jac.T.tolist() if along else jac.tolist()
            out.append(row)
        except (RuntimeError, ValueError) as e:  # ValueError: an event's root bracket lost
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

    n = p["n"]

    def segment(x, t, s, rtol, atol):
        """One diffeqsolve from (t, x) towards T with the sides s, ended by the first event:
        where it ended, whether an event ended it, and which surface flips there."""
        event = None
        offset = jnp.zeros(n)
        if n:
            h = jnp.stack(fp.surfaces(name, [x[i] for i in range(p["d"])], M))
            # A constant of the segment: no derivative may flow through it.
            offset = jax.lax.stop_gradient(2.0 * jnp.maximum(0.0, -s * h))
            event = diffrax.Event(cond_fn=cond, root_finder=optx.Newton(rtol=1e-14, atol=1e-14))
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(vector_field), solver, t0=t, t1=p["t"], dt0=None, y0=x,
            args=(s, offset), event=event, adjoint=diffrax.ForwardMode(),
            stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
            max_steps=1_000_000)
        t, x = sol.ts[-1], sol.ys[-1]
        if not n:
            return x, t, jnp.array(False), jnp.zeros(0, dtype=bool)
        fired = jnp.asarray(sol.event_mask)
        # The surface that reached zero: the smallest margin among those falling there (at a
        # simultaneous crossing the margins tie, and the one just flipped rises).
        rates = jax.jvp(lambda y: margins(y, s, offset), (x,),
                        (vector_field(t, x, (s, offset)),))[1]
        hit = jnp.argmin(jnp.where(rates < 0.0, margins(x, s, offset), jnp.inf))
        mask = (jnp.arange(n) == hit) & fired
        return x, t, fired, mask

    def trace(x, rtol, atol):
        """x(T), and (x(T), the segments' end times, their flipped surfaces, their count) as
        the auxiliary output: diffeqsolve again from each event until one reaches T, in a
        lax.while_loop that is not told how many events there are (at most MAX_EVENTS)."""
        if not n:
            x, _, _, _ = segment(x, 0.0, jnp.zeros(0), rtol, atol)
            return x, (x, jnp.zeros(0), jnp.zeros((0, 0), dtype=bool), jnp.array(0))

        def body(carry):
            x, t, s, k, _, ends, masks = carry
            x, t, fired, mask = segment(x, t, s, rtol, atol)
            s = jnp.where(mask, -s, s)
            ends = ends.at[k].set(t)
            masks = masks.at[k].set(mask)
            return x, t, s, k + 1, ~fired, ends, masks

        def going(carry):
            _, _, _, k, done, _, _ = carry
            return (~done) & (k < MAX_EVENTS + 1)

        start = (x, jnp.array(0.0), jnp.array(sides), jnp.array(0), jnp.array(False),
                 jnp.zeros(MAX_EVENTS + 1), jnp.zeros((MAX_EVENTS + 1, n), dtype=bool))
        x, _, _, k, done, ends, masks = jax.lax.while_loop(going, body, start)
        return x, (x, ends, masks, k + jnp.where(done, 0, MAX_EVENTS + 2))

    start = time.process_time()
    # What a user calls once: one jitted function giving the Jacobian and x(T) (jacfwd with
    # x(T) as its auxiliary output; forward mode evaluates the flow once with its tangents).
    both = jax.jit(jax.jacfwd(trace, has_aux=True))
    jax.block_until_ready(both(x0, 1e-6, 1e-8))
    compile_s = time.process_time() - start
    identity = jax.jit(lambda x: x)
    identity(x0).block_until_ready()
    harness = _time_empty(job["repeat"])
    dispatch = _time(lambda: identity(x0).block_until_ready(), job["repeat"])[0]
    out = []
    for rtol in job["tolerances"]:
        atol = ATOL_PER_RTOL * rtol

        def call():
            jac, aux = both(x0, rtol, atol)
            return jax.block_until_ready((jac, aux))
        try:
            cpu, runs, (jac, (x, ends, masks, segments)) = _time(call, job["repeat"])
            x, jac, segments = np.asarray(x), np.asarray(jac), int(segments)
            if segments > MAX_EVENTS + 1:
                raise RuntimeError(f"more than {MAX_EVENTS} events")
            # The events as the other tools report them: (time, surface) per flagged surface.
            events = [[float(t), j] for t, mask in zip(np.asarray(ends)[:segments],
                                                       np.asarray(masks)[:segments])
                      for j in np.flatnonzero(mask).tolist()]
            status = "solved" if np.all(np.isfinite(jac)) else "error"
            out.append({"tol": rtol, "cpu_s": cpu, "runs": runs, "compile_s": compile_s,
                        "harness_s": harness, "dispatch_s": dispatch, "x": x.tolist(),
                        "jacobian": jac.tolist(), "events": events, "segments": segments,
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


def bflow_python_model(name):
    """The problem as a bflow.Model written in SymPy: flow_problems' field and surfaces with
    SymPy symbols for x, bflow.signs(n) for the sides and SymPy for m (compiled once, cached)."""
    import sympy
    import bflow
    p = fp.PROBLEMS[name]
    x = list(sympy.symbols(f"x0:{p['d']}"))
    s = list(bflow.signs(p["n"]))
    return bflow.Model(x, field=fp.field(name, x, s, sympy), surfaces=fp.surfaces(name, x, sympy))


def run_bflow_python(job):
    """bflow's Python package in this process, timed as every Python tool: bflow.simulate with
    the unit vectors (or the test directions) as directions, on the problem written in SymPy
    (compiled before the timing; the compile time is in the row), dopri5 and the defaults."""
    import bflow
    name, p = job["problem"], fp.PROBLEMS[job["problem"]]
    start = time.perf_counter()
    model = bflow_python_model(name)
    compile_s = time.perf_counter() - start
    x0 = np.array(job["x0"], dtype=float)
    directions = (np.array(job["directions"]).T if job.get("directions")
                  else np.eye(p["d"]))
    harness = _time_empty(job["repeat"])
    out = []
    for rtol in job["tolerances"]:
        def call():
            return bflow.simulate(model, x0, p["t"], directions, backend=job["backend"],
                                  rtol=rtol, atol=ATOL_PER_RTOL * rtol)
        cpu, runs, r = _time(call, job["repeat"])
        if not r.ok:
            out.append({"tol": rtol, "status": "error", "message": r.message})
            continue
        row = {"tol": rtol, "cpu_s": cpu, "runs": runs, "harness_s": harness,
               "compile_s": compile_s, "x": np.asarray(r.x).tolist(), "steps": r.steps,
               "events": [{"t": e.t, "surfaces": list(e.surfaces)} for e in r.events],
               "notices": [n.message for n in r.notices], "status": "solved"}
        v = np.asarray(r.v)
        if job.get("directions"):
            row["images"] = v.T.tolist()
        else:
            row["jacobian"] = v.tolist()
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


WORKERS = {"reference-heyoka": reference_heyoka, "heyoka": run_heyoka, "scipy": run_scipy,
           "diffrax": run_diffrax, "bflow": run_bflow, "bflow-python": run_bflow_python,
           "hybrid-tools": run_hybrid_tools}


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


# Tolerances of SciPy's RK45 (fifth order; SciPy's documentation recommends DOP853 for high
# precision): below 1e-10 one derivative of the chain, 13 of its solves, takes seconds.
SCIPY_RK45_TOLERANCES = [1e-4, 1e-6, 1e-8, 1e-10]


def _tools(simultaneous, quick):
    """(tool, label, extra job fields) in the order of the tables."""
    low = QUICK_TOLERANCES if quick else SCIPY_RK45_TOLERANCES
    tools = [("bflow", "bflow dopri5", {"backend": "dopri5"}),
             ("bflow", "bflow dop853", {"backend": "dop853"}),
             ("bflow", "bflow defaults (auto)", {"backend": "auto"}),
             ("bflow", "bflow CVODES Adams", {"backend": "cvodes-adams"}),
             ("bflow-python", "bflow from Python (SymPy model), dopri5", {"backend": "dopri5"}),
             ("bflow-python", "bflow from Python (SymPy model), dop853", {"backend": "dop853"}),
             ("heyoka", "heyoka", {}),
             ("diffrax", "diffrax Tsit5", {"solver": "Tsit5"}),
             ("diffrax", "diffrax Dopri8", {"solver": "Dopri8"}),
             ("scipy", "SciPy DOP853 + FD", {"method": "DOP853"}),
             ("scipy", "SciPy RK45 + FD", {"method": "RK45", "tolerances": low}),
             ("scipy", "SciPy LSODA + FD", {"method": "LSODA"})]
    if simultaneous:
        tools.append(("scipy", "SciPy DOP853 + FD along v",
                      {"method": "DOP853", "along_directions": True}))
        tools.append(("hybrid-tools", "hybrid-tools", {}))
    return tools


# A row that reaches T with crossings other than the reference's (each surface's count), or
# with x(T) farther from the reference's than X_OFF times its tolerance, has not solved the
# problem, whatever its derivative's error: its status says which.
X_OFF = 1000.0


def crossings(events):
    """The surfaces crossed, sorted: from bflow's event records (each with its "surfaces") or
    from (time, surface) pairs."""
    out = []
    for e in events or []:
        out += list(e["surfaces"]) if isinstance(e, dict) else [int(e[1])]
    return sorted(out)


def check_row(row, ref):
    """The row's status after comparing its crossings and x(T) with the reference's."""
    if row.get("status") != "solved":
        return row
    mine, theirs = crossings(row.get("events")), crossings(ref["events"])
    if mine != theirs:
        row["status"] = "wrong crossings"
        row["message"] = (f"crossed surfaces {mine}, the reference {theirs}")
    elif row["x_error"] > X_OFF * row["tol"]:
        row["status"] = "x(T) off"
        row["message"] = (f"x(T) {row['x_error']:.3g} from the reference, more than "
                          f"{X_OFF:g} x tol {row['tol']:g}")
    return row


def _reference_row(name, ref, heyoka, versions, ctx, simultaneous):
    """The reference row, with the cross-check against heyoka in long double."""
    # The program's "problem" is its model's name (biped for biped-tilt): the row's is the
    # problem's.
    row = {**ref, "comparison": "flow", "problem": name, "tool": "reference",
           "version": f"examples::ReferenceFlow ({ctx.bflow_version})",
           "settings": (f"examples::ReferenceFlow, long double, RK6 step {ref['step']:g}, "
                        f"(8 D(a/4) - 6 D(a/2) + D(a)) / 3 at a = {ref['alpha']:g}")}
    if not simultaneous:
        row["jacobian"] = np.array(ref["images"]).T.tolist()
    if heyoka:
        check = {"tool": f"heyoka {versions.get('heyoka', '?')} long double",
                 "settings": heyoka.get("settings"), "cpu_s": heyoka.get("cpu_s"),
                 "x": heyoka["x"], "events": heyoka["events"],
                 "x_difference": _relative(heyoka["x"], ref["x"]),
                 "same_crossings": crossings(heyoka["events"]) == crossings(ref["events"])}
        if simultaneous:
            check["images"] = heyoka["images"]
            check["derivative_difference"] = max(_direction_errors(heyoka["images"],
                                                                   ref["images"]))
        else:
            check["jacobian"] = heyoka["jacobian"]
            check["derivative_difference"] = _relative(heyoka["jacobian"], row["jacobian"])
        if heyoka.get("x0_from_crossing"):
            check["x0_from_crossing_difference"] = _relative(heyoka["x0_from_crossing"],
                                                             ref["x0"])
        row["cross_check"] = check
    return row


def _errors(row, r, ref, simultaneous, directions, prefix=""):
    """x(T)'s and the derivative's errors of result r against the reference ref."""
    row[prefix + "x_error"] = _relative(r["x"], ref["x"])
    if simultaneous:
        images = r.get("images")
        if images is None:
            images = (np.array(r["jacobian"]) @ np.array(directions).T).T
        row[prefix + "direction_errors"] = _direction_errors(images, ref["images"])
        row[prefix + "error"] = max(row[prefix + "direction_errors"])
    else:
        row[prefix + "error"] = _relative(r["jacobian"], ref["jacobian"])


# What peers.py's --problems and --tools may name (a tool's rows: every method of it; "jump": the
# jump alone; "reference-heyoka": the long double cross-check of the reference).
SUBSETS = {"problems": list(fp.PROBLEMS),
           "tools": ["bflow", "bflow-python", "heyoka", "diffrax", "scipy", "hybrid-tools",
                     "reference-heyoka", "jump"]}


def run(ctx):
    ctx.flow_program = os.path.join(os.path.dirname(ctx.bflow), "peer_flow")
    versions = _versions(sys.executable)
    tolerances = QUICK_TOLERANCES if ctx.quick else TOLERANCES
    problems = ["chain", "ball", "biped-tilt", "biped", "three"]
    if ctx.quick:
        problems = ["chain", "ball", "three"]
    if getattr(ctx, "problems", None):
        problems = [p for p in problems if p in ctx.problems] or list(ctx.problems)
    chosen = getattr(ctx, "tools", None)

    def wanted(tool):
        return chosen is None or tool in chosen
    rows = []
    for name in problems:
        p = fp.PROBLEMS[name]
        simultaneous = name in DIRECTIONS
        directions = None
        if simultaneous:
            count = (QUICK_DIRECTIONS if ctx.quick else DIRECTIONS)[name]
            directions = _directions(name, count, p["d"])
        log(f"flow: {name}: the long double reference (examples::ReferenceFlow)")
        ref = _bflow_reference({"problem": name, "x0": p["x0"], "directions": directions,
                                "program": ctx.flow_program, "timeout": ctx.timeout})
        if ref.get("status") == "error":
            log(f"  the reference of {name}: {ref.get('message')}")
            continue
        x0 = ref["x0"]
        heyoka_ref = None
        if wanted("reference-heyoka"):
            log(f"flow: {name}: the cross-check, heyoka in long double")
            heyoka_ref = _spawn({"tool": "reference-heyoka", "problem": name, "x0": x0,
                                 "directions": directions}, ctx)
        ref_row = _reference_row(name, ref, heyoka_ref, versions, ctx, simultaneous)
        rows.append(ref_row)
        check = ref_row.get("cross_check")
        for tool, label, extra in _tools(simultaneous, ctx.quick):
            if not wanted(tool):
                continue
            extra = dict(extra)
            job = {"tool": tool, "problem": name, "x0": x0,
                   "tolerances": extra.pop("tolerances", tolerances),
                   "repeat": ctx.repeat, "directions": directions, **extra}
            if tool == "hybrid-tools":
                job["tolerances"] = [TABLE_RTOL]
            if tool == "bflow":
                job.update(program=ctx.flow_program, timeout=ctx.timeout)
                version = ctx.bflow_version
            elif tool == "bflow-python":
                version = f"{ctx.bflow_version}, Python package"
            elif tool == "diffrax":
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
                    _errors(row, r, ref_row, simultaneous, directions)
                    if check:
                        _errors(row, r, check, simultaneous, directions,
                                prefix="heyoka_reference_")
                    check_row(row, ref_row)
                rows.append(row)
    if wanted("jump"):
        import flow_jump
        ctx.jump_program = os.path.join(os.path.dirname(ctx.bflow), "peer_jump")
        rows += flow_jump.run(ctx)
    for r in rows:
        r.setdefault("comparison", "flow")
    return rows


def _settings(tool, extra, tol):
    if tool == "bflow":
        return f"{extra['backend']}, rtol {tol:g}, atol {ATOL_PER_RTOL * tol:g}, defaults"
    if tool == "bflow-python":
        return (f"bflow.simulate, {extra['backend']}, rtol {tol:g}, atol "
                f"{ATOL_PER_RTOL * tol:g}, defaults; the model written in SymPy, compiled "
                "before the timing")
    if tool == "heyoka":
        return (f"double, tol {tol:g}, variational equations, saltation by hand; the "
                "integrator compiled once and re-set for every run")
    if tool == "hybrid-tools":
        return (f"its simulator's loop with solve_ivp (RK45) rtol {tol:g} atol "
                f"{ATOL_PER_RTOL * tol:g}, its saltation matrices in its firing order, heyoka "
                "long double's transition matrices between them")
    if tool == "diffrax":
        return (f"{extra['solver']}, PIDController rtol {tol:g} atol {ATOL_PER_RTOL * tol:g}, "
                "one jit(jacfwd(has_aux)) call, ForwardMode, Event + optimistix Newton 1e-14, "
                "restarted after each event until T")
    how = "along each direction" if extra.get("along_directions") else "d + 1 runs"
    return (f"{extra.get('method', 'DOP853')} rtol {tol:g} atol {ATOL_PER_RTOL * tol:g}, "
            f"one-sided FD ({how}), step sqrt(rtol) max(1, |x0|)")


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


# The ratio table's columns: (header, [(row label, its name in the cell, CPU key)]); a column of
# several rows takes, at each error, the fastest of them and names it.
RATIO_COLUMNS = [
    ("bflow from Python (dopri5, dop853)",
     [("bflow from Python (SymPy model), dopri5", "dopri5", "cpu_s"),
      ("bflow from Python (SymPy model), dop853", "dop853", "cpu_s")]),
    ("bflow defaults (auto)", [("bflow defaults (auto)", None, "cpu_s")]),
    ("bflow CVODES Adams", [("bflow CVODES Adams", None, "cpu_s")]),
    ("heyoka, its integration", [("heyoka", None, "integration_cpu_s")]),
    ("heyoka, whole run", [("heyoka", None, "cpu_s")]),
    ("diffrax (Tsit5, Dopri8)", [("diffrax Tsit5", "Tsit5", "cpu_s"),
                                 ("diffrax Dopri8", "Dopri8", "cpu_s")]),
    ("SciPy + FD (DOP853, RK45, LSODA)", [("SciPy DOP853 + FD", "DOP853", "cpu_s"),
                                          ("SciPy RK45 + FD", "RK45", "cpu_s"),
                                          ("SciPy LSODA + FD", "LSODA", "cpu_s")]),
    ("SciPy DOP853 + FD along v", [("SciPy DOP853 + FD along v", None, "cpu_s")]),
]


def report(data, ctx):
    import flow_jump
    rows = data["rows"]
    flow_rows = [r for r in rows if r.get("comparison") == "flow"]
    jump_rows = [r for r in rows if r.get("comparison") == "jump"]
    m = data.get("machine", {})
    out = []
    after = m.get("load_average_after")
    load = (f"load average {common.fmt(m.get('load_average_before'))} before the run"
            + (f" and {common.fmt(after)} after it" if after is not None else ""))
    out.append(f"Measured {m.get('date', '?')} on {m.get('cpu', '?')} ({m.get('cores', '?')} "
               f"cores, {load}), {m.get('git', '?')}, {data.get('minutes', '?')} minutes"
               f"{' (quick)' if data.get('quick') else ''}. Versions: "
               + "; ".join(sorted({r['version'] for r in flow_rows if r.get('version')})) + ".")
    rerun = data.get("bflow_rows_rerun")
    if rerun:
        out.append(f"\nbflow's rows were run again on {rerun.get('date')} with {rerun.get('git')} "
                   f"(load average {common.fmt(rerun.get('load_average_before'))}), every other "
                   "row and the references kept from the run above.")
    problems = [p for p in fp.PROBLEMS if any(r["problem"] == p for r in flow_rows)]
    present = {r["tool"] for r in flow_rows}
    columns = [(h, [m_ for m_ in members if m_[0] in present]) for h, members in RATIO_COLUMNS]
    columns = [(h, members) for h, members in columns if members]
    header = ["problem", "error", "bflow CPU (backend)"] + [f"{h} / bflow" for h, _ in columns]
    table = []
    for name in problems:
        def points(tool, key="cpu_s"):
            return [(r.get("error"), r.get(key)) for r in flow_rows
                    if r["problem"] == name and r["tool"] == tool and r.get("status") == "solved"]
        for target in TARGETS:
            candidates = [(cpu_at(points(b), target), b.split()[1])
                          for b in ("bflow dopri5", "bflow dop853")]
            candidates = [(c, b) for c, b in candidates if c]
            base, backend = min(candidates) if candidates else (None, None)
            line = [name, f"{target:g}", f"{common.fmt(base)} s ({backend})" if base else "—"]
            for _, members in columns:
                found = [(cpu_at(points(tool, key), target), short)
                         for tool, short, key in members]
                found = [(c, short) for c, short in found if c]
                ran = any(points(tool, key) for tool, _, key in members)
                if found and base:
                    c, short = min(found)
                    line.append(common.fmt(c / base) + (f" ({short})" if short else ""))
                else:
                    line.append("not reached" if ran else "—")
            table.append(line)
    out.append("\n**Peer CPU / bflow CPU at equal error** (error of the derivative: the largest "
               "entry of dx(T)/dx0 off, over max(1, the largest entry), or at simultaneous "
               "events the largest relative error over the test directions, against the "
               "reference; each tool's CPU interpolated in log-log between its tolerances, over "
               "its rows whose status is `solved`; bflow's CPU is the faster of its two "
               "Runge-Kutta backends at each error, diffrax's and SciPy's the fastest of their "
               "methods, named in the cell; heyoka's integration is the CPU time inside its "
               "`propagate_until` calls, its whole run adds the Python that re-sets it and "
               "applies the saltation matrices; bflow's defaults (backend auto, no backend named) "
               "over its fastest backend says what a user who names none pays, >= 1; "
               "\"not reached\": no solved tolerance of the tool got there; > 1: bflow is "
               "faster).\n")
    out.append(common.table(header, table, ["---", "---:"] + ["---:"] * (len(header) - 2)))
    out.append(f"\nA row is `wrong crossings` when the surfaces it crossed (each surface's count) "
               f"differ from the reference's, `x(T) off` when its x(T) is farther from the "
               f"reference's than {X_OFF:g} times its tolerance (relative to max(1, |x|)); "
               "neither enters the ratios or the plots. *harness*: the CPU time per run of an "
               "empty call timed the same way in the tool's process (the timing loop's own "
               "cost, included in the tool's CPU).")
    # Per problem: the work-precision numbers.
    for name in problems:
        ref = next((r for r in flow_rows if r["problem"] == name and r["tool"] == "reference"),
                   None)
        out.append(f"\n### {fp.PROBLEMS[name]['title']}\n")
        if ref:
            out.append(_reference_text(ref))
        lines = []
        for r in flow_rows:
            if r["problem"] != name or r["tool"] == "reference":
                continue
            cpu = common.fmt(r.get("cpu_s"))
            if r.get("integration_cpu_s") is not None:
                cpu += f" (integration {common.fmt(r['integration_cpu_s'])})"
            harness = common.fmt(r.get("harness_s"))
            if r.get("dispatch_s") is not None:
                harness += f" (JAX dispatch {common.fmt(r['dispatch_s'])})"
            lines.append([r["tool"], f"{r.get('tol', 0):g}", r.get("status"), cpu,
                          harness if r.get("harness_s") is not None else "—",
                          common.fmt(r.get("x_error")), common.fmt(r.get("error")),
                          str(len(crossings(r["events"]))) if r.get("events") is not None
                          else "—"])
        out.append(common.table(["tool", "tol", "status", "CPU s", "harness s", "x(T) error",
                                 "derivative error", "crossings"], lines,
                                ["---", "---:", "---", "---:", "---:", "---:", "---:", "---:"]))
        if name in DIRECTIONS and ref:
            out.append(_piece_table(name, ref, flow_rows))
            earlier = data.get("hybrid_tools_rows_from")
            if earlier and any(r["tool"] == "hybrid-tools" and r["problem"] == name
                               for r in flow_rows):
                out.append(f"\nhybrid-tools was not run again: its x(T), crossings and "
                           f"derivative are those of the run of {earlier.get('date')} "
                           f"({earlier.get('git')}) from the same start, their errors measured "
                           "against this reference.")
    if ctx.plots:
        _plots(flow_rows, problems)
        out.append("\n![work-precision](peers_flow_smooth.png)\n"
                   "![work-precision](peers_flow_events.png)\n"
                   "![work-precision](peers_flow_simultaneous.png)")
    if jump_rows:
        out.append("\n### The jump alone\n")
        again = data.get("jump_rows_rerun")
        if again:
            out.append(f"Run by itself on {again.get('date')} (load average "
                       f"{common.fmt(again.get('load_average_before'))} before, "
                       f"{common.fmt(again.get('load_average_after'))} after, "
                       f"{again.get('minutes')} minutes), after the rows above.\n")
        earlier = data.get("jump_rows_from")
        if earlier:
            out.append(f"Not run again with the rows above: these rows are those of the run of "
                       f"{earlier.get('date')} ({earlier.get('git')}, load average "
                       f"{common.fmt(earlier.get('load_average_before'))}), without the "
                       "harness's own cost.\n")
        out.append(flow_jump.report(jump_rows, ctx))
    return "\n".join(out)


def _reference_text(ref):
    """The reference's settings, its own accuracy and the cross-check's disagreement."""
    text = (f"Reference: {ref.get('settings')}, {len(crossings(ref.get('events')))} crossings "
            f"({common.fmt(ref.get('cpu_s'))} s); halving its step changes the derivative by "
            f"{common.fmt(ref.get('step_change'))} and x(T) by "
            f"{common.fmt(ref.get('x_step_change'))}, halving a the derivative by "
            f"{common.fmt(ref.get('alpha_change'))}.")
    check = ref.get("cross_check")
    if check:
        text += (f" Cross-check, {check['tool']} ({check.get('settings')}): x(T) "
                 f"{common.fmt(check.get('x_difference'))} and the derivative "
                 f"{common.fmt(check.get('derivative_difference'))} apart, "
                 + ("the same crossings" if check.get("same_crossings")
                    else "**other crossings**"))
        if check.get("x0_from_crossing_difference") is not None:
            text += (f"; its own start from the crossing point "
                     f"{common.fmt(check['x0_from_crossing_difference'])} from the reference's")
        text += "."
    return text + "\n"


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
        tool = r["tool"] if r.get("status") == "solved" else f"{r['tool']} ({r['status']})"
        lines.append([tool] + cells + [f"{right} of {len(labels)}"])
    counts = {label: orders.count(label) for label in labels}
    header = ["tool (tol 1e-10)"] + [f"order {label} ({counts[label]} dir.)" for label in labels]
    header.append(f"orders right (error < {RIGHT_PIECE:g})")
    return ("\nLargest relative error ‖D v − D_ref v‖ / ‖D_ref v‖ over the test directions of "
            "each crossing order (the order the reference's perturbed trajectory crosses the "
            "surfaces in):\n\n" + common.table(header, lines))


STYLE = {"bflow dopri5": ("C0", "o-"), "bflow dop853": ("C4", "P-"),
         "bflow defaults (auto)": ("C8", "x--"),
         "bflow from Python (SymPy model), dopri5": ("C9", "*:"),
         "bflow from Python (SymPy model), dop853": ("C9", "h:"),
         "hybrid-tools": ("C5", "X"),
         "bflow CVODES Adams": ("C0", "s--"),
         "heyoka": ("C1", "^-"), "heyoka, its integration": ("C1", "^:"),
         "diffrax Tsit5": ("C2", "v-"), "diffrax Dopri8": ("C2", "<--"),
         "SciPy DOP853 + FD": ("C3", "D-"), "SciPy RK45 + FD": ("C3", "x--"),
         "SciPy LSODA + FD": ("C3", "1-."), "SciPy DOP853 + FD along v": ("C3", "d:")}


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
                source, key = tool, "cpu_s"
                if tool == "heyoka, its integration":
                    source, key = "heyoka", "integration_cpu_s"
                pts = sorted((r["error"], r[key]) for r in flow_rows
                             if r["problem"] == name and r["tool"] == source
                             and r.get("status") == "solved" and r.get("error")
                             and r.get(key))
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
