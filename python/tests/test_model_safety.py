"""Models written in SymPy against hostile input and a damaged cache: nothing of the user's text
reaches the compiler or runs as Python, every expression node outside the whitelist is a
ModelError naming the entry and the node, numbers are printed from their value, and the cache
checks what it loads (checksum before dlopen, key after), writes atomically and names what is
wrong with $BFLOW_CACHE_DIR. Cases that could kill the interpreter run in a child process."""

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import bflow
from bflow import model as model_module

x, y, k = sp.symbols("x y k")

PRELUDE = """
import os, sys
import numpy as np, sympy as sp, bflow
x, y, k = sp.symbols("x y k")
b0 = bflow.signs(1)[0]
def relay(kk=0.2):
    return bflow.Model([x, y], field=[y, (k - y**2)*y - b0], surfaces=[x], parameters={k: kk})
"""
RELAY_AT = "[0.2, (0.2 - 0.04) * 0.2 - 1.0]"  # relay(0.2).field([0.1, 0.2], "+")


def child(body: str, env=None, timeout=300.0):
    """Runs PRELUDE + body in a fresh interpreter; the child must not die of a signal."""
    code = PRELUDE + textwrap.dedent(body)
    full = dict(os.environ)
    full.update(env or {})
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=full, timeout=timeout)
    assert proc.returncode >= 0, f"signal {-proc.returncode}: {proc.stderr[-2000:]}"
    return proc


def libraries(directory: Path):
    return sorted(directory.glob("model_*.so"))


# --- 1. no user text in the generated source -------------------------------------------------

def test_a_state_name_with_code_runs_nothing_and_the_model_works(tmp_path):
    marker = tmp_path / "made"
    proc = child(f"""
        a = sp.Symbol('x\\n#include <cstdlib>\\nstatic int q = std::system("touch {marker}");\\n//')
        m = bflow.Model([a], field=[1 + a], surfaces=[a])
        print("FIELD", m.field([0.5], "+")[0])
    """, env={"BFLOW_CACHE_DIR": str(tmp_path / "cache")})
    assert proc.returncode == 0, proc.stderr
    assert not marker.exists(), "a state's name ran as C++"
    assert "FIELD 1.5" in proc.stdout


def test_the_source_holds_no_name_of_the_user():
    a = sp.Symbol("state_name_A\n//")
    p = sp.Symbol("param_name_B\n#error")
    s = sp.Symbol("sign_name_C")
    m = bflow.Model([a], field={"-": [p + a], "+": [-p]}, surfaces=[a - p],
                    parameters={p: 1.0})
    m2 = bflow.Model([a], field=[p * s], surfaces=[a], parameters={p: 1.0}, signs=[s])
    for source in (m.source, m2.source, m2._engine_source("step", "0")):
        for text in ("state_name_A", "param_name_B", "sign_name_C", "#error"):
            assert text not in source


# --- 2. strings are refused, never evaluated -------------------------------------------------

@pytest.mark.parametrize("make, where", [
    (lambda s: bflow.Model([x, y], field=["1", s], surfaces=[x]), "field[0]"),
    (lambda s: bflow.Model([x, y], field=[1, s], surfaces=[x]), "field[1]"),
    (lambda s: bflow.Model([x], field={"-": [1], "+": [s]}, surfaces=[x]), "field['+'][0]"),
    (lambda s: bflow.Model([x], field=[1], surfaces=[s]), "surfaces[0]"),
    (lambda s: bflow.Model([x], field=[sp.Symbol("u")], surfaces=[x],
                           controls=[sp.Symbol("u")], lagrange=s), "lagrange"),
    (lambda s: bflow.Model([x], field=[sp.Symbol("u")], surfaces=[x],
                           controls=[sp.Symbol("u")], path=[s]), "path[0]"),
    (lambda s: bflow.Model([x], field=[1], surfaces=[x - 1])._section(s), "section"),
    (lambda s: bflow.Model([x], field=[1], surfaces=[x], parameters={k: s}), "parameter k"),
])
def test_strings_are_refused_naming_the_entry(tmp_path, make, where):
    marker = tmp_path / "made"
    command = f'__import__("os").system("touch {marker}")'
    with pytest.raises(bflow.ModelError) as error:
        make(command)
    assert not marker.exists(), "a string was evaluated"
    assert where in str(error.value)
    assert "string" in str(error.value) or "real number" in str(error.value)


