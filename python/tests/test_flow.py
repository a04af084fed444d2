"""The flow's B-derivative from Python against closed forms, an exact flow, SciPy's integration
and the C++ API's own results through `bflow flow`."""

import json
import subprocess

import numpy as np
import pytest
import sympy as sp

import bflow

x, y, z = sp.symbols("x y z")


def pwconst_model(d=3, delta=0.25):
    """[B] (3.1): xdot = 1 - delta b, h(x) = x (the linear case of Section 3.1)."""
    states = [x, y, z][:d]
    b = bflow.signs(d)
    return bflow.Model(states, field=[1 - delta * b[i] for i in range(d)], surfaces=states)


def quadrants_model():
    """The README's Quadrants: F_b = (b0 ? 0.5 : 1, (b1 ? 1.6 : 1) - (b0 ? 0 : 0.4))."""
    return bflow.Model([x, y], field={"--": [1.0, 0.6], "+-": [0.5, 1.0], "-+": [1.0, 1.2],
                                      "++": [0.5, 1.6]}, surfaces=[x, y])


def quadrant_field(sides):
    f0 = 0.5 if sides[0] > 0 else 1.0
    f1 = (1.6 if sides[1] > 0 else 1.0) - (0.0 if sides[0] > 0 else 0.4)
    return np.array([f0, f1])


def exact_pwconst_flow(x0, t, field):
    """The flow of a piecewise-constant field with surfaces x_j = 0, crossing by crossing."""
    x = np.array(x0, dtype=float)
    sides = np.where(x > 0, 1, -1)
    left = t
    while True:
        f = field(sides)
        times = [(-x[j] / f[j], j) for j in range(len(x)) if x[j] * f[j] < 0 or
                 (x[j] == 0 and f[j] * sides[j] < 0)]
        tau = min(times)[0] if times else np.inf
        if tau >= left:
            return x + f * left
        x = x + f * tau
        left -= tau
        for time, j in times:
            if time == tau:
                x[j] = 0.0
                sides[j] = -sides[j]


def test_linear_case_closed_form():
    # From x0 = -F_--(0) / 2 all three surfaces are crossed at t = 1/2; at t = 1 the
    # B-derivative is (1 - delta) / (1 + delta) I ([B] (3.2)), a Jacobian.
    delta = 0.25
    m = pwconst_model(3, delta)
    D = bflow.flow_derivative(m, -np.full(3, (1 + delta) / 2), 1.0)
    assert len(D.events) == 1 and D.events[0].surfaces == [0, 1, 2]
    assert D.events[0].t == pytest.approx(0.5, abs=1e-12)
    assert D.is_linear()
    np.testing.assert_allclose(D.jacobian(), (1 - delta) / (1 + delta) * np.eye(3), atol=1e-12)


def test_quadrants_against_the_exact_flow():
    # Both surfaces at t = 0.5 from x0 = -F_-- / 2; the flow is piecewise linear, so one-sided
    # differences of the exact flow are exact up to rounding (1e-16 / alpha).
    m = quadrants_model()
    x0 = np.array([-0.5, -0.3])
    D = bflow.flow_derivative(m, x0, 1.0)
    assert [e.surfaces for e in D.events] == [[0, 1]]
    assert not D.is_linear()
    with pytest.raises(ValueError, match="piecewise linear"):
        D.jacobian()
    np.testing.assert_allclose(D.x, exact_pwconst_flow(x0, 1.0, quadrant_field), atol=1e-12)
    rng = np.random.default_rng(3)
    directions = rng.standard_normal((2, 40))
    alpha = 1e-6
    base = exact_pwconst_flow(x0, 1.0, quadrant_field)
    orders = set()
    for k in range(directions.shape[1]):
        dx = directions[:, k]
        fd = (exact_pwconst_flow(x0 + alpha * dx, 1.0, quadrant_field) - base) / alpha
        np.testing.assert_allclose(D.apply(dx), fd, rtol=0, atol=1e-8)
        orders.add(tuple(D.crossing_orders(dx)[0].order))
    assert orders == {(0, 1), (1, 0)}  # both pieces were exercised
    np.testing.assert_allclose(D.apply(directions),
                               np.column_stack([D.apply(directions[:, k])
                                                for k in range(directions.shape[1])]), atol=0)
    assert sorted(tuple(p[0][0]) for p in D.pieces()) == [(0, 1), (1, 0)]


def smooth_model():
    """Nonlinear fields; symmetric under x <-> y before the crossing, so from the diagonal both
    surfaces are crossed at once."""
    return bflow.Model([x, y], field={
        "--": [1 + 0.2 * y ** 2, 1 + 0.2 * x ** 2],
        "+-": [0.5 + 0.1 * sp.sin(y), 1.3 + 0.2 * x],
        "-+": [1.4 + 0.1 * x * y, 0.7],
        "++": [0.8 - 0.1 * y, 0.9 + 0.1 * x]}, surfaces=[x, y])


