"""Periodic orbits from Python against the C++ API's results through `bflow orbit`, and the
verdicts of the two scenes (the pronk hops stably, the thrusting biped unstably)."""

import json
import subprocess

import numpy as np
import pytest

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
