"""Models written in SymPy, compiled once into the templated functor a C++ user writes.

A model is d states, n switching surfaces h(x) and the vector field F_b(x) for every sign word b
(b_j = +1 on the + side of surface j, -1 on its - side), either as expressions in sign symbols
(``signs(n)``) or as a dict from sign words ("+-", ...) to expressions. bflow prints it as C++
(``field<T>`` and ``surfaces<T>`` templated on the scalar, so that Ceres Jets give DF and Dh
exactly as for a C++ model), compiles it with the system's C++ compiler into a shared library
and loads it. The library is cached under ``$BFLOW_CACHE_DIR`` (default ``~/.cache/bflow/models``)
by a key of the model's inputs (their ``srepr``), the engine, this generator's text and the
compiler command: the first use of a new model compiles (a few seconds), later uses and other
processes load it, after checking its checksum and the key it holds.

Nothing of the user's text reaches the compiler: every symbol is printed as a generated
identifier (``x[i]``, ``p_[j]``, ...), strings are refused (SymPy's ``sympify`` would evaluate
them as Python), and only a whitelist of expression nodes is printed.

Example (two surfaces crossed at once, [B] (3.1))::

    import sympy as sp, bflow
    x, y = sp.symbols("x y")
    b = bflow.signs(2)
    delta = sp.Symbol("delta")
    model = bflow.Model([x, y], field=[1 - delta * b[0], 1 - delta * b[1]],
                        surfaces=[x, y], parameters={delta: 0.5})
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import math
import numbers
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Dict, Mapping, Optional, Sequence

import sympy as sp
from sympy.printing.c import C99CodePrinter

from . import _bflow
from ._errors import ModelError

__all__ = ["Model", "signs", "ModelError", "compile_seconds"]

# Functions the generated code may call: each has an overload for Ceres Jets (sqrt and cbrt are
# powers in SymPy).
_FUNCTIONS = (sp.sin, sp.cos, sp.tan, sp.asin, sp.acos, sp.atan, sp.atan2, sp.sinh, sp.cosh,
              sp.tanh, sp.exp, sp.log)
_FUNCTION_NAMES = "sin cos tan asin acos atan atan2 sinh cosh tanh exp log sqrt cbrt and powers"
# Functions that branch on their argument: the branch belongs to a switching surface.
_BRANCHING = (sp.Piecewise, sp.Heaviside, sp.sign, sp.Max, sp.Min, sp.floor, sp.ceiling)
# A field given per sign word is printed as a switch over its 2^n words (and FESD takes its 2^n
# modes): above this many surfaces, write the field in the sign symbols.
MAX_WORD_SURFACES = 10

compile_seconds = {"last": 0.0}


def signs(n: int):
    """The sign symbols b_0 ... b_{n-1} of n surfaces: +1 or -1, the side of each surface."""
    if not isinstance(n, int) or n < 0 or n > 64:
        raise ModelError(f"signs: the number of surfaces must be an integer in [0, 64], got {n!r}")
    return sp.symbols(f"b_0:{n}", real=True) if n > 0 else ()


def _short(value) -> str:
    text = str(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _number_value(node, where: str) -> float:
    """The double nearest the exact number node (an Integer, Rational or Float), refusing one
    beyond the double range."""
    try:
        if isinstance(node, sp.Rational):
            value = int(node.p) / int(node.q)  # Python's int division rounds correctly
        else:
            value = float(node)
    except OverflowError:
        value = math.inf
    if not math.isfinite(value):
        raise ModelError(f"{where}: the number {_short(node)} is beyond the range of a double")
    return value


def _refusal(node, where: str) -> ModelError:
    name = type(node).__name__
    if isinstance(node, sp.Abs):
        arg = _short(node.args[0])
        return ModelError(
            f"{where}: Abs({arg}) has a kink where {arg} = 0, which is no switching surface (the "
            f"flow would step over it, its derivative wrong there); make the kink a surface: add "
            f"{arg} to the surfaces and write the field with its sign symbol b (b*({arg}))")
    if isinstance(node, _BRANCHING):
        return ModelError(
            f"{where}: {_short(node)} branches on the state; state the branches as the field of "
            "each sign word (the surfaces decide the side)")
    if isinstance(node, (sp.logic.boolalg.Boolean, sp.core.relational.Relational)):
        return ModelError(f"{where}: {_short(node)} is a condition ({name}), not a number; "
                          "a side is chosen by a switching surface and its sign symbol")
    if isinstance(node, (sp.Derivative, sp.Integral, sp.Subs)):
        return ModelError(f"{where}: {_short(node)} is an unevaluated {name}; evaluate it "
                          "(.doit()) into a closed form first")
    if node.is_Number or node in (sp.oo, -sp.oo, sp.zoo, sp.nan):
        return ModelError(f"{where}: {_short(node)} is not a finite real number")
    if node == sp.I or node.is_extended_real is False:
        return ModelError(f"{where}: {_short(node)} is not real (the field is real)")
    if isinstance(node, sp.Function) or getattr(node, "is_Function", False):
        return ModelError(f"{where}: the function {name} has no Jet overload; use "
                          f"{_FUNCTION_NAMES}")
    return ModelError(
        f"{where}: {_short(node)} ({name}) is not an expression bflow compiles: symbols, finite "
        f"real numbers, pi, E, sums, products and the functions {_FUNCTION_NAMES}")


def _check_nodes(expr, where: str) -> None:
    """Refuses every node outside the whitelist: symbols, finite real numbers, pi, E, Add, Mul,
    Pow and the functions with a Jet overload."""
    stack = [expr]
    while stack:
        node = stack.pop()
        if isinstance(node, sp.Symbol):
            continue
        if isinstance(node, (sp.Rational, sp.Float)):
            _number_value(node, where)
            continue
        if node is sp.pi or node is sp.E:
            continue
        if isinstance(node, (sp.Add, sp.Mul, sp.Pow, *_FUNCTIONS)):
            stack.extend(node.args)
            continue
        raise _refusal(node, where)


def _expression(value, where: str):
    """A SymPy expression from a SymPy expression or a real number; never parses text."""
    if isinstance(value, (str, bytes, bytearray)):
        raise ModelError(
            f"{where}: the string {_short(repr(value))} is not an expression: bflow does not "
            "parse strings (SymPy's sympify would run them as Python); build the expression "
            "from SymPy symbols")
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        raise ModelError(f"{where}: {value!r} is a truth value, not a number")
    if isinstance(value, sp.Basic):
        expr = value
    elif isinstance(value, numbers.Integral):
        expr = sp.Integer(int(value))
    elif isinstance(value, numbers.Real):
        number = float(value)
        if not math.isfinite(number):
            raise ModelError(f"{where}: {number!r} is not a finite number")
        expr = sp.Float(number)
    else:
        raise ModelError(f"{where}: {_short(repr(value))} ({type(value).__name__}) is neither "
                         "a SymPy expression nor a real number")
    _check_nodes(expr, where)
    return expr


def _expressions(values, what: str):
    if isinstance(values, (str, bytes, bytearray, sp.Basic)) or not hasattr(values, "__iter__"):
        raise ModelError(f"{what} must be a list of expressions, got {_short(repr(values))}")
    return [_expression(v, f"{what}[{k}]") for k, v in enumerate(values)]


def _real_value(value, where: str) -> float:
    """A parameter's value: a finite real number (a string is not parsed)."""
    if isinstance(value, (str, bytes, bytearray, bool)) or not isinstance(
            value, (numbers.Real, sp.Number)):
        raise ModelError(f"{where} must be a real number, got {_short(repr(value))}")
    try:
        number = float(value)
    except (TypeError, OverflowError):
        number = math.nan
    if not math.isfinite(number):
        raise ModelError(f"{where} must be a finite real number, got {_short(repr(value))}")
    return number


