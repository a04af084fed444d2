"""bflow: B-derivatives of nonsmooth flows, from Python.

The package wraps bflow's C++ library (the same code the ``bflow`` command runs): NumPy arrays in
and out, bflow's bad-input errors as ValueError with the C++ message, long calls without the GIL.

* ``JumpMap.from_limits(normals, field_limits)``: the B-derivative across a point where n surfaces
  meet (one surface: the saltation matrix; several: Algorithm 2.1 of [B], O(n^2 d) per direction).
* ``Model``: a vector field written in SymPy, compiled once (``bflow.model``).
* ``simulate``, ``flow_derivative``: the trajectory, its events and the B-derivative of the flow.
* ``fd``: finite differences of the same flow, to compare with.

docs/python.md has a tour.
"""

from __future__ import annotations

import sys
from typing import Optional

import numpy as np

try:
    from . import _bflow
except ImportError as error:  # the extension's IPOPT is the installed casadi package's
    if "libipopt" not in str(error):
        raise
    raise ImportError(
        f"bflow's extension links the IPOPT of the casadi package ({error}); install it beside "
        "bflow: pip install casadi==3.8.2") from error
from ._errors import ModelError


def __getattr__(name):
    # Models written in SymPy load SymPy (half a second) only when first used.
    if name in ("Model", "signs"):
        from . import model
        return getattr(model, name)
    raise AttributeError(f"module 'bflow' has no attribute {name!r}")

__all__ = ["JumpMap", "Model", "ModelError", "signs", "simulate", "flow_derivative",
           "FlowDerivative", "fd", "flow_options", "biped", "biped_initial_state", "pronk",
           "pronk_initial_state", "find_orbit", "continue_orbits", "PeriodicOrbit",
           "fesd_simulate", "fesd_exact", "FesdResult", "ocp_solve", "ocp_exact", "OcpResult",
           "sweep", "SweepRecord", "SweepRecords"]
__version__ = "0.1.0"

CrossingOrder = _bflow.CrossingOrder
Event = _bflow.Event
Notice = _bflow.Notice


def _as_array(a, name: str, ndim: Optional[int] = None) -> np.ndarray:
    try:
        arr = np.asarray(a, dtype=float)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be an array of numbers: {e}") from None
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimension(s), got shape {arr.shape}")
    return arr


def _set_option(obj, key: str, value, where: str) -> None:
    """obj.key = value, a value of the wrong type or out of the C++ range a ValueError naming
    the option and the value (not nanobind's "incompatible function arguments")."""
    current = getattr(obj, key)
    kind = type(current)
    if isinstance(current, bool):
        ok = isinstance(value, (bool, np.bool_))
        value = bool(value) if ok else value
        expected = "True or False"
    elif isinstance(current, int):
        ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
        if ok and not -2 ** 63 <= int(value) < 2 ** 63:
            raise ValueError(f"{where}: option {key}={value!r} is out of range")
        value = int(value) if ok else value
        expected = "an integer"
    elif isinstance(current, float):
        ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
            value, (bool, np.bool_))
        value = float(value) if ok else value
        expected = "a number"
    elif isinstance(current, str):
        ok = isinstance(value, str)
        expected = "a string"
    else:
        ok, expected = True, kind.__name__
    if not ok:
        raise ValueError(f"{where}: option {key}={value!r} must be {expected}, not "
                         f"{type(value).__name__}")
    try:
        setattr(obj, key, value)
    except TypeError as e:
        raise ValueError(f"{where}: option {key}={value!r} is out of the range of its C++ type "
                         f"({e})".replace("\n", " ")) from None


# The options of a run come in three groups (bflow/fesd/homotopy_options.h): the discretisation
# and the problem (the options object itself), the relaxation homotopy (its `homotopy`: a
# bflow::HomotopyOptions, or OcpHomotopyOptions for ocp_solve) and IPOPT with its linear solver
# (its `solver`, a bflow::SolverOptions, the same for fesd_simulate and ocp_solve). The keywords
# name them flat; each is set in its group.
_SOLVER_OPTIONS = ("linear_solver", "linear_solver_library", "blas_threads",
                   "keep_freed_memory", "derivative_programs")
_HOMOTOPY_OPTIONS = ("sigma_initial", "sigma_final", "sigma_factor", "superlinear",
                     "nlp_tolerance", "max_nlp_iterations", "relaxation",
                     "complementarity_tolerance", "intermediate_tolerance_factor", "warm_start",
                     "polish", "early_polish_sigma", "stop_at_complementarity",
                     "acceptable_tolerance", "max_total_iterations", "continue_after_failure",
                     "monotone_mu_down_to")


def _set_any_option(obj, key, value, where):
    for group, keys in (("solver", _SOLVER_OPTIONS), ("homotopy", _HOMOTOPY_OPTIONS)):
        if key in keys:
            part = getattr(obj, group)
            _set_option(part, key, value, where)
            setattr(obj, group, part)
            return
    _set_option(obj, key, value, where)


