"""Hostile input to the package, each case in a fresh interpreter: no signal, no file made by a
model's text, no silently wrong number; a clear ValueError (ModelError is one) naming the input,
or the right answer.

Every case runs its code in a child process (a crash there fails the case instead of killing
pytest) after ``import numpy as np, sympy as sp, bflow``, with the session's model cache. The
child prints one line ``OUTCOME <kind> <message>``: ``ok`` when the code ran through, else the
exception's class name and text; the case asserts the kind and words of the message.
"""

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

PRELUDE = """
import os, sys, time, threading
import numpy as np, sympy as sp, bflow
x, y, k, p, v, u = sp.symbols("x y k p v u")
b0 = bflow.signs(1)[0]
def relay(kk=0.2):
    return bflow.Model([x, y], field=[y, (k - y**2)*y - b0], surfaces=[x], parameters={k: kk})
def car():
    return bflow.Model([p, v], field=[v, (2 + b0)*u], surfaces=[v - 1], controls=[u],
                       lagrange=u**2 + p**2)
"""

RUNNER = """
import traceback
try:
{body}
except BaseException as e:
    print("OUTCOME", type(e).__name__, str(e).replace("\\n", " "), flush=True)
else:
    print("OUTCOME ok", flush=True)
"""


def run(body: str, timeout: float = 120.0, env=None, preexec_fn=None):
    """Runs PRELUDE and body in a child; returns (kind, message, completed process)."""
    code = PRELUDE + RUNNER.format(body=textwrap.indent(textwrap.dedent(body), "    "))
    child_env = dict(os.environ)
    child_env.update(env or {})
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=timeout, env=child_env, preexec_fn=preexec_fn)
    assert proc.returncode >= 0, (
        f"the child died of signal {-proc.returncode}; stderr: {proc.stderr[-2000:]}")
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("OUTCOME ")]
    assert lines, f"no outcome; returncode {proc.returncode}; stderr: {proc.stderr[-2000:]}"
    _, kind, *rest = lines[-1].split(" ", 2)
    return kind, (rest[0] if rest else ""), proc


def refused(kind: str, message: str, *words: str):
    assert kind in ("ValueError", "ModelError"), f"{kind}: {message}"
    for w in words:
        assert w.lower() in message.lower(), f"{w!r} not in {message!r}"


# --- nothing a model's text holds runs as code -----------------------------------------------

def test_a_state_name_never_reaches_the_compiler(tmp_path):
    marker = tmp_path / "pwned"
    kind, message, _ = run(f"""
        a = sp.Symbol('x\\n#include <cstdlib>\\nstatic int q = std::system("touch {marker}");\\n//')
        m = bflow.Model([a], field=[1], surfaces=[a])
        assert np.allclose(m.field([0.5], "+"), [1.0])
    """)
    assert not marker.exists(), "a state's name ran as C++"
    assert kind == "ok" or kind == "ModelError", message


@pytest.mark.parametrize("where", ["field", "surfaces", "parameter name"])
def test_names_and_strings_are_not_evaluated(tmp_path, where):
    marker = tmp_path / "pwned"
    command = f'__import__("os").system("touch {marker}")'
    body = {
        "field": f"bflow.Model([x, y], field=['1', '{command}'], surfaces=[x])",
        "surfaces": f"bflow.Model([x], field=[1], surfaces=['{command}'])",
        "parameter name": (f"bflow.Model([x], field=[k], surfaces=[x], "
                           f"parameters={{sp.Symbol('k\\n{command}'): 1.0}})"),
    }[where]
    kind, message, _ = run(body)
    assert not marker.exists(), f"a string in the {where} was evaluated"
    if where == "parameter name":
        assert kind in ("ok", "ModelError"), message
    else:
        refused(kind, message, "string")


# --- expressions: numbers by their value, refused nodes --------------------------------------

def test_an_exact_rational_beyond_double_range_is_printed_by_its_value():
    kind, message, _ = run("""
        m = bflow.Model([x], field=[sp.Rational(2**1100 + 1, 3 * 2**1100)], surfaces=[x - 1])
        f = m.field([0.0], "-")
        assert abs(f[0] - 1.0 / 3.0) <= 1e-15, f
    """)
    assert kind == "ok", message


