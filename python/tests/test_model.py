"""Models written in SymPy: refused clearly before any compiler runs, compiled once and cached,
and the field, surfaces and normals they give against the expressions themselves."""

import pickle

import numpy as np
import pytest
import sympy as sp

import bflow
from bflow import model as model_module

x, y, k = sp.symbols("x y k")


def rotating(kappa=0.5):
    b = bflow.signs(2)
    return bflow.Model([x, y], field=[1 + k * y * b[0], 0.8 + sp.sin(x) * b[1]],
                       surfaces=[x + 0.1 * y ** 2, y], parameters={k: kappa})


def test_compiled_once_then_cached():
    first = rotating()
    first.field([0.0, 0.0], "++")  # the flow's library is compiled on first use
    compiled_first = model_module.compile_seconds["last"]
    second = rotating()
    second.field([0.0, 0.0], "++")
    assert model_module.compile_seconds["last"] == 0.0
    assert compiled_first > 0.0
    assert second._compiled.path == first._compiled.path


def test_field_surfaces_and_normals_against_sympy():
    m = rotating(0.5)
    point = np.array([0.3, -0.7])
    for word in ["--", "+-", "-+", "++"]:
        b0 = 1 if word[0] == "+" else -1
        b1 = 1 if word[1] == "+" else -1
        expected = [1 + 0.5 * point[1] * b0, 0.8 + np.sin(point[0]) * b1]
        np.testing.assert_allclose(m.field(point, word), expected, rtol=1e-15)
    np.testing.assert_allclose(m.surface_values(point),
                               [point[0] + 0.1 * point[1] ** 2, point[1]], rtol=1e-15)
    # Dh by Jets against the symbolic gradient.
    np.testing.assert_allclose(m.normals(point), [[1.0, 0.2 * point[1]], [0.0, 1.0]],
                               rtol=1e-15)


def test_field_per_sign_word_equals_field_in_signs():
    b = bflow.signs(1)
    in_signs = bflow.Model([x, y], field=[1 + 0.5 * b[0] * x, -y], surfaces=[x])
    per_word = bflow.Model([x, y], field={"-": [1 - 0.5 * x, -y], "+": [1 + 0.5 * x, -y]},
                           surfaces=[x])
    for point in ([0.2, 1.0], [-3.0, 0.5]):
        for word in "-+":
            np.testing.assert_array_equal(in_signs.field(point, word),
                                          per_word.field(point, word))


def test_parameters_change_without_compiling():
    m = rotating(0.5)
    np.testing.assert_allclose(m.field([0.0, 1.0], "+-"), [1.5, 0.8], rtol=1e-15)
    changed = m.with_parameters(k=2.0)
    np.testing.assert_allclose(changed.field([0.0, 1.0], "+-"), [3.0, 0.8], rtol=1e-15)
    assert changed._compiled.path == m._compiled.path
    np.testing.assert_allclose(m.field([0.0, 1.0], "+-"), [1.5, 0.8], rtol=1e-15)
    with pytest.raises(bflow.ModelError, match="no parameter 'kappa'"):
        m.with_parameters(kappa=1.0)


def test_pickles():
    m = rotating(0.25)
    back = pickle.loads(pickle.dumps(m))
    np.testing.assert_array_equal(back.field([0.1, 0.2], "-+"), m.field([0.1, 0.2], "-+"))


@pytest.mark.parametrize("kwargs, message", [
    (dict(states=[x, y], field=[x + sp.Symbol("z"), y], surfaces=[x]), r"\['z'\] are neither"),
    (dict(states=[x, y], field=[sp.besselj(0, x), y], surfaces=[x]), "besselj has no Jet"),
    (dict(states=[x, y], field=[x], surfaces=[x]), "field has 1 expressions, expected 2"),
    (dict(states=[x, y], field={"-": [x, y]}, surfaces=[x]), "sign word '\\+' is missing"),
    (dict(states=[x, y], field={"-+": [x, y], "+": [x, y]}, surfaces=[x]), "must have 1"),
    (dict(states=[x, y], field=[sp.Piecewise((1, x > 0), (0, True)), y], surfaces=[x]),
     "branches on the state"),
    (dict(states=[x, y], field=[x, y], surfaces=[x * bflow.signs(1)[0]]),
     "cannot depend on the side"),
    (dict(states=[x, x], field=[x, x], surfaces=[x]), "repeat"),
    (dict(states=[x, y], field=[x, y], surfaces=[x], parameters={x: 1.0}),
     "both a state and a parameter"),
])
def test_bad_models_are_refused_before_compiling(kwargs, message):
    model_module.compile_seconds["last"] = -1.0
    with pytest.raises(bflow.ModelError, match=message):
        bflow.Model(**kwargs)
    assert model_module.compile_seconds["last"] == -1.0  # no compiler ran


def test_bad_points_are_refused():
    m = rotating()
    with pytest.raises(ValueError, match="vector of 2 numbers"):
        m.field([1.0, 2.0, 3.0], "--")
    with pytest.raises(ValueError, match="sides"):
        m.field([1.0, 2.0], "---")
