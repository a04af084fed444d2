"""Optimal control from Python: the built-in examples against their exact optima and the C++
API's results through `bflow ocp`, and the same problems written in SymPy against both."""

import json
import os
import re
import math
import subprocess

import numpy as np
import pytest
import sympy as sp

import bflow


def test_braking_block_as_in_the_cli_and_second_order_in_n(cli):
    exact = bflow.ocp_exact("braking-block")
    assert exact["objective"] == pytest.approx(2 * math.sqrt(5) + math.asinh(2) - 4, rel=1e-15)
    coarse = bflow.ocp_solve("braking-block", N=10)
    out = json.loads(subprocess.run([cli, "ocp", "--example", "braking-block", "--compact"],
                                    check=True, capture_output=True, text=True).stdout)
    assert coarse.status == out["status"] == "solved"
    assert coarse.objective == pytest.approx(out["objective"], rel=1e-12)
    assert coarse.ipopt_iterations == out["ipopt_iterations"]
    fine = bflow.ocp_solve("braking-block", N=20)
    errors = [r.objective - exact["objective"] for r in (coarse, fine)]
    # docs/ocp.md: 1.128e-2 at N = 10, 2.834e-3 at N = 20 (order 1.99).
    assert errors[0] == pytest.approx(1.128e-2, rel=1e-3)
    assert math.log2(errors[0] / errors[1]) == pytest.approx(2.0, abs=0.05)
    # The switch to sliding lands on an element boundary near the exact stop time.
    assert min(abs(t - exact["stop_time"]) for t in fine.switch_times) < 2e-3


def test_homotopy_and_solver_keywords_reach_their_groups():
    # The keywords are flat; each lands in the options' group (OcpOptions::homotopy, ::solver)
    # and changes the solve: sigma from 1e-2 to 1e-3 is two NLPs at those sigmas, no polish.
    r = bflow.ocp_solve("braking-block", N=3, sigma_initial=1e-2, sigma_final=1e-3,
                        early_polish_sigma=0.0, polish=False, blas_threads=0)
    assert [step.sigma for step in r.homotopy] == pytest.approx([1e-2, 1e-3], rel=1e-12)
    assert not any(step.polish for step in r.homotopy)
    assert "(its own count)" in r.blas or not r.blas.startswith("OpenBLAS"), r.blas
    # fesd_simulate's homotopy keywords land in FesdOptions::homotopy, whose check names them.
    with pytest.raises(ValueError, match=r"sigma_initial = 1, sigma_final = 2\b"):
        bflow.fesd_simulate("crossing", sigma_final=2.0)
    # The defaults of each owner's homotopy, as docs/ocp.md and docs/fesd.md state them.
    ocp, fesd = bflow._bflow.OcpOptions().homotopy, bflow._bflow.FesdOptions().homotopy
    assert (ocp.sigma_initial, ocp.sigma_final, ocp.nlp_tolerance, ocp.max_nlp_iterations,
            ocp.superlinear, ocp.polish, ocp.monotone_mu_down_to) == (100.0, 1e-10, 1e-10, 3000,
                                                                      False, True, 1e-2)
    assert (fesd.sigma_initial, fesd.sigma_final, fesd.nlp_tolerance, fesd.max_nlp_iterations,
            fesd.superlinear) == (1.0, 1e-12, 1e-13, 500, True)


def cli_ocp(cli, *args):
    # The command exits with 1 when the homotopy stops short of the complementarity tolerance,
    # and still prints the result.
    out = subprocess.run([cli, "ocp", "--compact", "--quiet", *args], check=False,
                         capture_output=True, text=True).stdout
    return json.loads(out)