def _sign_word(word, n: int) -> str:
    if isinstance(word, str):
        w = word
    else:
        try:
            w = "".join("+" if int(v) > 0 else "-" for v in word)
        except (TypeError, ValueError):
            w = None
    if w is None or len(w) != n or any(c not in "+-" for c in w):
        raise ModelError(
            f"field: the sign word {_short(repr(word))} must have {n} characters '+' or '-'")
    return w


class _Printer(C99CodePrinter):
    """C++ for a scalar type T: every number a T printed from its value, powers without integer
    exponents, every symbol a generated identifier (the expressions are checked by _check_nodes
    first)."""

    def __init__(self, names: Dict[sp.Symbol, str]):
        super().__init__()
        self._names = names

    def _print_Symbol(self, expr):
        if expr not in self._names:
            raise ModelError("an expression holds a symbol that is neither a state, a parameter "
                             "nor a sign symbol")
        return self._names[expr]

    _print_Dummy = _print_Symbol

    @staticmethod
    def _exact(expr) -> bool:
        return abs(int(expr.p)) <= 2 ** 53 and int(expr.q) <= 2 ** 53

    def _print_Integer(self, expr):
        if self._exact(expr):
            return f"T({int(expr)}.0)"
        return f"T({_number_value(expr, 'a number')!r})"

    def _print_Rational(self, expr):
        if self._exact(expr):
            return f"(T({int(expr.p)}.0) / T({int(expr.q)}.0))"
        return f"T({_number_value(expr, 'a number')!r})"

    def _print_Float(self, expr):
        return f"T({float(expr)!r})"

    def _print_Mul(self, expr):
        # The base printer splits a rational coefficient into numerator and denominator, which
        # overflow on their own when they exceed a double.
        c, rest = expr.as_coeff_Mul()
        if isinstance(c, sp.Rational) and not self._exact(c):
            return f"({self._print_Rational(c)} * ({self._print(rest)}))"
        return super()._print_Mul(expr)

    def _print_Pi(self, expr):
        return "T(3.141592653589793)"

    def _print_Exp1(self, expr):
        return "T(2.718281828459045)"

    def _print_Pow(self, expr):
        base, e = expr.as_base_exp()
        b = self._print(base)
        if e == sp.S.Half:
            return f"sqrt({b})"
        if e == -sp.S.Half:
            return f"(T(1.0) / sqrt({b}))"
        if e.is_Integer:
            n = int(e)
            if n == 0:
                return "T(1.0)"
            if 0 < n <= 4:
                return "(" + " * ".join([f"({b})"] * n) + ")"
            if -4 <= n < 0:
                return "(T(1.0) / (" + " * ".join([f"({b})"] * (-n)) + "))"
        if e.is_Rational:
            return f"pow({b}, {_number_value(e, 'an exponent')!r})"
        if e.is_Number:
            return f"pow({b}, {float(e)!r})"
        return f"pow({b}, {self._print(e)})"


def _assignments(printer: "_Printer", target: str, exprs, indent: str, offset: int = 0):
    """C++ lines target[offset + k] = exprs[k], common subexpressions (a sin of the same angle in
    several components, ...) computed once in a local of type T: with Jets each repeated call
    would cost a derivative's worth of work again."""
    # Dummies as temporaries: they never equal a user's symbol, whatever its name.
    temporaries, reduced = sp.cse(list(exprs), symbols=sp.numbered_symbols("c", cls=sp.Dummy))
    local = _Printer(dict(printer._names))
    lines = []
    for k, (symbol, value) in enumerate(temporaries):
        lines.append(f"{indent}const T cse{offset}_{k} = {local.doprint(value)};")
        local._names[symbol] = f"cse{offset}_{k}"
    for k, e in enumerate(reduced):
        lines.append(f"{indent}{target}[{offset + k}] = {local.doprint(e)};")
    return lines