def test_bytes_and_other_objects_are_refused_numbers_accepted():
    with pytest.raises(bflow.ModelError, match=r"field\[0\]: the string b'x'"):
        bflow.Model([x], field=[b"x"], surfaces=[x])
    with pytest.raises(bflow.ModelError, match=r"field\[0\]: .*neither a SymPy expression"):
        bflow.Model([x], field=[object()], surfaces=[x])
    with pytest.raises(bflow.ModelError, match=r"field\[0\]: True is a truth value"):
        bflow.Model([x], field=[True], surfaces=[x])
    m = bflow.Model([x, y], field=[np.float64(0.25), np.int64(3)], surfaces=[x])
    assert m.field_exprs == [sp.Float(0.25), sp.Integer(3)]


# --- 3. a whitelist of nodes -------------------------------------------------------------------

@pytest.mark.parametrize("expr, node", [
    (sp.oo, "oo"), (-sp.oo, "-oo"), (sp.zoo, "zoo"), (sp.nan, "nan"), (sp.I * x, "I"),
    (1 + 2 * sp.I, "I"), (x > 0, "x > 0"), (sp.And(x > 0, x < 1), "x > 0"),
    (sp.Derivative(sp.Function("g")(x), x), "Derivative"), (sp.Integral(x, x), "Integral"),
    (sp.Subs(x ** 2, x, 1), "Subs"), (sp.Piecewise((1, x > 0), (0, True)), "Piecewise"),
    (sp.Heaviside(x), "Heaviside"), (sp.sign(x), "sign"), (sp.Max(x, 1), "Max"),
    (sp.Min(x, 1), "Min"), (sp.floor(x), "floor"), (sp.ceiling(x), "ceiling"),
    (1 + sp.Abs(x - 1), "Abs(x - 1)"), (sp.GoldenRatio * x, "GoldenRatio"),
    (sp.Float(1e308) * 10, "beyond"), (sp.Integer(10) ** 400 * x, "beyond"),
])
def test_nodes_outside_the_whitelist_are_refused_naming_entry_and_node(expr, node):
    model_module.compile_seconds["last"] = -1.0
    with pytest.raises(bflow.ModelError) as error:
        bflow.Model([x, y], field=[1, expr], surfaces=[x - 2])
    message = str(error.value)
    assert message.startswith("field[1]: "), message
    assert node in message, message
    assert model_module.compile_seconds["last"] == -1.0  # no compiler ran


def test_abs_asks_for_its_kink_as_a_surface():
    with pytest.raises(bflow.ModelError, match="make the kink a surface"):
        bflow.Model([x], field=[sp.Abs(x)], surfaces=[x - 1])


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -np.inf, "1.0"])
def test_non_finite_parameter_values_are_refused(value):
    with pytest.raises(bflow.ModelError, match="parameter k"):
        bflow.Model([x], field=[k], surfaces=[x], parameters={k: value})
    m = bflow.Model([x], field=[k], surfaces=[x], parameters={k: 1.0})
    with pytest.raises(bflow.ModelError, match="with_parameters: k"):
        m.with_parameters(k=value)


# --- 4. numbers printed from their value -----------------------------------------------------