@pytest.mark.parametrize("name, python, command", [
    # One NLP each, at a relaxation that stops short of the tolerance, as tests/cli's cases: the
    # monoped's nosnoc setup at N = 3, sigma = 1; the hopper at N = 5 stopped at sigma = 100.
    ("monoped", dict(N=3, sigma_initial=1.0, sigma_final=1.0),
     ["--N", "3", "--sigma0", "1", "--sigma-final", "1"]),
    ("hopper", dict(N=5, sigma_final=100.0), ["--N", "5", "--sigma-final", "100"]),
])
def test_contact_examples_as_in_the_cli(cli, name, python, command):
    r = bflow.ocp_solve(name, **python)
    out = cli_ocp(cli, "--example", name, *command)
    assert r.status == out["status"] == "complementarity_not_reached"
    assert r.ipopt_iterations == out["ipopt_iterations"]
    # x_stages is d x (N + 1) and u nu x N; the command writes them stage by stage.
    np.testing.assert_allclose(r.x_stages.T, out["x"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.u.T, out["u"], rtol=0, atol=1e-12)
    # Time-freezing: the clock (state 8) ends each stage at its physical time.
    assert np.array(out["x"])[-1][8] == pytest.approx(
        {"monoped": 3.0, "hopper": 5.0}[name], abs=1e-3)


def test_turbo_car_reaches_the_exact_optimal_time():
    exact = bflow.ocp_exact("turbo-car")
    r = bflow.ocp_solve("turbo-car", N=5)
    assert r.ok and r.polished
    assert r.T == pytest.approx(exact["T"], abs=1e-9)
    np.testing.assert_allclose(r.switch_times, exact["switch_times"], atol=1e-9)
    # Each NLP names its mu strategy: monotone for the warm starts at sigma >= 1e-2, adaptive
    # for the first, those below and the polishes; monotone_mu_down_to=inf: adaptive throughout.
    relaxed = [s for s in r.homotopy if not s.polish]
    assert [s.sigma for s in relaxed[:5]] == pytest.approx([100, 10, 1, 0.1, 0.01], rel=1e-12)
    assert [s.mu_strategy for s in relaxed] == (["adaptive"] + ["monotone"] * 4
                                                + ["adaptive"] * (len(relaxed) - 5))
    assert [s.mu_init for s in relaxed[1:5]] == pytest.approx([0.1, 1e-2, 1e-3, 1e-4])
    assert all(s.mu_strategy == "adaptive" for s in r.homotopy if s.polish)
    a = bflow.ocp_solve("turbo-car", N=5, monotone_mu_down_to=float("inf"))
    assert a.ok and a.T == pytest.approx(exact["T"], abs=1e-9)
    assert {s.mu_strategy for s in a.homotopy} == {"adaptive"}


def test_derivative_programs_and_jets_reach_the_same_optimum_and_say_which_ran(cli):
    """The Jacobian and exact Hessian as programs traced once (the default) or by Jets at every
    evaluation (derivative_programs=False; the command's --jet-derivatives): the same optimal
    time of the turbo car, and each result names how its derivatives were computed."""
    exact = bflow.ocp_exact("turbo-car")
    programs = bflow.ocp_solve("turbo-car", N=5)
    jets = bflow.ocp_solve("turbo-car", N=5, derivative_programs=False)
    assert programs.ok and jets.ok
    assert programs.T == pytest.approx(exact["T"], abs=1e-9)
    assert jets.T == pytest.approx(exact["T"], abs=1e-9)
    traced = re.fullmatch(r"programs: (\d+) traced, none kept on Jets", programs.derivatives)
    assert traced and int(traced.group(1)) > 0, programs.derivatives
    assert jets.derivatives == "Jets (derivative_programs off)"
    command = json.loads(subprocess.run(
        [cli, "ocp", "--example", "turbo-car", "--N", "5", "--quiet", "--compact",
         "--jet-derivatives"], capture_output=True, text=True, check=True).stdout)
    assert command["derivatives"] == jets.derivatives
    assert command["T"] == pytest.approx(exact["T"], abs=1e-9)
    simulated = bflow.fesd_simulate("crossing")
    assert simulated.derivatives.startswith("programs: ")


def test_derivative_form_reaches_the_same_optimal_time_with_a_sparser_jacobian():
    exact = bflow.ocp_exact("turbo-car")
    integral = bflow.ocp_solve("turbo-car", N=5)
    derivative = bflow.ocp_solve("turbo-car", N=5, collocation_form="derivative")
    assert derivative.ok
    assert derivative.T == pytest.approx(exact["T"], abs=1e-9)
    assert derivative.jacobian_nonzeros < integral.jacobian_nonzeros


@pytest.mark.parametrize("call, message", [
    (lambda: bflow.ocp_solve("pendulum"), "braking-block, turbo-car, monoped and hopper"),
    (lambda: bflow.ocp_solve("hopper", N=7), "multiple of 5"),
    (lambda: bflow.ocp_solve("hopper", N=5, setup="strict"), "only the monoped has setups"),
    (lambda: bflow.ocp_solve("monoped", N=3, setup="loose"), "unknown monoped setup"),
    (lambda: bflow.ocp_solve("turbo-car", N=5, relaxation="smooth"), "unknown relaxation"),
    (lambda: bflow.ocp_solve("turbo-car", N=5, stage=5), "unknown option 'stage'"),
    (lambda: bflow.ocp_solve("turbo-car", N=5, collocation_form="weak"),
     "unknown collocation form \"weak\""),
    (lambda: bflow.ocp_solve("turbo-car", N=0), r"N=0 is outside \[1, "),
])
def test_bad_input_is_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# --- optimal control of models written in SymPy (examples/ocp_examples.h, the same problems)
p, v, u = sp.symbols("p v u")
b0 = bflow.signs(1)[0]


def turbo_car(**extra):
    # v' = (1 + 2a) u, a in gamma(v - 10): a = (1 + b) / 2 gives (2 + b) u.
    return bflow.Model([p, v], field=[v, (2 + b0) * u], surfaces=[v - 10], controls=[u],
                       terminal=[p - 200, v], **extra)


TURBO_DATA = dict(x0=[0, 0], T=15.0, time_optimal=True, x_lower=[-1e19, -20],
                  x_upper=[1e19, 20], u_lower=[-5], u_upper=[5])


def test_a_sympy_turbo_car_reaches_the_exact_optimal_time_as_the_builtin():
    exact = bflow.ocp_exact("turbo-car")
    builtin = bflow.ocp_solve("turbo-car", N=5)
    r = bflow.ocp_solve(turbo_car(), N=5, **TURBO_DATA)
    assert r.ok and r.polished
    assert r.T == pytest.approx(exact["T"], abs=1e-9)
    np.testing.assert_allclose(r.switch_times, exact["switch_times"], atol=1e-9)
    assert r.T == pytest.approx(builtin.T, abs=1e-10)
    np.testing.assert_allclose(r.u, builtin.u, atol=1e-7)


def test_a_sympy_braking_block_given_per_sign_word_matches_the_builtin():
    # x'' = u - sign(v) per sign word (the modes of the dense sign matrix), L = v^2 + u^2.
    model = bflow.Model([p, v], field={"+": [v, u - 1], "-": [v, u + 1]}, surfaces=[v],
                        controls=[u], lagrange=v ** 2 + u ** 2)
    exact = bflow.ocp_exact("braking-block")
    builtin = bflow.ocp_solve("braking-block", N=10)
    r = bflow.ocp_solve(model, N=10, x0=[0, 2], T=3.0)
    assert r.status == builtin.status == "solved"
    assert r.objective == pytest.approx(builtin.objective, rel=1e-9)
    # docs/ocp.md: the error at N = 10 is 1.128e-2.
    assert r.objective - exact["objective"] == pytest.approx(1.128e-2, rel=1e-3)


@pytest.mark.parametrize("build, message", [
    (lambda: bflow.Model([p, v], field=[v, u], surfaces=[v - u], controls=[u]),
     r"surfaces\[0\] uses the control"),
    (lambda: bflow.Model([p, v], field=[v, u], surfaces=[v], controls=[u], mayer=u ** 2),
     r"mayer\[0\] uses the control"),
    (lambda: bflow.Model([p, v], field=[v, 1], surfaces=[v], lagrange=v ** 2),
     "give its controls"),
    (lambda: bflow.Model([p, v], field=[v, u], surfaces=[], controls=[u]),
     "at least one switching surface"),
    (lambda: bflow.Model([p, v], field=[v, u], surfaces=[v], controls=[u],
                         terminal=[p * b0]), "cannot depend on the side"),
])
def test_bad_sympy_ocp_models_are_refused_before_compiling(build, message):
    with pytest.raises(bflow.ModelError, match=message):
        build()


@pytest.mark.parametrize("call, message", [
    (lambda: bflow.ocp_solve(turbo_car(), N=5, T=15.0), "needs x0 and T"),
    (lambda: bflow.ocp_solve(turbo_car(), N=5, **dict(TURBO_DATA, u_lower=[-5, 0])),
     "u_lower"),
    (lambda: bflow.ocp_solve("turbo-car", N=5, x0=[0, 0]), "has its own"),
    (lambda: bflow.fesd_simulate(turbo_car(), T=1.0, x0=[0, 0]), "optimal control model"),
    (lambda: bflow.flow_derivative(turbo_car(), [0, 0], 1.0), "optimal control model"),
    (lambda: bflow.ocp_solve(bflow.Model([p, v], field=[v, 1 - b0], surfaces=[v]), N=5,
                             x0=[0, 1], T=1.0), "no controls"),
])
def test_bad_sympy_ocp_input_is_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# --- threads, Ctrl-C and input checked before IPOPT (docs/ocp.md, Threads, Ctrl-C and what is
# refused). Cases that could end the interpreter with a signal run in a child process, so that a
# crash fails the test instead of killing pytest.
import sys
import textwrap


def _child(code, timeout=300):
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=timeout)