class Model:
    """A piecewise-smooth vector field with switching surfaces, compiled for bflow's engines.

    Args:
        states: the state symbols x_0 ... x_{d-1} (SymPy Symbols), in order.
        field: the vector field: a list of d expressions in the states, the parameters and the
            sign symbols of ``signs(n)``, or a dict from every sign word ("+-" for b_0 = +1,
            b_1 = -1) to a list of d expressions.
        surfaces: the n switching functions h_j(x) (expressions in states and parameters).
        parameters: values of the parameter symbols (changed later without compiling again by
            ``with_parameters``).
        signs: the sign symbols used in ``field`` (default ``signs(n)``, named b_0, b_1, ...).
        controls: control symbols u (an optimal control model, for ``bflow.ocp_solve``): the
            field may use them, the surfaces may not.
        lagrange: the running cost L(x, u) of an optimal control model.
        mayer: the terminal cost R(x(T)).
        path: path constraints g(x, u) (bounds in ``ocp_solve``; default g <= 0).
        terminal: terminal constraints g_T(x(T)) (default g_T = 0).

    A model without controls runs on every engine: the flow and its B-derivative, orbits and
    sweeps, and FESD (``bflow.fesd_simulate``); a model with controls is for
    ``bflow.ocp_solve``. Each engine's library is compiled on its first use (a model used only
    for FESD never compiles the flow's) and cached.

    Raises:
        ModelError (a ValueError) before any compiler runs: a string or any object that is
        neither a SymPy expression nor a real number, a node outside the whitelist (symbols,
        finite real numbers, pi, E, +, *, powers, the functions with a Jet overload: not
        Abs, Piecewise, oo, nan, I, conditions, Derivative, ...), a symbol that is not a state,
        parameter or sign symbol, a non-finite parameter value, a field of the wrong length, a
        missing sign word, a field per sign word of more than MAX_WORD_SURFACES surfaces, a
        surface count above 64.
    """

    def __init__(self, states: Sequence[sp.Symbol], field, surfaces: Sequence = (),
                 parameters: Mapping[sp.Symbol, float] | None = None, signs=None, *,
                 controls: Sequence[sp.Symbol] = (), lagrange=None, mayer=None,
                 path: Sequence = (), terminal: Sequence = ()):
        self.states = list(states)
        if not self.states or not all(isinstance(s, sp.Symbol) for s in self.states):
            raise ModelError(f"states must be a non-empty list of SymPy Symbols, got {states!r}")
        if len(set(self.states)) != len(self.states):
            raise ModelError(f"states repeat a symbol: {self.states}")
        d = len(self.states)
        self.surface_exprs = _expressions(surfaces, "surfaces")
        n = len(self.surface_exprs)
        if n > 64:
            raise ModelError(f"at most 64 surfaces, got {n}")
        parameters = dict(parameters or {})
        self.parameters = list(parameters.keys())
        for p in self.parameters:
            if not isinstance(p, sp.Symbol):
                raise ModelError(f"parameter names must be SymPy Symbols, got {p!r}")
        self.parameter_values = [_real_value(parameters[p], f"the value of the parameter {p}")
                                 for p in self.parameters]
        self.sign_symbols = list(signs) if signs is not None else list(globals()["signs"](n))
        if not all(isinstance(s, sp.Symbol) for s in self.sign_symbols):
            raise ModelError(f"signs must be SymPy Symbols, got {_short(self.sign_symbols)}")
        if len(self.sign_symbols) != n:
            raise ModelError(
                f"{len(self.sign_symbols)} sign symbols for {n} surfaces: give one per surface")
        names: Dict[sp.Symbol, str] = {}
        for i, s in enumerate(self.states):
            names[s] = f"x[{i}]"
        for j, p in enumerate(self.parameters):
            if p in names:
                raise ModelError(f"the symbol {p} is both a state and a parameter")
            names[p] = f"T(p_[{j}])"
        for j, s in enumerate(self.sign_symbols):
            if s in names:
                raise ModelError(f"the sign symbol {s} is also a state or a parameter")
            names[s] = f"T(double(b.sign({j})))"
        self.controls = list(controls)
        for k, u in enumerate(self.controls):
            if not isinstance(u, sp.Symbol):
                raise ModelError(f"controls must be SymPy Symbols, got {u!r}")
            if u in names:
                raise ModelError(f"the control {u} is also a state, a parameter or a sign symbol")
            names[u] = f"u[{k}]"
        self._names = names
        self.lagrange_expr = None if lagrange is None else _expression(lagrange, "lagrange")
        self.mayer_expr = None if mayer is None else _expression(mayer, "mayer")
        self.path_exprs = _expressions(path, "path")
        self.terminal_exprs = _expressions(terminal, "terminal")
        if not self.controls and (self.lagrange_expr is not None or self.mayer_expr is not None
                                  or self.path_exprs or self.terminal_exprs):
            raise ModelError("costs and constraints (lagrange, mayer, path, terminal) belong to "
                             "an optimal control model: give its controls")

        if isinstance(field, Mapping):
            if n > MAX_WORD_SURFACES:
                raise ModelError(
                    f"field: a field given per sign word is compiled as a switch over all 2^n "
                    f"words (and FESD takes them as 2^n modes): n = {n} surfaces would be "
                    f"{2 ** n} words, above the {2 ** MAX_WORD_SURFACES} of n = "
                    f"{MAX_WORD_SURFACES}; write the field as expressions in the sign symbols "
                    f"bflow.signs({n})")
            words = {}
            for word, exprs in field.items():
                w = _sign_word(word, n)
                if w in words:
                    raise ModelError(f"field: the sign word {w!r} is given twice")
                words[w] = _expressions(exprs, f"field[{w!r}]")
            if len(words) < 2 ** n:
                # Every key is a distinct word of n signs: one of the first len(words) + 1 is
                # missing.
                missing = next(w for w in map(lambda bits: _word_of_bits(bits, n),
                                              range(len(words) + 1)) if w not in words)
                raise ModelError(f"field: the sign word {missing!r} is missing "
                                 f"({2 ** n - len(words)} of {2 ** n} words missing)")
            self.field_words = words
            self.field_exprs = None
        else:
            self.field_exprs = _expressions(field, "field")
            self.field_words = None
        known = set(self.states) | set(self.parameters)
        for where, exprs, expected, extra, forbidden in self._all_exprs():
            if expected is not None and len(exprs) != expected:
                raise ModelError(f"{where} has {len(exprs)} expressions, expected {expected}")
            for k, e in enumerate(exprs):
                for symbols, what, why in forbidden:
                    used = e.free_symbols & set(symbols)
                    if used:
                        raise ModelError(f"{where}[{k}] uses the {what} "
                                         f"{sorted(map(str, used))}: {why}")
                unknown = e.free_symbols - known - set(extra) - {
                    s for symbols, _, _ in forbidden for s in symbols}
                if unknown:
                    raise ModelError(
                        f"{where}[{k}]: the symbol(s) {sorted(map(str, unknown))} are neither "
                        f"states {self.states}, parameters {self.parameters}"
                        + (f", controls {self.controls}" if self.controls else "")
                        + " nor sign symbols")
        if self.controls and n == 0:
            raise ModelError("an optimal control model needs at least one switching surface "
                             "(FESD detects its switches)")
        self._libraries: Dict[str, str] = {}
        self._keys: Dict[str, str] = {}
        self._step = None
        self._ocp = None
        self._compiled = None

    # --- the compiled libraries, one per engine, each compiled on first use
    def _key(self, engine: str, extra=()) -> str:
        """The cache key of one engine's library: a hash of the model's inputs (not of the
        generated source, so that a cached load neither runs cse nor prints C++)."""
        if engine not in self._keys or extra:
            fields = (self.field_exprs if self.field_exprs is not None
                      else sorted(self.field_words.items()))
            inputs = (engine, _GENERATOR, _command(Path("s"), Path("o")), str(_bflow.__file__),
                      _installed_digest(),
                      *map(_structure, (self.states, self.parameters, self.sign_symbols,
                                        self.controls, fields, self.surface_exprs,
                                        self.lagrange_expr, self.mayer_expr, self.path_exprs,
                                        self.terminal_exprs, list(extra))))
            key = hashlib.sha256(repr(inputs).encode()).hexdigest()[:32]
            if extra:
                return key
            self._keys[engine] = key
        return self._keys[engine]

    def _library(self, engine: str, key: str, make_source, load):
        """Loads the cached library of one engine (compiling it on a miss) with load(path). A
        library that holds another key is replaced and loaded from a fresh path (dlopen keeps a
        library by its path for the life of the process)."""
        info = (engine, len(self.states), len(self.surface_exprs))
        path = _cached_library(key, make_source, info)
        try:
            handle = load(str(path))
        except ValueError as error:
            if "not the model" not in str(error):
                raise
            print(f"bflow: {error}; compiling it again", file=sys.stderr, flush=True)
            _LOADED.add(str(path))  # dlopen keeps it: the rebuild is loaded from a fresh path
            path = _cached_library(key, make_source, info, rebuild=True)  # a fresh copy
            handle = load(str(path))
        _LOADED.add(str(path))
        return handle, str(path)

    @property
    def source(self) -> str:
        """The generated C++ of the flow's library (generated anew on each access)."""
        if self.controls:
            return None
        return self._source(self._key("flow"))

    def _all_exprs(self):
        """(where, expressions, expected count, symbols allowed beside states and parameters,
        [(forbidden symbols, what they are)])."""
        d, n = len(self.states), len(self.surface_exprs)
        signs_, controls = self.sign_symbols, self.controls
        side = (signs_, "sign symbol(s)", f"only the field depends on the side, "
                "h(x), costs and constraints cannot depend on the side")
        if self.field_exprs is not None:
            yield "field", self.field_exprs, d, list(signs_) + list(controls), []
        else:
            for w, exprs in self.field_words.items():
                yield f"field[{w!r}]", exprs, d, list(signs_) + list(controls), []
        control = (controls, "control(s)", "only the field, the Lagrange cost and the path "
                   "constraints take controls")
        yield "surfaces", self.surface_exprs, n, [], [side, control]
        if self.lagrange_expr is not None:
            yield "lagrange", [self.lagrange_expr], 1, controls, [side]
        if self.mayer_expr is not None:
            yield "mayer", [self.mayer_expr], 1, [], [side, control]
        yield "path", self.path_exprs, None, controls, [side]
        yield "terminal", self.terminal_exprs, None, [], [side, control]

    def _source(self, key: str) -> str:
        printer = _Printer(self._names)
        d, n, P = len(self.states), len(self.surface_exprs), len(self.parameters)
        lines = []

        def assign(target, exprs, indent):
            lines.extend(_assignments(printer, target, exprs, indent))

        lines.append("    template <typename T>")
        lines.append("    void field(const T* x, bflow::Signs b, T* xdot) const {")
        lines.append("  " + _USING.replace("\n", "\n  "))
        lines.append("      (void)b;")
        if self.field_exprs is not None:
            assign("xdot", self.field_exprs, "      ")
        else:
            lines.append("      switch (b.bits()) {")
            for w, exprs in sorted(self.field_words.items(),
                                   key=lambda item: _word_bits(item[0])):
                lines.append(f"        case {_word_bits(w)}u: {{")
                assign("xdot", exprs, "          ")
                lines.append("          return;")
                lines.append("        }")
            lines.append("        default:")
            lines.append("          for (int i = 0; i < kStates; ++i) xdot[i] = T(0.0);")
            lines.append("      }")
        lines.append("    }")
        lines.append("    template <typename T>")
        lines.append("    void surfaces(const T* x, T* h) const {")
        lines.append("  " + _USING.replace("\n", "\n  "))
        lines.append("      (void)x;")
        assign("h", self.surface_exprs, "      ")
        lines.append("    }")
        struct = "\n".join([f"  static constexpr int kStates = {d};",
                            f"  static constexpr int kSurfaces = {n};",
                            f"  double p_[{max(P, 1)}] = {{}};"] + lines)
        return self._library_source("flow", "bflow/integrators/model_adapter.h", struct,
                                    "SegmentModel", "bflow::ModelAdapter<GeneratedModel>",
                                    "model", key)

    # --- FESD and optimal control: the step inclusion x' = f(x, [u,] a), a_j in gamma(h_j(x))
    def _multilinear(self) -> bool:
        """Whether the field, given in the signs, is affine in each sign (then f(x, a) is the
        field with b_j = 2 a_j - 1, the step representation itself)."""
        if self.field_exprs is None:
            return False
        for e in self.field_exprs:
            for b in set(self.sign_symbols) & e.free_symbols:
                try:
                    poly = sp.Poly(e, b)
                except sp.PolynomialError:
                    return False
                if poly.degree() > 1 or any(b in c.free_symbols for c in poly.coeffs()):
                    return False
        return True

    def _step_struct(self) -> str:
        """The struct a C++ user of FESD or ocp_solve writes (fesd/step_model.h, ocp/ocp.h):
        switching c = h(x) and either f(x, [u,] a) or, for a field given per sign word (or not
        affine in the signs), every mode f_i(x, [u]) of the dense sign matrix."""
        d, n, P = len(self.states), len(self.surface_exprs), len(self.parameters)
        u_arg = "const T* u, " if self.controls else ""
        lines = [f"  static constexpr int kStates = {d};", f"  static constexpr int kSwitches = {n};"]
        if self.controls:
            lines.append(f"  static constexpr int kControls = {len(self.controls)};")
        lines.append(f"  double p_[{max(P, 1)}] = {{}};")

        def function(signature, names, emit):
            printer = _Printer(names)
            lines.append("  template <typename T>")
            lines.append(f"  {signature} const {{")
            lines.append(_USING)
            emit(printer)
            lines.append("  }")

        def assign(printer, target, exprs, offset=0):
            lines.extend(_assignments(printer, target, exprs, "    ", offset))

        function("void switching(const T* x, T* c)", self._names,
                 lambda pr: (lines.append("    (void)x;"), assign(pr, "c", self.surface_exprs)))
        modes = not self._multilinear()
        if not modes:
            names = dict(self._names)
            for j, b in enumerate(self.sign_symbols):
                names[b] = f"(T(2.0) * a[{j}] - T(1.0))"
            function(f"void field(const T* x, {u_arg}const T* a, T* xdot)", names,
                     lambda pr: (lines.append("    (void)x; (void)a;"),
                                 assign(pr, "xdot", self.field_exprs)))
        else:
            if n > 10:
                raise ModelError(f"FESD of a field given per sign word (or not affine in the "
                                 f"signs) takes its 2^n modes: n = {n} surfaces is above 10; "
                                 f"write the field as expressions affine in each sign")
            lines.insert(2, f"  static constexpr int kModes = {2 ** n};")

            def emit_modes(_):
                for r in range(2 ** n):
                    # Row r of SignMatrix::dense(n): side + of surface j iff bit n-1-j of r is 0.
                    word = "".join("-" if (r >> (n - 1 - j)) & 1 else "+" for j in range(n))
                    if self.field_words is not None:
                        exprs, names = self.field_words[word], self._names
                    else:
                        exprs, names = self.field_exprs, dict(self._names)
                        for j, b in enumerate(self.sign_symbols):
                            names[b] = "T(1.0)" if word[j] == "+" else "T(-1.0)"
                    assign(_Printer(names), "F", exprs, r * d)

            function(f"void modes(const T* x, {u_arg}T* F)", self._names,
                     lambda pr: (lines.append("    (void)x;"), emit_modes(pr)))
        if self.lagrange_expr is not None:
            function("T lagrange(const T* x, const T* u)", self._names,
                     lambda pr: lines.append(f"    (void)x; (void)u;\n"
                                             f"    return {pr.doprint(self.lagrange_expr)};"))
        if self.mayer_expr is not None:
            function("T mayer(const T* x)", self._names,
                     lambda pr: lines.append(f"    (void)x;\n"
                                             f"    return {pr.doprint(self.mayer_expr)};"))
        if self.path_exprs:
            lines.append(f"  static constexpr int kPath = {len(self.path_exprs)};")
            function("void path(const T* x, const T* u, T* g)", self._names,
                     lambda pr: (lines.append("    (void)x; (void)u;"),
                                 assign(pr, "g", self.path_exprs)))
        if self.terminal_exprs:
            lines.append(f"  static constexpr int kTerminal = {len(self.terminal_exprs)};")
            function("void terminal(const T* x, T* g)", self._names,
                     lambda pr: (lines.append("    (void)x;"),
                                 assign(pr, "g", self.terminal_exprs)))
        if modes:
            wrapper = ("bflow::ControlledPiecewiseSmoothAsStep" if self.controls
                       else "bflow::PiecewiseSmoothAsStep")
            made = f"{wrapper}<GeneratedModel>(model, bflow::SignMatrix::dense({n}))"
            kind = f"{wrapper}<GeneratedModel>"
        else:
            made, kind = "model", "GeneratedModel"
        return "\n".join(lines), kind, made

    def _engine_source(self, engine: str, key: str) -> str:
        body, kind, made = self._step_struct()
        if engine == "step":
            header, interface, adapter = "bflow/fesd/step_model.h", "StepModel", "StepModelAdapter"
        else:
            header, interface, adapter = "bflow/ocp/ocp.h", "OcpModel", "OcpModelAdapter"
        return self._library_source(engine, header, body, interface, f"bflow::{adapter}<{kind}>",
                                    made, key)

    def _library_source(self, engine: str, header: str, struct: str, interface: str,
                        adapter: str, made: str, key: str) -> str:
        """The shared library of one engine: the struct GeneratedModel (with its parameters in
        p_), bflow_<engine>_model_create / _destroy, which python/src/model_handle.h loads, and
        the key the library is cached under (checked after dlopen)."""
        return _LIBRARY_TEMPLATE.format(
            header=header, struct=struct, interface=interface, engine=engine,
            P=len(self.parameters), adapter=adapter, made=made, key=key)

    def _engine_model(self, engine: str, load):
        """The library of the step (FESD) or OCP engine, compiled on first use, loaded with
        load(path); later loads (other parameter values) reuse the path."""
        if engine in self._libraries:
            return load(self._libraries[engine])
        key = self._key(engine)
        handle, self._libraries[engine] = self._library(
            engine, key, lambda: self._engine_source(engine, key), load)
        return handle

    def _step_model(self):
        """The compiled step inclusion (FESD), compiled on first use."""
        if self.controls:
            raise ModelError(f"the model has controls {self.controls}: it is an optimal control "
                             "model (bflow.ocp_solve); FESD simulates a model without controls")
        if not self.surface_exprs:
            raise ModelError("FESD needs at least one switching surface")
        if self._step is None:
            values = self.parameter_values
            self._step = self._engine_model(
                "step", lambda path: _bflow._load_step_model(path, values))
        return self._step

    def _ocp_model(self):
        if not self.controls:
            raise ModelError("the model has no controls: give Model(..., controls=[u, ...]) "
                             "to solve an optimal control problem")
        if self._ocp is None:
            values = self.parameter_values
            self._ocp = self._engine_model("ocp",
                                           lambda path: _bflow._load_ocp_model(path, values))
        return self._ocp

    def _section(self, expression):
        """A Poincare section s(x) = 0 written in the states and parameters, compiled (on first
        use, cached) into the functor of orbits/periodic_orbit.h behind SectionAdapter."""
        s_expr = _expression(expression, "section")
        unknown = s_expr.free_symbols - set(self.states) - set(self.parameters)
        if unknown:
            raise ModelError(f"section: the symbol(s) {sorted(map(str, unknown))} are neither "
                             f"states {self.states} nor parameters {self.parameters}")
        key = self._key("section", (s_expr,))

        def source():
            struct = "\n".join([
                f"  double p_[{max(len(self.parameters), 1)}] = {{}};",
                "  template <typename T>", "  T operator()(const T* x) const {", _USING,
                "    (void)x;", f"    return {_Printer(self._names).doprint(s_expr)};", "  }"])
            return self._library_source("section", "bflow/orbits/periodic_orbit.h", struct,
                                        "PoincareSection",
                                        "bflow::SectionAdapter<GeneratedModel>", "model", key)

        values = self.parameter_values
        return self._library("section", key, source,
                             lambda path: _bflow._load_section(path, values))[0]

    def _flow_model(self):
        """The compiled flow (a SegmentModel), compiled on first use by a flow engine."""
        if self.controls:
            raise ModelError(f"the model has controls {self.controls}: it is an optimal control "
                             "model for bflow.ocp_solve; the flow, orbits, sweeps and jump maps "
                             "take a model without controls")
        if self._compiled is None:
            values, names = self.parameter_values, [str(q) for q in self.parameters]

            def load(path):
                return _bflow._load_model(path, values, names)

            if "flow" in self._libraries:
                self._compiled = load(self._libraries["flow"])
            else:
                key = self._key("flow")
                self._compiled, self._libraries["flow"] = self._library(
                    "flow", key, lambda: self._source(key), load)
        return self._compiled

    # --- what the C++ model provides
    @property
    def dim(self) -> int:
        """The number of states d."""
        return len(self.states)

    @property
    def surface_count(self) -> int:
        """The number of switching surfaces n."""
        return len(self.surface_exprs)

    def with_parameters(self, **values) -> "Model":
        """The same model (the same compiled library) with some parameters changed, by name."""
        names = {str(p): k for k, p in enumerate(self.parameters)}
        new = list(self.parameter_values)
        for name, v in values.items():
            if name not in names:
                raise ModelError(f"with_parameters: no parameter {name!r}; the model has "
                                 f"{sorted(names)}")
            new[names[name]] = _real_value(v, f"with_parameters: {name}")
        clone = object.__new__(Model)
        clone.__dict__.update(self.__dict__)
        clone.parameter_values = new
        clone._libraries = dict(self._libraries)
        clone._keys = dict(self._keys)
        clone._step = clone._ocp = clone._compiled = None  # loaded on use, with the new values
        return clone

    def field(self, x, sides: str):
        """F_b(x) for the sign word ``sides`` (e.g. "+-")."""
        return self._flow_model().field(_vector(x, "x", self.dim), sides)

    def surface_values(self, x):
        """h(x)."""
        return self._flow_model().surface_values(_vector(x, "x", self.dim))

    def normals(self, x):
        """Dh(x) (n x d), by Jets."""
        return self._flow_model().normals(_vector(x, "x", self.dim))

    def __reduce__(self):
        return (_rebuild, (self.states, self.field_exprs if self.field_exprs is not None
                           else self.field_words, self.surface_exprs,
                           dict(zip(self.parameters, self.parameter_values)), self.sign_symbols,
                           dict(controls=self.controls, lagrange=self.lagrange_expr,
                                mayer=self.mayer_expr, path=self.path_exprs,
                                terminal=self.terminal_exprs)))

    def __repr__(self):
        return (f"bflow.Model(states={self.states}, surfaces={self.surface_exprs}, "
                f"parameters={dict(zip(map(str, self.parameters), self.parameter_values))})")


