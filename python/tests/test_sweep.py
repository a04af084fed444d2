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
    ([(0, 0.0, 1.0, 0)], r"count of the axis x\[0\]=0 is outside \[1, "),
    ([(0, 0.0, 1.0, -2)], r"count of the axis x\[0\]=-2 is outside"),
    ([(0, 0.0)], "axis is"),
    # Beyond the C++ integer types: a ValueError naming the value, not nanobind's "incompatible
    # function arguments".
    ([(0, 0.0, 1.0, 2 ** 70)], r"count of the axis x\[0\]=1180591620717411303424 is outside"),
    ([(2 ** 40, 0.0, 1.0, 3)], r"state index of an axis=1099511627776 is outside"),
    ([(0, 0.0, 1.0, 2.5)], r"count of the axis x\[0\] must be an integer, got 2.5"),
])
def test_bad_axes_are_refused(axes, message):
    with pytest.raises(ValueError, match=message):
        bflow.sweep(quadrants(), [-0.5, -0.3], 1.0, axes, progress=False)


# --- parameter axes
delta = sp.Symbol("delta")


def one_surface():
    # x' = 1 - delta sign(x): from x0 < 0 the surface x = 0 is crossed at t_c = -x0 / (1 + delta),
    # then x(t) = (1 - delta)(t - t_c) and dx(t)/dx0 = (1 - delta) / (1 + delta).
    b = bflow.signs(1)[0]
    return bflow.Model([x], field=[1 - delta * b], surfaces=[x], parameters={delta: 0.3})


@pytest.mark.parametrize("name", ["delta", delta])
def test_a_parameter_axis_against_the_closed_form(name):
    records = bflow.sweep(one_surface(), [-1.0], 1.0, [(name, 0.1, 0.5, 5), (0, -1.0, -0.8, 3)],
                          progress=False)
    assert len(records) == 15
    for r in records:
        d, x0 = r.varied
        assert r.ok
        assert r.x_t[0] == pytest.approx((1 - d) * (1 + x0 / (1 + d)), abs=1e-12)
        assert r.images[0][0] == pytest.approx((1 - d) / (1 + d), abs=1e-12)
    # The first axis varies slowest: delta = 0.2 from the fourth record on.
    assert records[3].varied == pytest.approx([0.2, -1.0])


