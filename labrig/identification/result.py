"""The result object shared by every optimiser, and the plumbing they share.

Each optimiser returns an :class:`IdentResult`, modelled on
``scipy.optimize.OptimizeResult`` but with a fixed set of fields so callers
(and JSON reports) can rely on them.  The private helpers below validate the
common arguments (bounds, seed, population, iterations) and wrap the
population-vectorised objective so that every optimiser counts evaluations
and treats failed candidates the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from numbers import Integral
from typing import Any, Callable

import numpy as np

from labrig.core.fileio import finite_json
from labrig.model.start import describe_starts
from labrig.model import drive_units

__all__ = ["IdentResult", "finite_json", "at_bounds", "bound_warnings", "fit_warnings",
           "identification_warnings"]


@dataclass
class IdentResult:
    """Outcome of one optimisation run.

    Attributes
    ----------
    x : ndarray, shape (D,)
        Best point found, in the search space given to the optimiser
        (e.g. log parameters; the caller maps it back).
    fun : float
        Objective value at `x` (``inf`` if no candidate could be evaluated).
    nfev : int
        Number of candidate rows evaluated (a population call of P rows
        counts P).
    nit : int
        Number of iterations completed (starts, for the local optimiser).
    history : list of float
        Best objective value after each iteration.
    seed : int or None
        Seed actually used; passing it back reproduces the run exactly.
    message : str
        Why the run stopped.
    method : str
        ``"jfo"``, ``"pso"``, ``"co"``, or e.g. ``"jfo+co"`` after polishing.
    success : bool
        True if the run completed and `fun` is finite.
    jac : ndarray or None
        Jacobian of the residuals at `x` (local optimiser only).
    cost : float or None
        ``0.5 * sum(r**2)`` as reported by ``least_squares`` (local only).
    extra : dict
        Method-specific diagnostics (branch counts, covariance, ...).
    """

    x: np.ndarray
    fun: float
    nfev: int
    nit: int
    history: list[float] = field(default_factory=list)
    seed: int | None = None
    message: str = ""
    method: str = ""
    success: bool = False
    jac: np.ndarray | None = None
    cost: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable dict (arrays become lists, inf/nan None).

        Returns
        -------
        dict
            All fields, with numpy arrays and scalars converted to plain
            Python types and non-finite floats replaced by ``None`` (strict
            JSON has no ``inf``/``nan``).
        """
        return {
            "x": _jsonable(self.x),
            "fun": _jsonable(self.fun),
            "nfev": int(self.nfev),
            "nit": int(self.nit),
            "history": _jsonable(self.history),
            "seed": None if self.seed is None else int(self.seed),
            "message": str(self.message),
            "method": str(self.method),
            "success": bool(self.success),
            "jac": _jsonable(self.jac),
            "cost": _jsonable(self.cost),
            "extra": _jsonable(self.extra),
        }


def _jsonable(value: Any) -> Any:
    """Convert numpy containers/scalars recursively to JSON-safe values
    (:func:`finite_json`, with string keys, any integral number an int and a nested
    result its dict)."""
    return finite_json(value, key=str, other=_jsonable_leaf)


def _jsonable_leaf(value: Any) -> Any:
    """What :func:`finite_json` leaves as it is, as the result's JSON holds it."""
    if isinstance(value, Integral):
        return int(value)
    if isinstance(value, IdentResult):
        return value.to_dict()
    return value


#: "At a bound" means within this fraction of the bound's span, measured in the
#: coordinates the optimiser searches: decades for log-searched parameters. In
#: physical units 0.1 % of R's default 0.1..100 ohm box would be 0.1 ohm and call
#: R = 0.2 ohm "at" 0.1 ohm; in decades it is 0.003 (0.7 %), which is what an
#: optimiser pressed against the wall of its box actually ends within.
AT_BOUND_FRACTION = 1e-3