def _rebuild(states, field, surfaces, parameters, sign_symbols, ocp=None):
    return Model(states, field, surfaces, parameters, sign_symbols, **(ocp or {}))


def _vector(x, name: str, d: int):
    import numpy as np
    a = np.asarray(x, dtype=float)
    if a.ndim != 1 or a.shape[0] != d:
        raise ValueError(f"{name} must be a vector of {d} numbers, got shape {a.shape}")
    return a


def _structure(value):
    """The exact tree of an expression (or of a list, tuple or sign word of them) as nested
    tuples of strings and integers, for the cache key: like srepr, every node's class, every
    symbol's name and assumptions and every number's exact value, but without sorting the terms
    (5 to 10 times faster; equal trees give equal keys, which is all a key needs)."""
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, (list, tuple)):
        return tuple(_structure(v) for v in value)
    if isinstance(value, sp.Symbol):
        extra = (value.dummy_index,) if isinstance(value, sp.Dummy) else ()
        return (type(value).__name__, value.name, *extra,
                tuple(sorted(value.assumptions0.items())))
    if isinstance(value, sp.Rational):
        return ("Rational", int(value.p), int(value.q))
    if isinstance(value, sp.Float):
        return ("Float", value._mpf_, value._prec)
    if not value.args:
        return (type(value).__name__, str(value))
    return (type(value).__name__, *(_structure(a) for a in value.args))


