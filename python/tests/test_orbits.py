"""Periodic orbits from Python against the C++ API's results through `bflow orbit`, and the
verdicts of the two scenes (the pronk hops stably, the thrusting biped unstably)."""

import json
import subprocess

import numpy as np
import pytest
import sympy as sp

import bflow


def cli_orbit(cli, *args):
    out = subprocess.run([cli, "orbit", "--compact", "--quiet", *args], check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out)


def assert_same_orbit(orbit, expected):
    assert orbit.converged and expected["converged"]
    np.testing.assert_allclose(orbit.x, expected["x"], rtol=0, atol=1e-12)
    assert orbit.period == pytest.approx(expected["period"], rel=1e-12)
    assert orbit.growth_rate_lower == pytest.approx(expected["growth_rate_lower"], rel=1e-12)
    assert orbit.growth_rate_upper == pytest.approx(expected["growth_rate_upper"], rel=1e-12)
    assert orbit.stability == expected["stability"]


def test_pronk_is_stable_as_in_the_cli(cli):
    orbit = bflow.find_orbit(bflow.pronk(), "-x4", bflow.pronk_initial_state())
    assert_same_orbit(orbit, cli_orbit(cli, "--scene", "pronk"))
    assert orbit.stability == "stable" and orbit.growth_rate_upper < 1.0
    # Both feet land and lift off together: events of two surfaces, a return map with pieces.
    assert max(len(e.surfaces) for e in orbit.events) == 2
    assert not orbit.return_map.is_linear()
    # On the orbit, the return map fixes x* (to the tolerance).
    assert orbit.residual <= 1e-8 * (1 + np.max(np.abs(orbit.x)))


def test_thrusting_biped_is_unstable_as_in_the_cli(cli):
    model = bflow.biped(kappa=1000, beta=4, thrust=10)
    orbit = bflow.find_orbit(model, "-x4", [0, 0.8, 0, 0, 0, 0])
    assert_same_orbit(orbit, cli_orbit(cli, "--scene", "biped"))
    assert orbit.stability == "unstable" and orbit.growth_rate_lower > 1.0


def test_family_over_thrust_as_in_the_cli(cli):
    members = bflow.continue_orbits(lambda thrust: bflow.pronk(thrust=thrust), "-x4",
                                    [10.0, 11.0, 12.0], bflow.pronk_initial_state())
    expected = cli_orbit(cli, "--scene", "pronk", "--vary-param", "thrust=10:12:3")["family"]
    assert [m.value for m in members] == [10.0, 11.0, 12.0]
    for member, row in zip(members, expected):
        assert member.predictor == row["predictor"]
        assert_same_orbit(member.orbit, row)
    # More thrust, higher hops: the apex rises.
    heights = [m.orbit.x[1] for m in members]
    assert heights[0] < heights[1] < heights[2]


@pytest.mark.parametrize("section, message", [("y4", "y4"), ("x9", "x9")])
def test_bad_sections_are_refused(section, message):
    with pytest.raises(ValueError, match=message):
        bflow.find_orbit(bflow.pronk(), section, bflow.pronk_initial_state())


def test_bad_scene_parameters_are_refused():
    with pytest.raises(ValueError, match='"thrust"'):
        bflow.pronk(thrust=-1)


def test_an_orbit_says_why_it_does_not_pickle():
    import pickle
    orbit = bflow.find_orbit(bflow.pronk(), "-x4", bflow.pronk_initial_state(), stability=False)
    with pytest.raises(TypeError, match="PeriodicOrbit does not pickle: .*find_orbit again"):
        pickle.dumps(orbit)


# --- sections other than a coordinate's level
def relay_van_der_pol():
    # x' = y, y' = -x + (1 - x^2) y - 0.2 sign(x): a limit cycle that crosses x = 0 twice per
    # period, transversally.
    import sympy as sp
    x, y = sp.symbols("x y")
    b = bflow.signs(1)[0]
    return bflow.Model([x, y], field=[y, -x + (1 - x ** 2) * y - sp.Rational(1, 5) * b],
                       surfaces=[x]), x, y