@pytest.mark.parametrize("expr, words", [
    ("sp.oo", ["field[0]"]), ("-sp.oo", ["field[0]"]), ("sp.zoo", ["field[0]"]),
    ("sp.nan", ["field[0]"]), ("sp.I * x", ["field[0]"]), ("x > 0", ["field[0]"]),
    ("sp.Derivative(sp.Function('g')(x), x)", ["field[0]"]), ("sp.Abs(x)", ["Abs"]),
    ("sp.Integral(x, x)", ["field[0]"]),
])
def test_expressions_that_are_no_real_smooth_field_are_refused(expr, words):
    kind, message, _ = run(f"bflow.Model([x], field=[{expr}], surfaces=[x - 1])")
    refused(kind, message, *words)


def test_a_missing_sign_word_of_many_surfaces_is_refused_at_once():
    start = time.perf_counter()
    kind, message, _ = run("""
        n = 22
        xs = sp.symbols("x0:%d" % n)
        bflow.Model(list(xs), field={"+" * n: [1] * n}, surfaces=list(xs))
    """, timeout=60)
    refused(kind, message, "sign word")
    assert time.perf_counter() - start < 30, "the check enumerated every word"


def test_a_jump_map_of_many_surfaces_finishes_or_is_refused():
    kind, message, _ = run("""
        n = 24
        xs = sp.symbols("x0:%d" % n)
        m = bflow.Model(list(xs), field=[1] * n, surfaces=list(xs))
        bflow.JumpMap.at(m, np.zeros(n))
    """, timeout=60)
    assert kind in ("ok", "ValueError", "ModelError"), message


# --- the model cache --------------------------------------------------------------------------

def _libraries(directory):
    return sorted(p for p in directory.rglob("*.so"))


def test_a_cached_library_cut_short_is_rebuilt_not_loaded(tmp_path):
    env = {"BFLOW_CACHE_DIR": str(tmp_path)}
    kind, message, _ = run("relay().field([0.1, 0.2], '+')", env=env)
    assert kind == "ok", message
    for lib in _libraries(tmp_path):
        data = lib.read_bytes()
        lib.write_bytes(data[:8000])
    for _ in range(2):  # the rebuild is kept: the second run loads it
        kind, message, _ = run("""
            f = relay().field([0.1, 0.2], '+')
            assert np.allclose(f, [0.2, (0.2 - 0.04) * 0.2 - 1.0], rtol=1e-14), f
        """, env=env)
        assert kind == "ok", message


def test_another_models_library_under_the_key_is_not_used(tmp_path):
    env = {"BFLOW_CACHE_DIR": str(tmp_path / "a")}
    other = {"BFLOW_CACHE_DIR": str(tmp_path / "b")}
    assert run("relay().field([0.1, 0.2], '+')", env=env)[0] == "ok"
    assert run("bflow.Model([x, y], field=[1, 2], surfaces=[x]).field([0, 0], '+')",
               env=other)[0] == "ok"
    (mine,) = [p for p in _libraries(tmp_path / "a") if "failed" not in p.name]
    (theirs,) = [p for p in _libraries(tmp_path / "b") if "failed" not in p.name]
    mine.write_bytes(theirs.read_bytes())
    for sidecar in (tmp_path / "b").iterdir():  # the other model's checksum files too
        if sidecar.is_file() and sidecar.suffix != ".so":
            target = tmp_path / "a" / sidecar.name.replace(theirs.stem, mine.stem)
            target.write_bytes(sidecar.read_bytes())
    kind, message, _ = run("""
        f = relay().field([0.1, 0.2], '+')
        assert np.allclose(f, [0.2, (0.2 - 0.04) * 0.2 - 1.0], rtol=1e-14), f
    """, env=env)
    assert kind in ("ok", "ModelError"), message