def smooth_field(sides, s):
    xx, yy = s
    word = ("+" if sides[0] > 0 else "-") + ("+" if sides[1] > 0 else "-")
    return {"--": [1 + 0.2 * yy ** 2, 1 + 0.2 * xx ** 2],
            "+-": [0.5 + 0.1 * np.sin(yy), 1.3 + 0.2 * xx],
            "-+": [1.4 + 0.1 * xx * yy, 0.7],
            "++": [0.8 - 0.1 * yy, 0.9 + 0.1 * xx]}[word]


def scipy_flow(x0, t):
    """The same flow by SciPy's DOP853 with its own event location, surface by surface."""
    from scipy.integrate import solve_ivp
    state = np.array(x0, dtype=float)
    sides = np.where(state > 0, 1, -1)
    now = 0.0
    while now < t:
        events = []
        for j in range(2):
            ev = (lambda j: lambda _t, s: s[j])(j)
            ev.terminal = True
            ev.direction = -sides[j]  # towards the other side only (a start on h = 0 is no event)
            events.append(ev)
        sol = solve_ivp(lambda _t, s: smooth_field(sides, s), (now, t), state, method="DOP853",
                        rtol=1e-13, atol=1e-15, events=events)
        state = sol.y[:, -1]
        now = sol.t[-1]
        if sol.status == 1:
            # The surface whose event stopped the step, and every other one the state has reached
            # or crossed by then: from the diagonal both are crossed at once, and the rounding of
            # the dense output (which differs between CPUs) can put the second a few ulps past
            # its surface, where its event would never fire.
            hit = [j for j in range(2) if sol.t_events[j].size or sides[j] * state[j] <= 1e-12]
            for j in hit:
                sides[j] = -sides[j]
                state[j] = 0.0
    return state


def test_nonlinear_fields_against_scipy_one_sided_differences():
    m = smooth_model()
    x0 = np.array([-0.4, -0.4])
    D = bflow.flow_derivative(m, x0, 1.0, rtol=1e-10)
    assert [e.surfaces for e in D.events] == [[0, 1]]
    np.testing.assert_allclose(D.x, scipy_flow(x0, 1.0), atol=1e-9)
    base = scipy_flow(x0, 1.0)
    for dx in (np.array([1.0, 0.2]), np.array([0.1, 1.0]), np.array([-0.7, 0.4])):
        exact = D.apply(dx)
        errors = []
        for alpha in (1e-3, 1e-4):
            fd = (scipy_flow(x0 + alpha * dx, 1.0) - base) / alpha
            errors.append(np.max(np.abs(fd - exact)))
        # One-sided differences converge at first order: the error falls tenfold with alpha, to
        # below 1e-5 at alpha = 1e-4 (measured 2.3e-6 to 8.5e-6; a wrong derivative would stop
        # at its own error).
        assert errors[1] < 1.5e-5, errors
        assert errors[1] < 0.15 * errors[0], errors


def test_simulate_with_directions_matches_flow_derivative():
    m = smooth_model()
    x0 = np.array([-0.4, -0.4])
    dirs = np.array([[1.0, 0.1], [0.2, 1.0]])
    r = bflow.simulate(m, x0, 1.0, dirs, rtol=1e-10)
    D = bflow.flow_derivative(m, x0, 1.0, rtol=1e-10)
    assert r.ok and r.status == "reached the end"
    np.testing.assert_allclose(r.v, D.apply(dirs), atol=1e-8)
    np.testing.assert_allclose(bflow.fd.one_sided(m, x0, 1.0, dirs[:, 0], 1e-4, rtol=1e-12),
                               scipy_flow_difference(x0, dirs[:, 0], 1e-4), atol=1e-7)


def scipy_flow_difference(x0, dx, alpha):
    return (scipy_flow(x0 + alpha * dx, 1.0) - scipy_flow(x0, 1.0)) / alpha


def test_biped_matches_the_cli(cli):
    D = bflow.flow_derivative(bflow.biped(), bflow.biped_initial_state(), 0.6)
    args = [cli, "flow", "--scene", "biped", "--t", "0.6", "--compact"]
    for i in range(6):
        args += ["--dx", ",".join("1" if j == i else "0" for j in range(6))]
    out = json.loads(subprocess.run(args, check=True, capture_output=True, text=True).stdout)
    np.testing.assert_allclose(D.x, out["x_t"], rtol=0, atol=1e-12)
    for i, row in enumerate(out["directions"]):
        np.testing.assert_allclose(D.apply(np.eye(6)[i]), row["image"], rtol=0, atol=1e-12)
        assert [o.order for o in D.crossing_orders(np.eye(6)[i])] == row["orders"]
    # The README's C++ tour prints these digits.
    np.testing.assert_allclose(D.apply(np.eye(6)[2]),
                               [0.01957, -0.09941, 0.9754, 0.6247, -0.383, 0.1063], atol=6e-5)