def _word_of_bits(bits: int, n: int) -> str:
    """The sign word whose surface j is on its + side where bit j of bits is set."""
    return "".join("+" if (bits >> j) & 1 else "-" for j in range(n))


def _word_bits(word: str) -> int:
    return sum(1 << j for j, c in enumerate(word) if c == "+")


_USING = """    using std::sin; using std::cos; using std::tan; using std::asin;
    using std::acos; using std::atan; using std::atan2; using std::sinh;
    using std::cosh; using std::tanh; using std::exp; using std::log;
    using std::sqrt; using std::abs; using std::pow; using std::cbrt;"""

_LIBRARY_TEMPLATE = """// Generated by bflow from a SymPy model.
#include <cmath>
#include <cstdio>
#include <exception>

#include "{header}"

namespace {{

struct GeneratedModel {{
{struct}
}};

}}  // namespace

extern "C" bflow::{interface}* bflow_{engine}_model_create(const double* p, int count,
                                                           char* error, int error_size) {{
  if (count != {P}) {{
    std::snprintf(error, static_cast<std::size_t>(error_size),
                  "the model has {P} parameters, %d values were given", count);
    return nullptr;
  }}
  try {{
    GeneratedModel model;
    for (int k = 0; k < count; ++k) model.p_[k] = p[k];
    return new {adapter}({made});
  }} catch (const std::exception& e) {{
    std::snprintf(error, static_cast<std::size_t>(error_size), "%s", e.what());
    return nullptr;
  }}
}}

extern "C" void bflow_{engine}_model_destroy(bflow::{interface}* model) {{ delete model; }}

extern "C" const char bflow_model_key[] = "{key}";
"""