def test_two_threads_give_the_serial_results():
    # IPOPT and MUMPS from two threads at once (the GIL is released) ended in SIGSEGV ("PB
    # allocation in DMUMPS_LOAD_INIT"); serialised, each call gives the serial result.
    r = _child("""
        from concurrent.futures import ThreadPoolExecutor
        import numpy as np, bflow
        def run(k):
            if k % 2:
                return bflow.fesd_simulate("sliding-enter", newton=False, steps=2).x_end
            return bflow.ocp_solve("turbo-car", N=5).u
        serial = [run(k) for k in range(4)]
        with ThreadPoolExecutor(2) as pool:
            both = list(pool.map(run, range(4)))
        assert all(np.array_equal(a, b) for a, b in zip(serial, both)), (serial, both)
        print("same")
    """)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "same"


@pytest.mark.parametrize("data, message", [
    (dict(guess_u=[np.nan]), r"guess_u\(0, 0\) = nan must be finite"),
    (dict(guess_u=[np.inf]), r"guess_u\(0, 0\) = inf must be finite"),
    (dict(guess_u=[1e308]), "at the initial guess .* the objective is inf"),
    (dict(guess_x=[0, np.inf]), r"guess_x\[1\] = inf must be finite"),
    (dict(u_lower=[np.inf]), r"u_lower\[0\] = inf: a lower bound may be -inf"),
    (dict(T_max=5.0), "time_optimal is not set"),
])
def test_non_finite_or_absurd_data_is_a_value_error_not_a_crash(data, message):
    # Each of the guesses ended the interpreter with SIGSEGV; in a child process so that a
    # crash fails here.
    r = _child(f"""
        import numpy as np, sympy as sp, bflow
        nan, inf = float("nan"), float("inf")
        p, v, u = sp.symbols("p v u")
        b0 = bflow.signs(1)[0]
        m = bflow.Model([p, v], field=[v, u - b0], surfaces=[v], controls=[u],
                        lagrange=v ** 2 + u ** 2)
        try:
            bflow.ocp_solve(m, N=5, x0=[0, 2.0], T=2.0, **{data!r})
            print("solved")
        except ValueError as e:
            print("ValueError:", e)
    """)
    assert r.returncode == 0, r.stderr[-2000:]
    import re
    assert re.search(message, r.stdout), r.stdout