def test_rationals_beyond_a_double_are_printed_by_their_value():
    third = sp.Rational(2 ** 1100 + 1, 3 * 2 ** 1100)
    big = sp.Integer(2 ** 60 + 1)  # not a double: printed as the nearest one
    m = bflow.Model([x, y], field=[third, third * x + big / sp.Integer(2 ** 61)], surfaces=[x])
    f = m.field([0.75, 0.0], "+")
    assert abs(f[0] - 1 / 3) <= 1e-15 and abs(f[1] - (0.25 + 0.5)) <= 1e-15, f
    assert np.all(np.isfinite(f))


# --- 5. fields per sign word of many surfaces --------------------------------------------------

def test_a_field_per_sign_word_above_the_cap_is_refused_at_once():
    n = model_module.MAX_WORD_SURFACES + 12
    xs = sp.symbols(f"x0:{n}")
    with pytest.raises(bflow.ModelError, match=r"per sign word .* n = 22 .*bflow.signs\(22\)"):
        bflow.Model(list(xs), field={"+" * n: [1] * n}, surfaces=list(xs))


def test_a_missing_sign_word_is_named():
    xs = sp.symbols("x0:3")
    field = {w: [1, 1, 1] for w in ["---", "+--", "-+-", "++-", "+-+", "-++", "+++"]}
    with pytest.raises(bflow.ModelError, match=r"the sign word '--\+' is missing \(1 of 8"):
        bflow.Model(list(xs), field=field, surfaces=list(xs))
    with pytest.raises(bflow.ModelError, match="given twice"):
        bflow.Model([x], field={"+": [1], (1,): [2], "-": [0]}, surfaces=[x])


def test_jump_map_at_many_surfaces_evaluates_its_limits_lazily():
    # x_j' = 1 - delta b_j, h_j = x_j: every surface on its own, so the jump across all 24 at once
    # is (1 - delta) / (1 + delta) times the identity ([B] (3.2)) in every direction. A table
    # of the 2^24 limits from Python took minutes; the lazy limits cost n + 1 calls per apply.
    n, delta = 24, sp.Symbol("delta")
    xs = sp.symbols(f"x0:{n}")
    b = bflow.signs(n)
    m = bflow.Model(list(xs), field=[1 - delta * b[j] for j in range(n)], surfaces=list(xs),
                    parameters={delta: 0.5})
    J = bflow.JumpMap.at(m, np.zeros(n))
    assert J.surfaces == n and J.dim == n
    rng = np.random.default_rng(7)
    for _ in range(5):
        dx = rng.standard_normal(n)
        # Round-off of the walk through 24 crossings: a few n eps |dx|.
        np.testing.assert_allclose(J.apply(dx), dx / 3.0, rtol=0,
                                   atol=1e-14 * np.abs(dx).max())


# --- 6. the cache checks what it loads -------------------------------------------------------

def test_a_truncated_library_is_rebuilt_before_dlopen(tmp_path):
    env = {"BFLOW_CACHE_DIR": str(tmp_path)}
    assert child("relay().field([0.1, 0.2], '+')", env).returncode == 0
    (library,) = libraries(tmp_path)
    library.write_bytes(library.read_bytes()[:8000])
    check = f"assert np.allclose(relay().field([0.1, 0.2], '+'), {RELAY_AT}, rtol=1e-14)"
    proc = child(check, env)
    assert proc.returncode == 0, proc.stderr
    assert "does not match its checksum" in proc.stderr
    again = child(check, env)  # the rebuild is kept
    assert again.returncode == 0 and "compiling" not in again.stderr, again.stderr