def _compiler():
    return os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++") or "c++"


def _command(source: Path, output: Path):
    include = Path(__file__).resolve().parent / "include"
    # The compiler's own directories stay out of -isystem (it would break #include_next).
    system = [f"-isystem{d}" for d in (_bflow._eigen_include_dir, _bflow._ceres_include_dir)
              if d not in ("/usr/include", "/usr/local/include")]
    return [
        _compiler(), "-std=c++17", "-O2", "-fPIC", "-shared", "-DNDEBUG",
        "--param=large-function-growth=1000", "--param=inline-unit-growth=400",
        f"-I{include}", *system, str(source),
        str(Path(__file__).resolve().parent / "lib" / "libbflow_core.a"), "-o", str(output),
    ]


# The generator's version: a change to this file (the printer, the templates) is a new key.
_GENERATOR = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()
_INSTALLED: Optional[str] = None


def _installed_digest() -> str:
    """A digest of what a compiled model is built against: the headers and the core library
    installed with this package (a new bflow in the same place is a new key, so that a model
    compiled against another layout of its scalar types is never loaded)."""
    global _INSTALLED
    if _INSTALLED is None:
        root = Path(__file__).resolve().parent
        digest = hashlib.sha256()
        for path in sorted((root / "include").rglob("*")) + [root / "lib" / "libbflow_core.a"]:
            if path.is_file():
                digest.update(str(path.relative_to(root)).encode())
                digest.update(path.read_bytes())
        _INSTALLED = digest.hexdigest()
    return _INSTALLED
