"""Particle swarm optimisation with Clerc-Kennedy constriction (docs/physics.md, 'PSO').

Update, per particle and dimension (r1, r2 fresh U(0,1) draws)::

    v <- chi * (v + c1 r1 (p_i - x) + c2 r2 (g - x));  |v_d| <= UB_d - LB_d
    x <- x + v;  boundary handling;  evaluate the whole swarm in one call
    p_i <- x only on strict improvement;  g = best p_i (global-best topology)

with ``chi = 2 / |2 - phi - sqrt(phi^2 - 4 phi)|``, ``phi = c1 + c2 > 4``.
Defaults used here: c1 = c2 = 2.05 (chi = 0.7298437881), 50 particles,
positions uniform in the box, initial velocities ``U(LB - x, UB - x)``
(SPSO-2011 style, so the first move stays inside the box), absorbing
boundary.  pyswarms and mealpy use other defaults (e.g. inertia weights),
so their numbers are not directly comparable.

Boundary options (only the out-of-bounds components are touched):

``"absorb"``  clip to the bound and zero that velocity component (default).
``"reflect"`` mirror about the bound and reverse that velocity component.
``"random"``  re-draw the component uniformly in [LB, UB]; velocity kept.
``"wrap"``    periodic box: ``LB + (x - LB) mod (UB - LB)``; velocity kept.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from labrig.identification.result import (IdentResult, PopulationSolver, check_float,
                                          population_solver_doc)

__all__ = ["pso", "PSOSolver", "constriction", "apply_boundary"]

BOUNDARIES = ("absorb", "reflect", "random", "wrap")


def constriction(c1: float = 2.05, c2: float = 2.05) -> float:
    """Clerc-Kennedy constriction coefficient.

    Parameters
    ----------
    c1, c2 : float
        Cognitive and social acceleration coefficients; ``c1 + c2 > 4``.

    Returns
    -------
    float
        ``chi = 2 / |2 - phi - sqrt(phi**2 - 4 phi)|`` with ``phi = c1 + c2``
        (0.7298437881 for c1 = c2 = 2.05).
    """
    c1 = check_float("c1", c1, low=0.0)
    c2 = check_float("c2", c2, low=0.0)
    phi = c1 + c2
    if phi <= 4.0:
        raise ValueError(f"c1: c1 + c2 must exceed 4 for constriction, got {phi}")
    return 2.0 / abs(2.0 - phi - math.sqrt(phi * phi - 4.0 * phi))


def apply_boundary(X: np.ndarray, V: np.ndarray, lower: np.ndarray,
                   upper: np.ndarray, mode: str,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Bring positions back into the box; return new (X, V).

    Parameters
    ----------
    X, V : ndarray, shape (P, D)
        Positions after the move, and the velocities that produced them.
    lower, upper : ndarray, shape (D,)
    mode : {"absorb", "reflect", "random", "wrap"}
        See the module docstring.
    rng : numpy.random.Generator
        Used by ``"random"`` only.

    Returns
    -------
    X, V : ndarray
        New arrays; X is inside [lower, upper].
    """
    X = np.array(X, dtype=float)
    V = np.array(V, dtype=float)
    out = (X < lower) | (X > upper)
    if not out.any():
        return X, V
    width = upper - lower
    if mode == "absorb":
        X = np.clip(X, lower, upper)
        V[out] = 0.0
    elif mode == "reflect":
        # Mirror about the violated bound; the velocity clamp (|v| <= W)
        # means one mirror suffices, the modulo form covers the general case.
        y = np.mod(X - lower, 2.0 * width)
        X = np.where(out, lower + np.where(y > width, 2.0 * width - y, y), X)
        V[out] = -V[out]
    elif mode == "random":
        fresh = lower + rng.random(X.shape) * width
        X = np.where(out, fresh, X)
    elif mode == "wrap":
        X = np.where(out, lower + np.mod(X - lower, width), X)
    else:
        raise ValueError(f"boundary: must be one of {BOUNDARIES}, got {mode!r}")
    return np.clip(X, lower, upper), V