@pytest.mark.parametrize("forge_sidecar", [False, True])
def test_another_models_library_under_the_key_is_never_used(tmp_path, forge_sidecar):
    env = {"BFLOW_CACHE_DIR": str(tmp_path)}
    assert child("relay().field([0.1, 0.2], '+')", env).returncode == 0
    (mine,) = libraries(tmp_path)
    assert child("bflow.Model([x, y], field=[1, 2], surfaces=[x]).field([0, 0], '+')",
                 env).returncode == 0
    (theirs,) = [p for p in libraries(tmp_path) if p != mine]
    mine.write_bytes(theirs.read_bytes())
    sidecar = json.loads(theirs.with_suffix(".json").read_text())
    if forge_sidecar:  # the checksum passes: the key inside the library is what catches it
        sidecar["key"] = mine.stem[len("model_"):]
    mine.with_suffix(".json").write_text(json.dumps(sidecar))
    proc = child(f"assert np.allclose(relay().field([0.1, 0.2], '+'), {RELAY_AT}, rtol=1e-14)",
                 env)
    assert proc.returncode == 0, proc.stderr
    expected = "holds the key" if forge_sidecar else "does not match its checksum"
    assert expected in proc.stderr


def test_a_killed_compile_leaves_no_library_and_its_temporaries_are_cleaned(tmp_path):
    env = dict(os.environ, BFLOW_CACHE_DIR=str(tmp_path))
    code = PRELUDE + "relay().field([0.1, 0.2], '+')"
    proc = subprocess.Popen([sys.executable, "-c", code], env=env, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    line = proc.stderr.readline()
    assert line.startswith("bflow: compiling flow library for a model with 2 states, 1 "
                           "surfaces (first use; cached in"), line
    time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGKILL)  # the child and its compiler
    proc.wait(timeout=30)
    left = [p for p in tmp_path.iterdir() if p.suffix != ".lock"]
    assert not libraries(tmp_path) and all(p.is_file() for p in left), left
    assert all(p.name.startswith("bflow_tmp_") for p in left), left
    # Leftovers older than STALE_SECONDS (and folders of the older layout) go at the next
    # compile; a temporary of a compile under way (recent) stays.
    old = time.time() - model_module.STALE_SECONDS - 60
    folder = tmp_path / "tmpabc123"
    folder.mkdir()
    (folder / "model.cc").write_text("//")
    recent = tmp_path / "bflow_tmp_recent.cc"
    recent.write_text("//")
    for p in left + [folder]:
        os.utime(p, (old, old))
    again = child(f"assert np.allclose(relay().field([0.1, 0.2], '+'), {RELAY_AT})",
                  {"BFLOW_CACHE_DIR": str(tmp_path)})
    assert again.returncode == 0, again.stderr
    assert not any(p.exists() for p in left) and not folder.exists() and recent.exists()


# --- 7. $BFLOW_CACHE_DIR ---------------------------------------------------------------------

@pytest.mark.parametrize("setting, where", [("", "home/.cache/bflow/models"), (".", "cwd"),
                                            ("~/x", "home/x"), ("rel/dir", "cwd/rel/dir")])
def test_cache_dir_settings_resolve_to_absolute_folders(tmp_path, setting, where):
    (tmp_path / "cwd").mkdir()
    (tmp_path / "home").mkdir()
    proc = child(f"""
        os.chdir({str(tmp_path / "cwd")!r})
        assert np.allclose(relay().field([0.1, 0.2], '+'), {RELAY_AT})
        print("DIR", bflow.model.cache_dir())
    """, env={"BFLOW_CACHE_DIR": setting, "HOME": str(tmp_path / "home")})
    assert proc.returncode == 0, proc.stderr
    assert f"DIR {tmp_path / where}" in proc.stdout
    assert len(libraries(tmp_path / where)) == 1
    assert not (tmp_path / "cwd" / "~").exists()


def test_a_cache_dir_that_is_a_file_is_named(tmp_path, monkeypatch):
    afile = tmp_path / "a-file"
    afile.write_text("not a folder")
    monkeypatch.setenv("BFLOW_CACHE_DIR", str(afile))
    m = bflow.Model([x], field=[1], surfaces=[x])
    with pytest.raises(bflow.ModelError) as error:
        m.field([0.0], "+")
    message = str(error.value)
    assert f"$BFLOW_CACHE_DIR={str(afile)!r}" in message and "make the folder" in message
    assert "File exists" in message or "Not a directory" in message, message