def test_sections_written_three_ways_find_the_same_orbit():
    model, x, y = relay_van_der_pol()
    # s = x + y, crossed upwards, as a hyperplane and as a SymPy expression: the same function,
    # so the same Newton steps and the same orbit.
    plane = bflow.find_orbit(model, ([1.0, 1.0], 0.0), [-1.0, 1.0])
    sympy_section = bflow.find_orbit(model, x + y, [-1.0, 1.0])
    assert plane.converged and sympy_section.converged
    np.testing.assert_allclose(sympy_section.x, plane.x, rtol=0, atol=1e-12)
    assert sympy_section.period == pytest.approx(plane.period, rel=1e-12)
    assert abs(plane.x[0] + plane.x[1]) < 1e-9
    # Through y = 0 (a coordinate's level) the orbit is the same curve: its period and the
    # multiplier of the return map (a 1 x 1 map on the section) do not depend on the section.
    level = bflow.find_orbit(model, "x1", [-2.0, 0.0])
    assert level.converged
    assert level.period == pytest.approx(plane.period, rel=1e-8)
    for o in (plane, sympy_section):
        assert o.growth_rate_upper == pytest.approx(level.growth_rate_upper, rel=1e-6)
        assert o.stability == level.stability == "stable"


def test_a_sympy_section_with_a_parameter():
    import sympy as sp
    model, x, y = relay_van_der_pol()
    c = sp.Symbol("c")
    with_c = bflow.Model(model.states, field=model.field_exprs, surfaces=[x],
                         parameters={c: 0.0})
    orbit = bflow.find_orbit(with_c, x + y - c, [-1.0, 1.0])
    plane = bflow.find_orbit(model, ([1.0, 1.0], 0.0), [-1.0, 1.0])
    np.testing.assert_allclose(orbit.x, plane.x, rtol=0, atol=1e-12)


@pytest.mark.parametrize("section, message", [
    (([1.0, 0.0, 0.0], 0.0), "normal has 3 entries, the model 2 states"),
    (([0.0, 0.0], 0.0), "normal is zero"),
    (([1.0, float("nan")], 0.0), r"normal\[1\] is nan"),
    (3.0, "expected a coordinate's text"),
])
def test_bad_hyperplanes_are_refused(section, message):
    model, _, _ = relay_van_der_pol()
    with pytest.raises(ValueError, match=message):
        bflow.find_orbit(model, section, [-1.0, 1.0])


def test_a_sympy_section_needs_a_sympy_model_and_its_symbols():
    import sympy as sp
    with pytest.raises(ValueError, match="needs a bflow.Model written in SymPy"):
        bflow.find_orbit(bflow.pronk(), sp.Symbol("z"), bflow.pronk_initial_state())
    model, x, _ = relay_van_der_pol()
    with pytest.raises(bflow.ModelError, match=r"\['z'\] are neither states"):
        bflow.find_orbit(model, x + sp.Symbol("z"), [-1.0, 1.0])


def test_no_false_orbit_where_the_relay_oscillators_loops_shrink():
    # Near the origin every loop nearly closes (P(x) / x = 1.0013 at x = 3e-6): the run from
    # 0.0834 slides there and is reported as a vanishing orbit, not converged; from 0.19 the true
    # orbit (period 2.310931, its closed-form quadrature, tests/orbits/relay_orbit_test.cc).
    x, y, k = sp.symbols("x y k")
    s = bflow.signs(1)[0]
    m = bflow.Model([x, y], field=[y, (k - y**2) * y - s], surfaces=[x], parameters={k: 0.2})
    false = bflow.find_orbit(m, "-x1", [0.0834, 0.0])
    assert not false.converged
    assert "vanishing orbit" in false.message
    true = bflow.find_orbit(m, "-x1", [0.19, 0.0])
    assert true.converged, true.message
    assert abs(true.period - 2.310931026838881) < 2e-7