def _count(value, name: str, where: str, lo: int = 1, hi: int = 2 ** 31 - 1) -> int:
    """An integer count (N, steps, threads, ...) in [lo, hi], else a ValueError naming it."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{where}: {name} must be an integer, got {value!r}")
    if not lo <= int(value) <= hi:
        raise ValueError(f"{where}: {name}={value!r} is outside [{lo}, {hi}]")
    return int(value)


class JumpMap:
    """The B-derivative of the flow across a point where n surfaces meet ([B] Sections 2.3, 5, 6).

    Build it with ``JumpMap.from_limits(normals, field_limits)`` (normals n x d, oriented so that
    the flow crosses every surface from - to +; field_limits d x 2^n, column ``b`` the field's
    limit F_b for the sign word whose bit j is 1 where b_j = +) or from a model at a point
    (``JumpMap.at(model, rho, surfaces)``). ``apply(dx)`` maps one direction (shape (d,)) or a
    block of columns (shape (d, k)).
    """

    def __init__(self, native):
        self._native = native

    @classmethod
    def from_limits(cls, normals, field_limits) -> "JumpMap":
        """From the normals eta (n x d) and the field limits Gamma (d x 2^n)."""
        eta = _as_array(normals, "normals", 2)
        gamma = _as_array(field_limits, "field_limits", 2)
        return cls(_bflow.JumpMap(np.asfortranarray(eta), np.asfortranarray(gamma)))

    @classmethod
    def at(cls, model, rho, surfaces=None, before: Optional[str] = None) -> "JumpMap":
        """At a point rho of a model where the given surfaces (default: all) meet.

        The normals are Dh_j(rho) by Jets, oriented by the flow; the limits F_b(rho). Sides of
        the surfaces not listed come from ``before`` (a sign word over all surfaces) or from the
        signs of h(rho).
        """
        native = _model(model)
        rho = _as_array(rho, "rho", 1)
        if rho.shape[0] != native.states:
            raise ValueError(f"JumpMap.at: rho has {rho.shape[0]} entries, the model "
                             f"{native.states} states")
        n = native.surfaces
        chosen = list(range(n)) if surfaces is None else [int(j) for j in surfaces]
        for j in chosen:
            if not 0 <= j < n:
                raise ValueError(f"JumpMap.at: surface {j} is out of range [0, {n})")
        h = native.surface_values(rho)
        word = list(before) if before is not None else ["+" if v > 0 else "-" for v in h]
        if len(word) != n:
            raise ValueError(f"JumpMap.at: before={before!r} must name all {n} surfaces")
        normals = native.normals(rho)[chosen, :]
        # Orientation: the flow crosses surface j from - to + in the JumpMap's frame.
        base = list(word)
        for j in chosen:
            base[j] = "-"
        f = native.field(rho, "".join(base))
        orient = np.sign(normals @ f)
        if np.any(orient == 0):
            raise ValueError(f"JumpMap.at: the field is tangent to surface(s) "
                             f"{[chosen[k] for k in np.flatnonzero(orient == 0)]} at rho")
        # The limits are evaluated lazily in C++ (n + 1 field calls per direction), so any n up
        # to the JumpMap's 64 surfaces costs no 2^n table.
        return cls(_bflow._jump_map_at(native, rho, chosen, "".join(base),
                                       [int(o) for o in orient]))

    @property
    def surfaces(self) -> int:
        """n, the number of surfaces."""
        return self._native.surfaces

    @property
    def dim(self) -> int:
        """d, the dimension of the state."""
        return self._native.dim

    @property
    def normals(self) -> np.ndarray:
        return self._native.normals

    def apply(self, dx, out: Optional[np.ndarray] = None) -> np.ndarray:
        """B(dx): one direction (d,) or a block of columns (d, k). For one direction, ``out``
        (a writable contiguous float64 array of d numbers) receives the image without a new
        array being made, and is returned."""
        a = np.asarray(dx, dtype=float)
        if a.ndim == 1:
            if out is not None:
                if not (isinstance(out, np.ndarray) and out.dtype == np.float64 and out.ndim == 1
                        and out.flags.c_contiguous and out.flags.writeable):
                    raise ValueError("apply: out must be a writable contiguous float64 vector")
                self._native._apply_into(a, out)
                return out
            return self._native._apply_vector(a)
        if a.ndim == 2:
            return self._native._apply_block(np.asfortranarray(a))
        raise ValueError(f"apply: dx must have shape (d,) or (d, k), got {a.shape}")

    __call__ = apply

    def order(self, dx) -> CrossingOrder:
        """The order in which the perturbation dx crosses the surfaces, and when."""
        return self._native.order(_as_array(dx, "dx", 1))

    def active_jacobian(self, dx) -> np.ndarray:
        """The saltation product M_sigma of the piece that is active at dx."""
        return self._native.active_jacobian(_as_array(dx, "dx", 1))

    def saltation(self, order) -> np.ndarray:
        """M_sigma for a crossing order sigma (a permutation of 0..n-1)."""
        return self._native.saltation([int(j) for j in order])

    def pieces(self):
        """All n! linear pieces as (order, matrix) pairs (n <= 10)."""
        return self._native._pieces()

    @property
    def triangulation(self):
        """The simplicial fan of [B] Section 5: a dict with zeta, zeta_image, lineality_basis,
        scale_exponent and simplices (order, words)."""
        zeta, image, lineality, exponent, simplices = self._native._triangulation()
        return {"zeta": zeta, "zeta_image": image, "lineality_basis": lineality,
                "scale_exponent": exponent, "simplices": simplices}

    def __repr__(self):
        return f"bflow.JumpMap(surfaces={self.surfaces}, dim={self.dim})"

    def __reduce__(self):
        # By its normals and the table of every word's limit (n <= 24).
        return (JumpMap.from_limits, (self.normals, self._native._limits_table()))


_OPTION_NAMES = ("rtol", "atol", "max_step", "max_steps", "backend", "grouping",
                 "grouping_safety", "window", "near_simultaneity_band", "grazing_threshold",
                 "max_events", "initial_sides")


def flow_options(base=None, **options) -> "_bflow.FlowOptions":
    """FlowOptions from keyword arguments: rtol (1e-8), atol (1e-2 rtol), max_step, max_steps,
    backend ("auto", the default: dopri5 at rtol > 3e-8 on a model with surfaces and fewer than
    8 states, else dop853; or "dopri5", "dop853", "cvodes-bdf", "cvodes-adams"; the result's
    ``backend`` names the one that ran), grouping ("auto", "none",
    "window"), grouping_safety, window, near_simultaneity_band, grazing_threshold, max_events,
    initial_sides (a sign word). ``base``: FlowOptions to start from (default: the defaults)."""
    o = _bflow.FlowOptions() if base is None else base
    for key, value in options.items():
        if key not in _OPTION_NAMES:
            raise ValueError(f"unknown option {key!r}; the options are {', '.join(_OPTION_NAMES)}")
        _set_option(o, key, value, "flow options")
    return o


def _model(model) -> "_bflow.Model":
    if isinstance(model, _bflow.Model):
        return model
    flow_model = getattr(model, "_flow_model", None)  # a bflow.Model written in SymPy
    if flow_model is not None:
        return flow_model()
    raise ValueError(f"expected a bflow.Model, got {type(model).__name__}")


def _x0(model, x0):
    native = _model(model)
    x = _as_array(x0, "x0", 1)
    if x.shape[0] != native.states:
        raise ValueError(f"x0 has {x.shape[0]} entries, the model {native.states} states")
    return native, x


def simulate(model, x0, t: float, directions=None, **options):
    """x(t) from x0, with every event, and (if given) the B-derivative applied to each column of
    ``directions`` (d x k, or one direction (d,)). Options: see ``flow_options``."""
    native, x = _x0(model, x0)
    dirs = None
    if directions is not None:
        dirs = _as_array(directions, "directions")
        if dirs.ndim == 1:
            dirs = dirs[:, None]
        dirs = np.asfortranarray(dirs)
    return _bflow._simulate(native, x, float(t), dirs, flow_options(**options))


class FlowDerivative:
    """The B-derivative of the flow phi_t at x0: any direction without simulating again.

    ``apply(dx)`` for one direction or a block; ``jacobian()`` only where the derivative is
    linear (raises ValueError naming the event where it is not); ``pieces()`` all linear pieces;
    ``crossing_orders(dx)`` and ``active_jacobian(dx)`` for the piece dx takes. ``events`` are
    the run's events (times, surfaces, grouping), ``notices`` what the engine decided for the user,
    ``x`` the final state, ``options`` the options used (backend, tolerances).
    """

    def __init__(self, native, trajectory, options):
        self._native = native
        self.trajectory = trajectory
        self.options = options

    @property
    def x(self) -> np.ndarray:
        """x(t), the final state of the run."""
        return self.trajectory.x

    @property
    def events(self):
        """The run's events in time order (``Event``: t, rho, surfaces crossed together, their
        crossing times, how they were grouped)."""
        return self.trajectory.events

    @property
    def notices(self):
        """What the engine decided for the user (``Notice``: a grouping of near-simultaneous
        crossings, a step accepted loosely, ...), each with its numbers."""
        return self.trajectory.notices

    @property
    def backend(self) -> str:
        """The integrator that ran ("dopri5", "dop853", "cvodes-bdf", "cvodes-adams"): the one
        named in the options, or the one backend "auto" (the default) chose."""
        return self.trajectory.backend

    @property
    def dim(self) -> int:
        """d, the dimension of the state."""
        return self._native.dim

    def apply(self, dx) -> np.ndarray:
        """D phi_t(x0; dx): the image of one direction (shape (d,)) or of each column of a block
        (shape (d, k)), through every event's jump in its own crossing order. A direction of the
        wrong size is a ValueError."""
        a = np.asarray(dx, dtype=float)
        if a.ndim == 1:
            return self._native._apply_vector(a)
        if a.ndim == 2:
            return self._native._apply_block(np.asfortranarray(a))
        raise ValueError(f"apply: dx must have shape (d,) or (d, k), got {a.shape}")

    __call__ = apply

    def jacobian(self) -> np.ndarray:
        """The d x d Jacobian, where the B-derivative is linear (no event with more than one
        piece); else a ValueError naming the event where it is not (use ``apply`` or
        ``pieces``)."""
        return self._native.jacobian()

    def is_linear(self) -> bool:
        """Whether the B-derivative is linear (one piece): then ``jacobian()`` exists."""
        return self._native.is_linear()

    def pieces(self):
        """Every linear piece: (orders per event, matrix) pairs."""
        return [(p.orders, p.matrix) for p in self._native.pieces()]

    def crossing_orders(self, dx):
        """Per event, the order in which the perturbation dx crosses its surfaces and when
        (``CrossingOrder``): which piece dx takes."""
        return self._native.crossing_orders(_as_array(dx, "dx", 1))

    def active_jacobian(self, dx) -> np.ndarray:
        """The d x d matrix of the linear piece that is active at dx (apply(dx) equals it
        times dx)."""
        return self._native.active_jacobian(_as_array(dx, "dx", 1))

    def jumps(self):
        """Each event's jump map (``JumpMap``), in time order."""
        return [JumpMap(j) for j in self._native.jumps()]

    def __reduce__(self):
        return self._native.__reduce__()

    def __repr__(self):
        return (f"bflow.FlowDerivative(dim={self.dim}, events={len(self.events)}, "
                f"linear={self.is_linear()}, backend={self.backend!r})")