def test_a_biped_parameter_axis_matches_the_command(cli):
    import json
    import subprocess
    dx = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0]
    records = bflow.sweep(bflow.biped(), bflow.biped_initial_state(), 0.6,
                          [("kappa", 5e3, 2e4, 4)], directions=[dx], rtol=1e-10, progress=False)
    out = subprocess.run([cli, "sweep", "--scene", "biped", "--vary-param", "kappa=5e3:2e4:4",
                          "--dx", ",".join(map(str, dx)), "--rtol", "1e-10", "--quiet"],
                         check=True, capture_output=True, text=True).stdout.splitlines()
    lines = [json.loads(line) for line in out[1:]]
    assert len(records) == len(lines) == 4
    for r, line in zip(records, lines):
        assert r.varied == pytest.approx(line["varied"], rel=1e-15)
        np.testing.assert_allclose(r.x_t, line["x_t"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(r.images[0], line["images"][0], rtol=0, atol=1e-12)
    # kappa changes the flow: the samples differ.
    assert abs(records[0].x_t[1] - records[-1].x_t[1]) > 1e-6


@pytest.mark.parametrize("model, x0, axes, message", [
    (one_surface, [-1.0], [("kappa", 0.0, 1.0, 2)],
     r"no parameter \"kappa\" \(its parameters: delta\)"),
    (quadrants, [-0.5, -0.3], [("delta", 0.0, 1.0, 2)], "has no parameter"),
    (bflow.biped, bflow.biped_initial_state(), [("stiffness", 1.0, 2.0, 2)],
     "unknown biped parameter"),
])
def test_bad_parameter_axes_are_refused(model, x0, axes, message):
    with pytest.raises(ValueError, match=message):
        bflow.sweep(model(), x0, 0.5, axes, progress=False)


def test_a_state_on_two_axes_is_refused_and_threads_beyond_the_samples_are_not_started():
    m = quadrants()
    with pytest.raises(ValueError, match=r"x\[0\] is varied by axes 0 and 1"):
        bflow.sweep(m, [-0.5, -0.3], 1.0, [(0, -1.0, 0.0, 3), (0, 0.0, 1.0, 2)], progress=False)
    # 600 threads for 3 samples: three workers, the same records as one thread.
    axes = [(0, -0.6, -0.4, 3)]
    many = bflow.sweep(m, [-0.5, -0.3], 1.0, axes, threads=600, progress=False)
    one = bflow.sweep(m, [-0.5, -0.3], 1.0, axes, threads=1, progress=False)
    assert [list(r.x_t) for r in many] == [list(r.x_t) for r in one]


@pytest.mark.parametrize("threads, message", [
    (2 ** 40, r"threads=1099511627776 is outside \[0, 2147483647\]"),
    (-1, r"threads=-1 is outside"),
    (1.5, r"threads must be an integer, got 1.5"),
])
def test_bad_thread_counts_are_refused_naming_the_value(threads, message):
    with pytest.raises(ValueError, match=message):
        bflow.sweep(quadrants(), [-0.5, -0.3], 1.0, [(0, -0.6, -0.4, 3)], threads=threads,
                    progress=False)


def test_the_thread_cap_is_reported(capfd):
    m = quadrants()
    axes = [(0, -0.6, -0.4, 3)]
    many = bflow.sweep(m, [-0.5, -0.3], 1.0, axes, threads=600, progress=True)
    assert isinstance(many, bflow.SweepRecords) and len(many) == 3
    assert many.threads == 3
    assert many.notices == ["threads=600 capped at 3, one per sample"]
    assert "sweep: 3 samples on 3 threads (one per sample)" in capfd.readouterr().err
    two = bflow.sweep(m, [-0.5, -0.3], 1.0, axes, threads=2, progress=False)
    assert two.threads == 2 and two.notices == []


def _relay():
    k = sp.Symbol("k")
    s = bflow.signs(1)[0]
    return bflow.Model([x, y], field=[y, (k - y**2) * y - s], surfaces=[x], parameters={k: 0.2})


def test_an_interrupted_sweep_keeps_its_finished_records_each_its_own_flow_derivative():
    """A SIGINT raised from another thread while the sweep runs: KeyboardInterrupt carrying a
    prefix of the grid, each record equal to flow_derivative at its own start."""
    import signal
    import threading
    m = _relay()
    m.field([0.1, 0.0], "+")  # compiled before the timer starts
    samples = 200000
    timer = threading.Timer(1.0, signal.raise_signal, args=(signal.SIGINT,))
    # Python's own handler, as a user's interpreter has it (pytest-xdist's workers ignore SIGINT).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt) as info:
            bflow.sweep(m, [0.5, 0.0], 5.0, [(0, 0.1, 1.0, samples)], threads=2, progress=False)
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    e = info.value
    records = e.args[1]
    assert records is e.records
    assert 0 < len(records) < samples
    assert f"{len(records)} of {samples} samples finished" in e.args[0]
    assert f"the {samples - len(records)} unfinished ones are left out" in e.args[0]
    assert [r.index for r in records] == list(range(len(records)))
    step = records[:: max(1, len(records) // 20)]  # at most ~20 checked: each is a full run
    for r in step:
        assert r.ok, r.message
        assert r.varied == pytest.approx([0.1 + 0.9 * r.index / (samples - 1)], rel=0, abs=1e-15)
        start = [r.varied[0], 0.0]
        D = bflow.flow_derivative(m, start, 5.0)
        np.testing.assert_allclose(r.x_t, D.x, rtol=0, atol=1e-12)
        for k, image in enumerate(r.images):
            np.testing.assert_allclose(image, D.apply(np.eye(2)[k]), rtol=0, atol=1e-12)


def test_a_sweep_beyond_memory_is_refused_before_it_runs():
    with pytest.raises(ValueError) as info:
        bflow.sweep(quadrants(), [-0.5, -0.3], 1.0,
                    [(0, -1.0, 0.0, 10 ** 6), (1, -1.0, 1.0, 10 ** 6)], progress=False)
    message = str(info.value)
    assert "1000000000000 samples" in message and "bytes" in message
    assert "bflow sweep" in message
    # A record holds at least its two varied values, x_t and two images of 2 doubles: 96 bytes
    # of numbers, so 10^12 records need more than 9.6e13 bytes.
    needed = float(message.split("hold about ")[1].split(" bytes")[0])
    assert needed > 9.6e13
