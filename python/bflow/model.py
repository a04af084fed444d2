"""Models written in SymPy, compiled once into the templated functor a C++ user writes.

A model is d states, n switching surfaces h(x) and the vector field F_b(x) for every sign word b
(b_j = +1 on the + side of surface j, -1 on its - side), either as expressions in sign symbols
(``signs(n)``) or as a dict from sign words ("+-", ...) to expressions. bflow prints it as C++
(``field<T>`` and ``surfaces<T>`` templated on the scalar, so that Ceres Jets give DF and Dh
exactly as for a C++ model), compiles it with the system's C++ compiler into a shared library
and loads it. The library is cached under ``$BFLOW_CACHE_DIR`` (default ``~/.cache/bflow/models``)
by a hash of the generated source and the compiler command: the first call with a new model
compiles (a few seconds), later calls and other processes load it.

Example (two surfaces crossed at once, [B] (3.1))::

    import sympy as sp, bflow
    x, y = sp.symbols("x y")
    b = bflow.signs(2)
    delta = sp.Symbol("delta")
    model = bflow.Model([x, y], field=[1 - delta * b[0], 1 - delta * b[1]],
                        surfaces=[x, y], parameters={delta: 0.5})
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Dict, Mapping, Sequence, Union

import sympy as sp
from sympy.printing.c import C99CodePrinter

from . import _bflow
from ._errors import ModelError

__all__ = ["Model", "signs", "ModelError", "compile_seconds"]

# Functions the generated code may call: each has an overload for Ceres Jets.
_ALLOWED_FUNCTIONS = {
    "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "exp", "log",
    "sqrt", "Abs", "Pow", "Add", "Mul", "cbrt",
}

compile_seconds = {"last": 0.0}


def signs(n: int):
    """The sign symbols b_0 ... b_{n-1} of n surfaces: +1 or -1, the side of each surface."""
    if not isinstance(n, int) or n < 0 or n > 64:
        raise ModelError(f"signs: the number of surfaces must be an integer in [0, 64], got {n!r}")
    return sp.symbols(f"b_0:{n}", real=True) if n > 0 else ()


class _Printer(C99CodePrinter):
    """C++ for a scalar type T: every number a T, powers without integer exponents."""

    def __init__(self, names: Dict[sp.Symbol, str]):
        super().__init__()
        self._names = names

    def _print_Symbol(self, expr):
        if expr not in self._names:
            raise ModelError(
                f"the symbol {expr} is neither a state, a parameter nor a sign symbol")
        return self._names[expr]

    def _print_Integer(self, expr):
        return f"T({int(expr)}.0)"

    def _print_Rational(self, expr):
        return f"(T({int(expr.p)}.0) / T({int(expr.q)}.0))"

    def _print_Float(self, expr):
        return f"T({float(expr)!r})"

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
            return f"pow({b}, {float(n)!r})"
        if e.is_Number:
            return f"pow({b}, {float(e)!r})"
        return f"pow({b}, {self._print(e)})"

    def _print_Abs(self, expr):
        return f"abs({self._print(expr.args[0])})"


def _assignments(printer: "_Printer", target: str, exprs, indent: str, offset: int = 0):
    """C++ lines target[offset + k] = exprs[k], common subexpressions (a sin of the same angle in
    several components, ...) computed once in a local of type T: with Jets each repeated call
    would cost a derivative's worth of work again."""
    temporaries, reduced = sp.cse(list(exprs), symbols=sp.numbered_symbols("_cse"))
    local = _Printer(dict(printer._names))
    lines = []
    for k, (symbol, value) in enumerate(temporaries):
        lines.append(f"{indent}const T cse{offset}_{k} = {local.doprint(value)};")
        local._names[symbol] = f"cse{offset}_{k}"
    for k, e in enumerate(reduced):
        lines.append(f"{indent}{target}[{offset + k}] = {local.doprint(e)};")
    return lines


def _check_functions(expr, where: str):
    for node in sp.preorder_traversal(expr):
        if isinstance(node, (sp.Piecewise, sp.Heaviside)) or type(node).__name__ in (
                "sign", "Max", "Min", "floor", "ceiling"):
            raise ModelError(
                f"{where}: {node} branches on the state; state the branches as the field of "
                "each sign word (the surfaces decide the side)")
        if isinstance(node, sp.Function) or (isinstance(node, sp.Basic) and node.is_Function):
            name = type(node).__name__
            if name not in _ALLOWED_FUNCTIONS:
                raise ModelError(
                    f"{where}: the function {name} has no Jet overload; use "
                    + ", ".join(sorted(_ALLOWED_FUNCTIONS - {"Pow", "Add", "Mul"})))