def flow_derivative(model, x0, t: float, **options) -> FlowDerivative:
    """The B-derivative of the flow of ``model`` from x0 over [0, t]. Options: ``flow_options``.
    Raises ValueError for bad input, grazing, sliding, or a run that does not reach t."""
    native, x = _x0(model, x0)
    o = flow_options(**options)
    derivative, trajectory = _bflow._flow_derivative(native, x, float(t), o)
    return FlowDerivative(derivative, trajectory, o)


def biped(**params) -> "_bflow.Model":
    """The vertical-plane biped of [B] Section 3.2.4 (d = 6, x = (x, y, theta, xdot, ydot,
    thetadot), two feet): the C++ scene (bflow/core/biped.h). Parameters by name: variant
    ("conservative", "dissipative", "mode-damping", the default), m, J, g, leg_length, psi,
    kappa, beta, thrust, thrust_speed. From ``biped_initial_state()`` both feet touch the ground
    together at t = 0.3968."""
    return _bflow._biped({k: str(v) for k, v in params.items()})


def biped_initial_state() -> np.ndarray:
    """(0, 1, 0, 0, 0, 0): at rest above the ground."""
    return _bflow._biped_initial_state()


def pronk(**params) -> "_bflow.Model":
    """The pronking body of bflow/core/pronk.h (d = 6, two vertical legs at its hips, flat
    ground, the legs' thrust and a soft horizontal tether): its defaults hop stably (its orbit
    through the apex, section "-x4", is the C++ tests' stable orbit). Parameters by name: m, J, g,
    hip, leg_length, kappa, beta, thrust, thrust_speed, tether, tether_damping."""
    return _bflow._pronk({k: str(v) for k, v in params.items()})