@pytest.mark.parametrize("code, text", [(errno.ENOSPC, "No space left on device"),
                                        (errno.EACCES, "Permission denied")])
def test_a_full_or_read_only_cache_is_named(tmp_path, monkeypatch, code, text):
    def refuse(path, data):
        raise OSError(code, os.strerror(code), str(path))

    monkeypatch.setenv("BFLOW_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(model_module, "_write_file", refuse)
    m = bflow.Model([x], field=[2], surfaces=[x])
    with pytest.raises(bflow.ModelError) as error:
        m.field([0.0], "+")
    message = str(error.value)
    assert f"$BFLOW_CACHE_DIR={str(tmp_path)!r}" in message and text in message, message
    assert not [p for p in tmp_path.iterdir() if p.suffix != ".lock"]  # no temporary left


# --- 8. a cached model costs no cse, and each engine compiles on its first use ----------------

def test_a_model_compiles_nothing_until_used_and_fesd_never_compiles_the_flow(tmp_path,
                                                                              monkeypatch):
    monkeypatch.setenv("BFLOW_CACHE_DIR", str(tmp_path))
    b = bflow.signs(1)[0]
    m = bflow.Model([x, y], field=[1 - 0.5 * b, 1], surfaces=[x + 0.25])
    assert list(tmp_path.iterdir()) == []
    step = m._step_model()  # what fesd_simulate runs on
    assert (step.states, step.switches) == (2, 1)
    engines = {json.loads(p.read_text())["engine"] for p in tmp_path.glob("model_*.json")}
    assert engines == {"step"}


def test_a_cached_model_runs_no_cse(monkeypatch):
    b = bflow.signs(1)[0]

    def make():
        return bflow.Model([x, y], field=[sp.sin(x) + b, sp.sin(x) * sp.cos(y)], surfaces=[y])

    expected = make().field([0.5, 0.25], "+")

    def boom(*args, **kwargs):
        raise AssertionError("cse ran for a cached model")

    monkeypatch.setattr(sp, "cse", boom)
    np.testing.assert_array_equal(make().field([0.5, 0.25], "+"), expected)
    np.testing.assert_allclose(expected, [np.sin(0.5) + 1, np.sin(0.5) * np.cos(0.25)],
                               rtol=1e-15)


# --- 9. a failed compile names source that exists; progress lines -----------------------------

def test_a_failed_compile_keeps_its_source_and_names_it(tmp_path, monkeypatch, capfd):
    compiler = tmp_path / "cxx"
    compiler.write_text("#!/bin/sh\necho 'error: refused by the test compiler' >&2\nexit 1\n")
    compiler.chmod(0o755)
    monkeypatch.setenv("CXX", str(compiler))
    monkeypatch.setenv("BFLOW_CACHE_DIR", str(tmp_path / "cache"))
    m = bflow.Model([x, y], field=[1, 2], surfaces=[x, y])
    with pytest.raises(bflow.ModelError, match="refused by the test compiler") as error:
        m.field([0.0, 0.0], "++")
    (failed,) = (tmp_path / "cache").glob("failed_*.cc")
    assert str(failed) in str(error.value)
    assert "bflow_flow_model_create" in failed.read_text()
    err = capfd.readouterr().err
    assert ("bflow: compiling flow library for a model with 2 states, 2 surfaces (first use; "
            f"cached in {tmp_path / 'cache'})") in err


def test_a_compile_reports_its_start_and_its_seconds(tmp_path, monkeypatch, capfd):
    monkeypatch.setenv("BFLOW_CACHE_DIR", str(tmp_path))
    bflow.Model([x], field=[3], surfaces=[x]).field([0.0], "+")
    err = capfd.readouterr().err.splitlines()
    assert err[0].startswith("bflow: compiling flow library for a model with 1 states, 1 ")
    assert err[1].startswith("bflow: compiled flow library in ") and err[1].endswith(" s")