class PSOSolver(PopulationSolver):
    """Steppable constricted PSO; see the module docstring.

    Parameters are those of :func:`pso`.  State: positions ``X``,
    velocities ``V``, personal bests ``P``/``fP``, global best
    ``x_best``/``f_best``.
    """

    method = "pso"

    def __init__(self, fun: Callable, lower: Any, upper: Any, *, pop: int = 50,
                 iters: int = 200, seed: int | None = None, c1: float = 2.05,
                 c2: float = 2.05, boundary: str = "absorb",
                 callback: Callable | None = None) -> None:
        super().__init__(fun, lower, upper, pop=pop, iters=iters, seed=seed,
                         callback=callback)
        if boundary not in BOUNDARIES:
            raise ValueError(f"boundary: must be one of {BOUNDARIES}, got {boundary!r}")
        self.chi = constriction(c1, c2)
        self.c1, self.c2 = float(c1), float(c2)
        self.boundary = boundary
        self.vmax = self.upper - self.lower

        shape = (self.pop, self.dim)
        self.X = self.lower + self.rng.random(shape) * self.vmax
        self.V = (self.lower - self.X) + self.rng.random(shape) * self.vmax
        self.f = self.objective(self.X)
        self.P, self.fP = self.X.copy(), self.f.copy()
        i = int(np.argmin(self.fP))
        self.x_best, self.f_best = self.P[i].copy(), float(self.fP[i])

    def _iterate(self, t: int) -> None:
        shape = (self.pop, self.dim)
        r1 = self.rng.random(shape)
        r2 = self.rng.random(shape)
        V = self.chi * (self.V + self.c1 * r1 * (self.P - self.X)
                        + self.c2 * r2 * (self.x_best - self.X))
        V = np.clip(V, -self.vmax, self.vmax)
        self.X, self.V = apply_boundary(self.X + V, V, self.lower, self.upper,
                                        self.boundary, self.rng)
        self.f = self.objective(self.X)
        better = self.f < self.fP  # strict: ties keep the old personal best
        self.P[better], self.fP[better] = self.X[better], self.f[better]
        i = int(np.argmin(self.fP))
        if self.fP[i] < self.f_best:
            self.x_best, self.f_best = self.P[i].copy(), float(self.fP[i])

    def _extra(self) -> dict[str, Any]:
        return {"pop": self.pop, "iters": self.iters, "c1": self.c1,
                "c2": self.c2, "chi": self.chi, "boundary": self.boundary}


@population_solver_doc
def pso(fun: Callable[[np.ndarray], np.ndarray], lower: Any, upper: Any, *,
        pop: int = 50, iters: int = 200, seed: int | None = None,
        c1: float = 2.05, c2: float = 2.05, boundary: str = "absorb",
        callback: Callable[[int, float], Any] | None = None) -> IdentResult:
    """Minimise `fun` over a box with constricted global-best PSO.

    Parameters
    ----------
    fun : callable
        Population-vectorised objective ``fun(X) -> f``, X shape (P, D),
        f shape (P,); lower is better; NaN counts as +inf.  Called once per
        iteration with the whole swarm.
    lower, upper : array_like, shape (D,)
        Finite bounds, ``lower < upper``.
    pop : int
        Swarm size (>= 2).
    iters : int
        Iterations (>= 1).  Total evaluations: ``pop*(iters+1)``.
    seed : int or None
        Seed for ``numpy.random.default_rng``; None draws one (reported).
    c1, c2 : float
        Acceleration coefficients, ``c1 + c2 > 4``.
    boundary : {"absorb", "reflect", "random", "wrap"}
        Boundary handling; see the module docstring.
    %(callback)s

    Returns
    -------
    IdentResult
        ``method="pso"``.

    Raises
    ------
    ValueError
        Bad argument; the message starts with the argument's name.
    """
    return PSOSolver(fun, lower, upper, pop=pop, iters=iters, seed=seed,
                     c1=c1, c2=c2, boundary=boundary, callback=callback).run()