def pronk_initial_state() -> np.ndarray:
    """(0, 1, 0, 0, 0, 0)."""
    return _bflow._pronk_initial_state()


PeriodicOrbit = _bflow.PeriodicOrbit


def _orbit_options(tolerance, max_iterations, stability, max_return_time, min_return_time,
                   flow):
    o = _bflow.OrbitOptions()
    o.tolerance = float(tolerance)
    o.max_newton_iterations = int(max_iterations)
    o.stability = bool(stability)
    o.max_return_time = float(max_return_time)
    o.min_return_time = float(min_return_time)
    o.flow = flow_options(_bflow._default_orbit_flow_options(), **flow)
    return o


def _section(model, states: int, section):
    """The native Poincare section: a coordinate's text, a hyperplane (normal, offset), or an
    expression in the states of a model written in SymPy."""
    if isinstance(section, str):
        return _bflow._coordinate_section(section, states)
    symbolic = sys.modules.get("sympy")
    if symbolic is not None and isinstance(section, symbolic.Basic):
        compile_section = getattr(model, "_section", None)
        if compile_section is None:
            raise ValueError("a section written in SymPy needs a bflow.Model written in SymPy "
                             "(its states are the section's symbols); for this model give a "
                             "coordinate (\"-x4\") or a hyperplane (normal, offset)")
        return compile_section(section)
    if isinstance(section, tuple) and len(section) == 2:
        normal, offset = section
        return _bflow._hyperplane_section(_as_array(normal, "section normal", 1), float(offset))
    raise ValueError(f"section: expected a coordinate's text (\"-x4\", \"x1=0.3\"), a hyperplane "
                     f"(normal, offset) or a SymPy expression s(x), got {section!r}")


def find_orbit(model, section, guess, *, tolerance: float = 1e-8, max_iterations: int = 40,
               stability: bool = True, max_return_time: float = 100.0,
               min_return_time: float = 0.0, **flow) -> PeriodicOrbit:
    """A periodic orbit through the Poincare section s(x) = 0 (crossed from s < 0 to s > 0),
    by a nonsmooth Newton method on its return map, and the stability verdict from the return
    map's B-derivative.

    Args:
        section: "x4" (s = x_4), "-x4" (s = -x_4: x_4 from + to -, e.g. the apex of a hop),
            "x1=0.3" (s = x_1 - 0.3), "-x1=0.3"; a hyperplane ``(normal, offset)``,
            s = normal . x - offset; or, for a model written in SymPy, an expression s(x) in its
            states and parameters (compiled once, its gradient by Jets).
        guess: a state near the orbit (projected onto the section).
        tolerance: converged when |P(x) - x|_inf <= tolerance (1 + |x|_inf).
        flow: FlowOptions by keyword (``flow_options``); the orbit's defaults are rtol 1e-10,
            atol 1e-12 with the tangents in the error norm.

    Returns the orbit: ``converged`` (with ``message`` when not), ``x``, ``period``,
    ``return_map`` (DP(x*), a FlowDerivative: pieces, crossing orders), ``growth_rate_lower`` and
    ``growth_rate_upper`` (a bracket on the growth rate of DP(x*) restricted to the section),
    ``stability`` ("stable", "unstable", "undecided"), ``bracket`` (how each end was obtained),
    ``events``, ``notices``, ``decisions`` (what the solver decided for you), ``steps``.
    """
    native, x = _x0(model, guess)
    options = _orbit_options(tolerance, max_iterations, stability, max_return_time,
                             min_return_time, flow)
    return _bflow._find_orbit(native, _section(model, native.states, section), x, options)