def _sympify_list(values, what: str):
    try:
        return [sp.sympify(v) for v in values]
    except (sp.SympifyError, TypeError) as e:
        raise ModelError(f"{what}: {e}") from None


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
    sweeps (compiled at construction), and FESD (``bflow.fesd_simulate``, compiled on first
    use). A model with controls is for ``bflow.ocp_solve``.

    Raises:
        ModelError (a ValueError) before any compiler runs: a symbol that is not a state,
        parameter or sign symbol, a function without a Jet overload, a field of the wrong
        length, a missing sign word, a surface count above 64.
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
        self.surface_exprs = _sympify_list(surfaces, "surfaces")
        n = len(self.surface_exprs)
        if n > 64:
            raise ModelError(f"at most 64 surfaces, got {n}")
        parameters = dict(parameters or {})
        self.parameters = list(parameters.keys())
        for p in self.parameters:
            if not isinstance(p, sp.Symbol):
                raise ModelError(f"parameter names must be SymPy Symbols, got {p!r}")
        self.parameter_values = [float(parameters[p]) for p in self.parameters]
        self.sign_symbols = list(signs) if signs is not None else list(globals()["signs"](n))
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
        self.lagrange_expr = None if lagrange is None else _sympify_list([lagrange], "lagrange")[0]
        self.mayer_expr = None if mayer is None else _sympify_list([mayer], "mayer")[0]
        self.path_exprs = _sympify_list(path, "path")
        self.terminal_exprs = _sympify_list(terminal, "terminal")
        if not self.controls and (self.lagrange_expr is not None or self.mayer_expr is not None
                                  or self.path_exprs or self.terminal_exprs):
            raise ModelError("costs and constraints (lagrange, mayer, path, terminal) belong to "
                             "an optimal control model: give its controls")

        if isinstance(field, Mapping):
            words = {}
            for word, exprs in field.items():
                w = word if isinstance(word, str) else "".join(
                    "+" if int(v) > 0 else "-" for v in word)
                if len(w) != n or any(c not in "+-" for c in w):
                    raise ModelError(
                        f"field: the sign word {word!r} must have {n} characters '+' or '-'")
                words[w] = _sympify_list(exprs, f"field[{w!r}]")
            missing = [w for w in _all_words(n) if w not in words]
            if missing:
                raise ModelError(f"field: the sign word {missing[0]!r} is missing "
                                 f"({len(missing)} of {2 ** n} words missing)")
            self.field_words = words
            self.field_exprs = None
        else:
            self.field_exprs = _sympify_list(field, "field")
            self.field_words = None
        known = set(self.states) | set(self.parameters)
        for where, exprs, expected, extra, forbidden in self._all_exprs():
            if expected is not None and len(exprs) != expected:
                raise ModelError(f"{where} has {len(exprs)} expressions, expected {expected}")
            for k, e in enumerate(exprs):
                _check_functions(e, f"{where}[{k}]")
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
        self._libraries: Dict[str, str] = {}
        self._step = None
        self._ocp = None
        if self.controls:
            if n == 0:
                raise ModelError("an optimal control model needs at least one switching surface "
                                 "(FESD detects its switches)")
            self.source = None
            self._compiled = None
            self._load_ocp()
        else:
            self.source = self._source()
            self._compiled = _bflow._load_model(str(_compile(self.source)), self.parameter_values,
                                                [str(q) for q in self.parameters])

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

    def _source(self) -> str:
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
                lines.append(f"        case {_word_bits(w)}u: {{  // {w}")
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
                                    "model")

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
                    lines.append(f"    // {word}")
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

    def _engine_source(self, engine: str) -> str:
        body, kind, made = self._step_struct()
        if engine == "step":
            header, interface, adapter = "bflow/fesd/step_model.h", "StepModel", "StepModelAdapter"
        else:
            header, interface, adapter = "bflow/ocp/ocp.h", "OcpModel", "OcpModelAdapter"
        return self._library_source(engine, header, body, interface, f"bflow::{adapter}<{kind}>",
                                    made)

    def _library_source(self, engine: str, header: str, struct: str, interface: str,
                        adapter: str, made: str) -> str:
        """The shared library of one engine: the struct GeneratedModel (with its parameters in
        p_) and bflow_<engine>_model_create / _destroy, which python/src/model_handle.h loads."""
        return _LIBRARY_TEMPLATE.format(
            states=", ".join(map(str, self.states)), header=header, struct=struct,
            interface=interface, engine=engine, P=len(self.parameters), adapter=adapter,
            made=made)

    def _engine_library(self, engine: str) -> str:
        if engine not in self._libraries:
            self._libraries[engine] = str(_compile(self._engine_source(engine)))
        return self._libraries[engine]

    def _step_model(self):
        """The compiled step inclusion (FESD), compiled on first use."""
        if self.controls:
            raise ModelError(f"the model has controls {self.controls}: it is an optimal control "
                             "model (bflow.ocp_solve); FESD simulates a model without controls")
        if not self.surface_exprs:
            raise ModelError("FESD needs at least one switching surface")
        if self._step is None:
            self._step = _bflow._load_step_model(self._engine_library("step"),
                                                 self.parameter_values)
        return self._step

    def _load_ocp(self):
        self._ocp = _bflow._load_ocp_model(self._engine_library("ocp"), self.parameter_values)

    def _ocp_model(self):
        if not self.controls:
            raise ModelError("the model has no controls: give Model(..., controls=[u, ...]) "
                             "to solve an optimal control problem")
        return self._ocp

    def _section(self, expression):
        """A Poincare section s(x) = 0 written in the states and parameters, compiled (on first
        use, cached) into the functor of orbits/periodic_orbit.h behind SectionAdapter."""
        s_expr = _sympify_list([expression], "section")[0]
        _check_functions(s_expr, "section")
        unknown = s_expr.free_symbols - set(self.states) - set(self.parameters)
        if unknown:
            raise ModelError(f"section: the symbol(s) {sorted(map(str, unknown))} are neither "
                             f"states {self.states} nor parameters {self.parameters}")
        struct = "\n".join([
            f"  double p_[{max(len(self.parameters), 1)}] = {{}};",
            "  template <typename T>", "  T operator()(const T* x) const {", _USING,
            "    (void)x;", f"    return {_Printer(self._names).doprint(s_expr)};", "  }"])
        source = self._library_source("section", "bflow/orbits/periodic_orbit.h", struct,
                                      "PoincareSection", "bflow::SectionAdapter<GeneratedModel>",
                                      "model")
        return _bflow._load_section(str(_compile(source)), self.parameter_values)

    def _flow_model(self):
        if self._compiled is None:
            raise ModelError(f"the model has controls {self.controls}: it is an optimal control "
                             "model for bflow.ocp_solve; the flow, orbits, sweeps and jump maps "
                             "take a model without controls")
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
            new[names[name]] = float(v)
        clone = object.__new__(Model)
        clone.__dict__.update(self.__dict__)
        clone.parameter_values = new
        clone._libraries = dict(self._libraries)
        clone._step = None
        if self._compiled is not None:
            clone._compiled = _bflow._load_model(self._compiled.path, new,
                                                 [str(q) for q in self.parameters])
        if self.controls:
            clone._load_ocp()
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