def test_standard_with_cross_complementarity_is_refused():
    with pytest.raises(ValueError, match="cross complementarity point-sums belongs to FESD"):
        bflow.ocp_solve("turbo-car", N=5, standard=True, cross_complementarity="point-sums")


def default_sigint():
    """preexec_fn of a child that must see Ctrl-C as a user does: SIGINT back to its default
    (pytest-xdist's workers ignore SIGINT, a child inherits that, and Python installs its
    KeyboardInterrupt handler only where SIGINT is not ignored)."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_stops_a_long_solve_with_the_partial_result():
    # The turbo car at N = 200 takes minutes; SIGINT after 2 s must end it within 10 s (IPOPT
    # iterations of this size take well under a second) with KeyboardInterrupt carrying the
    # result of the last solved NLP.
    import signal
    import time
    child = subprocess.Popen([sys.executable, "-c", textwrap.dedent("""
        import sys, time, bflow
        print("start", flush=True)
        try:
            bflow.ocp_solve("turbo-car", N=200)
            print("finished")
        except KeyboardInterrupt as e:
            r = e.args[1]
            print("KeyboardInterrupt", r.status, e.result is r, flush=True)
    """)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)
    assert child.stdout.readline().strip() == "start"
    time.sleep(2.0)
    sent = time.monotonic()
    child.send_signal(signal.SIGINT)
    out, err = child.communicate(timeout=60)
    waited = time.monotonic() - sent
    assert out.strip() == "KeyboardInterrupt cancelled True", (out, err[-2000:])
    assert waited < 10.0, waited


def test_the_results_name_the_solver_stack_the_command_uses(cli):
    """OcpResult and FesdResult name IPOPT, the linear solver with their versions and the BLAS
    with its threads, as the command's JSON does; the extension's IPOPT is the one in the installed casadi package."""
    r = bflow.ocp_solve("braking-block", N=2, elements=1)
    f = bflow.fesd_simulate("crossing")
    assert re.fullmatch(r"IPOPT 3\.\d+\.\d+", r.ipopt)
    assert re.fullmatch(r"mumps 5\.\d+\.\d+", r.linear_solver)
    assert (f.ipopt, f.linear_solver) == (r.ipopt, r.linear_solver)
    command = json.loads(subprocess.run(
        [cli, "ocp", "--example", "braking-block", "--N", "2", "--nfe", "1", "--quiet",
         "--compact"], capture_output=True, text=True, check=True).stdout)
    assert (command["ipopt"], command["linear_solver"]) == (r.ipopt, r.linear_solver)
    # The BLAS under MUMPS, casadi's OpenBLAS, on the one thread asked by default.
    assert re.fullmatch(r"OpenBLAS \d+\.\d+\.\d+, 1 thread \(libcasadi-tp-openblas\.so\.0\)",
                        r.blas), r.blas
    assert f.blas == r.blas == command["blas"]
    assert "2 threads" in bflow.ocp_solve("braking-block", N=2, elements=1, blas_threads=2).blas
    import casadi  # noqa: F401  (the package whose libipopt.so.3 the extension's run path names)
    casadi_dir = os.path.dirname(casadi.__file__)
    with open("/proc/self/maps") as maps:
        loaded = {line.split()[-1] for line in maps if line.rstrip().endswith("libipopt.so.3")}
    assert loaded == {os.path.realpath(os.path.join(casadi_dir, "libipopt.so.3"))}