def continue_orbits(make_model, section, values, guess, *, secant: bool = True,
                    progress: bool = False, **orbit_options):
    """A family of orbits over a parameter: for each value in order, ``make_model(value)`` (e.g.
    ``lambda k: bflow.pronk(kappa=k)`` or ``model.with_parameters``), its orbit from a secant
    prediction through the last two members found (or the last one, or ``guess``). Returns the
    members: ``value``, ``orbit``, ``guess`` (where the accepted run started), ``predictor``,
    ``decisions``, ``runs``. ``progress=True`` prints one line per member on stderr."""
    import sys
    options = _orbit_options(orbit_options.pop("tolerance", 1e-8),
                             orbit_options.pop("max_iterations", 40),
                             orbit_options.pop("stability", True),
                             orbit_options.pop("max_return_time", 100.0),
                             orbit_options.pop("min_return_time", 0.0), orbit_options)
    values = [float(v) for v in values]
    g = _as_array(guess, "guess", 1)

    def solve(value, start):
        model = make_model(value)
        native = _model(model)
        return _bflow._find_orbit(native, _section(model, native.states, section), start, options)

    def report(index, member):
        o = member.orbit
        print(f"member {index + 1}/{len(values)}: value {member.value:.6g}, "
              f"{'converged' if o.converged else 'not converged'}, period {o.period:.6g}, "
              f"growth rate in [{o.growth_rate_lower:.4g}, {o.growth_rate_upper:.4g}], "
              f"{o.stability}", file=sys.stderr, flush=True)

    return _bflow._continue_orbits(values, g, solve, bool(secant), report if progress else None)


FesdResult = _bflow.FesdResult
_FESD_DEFAULTS = {"irma": (100.0, 20), "crossing": (1.0, 4), "sliding-enter": (1.0, 4),
                  "sliding-leave": (2.0, 4), "spontaneous": (1.0, 4)}
_FESD_OPTIONS = ("scheme", "stages", "elements", "standard", "formulation", "lifting_depth",
                 "newton", "sensitivities",
                 "sigma_initial", "sigma_final", "sigma_factor", "superlinear", "nlp_tolerance",
                 "max_nlp_iterations",
                 "exact_hessian") + _SOLVER_OPTIONS


def _interrupted(result):
    """A run that Ctrl-C cancelled: KeyboardInterrupt with the partial result as e.args[1] and
    e.result; any other result as it is."""
    if result.status == "cancelled":
        e = KeyboardInterrupt(result.message, result)
        e.result = result
        raise e
    return result