@pytest.mark.parametrize("value", ["", ".", "~/bflow-hostile-cache", "FILE", "READONLY"])
def test_cache_directory_settings(tmp_path, value):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    if value == "FILE":
        value = str(tmp_path / "a-file")
        (tmp_path / "a-file").write_text("not a folder")
    elif value == "READONLY":
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        value = str(ro)
        if os.access(ro, os.W_OK):  # root writes anywhere: nothing to test
            pytest.skip("the tests run as root: a read-only folder is writable")
    home = tmp_path / "home"
    home.mkdir()
    code = ("bflow.Model([x], field=[1 + k], surfaces=[x - 1], parameters={k: 1.0})"
            ".field([0.0], '-')")
    proc_env = {"BFLOW_CACHE_DIR": value, "HOME": str(home)}
    code_in_cwd = f"os.chdir({str(cwd)!r})\n{code}"
    for attempt in range(2):  # the second run loads what the first compiled
        kind, message, proc = run(code_in_cwd, env=proc_env)
        assert not (cwd / "~").exists(), "a folder named ~ was made"
        if kind != "ok":
            refused(kind, message, "BFLOW_CACHE_DIR")
            break
        assert attempt == 0 or "compiling" not in proc.stderr, proc.stderr


# --- optimal control and FESD ----------------------------------------------------------------

@pytest.mark.parametrize("guess", ["guess_u=[np.nan]", "guess_u=[np.inf]", "guess_u=[1e308]",
                                   "guess_x=[0, np.inf]", "guess_x=[np.nan, 0]",
                                   "x0=[0, np.nan]", "u_lower=[np.nan]"])
def test_non_finite_ocp_data_are_refused(guess):
    data = {"x0": "[0, 2.0]", "T": "2.0"}
    key, value = guess.split("=", 1)
    data[key] = value
    kind, message, _ = run("bflow.ocp_solve(car(), N=5, " +
                           ", ".join(f"{k}={v}" for k, v in data.items()) + ")")
    refused(kind, message, guess.split("=")[0])


def test_ocp_and_fesd_from_two_threads_equal_serial_runs():
    kind, message, _ = run("""
        from concurrent.futures import ThreadPoolExecutor
        def ocp(_):
            r = bflow.ocp_solve("turbo-car", N=5)
            return r.T, r.objective, r.status
        def fesd(_):
            r = bflow.fesd_simulate("sliding-enter", newton=False)
            return tuple(r.x_end), r.status
        for f in (ocp, fesd):
            serial = [f(i) for i in range(2)]
            with ThreadPoolExecutor(2) as pool:
                parallel = list(pool.map(f, range(4)))
            assert all(p == serial[0] for p in parallel), (serial, parallel)
    """, timeout=600)
    assert kind == "ok", message


def test_a_horizon_too_long_to_integrate_is_refused():
    kind, message, _ = run("bflow.fesd_simulate('crossing', T=1e308)")
    refused(kind, message, "1e+308")


@pytest.mark.parametrize("call, option", [
    ("bflow.simulate(bflow.biped(), bflow.biped_initial_state(), 0.6, max_steps=2**70)",
     "max_steps"),
    ("bflow.simulate(bflow.biped(), bflow.biped_initial_state(), 0.6, rtol='1e-6')", "rtol"),
    ("bflow.ocp_solve('turbo-car', N=2**40)", "N"),
    ("bflow.fesd_simulate('crossing', steps='4')", "steps"),
    ("bflow.ocp_solve('turbo-car', N=5, sigma_initial='big')", "sigma_initial"),
])
def test_options_of_the_wrong_type_name_the_option(call, option):
    kind, message, _ = run(call)
    refused(kind, message, option)


def test_contradictory_ocp_options_are_refused(cli):
    proc = subprocess.run([cli, "ocp", "--example", "turbo-car", "--cross", "point-sums",
                           "--standard"], capture_output=True, text=True, timeout=120)
    assert proc.returncode not in (0,) and proc.returncode > 0, proc.stdout[-500:]
    assert "standard" in proc.stderr


# --- orbits -----------------------------------------------------------------------------------

def test_no_false_orbit_near_the_equilibrium_on_the_surface():
    # P(x)/x = 1.0013 near the origin: no fixed point there; the true orbit has period 2.310931.
    kind, message, proc = run("""
        o = bflow.find_orbit(relay(), '-x1', [0.0834, 0.0])
        print("ORBIT", o.converged, o.period, float(np.max(np.abs(o.x))))
    """)
    assert kind == "ok", message
    (line,) = [ln for ln in proc.stdout.splitlines() if ln.startswith("ORBIT")]
    _, converged, period, size = line.split()
    if converged == "True":
        assert abs(float(period) - 2.310931) < 1e-5, line


