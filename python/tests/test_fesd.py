"""FESD simulation from Python: the built-in Filippov examples against their exact solutions
([F] Example 3) and the C++ API's results through `bflow fesd`, and the same systems written in
SymPy against the built-in C++ examples and the exact solutions."""

import json
import subprocess

import numpy as np
import pytest
import sympy as sp

import bflow

CASES = ["crossing", "sliding-enter", "sliding-leave", "spontaneous"]


@pytest.mark.parametrize("example", CASES)
def test_switching_cases_as_in_the_cli(cli, example):
    r = bflow.fesd_simulate(example)
    out = json.loads(subprocess.run([cli, "fesd", "--example", example, "--compact"], check=True,
                                    capture_output=True, text=True).stdout)
    assert r.ok
    np.testing.assert_allclose(r.x_end, out["x_T"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.switch_times, out["switch_times"], rtol=0, atol=1e-12)
    if out.get("sensitivity"):
        np.testing.assert_allclose(r.sensitivity, out["sensitivity"], rtol=0, atol=1e-12)


@pytest.mark.parametrize("example, switch_error, state_error", [
    # Radau IIA with 2 stages, N_FE = 3, 4 steps (the defaults): the switch lands on an element
    # boundary; measured errors 0 (crossing: the switch at 1/3 is exact), 3.9e-6 (the sliding
    # mode's entry, a root of 0.54 - t - 0.04 cos 5t), 0 (sliding-leave, at t = 1).
    ("crossing", 1e-12, 1e-12),
    ("sliding-enter", 1e-5, 1e-12),
    ("sliding-leave", 1e-12, 1e-12),
])
def test_switching_cases_against_their_exact_solutions(example, switch_error, state_error):
    exact = bflow.fesd_exact(example)
    r = bflow.fesd_simulate(example)
    assert len(r.switch_times) == len(exact["switch_times"])
    np.testing.assert_allclose(r.switch_times, exact["switch_times"], rtol=0, atol=switch_error)
    np.testing.assert_allclose(r.x_end, exact["x_end"], rtol=0, atol=state_error)


def test_stewart_and_step_formulations_agree_on_crossing():
    step = bflow.fesd_simulate("crossing", formulation="step")
    stewart = bflow.fesd_simulate("crossing", formulation="stewart")
    np.testing.assert_allclose(stewart.x_end, step.x_end, atol=1e-10)
    assert stewart.switch_times == pytest.approx(step.switch_times, abs=1e-10)


@pytest.mark.parametrize("call, message", [
    (lambda: bflow.fesd_simulate("pendulum"), "unknown example 'pendulum'"),
    (lambda: bflow.fesd_simulate("crossing", elements=0), "N_FE >= 1"),
    (lambda: bflow.fesd_simulate("crossing", formulation="heaviside"), "heaviside"),
    (lambda: bflow.fesd_simulate("crossing", nfe=3), "unknown option 'nfe'"),
    (lambda: bflow.fesd_exact("irma"), "no closed-form"),
])
def test_bad_input_is_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# --- models written in SymPy: the same step inclusion as the built-in C++ examples
sx, tau = sp.symbols("x tau")
b0 = bflow.signs(1)[0]


def crossing_model(field):
    return bflow.Model([sx], field=field, surfaces=[sx])


@pytest.mark.parametrize("field, modes", [
    ([2 - b0], False),               # affine in the sign: f(x, a) = 2 - (2a - 1)
    ({"+": [1], "-": [3]}, True),    # per sign word: the two modes and the dense sign matrix
    ([2 - b0 ** 3], True),           # not affine in the sign as written: its two sign words
])
def test_a_sympy_crossing_matches_the_builtin_case_and_the_exact_switch(field, modes):
    # b^3 is not (2a - 1)^3 between the sides: only the modes give the step inclusion.
    assert crossing_model(field)._step_model().modes == (2 if modes else 0)
    exact = bflow.fesd_exact("crossing")
    builtin = bflow.fesd_simulate("crossing")
    r = bflow.fesd_simulate(crossing_model(field), T=exact["t_end"], x0=exact["x0"], steps=4)
    assert r.ok
    np.testing.assert_allclose(r.switch_times, exact["switch_times"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.x_end, exact["x_end"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.x_end, builtin.x_end, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.sensitivity, builtin.sensitivity, rtol=0, atol=1e-12)


@pytest.mark.parametrize("formulation", ["step", "stewart"])
def test_a_sympy_sliding_mode_given_per_sign_word_matches_the_builtin_case(formulation):
    # [F] Example 3's sliding-enter case, x' = -sign(x) + 0.2 sin(5 tau), tau' = 1, its two
    # sign words given as modes.
    model = bflow.Model([sx, tau], field={"+": [-1 + sp.Rational(1, 5) * sp.sin(5 * tau), 1],
                                          "-": [1 + sp.Rational(1, 5) * sp.sin(5 * tau), 1]},
                        surfaces=[sx])
    exact = bflow.fesd_exact("sliding-enter")
    builtin = bflow.fesd_simulate("sliding-enter", formulation=formulation)
    r = bflow.fesd_simulate(model, T=exact["t_end"], x0=exact["x0"], steps=4,
                            formulation=formulation)
    assert r.ok and builtin.ok
    # The same NLPs up to rounding: the C++ case writes 1 - 2a + 0.2 sin(5 tau).
    np.testing.assert_allclose(r.x_end, builtin.x_end, rtol=0, atol=1e-10)
    np.testing.assert_allclose(r.switch_times, builtin.switch_times, rtol=0, atol=1e-10)
    # Against the exact solution, as the built-in case (errors above): entry within 1e-5.
    np.testing.assert_allclose(r.switch_times, exact["switch_times"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(r.x_end, exact["x_end"], rtol=0, atol=1e-12)


def test_irma_written_in_sympy_matches_the_builtin_network():
    # IRMA ([F] Section 7.1, examples/irma.h) with a_k = (1 + b_k) / 2: seven surfaces, products
    # of selections (a_0 a_6, a_1 a_4), u = 1 as a parameter.
    x = sp.symbols("x1:6")
    b = bflow.signs(7)
    a = [(1 + bk) / 2 for bk in b]
    u = sp.Symbol("u")
    field = [-0.05 * x[0] + 1.1e-4 + 9e-4 * a[5],
             -0.04 * x[1] + 3e-4 + 0.15 * a[0] * (1 - (1 - u) * a[6]),
             -0.05 * x[2] + 6e-4 + 0.018 * a[2],
             -0.02 * x[3] + 5e-4 * a[1] + 0.03 * a[1] * (1 - a[4]),
             -0.6 * x[4] + 7.5e-4 + 0.015 * a[3]]
    surfaces = [x[0] - 0.01, x[1] - 0.01, x[1] - 0.06, x[1] - 0.08, x[2] - 0.035, x[3] - 0.04,
                x[4] - 0.01]
    model = bflow.Model(list(x), field=field, surfaces=surfaces, parameters={u: 1.0})
    builtin = bflow.fesd_simulate("irma")
    r = bflow.fesd_simulate(model, T=100.0, x0=bflow._bflow._irma_initial_state(), steps=20)
    assert r.ok and builtin.ok
    np.testing.assert_allclose(r.x_end, builtin.x_end, rtol=0, atol=1e-10)
    np.testing.assert_allclose(r.switch_times, builtin.switch_times, rtol=0, atol=1e-8)


@pytest.mark.parametrize("call, message", [
    (lambda: bflow.fesd_simulate(crossing_model([2 - b0]), T=1.0), "needs T and x0"),
    (lambda: bflow.fesd_simulate(crossing_model([2 - b0]), T=1.0, x0=[0.0, 1.0]),
     "x0 has 2 entries, the model 1 states"),
    (lambda: bflow.fesd_simulate(bflow.Model([sx], field=[1 - sx], surfaces=[]), T=1.0, x0=[0.0]),
     "at least one switching surface"),
])
def test_bad_sympy_fesd_input_is_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_a_horizon_whose_steps_cannot_be_integrated_is_a_value_error():
    # T = 1e308 returned x0 with ok=False and no exception.
    with pytest.raises(ValueError, match=r"T = 1e\+308 over N_sim = 4 steps"):
        bflow.fesd_simulate("crossing", T=1e308, steps=4)


def test_progress_prints_one_line_per_step(capfd):
    r = bflow.fesd_simulate("sliding-enter", steps=4, progress=True)
    assert r.ok and r.status == "converged" and r.message == ""
    lines = [l for l in capfd.readouterr().err.splitlines() if l.startswith("step ")]
    assert [l.split(":")[0] for l in lines] == [f"step {k}/4" for k in range(1, 5)]
    assert lines[1].startswith("step 2/4: t 0.25 + 0.25")


def test_the_result_documents_ok_status_and_message():
    doc = bflow.FesdResult.__doc__
    for field in ("ok:", "status:", "message:"):
        assert field in doc, field