def fesd_simulate(model, T: Optional[float] = None, x0=None, *,
                  steps: Optional[int] = None, progress: bool = False, **options) -> FesdResult:
    """A Filippov system simulated by Finite Elements with Switch Detection (docs/fesd.md), from
    x0 over [0, T] in ``steps`` integration steps.

    ``model``: a ``bflow.Model`` without controls (T and x0 required, 10 steps by default; its
    field is the step inclusion f(x, a), a_j in gamma(h_j(x)): the field with b_j = 2 a_j - 1
    when it is affine in each sign, else the convex combination of its 2^n sign words), or a
    built-in example: "irma" (T = 100, 20 steps by default) or one of the switching cases of
    [F] Example 3, "crossing", "sliding-enter", "sliding-leave" (T = 2), "spontaneous"
    (T = 1, 4 steps), whose exact solutions ``fesd_exact`` gives.

    Options, by group (as the C++ FesdOptions, its homotopy and its solver). The
    discretisation: scheme ("radau", "gauss"), stages (n_s, 2), elements (N_FE, 3),
    formulation ("step", "stewart"), lifting_depth, standard, newton, sensitivities (dx(T)/dx0,
    on). The homotopy: sigma_initial (1), sigma_final (1e-12), sigma_factor (0.1), superlinear
    (on), nlp_tolerance (1e-13), max_nlp_iterations (500). The solver: exact_hessian,
    linear_solver ("mumps", "spral", HSL's "ma27" ... "ma97", "pardiso"),
    linear_solver_library (the HSL or PARDISO library file), blas_threads (OpenBLAS's threads
    while IPOPT solves, 1; 0: OpenBLAS's own count), keep_freed_memory (the process keeps
    the memory MUMPS frees between factorisations, on; glibc's malloc settings, kept for the
    process once a solve has set them), derivative_programs (the Jacobian and exact Hessian as
    programs traced once from the model, on; off: Jets at every evaluation, the same numbers
    to rounding). ``progress=True`` prints one line per integration step on stderr.

    Returns a FesdResult: ok (the run reached T), status ("converged", "step failed", "invalid
    model"), message (why not ok, and notes), x_end, grid, states, step_sizes, switch_times,
    active_sets, sensitivity, the solver stack (ipopt, e.g. "IPOPT 3.14.19", linear_solver,
    e.g. "mumps 5.8.2", and blas, e.g. "OpenBLAS 0.3.28, 1 thread (libcasadi-tp-openblas.so.0)") and the counters of what the solver did (halved_steps, newton_steps,
    acceptable_only_steps). A horizon whose steps T / steps cannot be integrated
    (above 1e18, or elements below the smallest normal double) is a ValueError naming T and
    steps. The GIL is released while it runs; calls from several threads are safe, their IPOPT
    solves taking turns (one at a time in a process). Ctrl-C stops the run between steps or
    IPOPT iterations and raises KeyboardInterrupt, the partial result (status "cancelled", the
    steps done) attached as ``e.args[1]`` and ``e.result``."""
    step_model = getattr(model, "_step_model", None)
    if step_model is None and model not in _FESD_DEFAULTS:
        raise ValueError(f"fesd_simulate: unknown example {model!r}; give a bflow.Model or one "
                         "of the examples " + ", ".join(_FESD_DEFAULTS))
    t_end, default_steps = (None, 10) if step_model else _FESD_DEFAULTS[model]
    o = _bflow.FesdOptions()
    o.steps = _count(steps if steps is not None else default_steps, "steps", "fesd_simulate")
    for key, value in options.items():
        if key not in _FESD_OPTIONS:
            raise ValueError(f"unknown option {key!r}; the options are {', '.join(_FESD_OPTIONS)}")
        _set_any_option(o, key, value, "fesd_simulate")
    if progress:
        def report(step):
            print(f"step {step.index + 1}/{step.planned}: t {step.t:.10g} + {step.length:.6g}"
                  f"{' (halved ' + str(step.halvings) + ' times)' if step.halvings else ''}, "
                  f"{'newton' if step.newton else str(step.nlp_iterations) + ' IPOPT iterations'}"
                  f", complementarity {step.complementarity:.2g}", file=sys.stderr, flush=True)
        o.progress = report
    start = None if x0 is None else _as_array(x0, "x0", 1)
    if step_model is None:
        return _interrupted(
            _bflow._fesd_example(model, float(T if T is not None else t_end), start, o))
    native = step_model()
    if T is None or start is None:
        raise ValueError("fesd_simulate: a bflow.Model needs T and x0")
    if start.shape[0] != native.states:
        raise ValueError(f"fesd_simulate: x0 has {start.shape[0]} entries, the model "
                         f"{native.states} states")
    return _interrupted(_bflow._fesd_model(native, float(T), start, o))


def fesd_exact(example: str) -> dict:
    """The exact solution of a switching case of [F] Example 3: x0, t_end, switch_times, x_end."""
    (x0, t_end), (switches, x_end) = _bflow._fesd_exact(example)
    return {"x0": x0, "t_end": t_end, "switch_times": switches, "x_end": x_end}


OcpResult = _bflow.OcpResult
_OCP_OPTIONS = ("elements", "collocation_stages", "scheme", "collocation_form", "formulation",
                "standard",
                "lifting_depth", "cross_complementarity", "step_deviation_weight",
                "equilibration_weight") + _HOMOTOPY_OPTIONS + (
                "exact_hessian",) + _SOLVER_OPTIONS


_OCP_PROBLEM = ("x0", "T", "time_optimal", "T_min", "T_max", "x_lower", "x_upper", "u_lower",
                "u_upper", "path_lower", "path_upper", "terminal_lower", "terminal_upper",
                "guess", "guess_x", "guess_u")


_CONTACT_DEFAULTS = {"monoped": (30, "step"), "hopper": (50, "stewart")}