def at_bounds(space: Any, params: dict) -> list[tuple[str, float, str, float]]:
    """``(name, value, "lower"/"upper", bound)`` for every free parameter of ``space``
    that ended within :data:`AT_BOUND_FRACTION` of a bound (in search coordinates)."""
    out = []
    for n, lo, hi, lg in zip(space.names, space.lower, space.upper, space.log):
        v = params.get(n)
        if n in space.fixed or v is None or not math.isfinite(v):
            continue
        lo, hi, v = float(lo), float(hi), float(v)
        if lg:  # log-searched parameters are positive; compare in decades
            f = lambda x: math.log10(max(x, 1e-300))  # noqa: E731
        else:
            f = lambda x: x  # noqa: E731
        tol = AT_BOUND_FRACTION * (f(hi) - f(lo))
        if f(v) - f(lo) <= tol:
            out.append((n, v, "lower", lo))
        elif f(hi) - f(v) <= tol:
            out.append((n, v, "upper", hi))
    return out


def bound_warnings(space: Any, params: dict, units: dict | None = None,
                   shown: dict | None = None) -> list[str]:
    """One sentence per free parameter that ended at a bound of ``space``.

    ``space`` has ``names``, ``lower``, ``upper``, ``log`` and ``fixed`` (an
    ``objective.Space``); ``params`` maps names to physical values; ``units``
    maps names to unit strings ("-" or "" for none); ``shown`` maps a name to the
    ``(name, factor, unit)`` a user reads it as (a torque drive's ``tc_nm``).
    """
    units = units or {}
    out = []
    for n, v, side, bound in at_bounds(space, params):
        beyond = "below" if side == "lower" else "above"
        if shown and n in shown:
            n, f, units = shown[n][0], shown[n][1], {**units, shown[n][0]: shown[n][2]}
            v, bound = v * f, bound * f
        u = units.get(n, "")
        u = f" {u}" if u and u != "-" else ""
        out.append(f"{n} = {v:.4g}{u} is at the {side} bound {bound:.4g}{u}: the data may want "
                   f"a value {beyond} it; widen the bound (--bounds {n}=LOW:HIGH) or check the "
                   "units")
    return out


def fit_warnings(fit_percent: dict, where: str) -> list[str]:
    """One sentence per channel whose fit % is below zero (or not a number).

    ``where`` says what the fit is over, e.g. ``"run 'sq_1.20V'"`` or ``"all runs"``.
    A fit below zero means the model is further from the measurement than the
    measurement's own mean is: worse than a constant.
    """
    out = []
    for ch in ("speed", "position"):
        fp = fit_percent.get(ch)
        if fp is None or fp >= 0:  # NaN fails ">= 0" and is reported too
            continue
        out.append(f"{where}: {ch} fit {fp:.1f} % is below zero: the model is worse than a "
                   "constant (the measurement's mean); check that the model belongs to these "
                   "data (rig constants, units) or that the fit converged")
    return out


def identification_warnings(ident: Any) -> list[str]:
    """Bound and fit warnings of an ``fit.Identification``."""
    plant = ident.space.plant
    units = dict(plant.units)
    units.update({key: p.unit for key, p in ident.effects.units()})
    notes = []
    if not plant.current_output and ident.dataset.get("current_unused"):
        notes.append(f"the runs' current channel is kept but not fitted: on a "
                     f"{plant.kind}-driven plant the current is the drive's command")
    lost = ident.dataset.get("gap_samples") or 0
    if lost:
        notes.append(f"{lost} samples lost on the link (gap = 1) are left out of the fit, "
                     "the residuals and the noise floors")
    drift = ident.dataset.get("position_drift")
    if drift:
        notes.append(f"{drift['description']}: weighted at its noise floor it outweighs the "
                     "speed and pulls the fit towards its wander; --weights "
                     f"p={drift['suggested_p']:.3g},q=1 weights it by its drift as well "
                     "(labrig diagnose does so itself)")
    if ident.dataset.get("sensor_lag"):
        notes.append(ident.dataset["sensor_lag"])
    if ident.dataset.get("starts"):
        notes.append(describe_starts(ident.dataset["starts"], plant.speed_unit(),
                                     plant.position_unit()))

    shown = drive_units.shown_keys(ident.effects, plant.kind, ident.constants)
    return (bound_warnings(ident.space, ident.params, units, shown)
            + fit_warnings(ident.metrics.get("fit_percent", {}), "all runs") + notes)