# A temporary of a compile (bflow_tmp_*) or a fresh copy older than this is a leftover of a
# process that was killed (or is done with it) and is removed by the next compile.
STALE_SECONDS = 600.0
_LOADED: set = set()       # libraries this process has dlopened, by path
_VERIFIED: Dict[str, tuple] = {}  # path -> (inode, size, mtime) whose checksum matched


def _cache_location():
    """(the cache folder, the $BFLOW_CACHE_DIR setting or None for the default)."""
    setting = os.environ.get("BFLOW_CACHE_DIR")
    if not setting:  # unset or "": the default
        return Path.home() / ".cache" / "bflow" / "models", None
    expanded = os.path.expanduser(setting)
    if expanded.startswith("~"):
        raise ModelError(f"$BFLOW_CACHE_DIR={setting!r}: {expanded.split('/')[0]!r} names no "
                         "home folder; give an absolute path")
    return Path(os.path.abspath(expanded)), setting


def cache_dir() -> Path:
    """Where compiled models are kept: $BFLOW_CACHE_DIR ("~" expanded, a relative path taken
    from the current folder; unset or "" for the default ~/.cache/bflow/models)."""
    return _cache_location()[0]


def _cache_error(directory: Path, setting, action: str, error: OSError) -> ModelError:
    where = (f"$BFLOW_CACHE_DIR={setting!r}" if setting is not None
             else "the default model cache ($BFLOW_CACHE_DIR unset)")
    reason = error.strerror or str(error)
    return ModelError(f"{where}: cannot {action} {directory}: {reason} (errno {error.errno}); "
                      "set $BFLOW_CACHE_DIR to a writable folder")


