"""Sweeps over initial states from Python: grid order, the same records on any number of
threads, each sample equal to its own flow_derivative, failed samples recorded."""

import numpy as np
import pytest
import sympy as sp

import bflow

x, y = sp.symbols("x y")


def quadrants():
    return bflow.Model([x, y], surfaces=[x, y], field={
        "--": [1.0, 0.6], "+-": [0.5, 1.0], "-+": [1.0, 1.2], "++": [0.5, 1.6]})


def test_grid_order_structures_and_samples():
    m = quadrants()
    axes = [(0, -0.6, -0.4, 5), (1, -0.4, -0.2, 5)]
    records = bflow.sweep(m, [-0.5, -0.3], 1.0, axes, directions=[[1.0, 0.0]], progress=False)
    assert len(records) == 25
    # The first axis varies slowest.
    assert records[1].varied == pytest.approx([-0.6, -0.35])
    assert records[5].varied == pytest.approx([-0.55, -0.4])
    # The centre of the grid is x0 = -F_-- / 2: both surfaces at t = 1/2, one event; elsewhere
    # two events, in the order the start decides.
    centre = records[12]
    assert centre.structure() == "0+1 (0>1)" and centre.pieces == 2
    assert {r.structure() for r in records} == {"0+1 (0>1)", "0 | 1", "1 | 0"}
    for r in records:
        assert r.ok
        D = bflow.flow_derivative(m, r.varied, 1.0)
        np.testing.assert_allclose(r.x_t, D.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(r.images[0], D.apply([1.0, 0.0]), rtol=0, atol=1e-12)


def test_threads_do_not_change_the_records():
    m = quadrants()
    axes = [(0, -0.7, -0.3, 9)]
    one = bflow.sweep(m, [-0.5, -0.3], 1.0, axes, threads=1, progress=False)
    two = bflow.sweep(m, [-0.5, -0.3], 1.0, axes, threads=2, progress=False)
    for a, b in zip(one, two):
        assert a.varied == b.varied and a.structure() == b.structure()
        np.testing.assert_array_equal(a.x_t, b.x_t)
        for ia, ib in zip(a.images, b.images):
            np.testing.assert_array_equal(ia, ib)


def test_a_failed_sample_is_a_record():
    # x[0] = 0 starts on surface 0: that sample is refused, the others run.
    records = bflow.sweep(quadrants(), [-0.5, -0.3], 1.0, [(0, -0.2, 0.0, 3)], progress=False)
    assert [r.ok for r in records] == [True, True, False]
    assert records[2].status == "rejected" and "surface" in records[2].message


@pytest.mark.parametrize("axes, message", [
    ([(2, 0.0, 1.0, 3)], r"x\[2\] is outside"),
    ([(0, 0.0, 1.0, 0)], "count 0"),
    ([(0, 0.0)], "axis is"),
])
def test_bad_axes_are_refused(axes, message):
    with pytest.raises(ValueError, match=message):
        bflow.sweep(quadrants(), [-0.5, -0.3], 1.0, axes, progress=False)