# --------------------------------------------------------------------------
# Shared plumbing (private).  Errors are ValueError naming the argument, so
# the caller can convert them into user errors.
# --------------------------------------------------------------------------

def check_bounds(lower: Any, upper: Any) -> tuple[np.ndarray, np.ndarray]:
    """Validate and return `lower`, `upper` as float arrays of shape (D,).

    Bounds must be finite, 1-D, of equal shape, and strictly ordered
    (``least_squares`` needs ``lower < upper``; a fixed parameter should be
    removed from the search space instead).
    """
    try:
        lo = np.asarray(lower, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"lower: not numeric ({exc})") from None
    try:
        hi = np.asarray(upper, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"upper: not numeric ({exc})") from None
    if lo.ndim != 1 or lo.size == 0:
        raise ValueError(f"lower: must be a non-empty 1-D array, got shape {lo.shape}")
    if hi.shape != lo.shape:
        raise ValueError(
            f"upper: shape {hi.shape} does not match lower shape {lo.shape}")
    if not np.all(np.isfinite(lo)):
        raise ValueError("lower: must be finite")
    if not np.all(np.isfinite(hi)):
        raise ValueError("upper: must be finite")
    bad = np.flatnonzero(~(lo < hi))
    if bad.size:
        raise ValueError(
            f"lower: must be < upper in every dimension (violated at index "
            f"{bad.tolist()})")
    return lo.copy(), hi.copy()


def check_int(name: str, value: Any, minimum: int) -> int:
    """Return `value` as int, raising ValueError naming it if < `minimum`."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Integral, np.integer)):
        raise ValueError(f"{name}: must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name}: must be >= {minimum}, got {value}")
    return int(value)


def check_float(name: str, value: Any, *, low: float | None = None,
                high: float | None = None, low_open: bool = False) -> float:
    """Return `value` as a finite float within [low, high] (or (low, high])."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {v}")
    if low is not None and (v <= low if low_open else v < low):
        raise ValueError(f"{name}: must be {'>' if low_open else '>='} {low}, got {v}")
    if high is not None and v > high:
        raise ValueError(f"{name}: must be <= {high}, got {v}")
    return v


def check_seed(seed: Any) -> int:
    """Return the seed to use; ``None`` draws fresh OS entropy.

    The drawn entropy is returned (and reported in the result) so that any
    run, seeded or not, can be reproduced.
    """
    if seed is None:
        return int(np.random.SeedSequence().entropy)
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (Integral, np.integer)):
        raise ValueError(f"seed: must be a non-negative integer or None, got {seed!r}")
    if seed < 0:
        raise ValueError(f"seed: must be non-negative, got {seed}")
    return int(seed)


def check_callable(name: str, value: Any, optional: bool = False) -> None:
    """Raise ValueError naming `name` if `value` is not callable."""
    if value is None and optional:
        return
    if not callable(value):
        raise ValueError(f"{name}: must be callable, got {type(value).__name__}")


class PopulationObjective:
    """Wrap ``fun(X) -> f`` (X shape (P, D), f shape (P,)) and count rows.

    NaN results are mapped to ``+inf`` so a failed candidate (e.g. a
    diverging simulation) can never be selected as the best.
    """

    def __init__(self, fun: Callable[[np.ndarray], Any], dim: int) -> None:
        check_callable("fun", fun)
        self.fun = fun
        self.dim = dim
        self.nfev = 0

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        P = X.shape[0]
        f = np.asarray(self.fun(X), dtype=float)
        if f.shape not in ((P,), (P, 1)):
            raise ValueError(
                f"fun: must return shape ({P},) for input shape {X.shape}, "
                f"got {f.shape}")
        f = f.reshape(P).copy()
        f[np.isnan(f)] = np.inf
        self.nfev += P
        return f


