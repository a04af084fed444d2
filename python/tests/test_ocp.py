"""Optimal control of the built-in examples from Python, against their exact optima and the C++
API's results through `bflow ocp`."""

import json
import math
import subprocess

import numpy as np
import pytest

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


def test_turbo_car_reaches_the_exact_optimal_time():
    exact = bflow.ocp_exact("turbo-car")
    r = bflow.ocp_solve("turbo-car", N=5)
    assert r.ok and r.polished
    assert r.T == pytest.approx(exact["T"], abs=1e-9)
    np.testing.assert_allclose(r.switch_times, exact["switch_times"], atol=1e-9)


@pytest.mark.parametrize("call, message", [
    (lambda: bflow.ocp_solve("monoped"), "the bflow command"),
    (lambda: bflow.ocp_solve("turbo-car", N=5, relaxation="smooth"), "unknown relaxation"),
    (lambda: bflow.ocp_solve("turbo-car", N=5, stage=5), "unknown option 'stage'"),
    (lambda: bflow.ocp_solve("turbo-car", N=0), "stages"),
])
def test_bad_input_is_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()