def _all_words(n: int):
    return ["".join("+" if (bits >> j) & 1 else "-" for j in range(n)) for bits in range(2 ** n)]


def _word_bits(word: str) -> int:
    return sum(1 << j for j, c in enumerate(word) if c == "+")


_USING = """    using std::sin; using std::cos; using std::tan; using std::asin;
    using std::acos; using std::atan; using std::atan2; using std::sinh;
    using std::cosh; using std::tanh; using std::exp; using std::log;
    using std::sqrt; using std::abs; using std::pow; using std::cbrt;"""

_LIBRARY_TEMPLATE = """// Generated by bflow from a SymPy model; states ({states}).
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


def cache_dir() -> Path:
    """Where compiled models are kept ($BFLOW_CACHE_DIR, default ~/.cache/bflow/models)."""
    return Path(os.environ.get("BFLOW_CACHE_DIR", Path.home() / ".cache" / "bflow" / "models"))


def _compile(source: str) -> Path:
    import time
    key = hashlib.sha256(
        (source + "\n" + " ".join(_command(Path("s"), Path("o"))) + "\n" +
         _bflow.__file__).encode()).hexdigest()[:24]
    directory = cache_dir()
    library = directory / f"model_{key}.so"
    if library.exists():
        compile_seconds["last"] = 0.0
        return library
    directory.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=directory) as work:
        src = Path(work) / "model.cc"
        src.write_text(source)
        out = Path(work) / "model.so"
        run = subprocess.run(_command(src, out), capture_output=True, text=True)
        if run.returncode != 0:
            raise ModelError("the C++ compiler refused the generated model:\n" +
                             run.stderr[-4000:] + f"\n(source kept in the message above; "
                             f"command: {' '.join(_command(src, out))})")
        os.replace(out, library)  # atomic: another process sees the whole library or none
    compile_seconds["last"] = time.perf_counter() - start
    return library