#: the ``callback`` parameter of each population solver's function, whose protocol
#: :meth:`PopulationSolver.step` keeps (see :func:`population_solver_doc`)
CALLBACK_DOC = """callback : callable, optional
        ``callback(iteration, best_fun)`` after each iteration (1-based);
        raising ``StopIteration`` stops the run (its return value is
        ignored)."""


def population_solver_doc(func: Callable) -> Callable:
    """``func`` with ``%(callback)s`` in its docstring replaced by :data:`CALLBACK_DOC`:
    every solver documents the callback that :class:`PopulationSolver` calls alike."""
    if func.__doc__:
        func.__doc__ = func.__doc__ % {"callback": CALLBACK_DOC}
    return func


class PopulationSolver:
    """Base of the steppable population solvers (JFO, PSO).

    Subclasses set ``method``, evaluate an initial population in
    ``__init__`` (setting ``x_best``/``f_best``) and implement
    :meth:`_iterate`.  This class owns the iteration counter, history,
    callback protocol and result assembly, so both solvers behave alike.
    """

    method = ""

    def __init__(self, fun: Callable, lower: Any, upper: Any, *, pop: int,
                 iters: int, seed: Any, callback: Callable | None) -> None:
        self.lower, self.upper = check_bounds(lower, upper)
        self.dim = self.lower.size
        self.pop = check_int("pop", pop, 2)
        self.iters = check_int("iters", iters, 1)
        check_callable("callback", callback, optional=True)
        self.callback = callback
        self.seed = check_seed(seed)
        self.rng = np.random.default_rng(self.seed)
        self.objective = PopulationObjective(fun, self.dim)
        self.nit = 0
        self.history: list[float] = []
        self.stopped = False
        self.x_best = np.full(self.dim, np.nan)
        self.f_best = np.inf

    @property
    def nfev(self) -> int:
        """Candidate rows evaluated so far."""
        return self.objective.nfev

    @property
    def done(self) -> bool:
        """True once the iteration budget is spent or a callback stopped it."""
        return self.stopped or self.nit >= self.iters

    def step(self) -> float:
        """Run one iteration, call the callback, and return the best value.

        Returns
        -------
        float
            Best objective value found so far.
        """
        if self.done:
            raise RuntimeError("solver has finished; call result()")
        self._iterate(self.nit + 1)
        self.nit += 1
        self.history.append(float(self.f_best))
        if self.callback is not None:
            # Stop on StopIteration rather than on a True return value (the
            # scipy convention): progress-bar helpers such as tqdm.update()
            # return True, which would silently end the run.
            try:
                self.callback(self.nit, float(self.f_best))
            except StopIteration:
                self.stopped = True
        return float(self.f_best)

    def run(self) -> IdentResult:
        """Iterate until done and return the result."""
        while not self.done:
            self.step()
        return self.result()

    def result(self) -> IdentResult:
        """Assemble an :class:`IdentResult` for the current state."""
        if self.stopped:
            message = f"stopped by callback after {self.nit} iterations"
        elif self.nit >= self.iters:
            message = f"completed {self.nit} iterations"
        else:
            message = f"in progress ({self.nit} of {self.iters} iterations)"
        finite = bool(np.isfinite(self.f_best))
        if not finite:
            message += "; no candidate returned a finite objective"
        return IdentResult(
            x=self.x_best.copy(), fun=float(self.f_best), nfev=self.nfev,
            nit=self.nit, history=list(self.history), seed=self.seed,
            message=message, method=self.method, success=finite,
            extra=self._extra())

    def _iterate(self, t: int) -> None:  # pragma: no cover - every solver overrides it
        raise TypeError(f"{type(self).__name__} must implement _iterate(t)")

    def _extra(self) -> dict[str, Any]:
        return {}