# --- sweeps -----------------------------------------------------------------------------------

def _address_limit():
    import resource
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))


def test_a_sweep_with_more_threads_than_can_start():
    kind, message, _ = run("""
        m = bflow.Model([x, y], field=[1, 0.5], surfaces=[x])
        r = bflow.sweep(m, [-0.5, 0.0], 1.0, [(1, -1, 1, 8)], threads=600, progress=False)
        assert len(r) == 8 and all(s.status == "ok" for s in r)
    """, preexec_fn=_address_limit)
    assert kind in ("ok", "ValueError"), message


def test_the_same_state_on_two_axes_is_refused():
    kind, message, _ = run("""
        m = bflow.Model([x, y], field=[1, 0.5], surfaces=[x])
        bflow.sweep(m, [-0.5, 0.0], 1.0, [(1, -1, 1, 3), (1, 0, 2, 3)], progress=False)
    """)
    refused(kind, message, "1")


def test_a_sweep_too_large_for_memory_is_refused_up_front():
    start = time.perf_counter()
    kind, message, _ = run("""
        m = bflow.Model([x, y], field=[1, 0.5], surfaces=[x])
        bflow.sweep(m, [-0.5, 0.0], 1.0, [(0, -1, 0, 100000), (1, -1, 1, 10000)], progress=False)
    """, timeout=60)
    refused(kind, message, "bytes")
    assert time.perf_counter() - start < 30


def default_sigint():
    """preexec_fn of a child that must see Ctrl-C as a user does: SIGINT back to its default
    (pytest-xdist's workers ignore SIGINT, a child inherits that, and Python installs its
    KeyboardInterrupt handler only where SIGINT is not ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupted(body: str, after: float, within: float):
    """Runs body in a child, sends SIGINT `after` seconds after it prints READY; returns its
    stdout, stderr and the seconds from the signal to its exit."""
    code = PRELUDE + textwrap.dedent(body)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)
    first = proc.stdout.readline()
    assert first.startswith("READY"), (first, proc.stderr.read()[-2000:])
    time.sleep(after)
    sent = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=within + 60)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the run did not stop after SIGINT")
    waited = time.perf_counter() - sent
    assert proc.returncode >= 0, f"signal {-proc.returncode}: {err[-2000:]}"
    return out, err, waited


def test_ctrl_c_stops_a_sweep_and_keeps_its_finished_samples():
    out, err, waited = _interrupted("""
        m = relay()
        m.field([0.1, 0.0], "+")
        print("READY", flush=True)
        try:
            bflow.sweep(m, [0.5, 0.0], 50.0, [(0, 0.1, 1.0, 200000)], progress=False, threads=1)
            print("FINISHED")
        except KeyboardInterrupt as e:
            done = e.args[1] if len(e.args) > 1 else []
            ok = [r for r in done if r.status == "ok"]
            print("INTERRUPTED", len(ok), flush=True)
    """, after=1.5, within=10.0)
    assert "INTERRUPTED" in out, (out, err[-2000:])
    assert int(out.split("INTERRUPTED")[1].split()[0]) > 0
    assert waited < 10.0


def test_ctrl_c_stops_an_optimal_control_run():
    out, err, waited = _interrupted("""
        print("READY", flush=True)
        try:
            bflow.ocp_solve("turbo-car", N=200)
            print("FINISHED")
        except KeyboardInterrupt:
            print("INTERRUPTED", flush=True)
    """, after=2.0, within=10.0)
    assert "INTERRUPTED" in out, (out, err[-2000:])
    assert waited < 10.0


# --- flow -------------------------------------------------------------------------------------

def test_a_side_that_contradicts_the_surface_is_refused():
    kind, message, _ = run("""
        bflow.simulate(bflow.biped(), bflow.biped_initial_state(), 0.6, initial_sides='++')
    """)
    refused(kind, message, "initial_sides")
