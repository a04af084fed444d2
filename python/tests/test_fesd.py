"""FESD simulation of the built-in Filippov examples from Python, against their exact solutions
([F] Example 3) and the C++ API's results through `bflow fesd`."""

import json
import subprocess

import numpy as np
import pytest

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