def ocp_solve(model, N: Optional[int] = None, *, progress: bool = False,
              setup: Optional[str] = None, **options) -> OcpResult:
    """An optimal control problem through FESD (docs/ocp.md), at N control stages.

    ``model``: a ``bflow.Model`` with controls (its costs and constraints are the model's), with
    the problem's data as keywords: x0 (required), T (the horizon, required; with
    time_optimal=True the initial guess of the free, minimised T, between T_min and T_max),
    x_lower/x_upper (at every element boundary), u_lower/u_upper, path_lower/path_upper (default
    g <= 0), terminal_lower/terminal_upper (default g_T = 0), guess ("constant", or "simulation":
    guess_u simulated by FESD), guess_x, guess_u (nu x N, or one column). Or a built-in example:
    "braking-block" (the optimum slides; exact cost 2 sqrt 5 + asinh 2 - 4) or "turbo-car"
    (time-optimal, T* = 40/3), whose data are built in (N = 10 by default); or a contact
    example through time-freezing, "monoped" (nosnoc's benchmark, N = 30 by default, ``setup``
    "nosnoc" or "strict") or "hopper" (five jumps, N = 50 by default, a multiple of 5), each
    starting from the options it comes with (the bflow ocp command's defaults), which keywords
    override; their full runs take minutes to an hour (docs/ocp.md).

    Options, by group (as the C++ OcpOptions, its homotopy and its solver). The
    discretisation: elements (N_FE, 3), collocation_stages (2), scheme, collocation_form
    ("integral", or "derivative": D (X - x_n) = h F, nosnoc's form, sparser KKT matrices),
    formulation, standard, lifting_depth, cross_complementarity ("element-sums", "point-pairs", "point-sums"; FESD
    only: with standard=True it is refused, and a contact example's own choice is left out),
    step_deviation_weight, equilibration_weight. The homotopy: relaxation ("scholtes", "l1",
    "elastic"), sigma_initial (100), sigma_final (1e-10), sigma_factor (0.1), superlinear,
    nlp_tolerance (1e-10), max_nlp_iterations (3000), complementarity_tolerance (1e-9),
    intermediate_tolerance_factor, warm_start, polish, early_polish_sigma,
    stop_at_complementarity, acceptable_tolerance, max_total_iterations,
    continue_after_failure, monotone_mu_down_to (1e-2: the warm-started NLPs at sigma >= it run
    IPOPT's monotone mu strategy, the rest its adaptive one; ``float("inf")``: adaptive
    throughout; each step's ``mu_strategy`` says which ran, ``mu_init`` the mu it started
    from, which the monotone strategy reads). The solver: exact_hessian, linear_solver, linear_solver_library,
    blas_threads (OpenBLAS's threads while IPOPT solves, 1; 0: its own count),
    keep_freed_memory and derivative_programs (as for fesd_simulate). ``progress=True`` prints
    one line per NLP on stderr. The GIL is
    released while IPOPT runs; calls from several threads are safe, their NLPs taking turns
    (IPOPT solves run one at a time in a process). Ctrl-C stops the solve at the next IPOPT
    iteration and raises KeyboardInterrupt, the result of the last solved NLP (status
    "cancelled") attached as ``e.args[1]`` and ``e.result``. Guesses, bounds and data that are
    NaN, infinite where no bound is meant, or at which the model's values are not finite are a
    ValueError naming the entry. ``ocp_exact`` gives the exact optimum."""
    import sys
    ocp_model = getattr(model, "_ocp_model", None)
    contact = ocp_model is None and model in _CONTACT_DEFAULTS
    if setup is not None and model != "monoped":
        raise ValueError(f"ocp_solve: only the monoped has setups (nosnoc, strict), not "
                         f"{model!r}")
    if contact:
        default_n, default_formulation = _CONTACT_DEFAULTS[model]
        o = _bflow._contact_options(model, _count(N if N is not None else default_n, "N",
                                                  "ocp_solve"),
                                    setup or "nosnoc",
                                    options.pop("formulation", default_formulation))
    else:
        o = _bflow.OcpOptions()
        o.stages = _count(N if N is not None else 10, "N", "ocp_solve")
    data = {k: options.pop(k) for k in list(options) if k in _OCP_PROBLEM}
    if data and ocp_model is None:
        raise ValueError(f"ocp_solve: {sorted(data)} are data of a bflow.Model's problem; the "
                         f"built-in example {model!r} has its own")
    for key, value in options.items():
        if key not in _OCP_OPTIONS:
            raise ValueError(f"unknown option {key!r}; the options are {', '.join(_OCP_OPTIONS)}"
                             + (f"; the problem's data: {', '.join(_OCP_PROBLEM)}"
                                if ocp_model is not None else ""))
        _set_any_option(o, key, value, "ocp_solve")
    if contact and o.standard and "cross_complementarity" not in options:
        # The example's settings for FESD's free element lengths and cross complementarity, of
        # no use to standard time-stepping (fixed lengths, products point by point): the same
        # solve without them, as the bflow ocp command does.
        o.cross_complementarity = "element-sums"
        o.step_deviation_weight = 0.0
        o.equilibration_weight = 0.0
    if progress:
        def report(step):
            print(f"sigma {step.sigma:.3g}{' (polish)' if step.polish else ''}: "
                  f"{step.iterations} iterations, cost {step.objective:.10g}, "
                  f"complementarity {step.complementarity:.2g}, {step.ipopt_status}",
                  file=sys.stderr, flush=True)
        o.progress = report
    if contact:
        return _interrupted(_bflow._contact_solve(model, setup or "nosnoc", o))
    if ocp_model is None:
        return _interrupted(_bflow._ocp_example(str(model), o))
    native = ocp_model()
    if "x0" not in data or "T" not in data:
        raise ValueError("ocp_solve: a bflow.Model's problem needs x0 and T (the horizon)")
    problem = _bflow.OcpProblem()
    for key, value in data.items():
        if key == "T":
            problem.horizon = float(value)
        elif key == "guess_u":
            u = np.asarray(value, dtype=float)
            problem.guess_u = np.asfortranarray(u.reshape(-1, 1) if u.ndim == 1 else u)
        elif key in ("time_optimal", "guess"):
            setattr(problem, key, value)
        elif key in ("T_min", "T_max"):
            setattr(problem, key, float(value))
        else:
            setattr(problem, key, _as_array(np.atleast_1d(value), key, 1))
    return _interrupted(_bflow._ocp_model(native, problem, o))