def _write_file(path: Path, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _verified(library: Path, key: str) -> bool:
    """Whether library is whole and of this key: its sidecar names the key, the size and the
    sha256 of the file (checked before any dlopen; once per process while the file is
    unchanged)."""
    try:
        info = json.loads(library.with_suffix(".json").read_text())
        st = os.stat(library)
    except (OSError, ValueError):
        return False
    if not isinstance(info, dict) or info.get("key") != key or info.get("size") != st.st_size:
        return False
    stamp = (st.st_ino, st.st_size, st.st_mtime_ns)
    if _VERIFIED.get(str(library)) == stamp:
        return True
    try:
        ok = _sha256(library) == info.get("sha256")
    except OSError:
        return False
    if ok:
        _VERIFIED[str(library)] = stamp
    return ok


def _clean_stale(directory: Path) -> None:
    """Removes what killed compiles left (bflow_tmp_* files, the tmp* folders of older
    versions holding only model.cc / model.so) and fresh copies, all older than
    STALE_SECONDS."""
    now = time.time()
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return
    for entry in entries:
        try:
            old = now - entry.stat(follow_symlinks=False).st_mtime > STALE_SECONDS
            if not old:
                continue
            name = entry.name
            if entry.is_file(follow_symlinks=False) and (
                    name.startswith("bflow_tmp_") or
                    (name.startswith("model_") and name.count(".") == 2)):
                os.unlink(entry.path)
            elif (entry.is_dir(follow_symlinks=False) and name.startswith("tmp")
                  and set(os.listdir(entry.path)) <= {"model.cc", "model.so"}):
                shutil.rmtree(entry.path)
        except OSError:
            pass  # another process removed it, or it is not ours to remove


def _fresh_copy(library: Path) -> Path:
    """A copy of library under a name this process has not loaded: model_<key>.<tag>.so."""
    fresh = library.with_name(f"{library.stem}.{os.getpid()}_{time.time_ns()}.so")
    shutil.copyfile(library, fresh)
    return fresh


def _cached_library(key: str, make_source, info, rebuild: bool = False) -> Path:
    """The library of this key in the cache, checked (checksum, key); compiled on a miss, on a
    damaged or replaced file, or when rebuild. Compiles of one key are serialised by a lock
    file; the library and its sidecar are written to temporaries and renamed (atomic)."""
    engine, d, n = info
    directory, setting = _cache_location()
    library = directory / f"model_{key}.so"
    if not rebuild and _verified(library, key):
        compile_seconds["last"] = 0.0
        return library
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise _cache_error(directory, setting, "make the folder", error) from None
    try:
        lock = open(directory / f"model_{key}.lock", "a")
    except OSError as error:
        raise _cache_error(directory, setting, "write in", error) from None
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not rebuild and _verified(library, key):  # another process compiled it meanwhile
            compile_seconds["last"] = 0.0
            return library
        if not rebuild and library.exists():
            print(f"bflow: the cached library {library} does not match its checksum or key "
                  "(damaged or replaced): compiling it again", file=sys.stderr, flush=True)
        _clean_stale(directory)
        _compile_into(library, key, make_source(), engine, d, n, directory, setting)
    return _fresh_copy(library) if str(library) in _LOADED else library


def _compile_into(library: Path, key: str, source: str, engine: str, d: int, n: int,
                  directory: Path, setting) -> None:
    start = time.perf_counter()
    print(f"bflow: compiling {engine} library for a model with {d} states, {n} surfaces "
          f"(first use; cached in {directory})", file=sys.stderr, flush=True)
    stem = directory / f"bflow_tmp_{key}_{os.getpid()}_{time.time_ns()}"
    src, out, meta = (stem.with_suffix(".cc"), stem.with_suffix(".so"),
                      stem.with_suffix(".json"))
    try:
        try:
            _write_file(src, source.encode())
        except OSError as error:
            raise _cache_error(directory, setting, "write the generated source in",
                               error) from None
        run = subprocess.run(_command(src, out), capture_output=True, text=True)
        if run.returncode != 0:
            failed = directory / f"failed_{key}.cc"
            os.replace(src, failed)
            raise ModelError(
                f"the C++ compiler refused the generated {engine} library (its source is kept "
                f"in {failed}):\n{run.stderr[-4000:]}\ncommand: "
                f"{' '.join(_command(failed, library))}")
        sidecar = {"key": key, "engine": engine, "size": out.stat().st_size,
                   "sha256": _sha256(out)}
        try:
            _write_file(meta, json.dumps(sidecar).encode())
        except OSError as error:
            raise _cache_error(directory, setting, "write the checksum in", error) from None
        # The sidecar first: a reader between the two renames sees a checksum that does not
        # match the old file and compiles again; never a library with a wrong checksum.
        os.replace(meta, library.with_suffix(".json"))
        os.replace(out, library)
    finally:
        for temporary in (src, out, meta):
            try:
                temporary.unlink()
            except FileNotFoundError:
                pass
    seconds = time.perf_counter() - start
    compile_seconds["last"] = seconds
    print(f"bflow: compiled {engine} library in {seconds:.1f} s", file=sys.stderr, flush=True)
