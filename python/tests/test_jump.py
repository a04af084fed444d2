"""JumpMap from NumPy against closed forms, its own pieces and the C++ API through `bflow jump`."""

import json
import math
import subprocess

import numpy as np
import pytest

import bflow

# [B] (3.1) in the plane, the table of the README's `bflow jump` example: columns are the words --, +-, -+, ++ (bit j set
# where surface j is on its + side).
NORMALS = np.eye(2)
LIMITS = np.array([[1.0, 0.5, 1.7, 0.7],
                   [1.0, 1.6, 0.6, 0.7]])


def quadrants():
    return bflow.JumpMap.from_limits(NORMALS, LIMITS)


def test_two_surfaces_against_the_crossings_by_hand():
    # dx = (-1, -0.5) reaches surface 1 first (at time 0.5 on the F_-- line), then surface 0;
    # the image follows by hand.
    B = quadrants()
    dx = np.array([-1.0, -0.5])
    o = B.order(dx)
    assert o.order == [1, 0]
    assert o.times[0] == pytest.approx(0.5, abs=1e-15)
    # After 0.5: (-0.5, 0); along F_-+ for 0.5 / 1.7 to (0, 0.3/1.7); then F_++ for the rest.
    t1 = 0.5 / 1.7
    y = 0.6 * t1
    # The perturbed state minus the nominal one once both have crossed (both then move along
    # F_++), taken back to time 0: the point of the last crossing moved back along F_++.
    tc = 0.5 + t1
    expected = np.array([0.0, y]) - np.array([0.7, 0.7]) * tc
    np.testing.assert_allclose(B.apply(dx), expected, rtol=0, atol=1e-15)


def test_block_equals_columns_and_pieces_cover_apply():
    B = quadrants()
    rng = np.random.default_rng(7)
    dx = rng.standard_normal((2, 50))
    block = B.apply(dx)
    for k in range(dx.shape[1]):
        col = B.apply(dx[:, k])
        np.testing.assert_array_equal(block[:, k], col)
        # The active piece reproduces the image (B is linear on each cone).
        np.testing.assert_allclose(B.active_jacobian(dx[:, k]) @ dx[:, k], col, atol=1e-14)
    pieces = B.pieces()
    assert sorted(tuple(p[0]) for p in pieces) == [(0, 1), (1, 0)]
    for order, matrix in pieces:
        np.testing.assert_allclose(matrix, B.saltation(order), atol=0)


def test_linear_case_of_section_3_1():
    # Delta(b) = -delta b: every piece is (1 - delta) / (1 + delta) I ([B] (3.2)).
    d, delta = 4, 0.3
    n = d
    limits = np.empty((d, 2 ** n))
    for bits in range(2 ** n):
        for i in range(d):
            plus = (bits >> i) & 1
            limits[i, bits] = 1 - delta if plus else 1 + delta
    B = bflow.JumpMap.from_limits(np.eye(d), limits)
    dx = np.array([0.3, -1.2, 0.7, 2.0])
    np.testing.assert_allclose(B.apply(dx), (1 - delta) / (1 + delta) * dx, rtol=1e-15)
    assert len(B.pieces()) == math.factorial(n)


def test_matches_the_cli(cli):
    words = {"--": [1, 1], "+-": [0.5, 1.6], "-+": [1.7, 0.6], "++": [0.7, 0.7]}
    tangents = [[1.0, 0.0], [-1.0, -0.5], [0.25, -3.0]]
    out = subprocess.run([cli, "jump", "--input", "-"], check=True, capture_output=True,
                         text=True, input=json.dumps({"normals": [[1, 0], [0, 1]],
                                                      "field_limits": words,
                                                      "tangents": tangents}))
    results = json.loads(out.stdout)["results"]
    B = quadrants()
    for dx, r in zip(tangents, results):
        np.testing.assert_allclose(B.apply(dx), r["image"], rtol=0, atol=1e-12)
        assert B.order(dx).order == r["order"]
        np.testing.assert_allclose(B.active_jacobian(dx), r["jacobian"], rtol=0, atol=1e-12)