def ocp_exact(example: str) -> dict:
    """The exact optimum of a built-in OCP example: braking-block (objective, stop_time,
    final_position) or turbo-car (T, switch_times, control_switch_times)."""
    return {k: (v[0] if len(v) == 1 else v) for k, v in _bflow._ocp_exact(example).items()}


SweepRecord = _bflow.SweepRecord


class SweepRecords(list):
    """The records of a sweep, in grid order (a list), with what the sweep decided: ``threads``,
    the worker threads that ran (the threads asked for, or one per core, capped at one per
    sample), and ``notices``, one line per such decision (e.g. "threads=600 capped at 8, one per
    sample")."""

    def __init__(self, records, threads: int, notices):
        super().__init__(records)
        self.threads = threads
        self.notices = list(notices)


def sweep(model, x0, t: float, axes, directions=None, *, threads: int = 0,
          progress: bool = True, **options):
    """The flow and its B-derivative at every point of a grid of initial states and parameters,
    on ``threads`` threads (0: one per core), the GIL released. ``axes``: (index, lo, hi, count)
    per varied state, or (name, lo, hi, count) per varied parameter (of a SymPy model, or of the
    biped or the pronk), count equally spaced values from lo to hi (the first axis varies
    slowest); the other states are x0's and the other parameters the model's. ``directions``: the B-derivative's images of these (k x d or one d-vector;
    default the unit vectors). ``progress`` prints a progress line on stderr. Options: see
    ``flow_options``.

    Returns the records in grid order: ``varied``, ``status`` ("ok", or why the sample failed:
    a failed sample does not stop the sweep), ``message``, ``x_t``, ``images`` (one per
    direction), ``orders`` (per direction, per event: the crossing order), ``pieces``,
    ``structure(direction)`` (e.g. "0+1 (1>0)": which surfaces cross together, in which order).
    The list is a ``SweepRecords``: its ``threads`` is the pool's size (at most one thread per
    sample) and ``notices`` says when the threads asked for were capped.

    Ctrl-C stops the sweep within about 50 ms plus the samples in hand (one per thread) and
    raises KeyboardInterrupt with the finished records, in grid order from the first sample, as
    ``e.args[1]`` and ``e.records``; the message counts the unfinished samples, left out.

    The records are held in memory: before any sample runs, a sweep whose records would exceed
    3/4 of the machine's physical memory (or of the address-space limit) is refused with a
    ValueError naming the samples and the bytes, counting each record without events, and
    again at the first record with that record's events assumed for every sample. The command
    ``bflow sweep`` streams records to a file instead."""
    threads = _count(threads, "threads", "sweep", lo=0)
    native, x = _x0(model, x0)
    if directions is None:
        dirs = [row for row in np.eye(native.states)]
    else:
        d = _as_array(directions, "directions")
        dirs = [d] if d.ndim == 1 else [row for row in d]
    grid = []
    for axis in axes:
        try:
            what, lo, hi, count = axis
        except (TypeError, ValueError):
            raise ValueError("sweep: an axis is (index, lo, hi, count) or (parameter name, lo, "
                             f"hi, count), got {axis!r}") from None
        if isinstance(what, _parameter_name_types()):
            index, parameter = -1, str(what)
        else:
            index = _count(what, "the state index of an axis", "sweep", lo=-2 ** 31)
            parameter = ""
        label = parameter or f"x[{index}]"
        # 2^53: the most samples a grid takes (indices exact in a double).
        count = _count(count, f"the count of the axis {label}", "sweep", lo=1, hi=2 ** 53)
        grid.append((index, parameter, float(lo), float(hi), count))
    records, pool, cancelled, samples = _bflow._sweep(
        native, x, float(t), grid, [np.asarray(v, dtype=float) for v in dirs],
        flow_options(**options), threads, bool(progress))
    notices = []
    if threads > pool:
        notices.append(f"threads={threads} capped at {pool}, one per sample")
    result = SweepRecords(records, pool, notices)
    del records
    if cancelled:
        e = KeyboardInterrupt(f"sweep: interrupted; {len(result)} of {samples} samples finished, "
                              f"the {samples - len(result)} unfinished ones are left out", result)
        e.records = result
        raise e
    return result


def _parameter_name_types():
    """What names a parameter axis: a string, or a SymPy Symbol (without importing SymPy)."""
    symbol = sys.modules.get("sympy")
    return (str, symbol.Symbol) if symbol is not None else (str,)


class fd:  # noqa: N801 (a namespace, as bflow::fd in C++)
    """Finite differences of the simulated flow (every run with grouping "none")."""

    @staticmethod
    def one_sided(model, x0, t: float, dx, alpha: float, **options) -> np.ndarray:
        """(phi_t(x0 + alpha dx) - phi_t(x0)) / alpha."""
        native, x = _x0(model, x0)
        return _bflow._fd_one_sided(native, x, float(t), _as_array(dx, "dx", 1), float(alpha),
                                    flow_options(**options))

    @staticmethod
    def central(model, x0, t: float, dx, alpha: float, **options) -> np.ndarray:
        """(phi_t(x0 + alpha dx) - phi_t(x0 - alpha dx)) / (2 alpha)."""
        native, x = _x0(model, x0)
        return _bflow._fd_central(native, x, float(t), _as_array(dx, "dx", 1), float(alpha),
                                  flow_options(**options))