@pytest.mark.parametrize("call, message", [
    (lambda m: bflow.flow_derivative(m, [0.1, 0.2, 0.3], 1.0), "x0 has 3 entries"),
    (lambda m: bflow.flow_derivative(m, [-0.5, -0.3], 1.0, rtool=1e-6), "unknown option 'rtool'"),
    (lambda m: bflow.flow_derivative(m, [-0.5, -0.3], 1.0, backend="rk4"), "rk4"),
    (lambda m: bflow.flow_derivative(m, [-0.5, -0.3], 1.0, rtol=-1.0), "rtol"),
    (lambda m: bflow.flow_derivative(m, [np.nan, -0.3], 1.0), "x0"),
    (lambda m: bflow.flow_derivative("not a model", [0.0], 1.0), "expected a bflow.Model"),
])
def test_bad_input_is_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call(quadrants_model())


def test_sympy_model_matches_the_cpp_scene_through_the_cli(cli):
    # The pwconst scene of `bflow flow` (examples/piecewise_constant.h, the linear case d = 3)
    # and the same field written in SymPy: the same trajectory, event and derivative to 1e-12.
    directions = [[1.0, 0.0, 0.0], [0.3, -2.0, 0.5], [-1.0, 0.25, 4.0]]
    args = [cli, "flow", "--scene", "pwconst", "--param", "d=3", "--param", "delta=0.25",
            "--compact"]
    for dx in directions:
        args += ["--dx", ",".join(repr(v) for v in dx)]
    out = json.loads(subprocess.run(args, check=True, capture_output=True, text=True).stdout)
    D = bflow.flow_derivative(pwconst_model(3, 0.25), out["x0"], out["t"])
    np.testing.assert_allclose(D.x, out["x_t"], rtol=0, atol=1e-12)
    assert [e.surfaces for e in D.events] == [e["surfaces"] for e in out["events"]]
    assert D.events[0].t == pytest.approx(out["events"][0]["t"], abs=1e-12)
    for dx, row in zip(directions, out["directions"]):
        np.testing.assert_allclose(D.apply(dx), row["image"], rtol=0, atol=1e-12)


def test_results_say_why_they_do_not_pickle():
    import pickle
    m = quadrants_model()
    D = bflow.flow_derivative(m, [-0.5, -0.3], 1.0)
    with pytest.raises(TypeError, match="FlowDerivative does not pickle: .*flow_derivative again"):
        pickle.dumps(D)
    with pytest.raises(TypeError, match="Event does not pickle"):
        pickle.dumps(D.events[0])
    # A jump of the derivative pickles (by its table) and maps as before.
    jump = D.jumps()[0]
    back = pickle.loads(pickle.dumps(jump))
    np.testing.assert_array_equal(back.apply([-1.0, -0.5]), jump.apply([-1.0, -0.5]))


def test_central_differences_average_the_two_sides_of_a_nonlinear_b_derivative():
    # At the quadrants' simultaneous crossing the B-derivative is piecewise linear: +dx and -dx
    # cross the surfaces in opposite orders, so the central difference is (D dx - D(-dx)) / 2,
    # not D dx. The flow is piecewise linear, so the exact flow's differences agree to rounding.
    m = quadrants_model()
    x0 = -quadrant_field([-1, -1]) / 2
    dx = np.array([1.0, -0.3])
    alpha = 1e-6
    D = bflow.flow_derivative(m, x0, 1.0, rtol=1e-12)
    central = bflow.fd.central(m, x0, 1.0, dx, alpha, rtol=1e-12)
    exact = (exact_pwconst_flow(x0 + alpha * dx, 1.0, quadrant_field)
             - exact_pwconst_flow(x0 - alpha * dx, 1.0, quadrant_field)) / (2 * alpha)
    np.testing.assert_allclose(central, exact, rtol=0, atol=1e-8)
    np.testing.assert_allclose(central, (D.apply(dx) - D.apply(-dx)) / 2, rtol=0, atol=1e-8)
    assert np.max(np.abs(central - D.apply(dx))) > 1e-2


def test_initial_sides_that_contradict_h_are_refused():
    # The biped's start is in the air (h < 0 for both feet): "++" would use the contact field
    # there. A side is the caller's only where x0 is on the surface to the integration
    # tolerance; beyond it, the message names the surface, the side and h_j(x0).
    m, x0 = bflow.biped(), bflow.biped_initial_state()
    with pytest.raises(ValueError, match=r'initial_sides "\+\+" puts x0 on side \+ of surface 0, '
                                         r'but h_0\(x0\) = -'):
        bflow.simulate(m, x0, 0.6, initial_sides="++")
    with pytest.raises(ValueError, match="surface 0"):
        bflow.flow_derivative(m, x0, 0.6, initial_sides="+-")
    # The sides h(x0) has are accepted and give the default run.
    given = bflow.simulate(m, x0, 0.6, initial_sides="--")
    default = bflow.simulate(m, x0, 0.6)
    np.testing.assert_array_equal(given.x, default.x)