def test_triangulation_has_n_factorial_simplices():
    t = quadrants().triangulation
    assert len(t["simplices"]) == 2
    assert t["zeta"].shape[0] == 2


@pytest.mark.parametrize("normals, limits, message", [
    (np.eye(2), np.ones((2, 3)), "2 x 4 table"),
    (np.ones((2, 2)), LIMITS, "rank"),
    (np.eye(2), -LIMITS, "not transversal"),
    (np.eye(2)[:, :, None], LIMITS, "dimension"),
])
def test_bad_input_is_refused(normals, limits, message):
    with pytest.raises(ValueError, match=message):
        bflow.JumpMap.from_limits(normals, limits)


def test_bad_direction_is_refused():
    B = quadrants()
    with pytest.raises(ValueError):
        B.apply([1.0, 2.0, 3.0])
    with pytest.raises(ValueError):
        B.apply([np.nan, 0.0])
    with pytest.raises(ValueError):
        B.apply(np.zeros((2, 2, 2)))


def test_pickles_by_its_table():
    import pickle
    B = quadrants()
    back = pickle.loads(pickle.dumps(B))
    np.testing.assert_array_equal(back.normals, B.normals)
    for dx in ([-1.0, -0.5], [0.3, 2.0]):
        np.testing.assert_array_equal(back.apply(dx), B.apply(dx))


def test_apply_into_a_given_array():
    B = quadrants()
    out = np.empty(2)
    result = B.apply([-1.0, -0.5], out=out)
    assert result is out
    np.testing.assert_array_equal(out, B.apply([-1.0, -0.5]))
    with pytest.raises(ValueError, match="out must be"):
        B.apply([-1.0, -0.5], out=np.empty(2, dtype=np.float32))
    with pytest.raises(ValueError, match="out has 3 entries"):
        B.apply([-1.0, -0.5], out=np.empty(3))


def test_at_orients_surfaces_crossed_from_plus_to_minus():
    # The quadrants mirrored through the origin, F'_b = -F_{-b}: their flow is x -> -phi(-x), so
    # they cross both surfaces from + to - where the quadrants cross from - to +, and their jump
    # map is J'(dx) = -J(-dx). A jump map that took every crossing as - to + would not be.
    import sympy as sp
    x, y = sp.symbols("x y")
    words = {"--": [1.0, 0.6], "+-": [0.5, 1.0], "-+": [1.0, 1.2], "++": [0.5, 1.6]}
    flip = {"-": "+", "+": "-"}
    quadrants = bflow.Model([x, y], field=words, surfaces=[x, y])
    mirrored = bflow.Model([x, y], surfaces=[x, y], field={
        "".join(flip[c] for c in w): [-v for v in f] for w, f in words.items()})
    J = bflow.JumpMap.at(quadrants, [0.0, 0.0])
    K = bflow.JumpMap.at(mirrored, [0.0, 0.0])
    for dx in ([1.0, -0.3], [-0.2, 1.0], [0.7, 0.7], [-1.0, 0.1]):
        dx = np.array(dx)
        np.testing.assert_allclose(K.apply(dx), -J.apply(-dx), rtol=0, atol=1e-14)
        assert K.order(dx).order == J.order(-dx).order
    # And the mirrored flow's B-derivative across that point, from the event-driven engine.
    x0 = np.array([0.5, 0.3])  # -F'_++ / 2: both surfaces at t = 1/2
    D = bflow.flow_derivative(mirrored, x0, 0.5 + 1e-9, rtol=1e-12)
    assert D.events[0].surfaces == [0, 1]
    for dx in ([1.0, -0.3], [-0.2, 1.0]):
        np.testing.assert_allclose(D.apply(dx), K.apply(np.array(dx)), rtol=0, atol=1e-7)
