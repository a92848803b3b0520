"""Jellyfish Search (Chou & Truong 2021), as in docs/physics.md, 'Jellyfish Search'.

Algorithm (t = 1..T, N jellyfish, D dimensions, r a fresh U(0,1) draw,
r(D) a vector of D draws)::

    mu = mean of the population; (Xb, fb) = best so far
    for each jellyfish i:
        c = (1 - t/T) * (2 r - 1)                       # time control
        if |c| >= c0:      X' = X_i + r(D) * (Xb - beta r mu)       # ocean current
        elif passive(c):   X' = X_i + gamma r (UB - LB)             # type A
        else:              j != i at random
                           d = X_j - X_i if f_j < f_i else X_i - X_j
                           X' = X_i + r(D) * d                      # type B
        wrap X' into the box; keep X' if f(X') < f_i; update the best at once

The ocean current is taken with probability ``max(0, 1 - c0 / (1 - t/T))``.

Passive/active rule (``rule``):

``"paper"``
    passive iff ``r > 1 - |c|``.  Given ``|c| < c0`` the passive
    probability is ``E|c|``.
``"reference"``
    the authors' MATLAB v1.0 tests ``r > 1 - c`` with the *signed* c, so a
    negative c never gives a passive move: the passive probability is
    ``E[max(c, 0)]``, half that of the paper rule (c is symmetric about 0).

Both rules consume the same random numbers, so for one seed they differ only
where the test differs.

Execution modes (``batch``):

``batch=False``
    exact sequential semantics above: one objective call of one row per
    jellyfish; later jellyfish see earlier jellyfish's accepted moves and the
    updated best (mu stays the start-of-iteration mean).
``batch=True`` (default)
    all N trial moves of an iteration are built from the population, fitness
    values and best *at the start of the iteration*, evaluated in ONE
    vectorised call, then greedy selection and the best update are applied.
    This is a synchronous ("Jacobi") variant of the same moves; it is much
    faster when simulating P candidates costs about as much as one, at the
    price of information reaching the rest of the swarm one iteration later.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from labrig.identification.result import (IdentResult, PopulationSolver, check_float,
                                          population_solver_doc)

__all__ = ["jellyfish", "JellyfishSolver", "logistic_init", "wrap_bounds"]

RULES = ("paper", "reference")
BRANCHES = ("ocean", "passive", "active")


def logistic_init(pop: int, lower: np.ndarray, upper: np.ndarray,
                  rng: np.random.Generator, eta: float = 4.0) -> np.ndarray:
    """Chaotic logistic-map initial population.

    ``x_1 = U(0,1)^D``, ``x_{k+1} = eta x_k (1 - x_k)`` along the population,
    ``X_k = LB + x_k (UB - LB)``.  For ``0 < eta <= 4`` the map sends [0, 1]
    into itself, so every point is inside the box.

    Parameters
    ----------
    pop : int
        Population size N.
    lower, upper : ndarray, shape (D,)
        Box bounds.
    rng : numpy.random.Generator
        Draws x_1.
    eta : float
        Logistic-map parameter (4 is fully chaotic).

    Returns
    -------
    ndarray, shape (pop, D)
    """
    u = np.empty((pop, lower.size))
    u[0] = rng.random(lower.size)
    for k in range(1, pop):
        u[k] = eta * u[k - 1] * (1.0 - u[k - 1])
    return lower + u * (upper - lower)


def wrap_bounds(X: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Wrap points into the box the way JS does, in closed form.

    JS repeats ``x > UB -> LB + (x - UB)`` and ``x < LB -> UB + (x - LB)``
    until x is inside; i.e. it shifts x by whole box widths W.  Doing it with
    ``ceil`` gives the same point without an unbounded loop: above the box
    the result lies in (LB, UB], below it in [LB, UB).

    Parameters
    ----------
    X : ndarray, shape (..., D)
    lower, upper : ndarray, shape (D,)

    Returns
    -------
    ndarray
        A new array, same shape as X, inside [lower, upper].
    """
    X = np.array(X, dtype=float)
    width = upper - lower
    above = X > upper
    below = X < lower
    k_up = np.ceil((X - upper) / width)
    k_dn = np.ceil((lower - X) / width)
    X = np.where(above, X - k_up * width, X)
    X = np.where(below, X + k_dn * width, X)
    # Rounding can leave a hair outside when |x| >> W; clamp that residue.
    return np.clip(X, lower, upper)


class JellyfishSolver(PopulationSolver):
    """Steppable Jellyfish Search; see the module docstring.

    Parameters are those of :func:`jellyfish`.  Use :meth:`step` for one
    iteration, :meth:`run` to finish, :meth:`result` for the result.  The
    population is in ``X`` (shape (pop, D)) with objective values ``f``.
    """

    method = "jfo"

    def __init__(self, fun: Callable, lower: Any, upper: Any, *, pop: int = 50,
                 iters: int = 200, seed: int | None = None, rule: str = "paper",
                 beta: float = 3.0, gamma: float = 0.1, c0: float = 0.5,
                 eta: float = 4.0, batch: bool = True,
                 callback: Callable | None = None) -> None:
        super().__init__(fun, lower, upper, pop=pop, iters=iters, seed=seed,
                         callback=callback)
        if rule not in RULES:
            raise ValueError(f"rule: must be one of {RULES}, got {rule!r}")
        self.rule = rule
        self.beta = check_float("beta", beta, low=0.0)
        self.gamma = check_float("gamma", gamma, low=0.0)
        self.c0 = check_float("c0", c0, low=0.0, high=1.0)
        self.eta = check_float("eta", eta, low=0.0, high=4.0, low_open=True)
        self.batch = bool(batch)
        # Per-iteration counts of (ocean, passive, active) moves, so the
        # branch probabilities can be checked against theory.
        self.branch_counts = np.zeros((self.iters, 3), dtype=np.int64)

        self.X = logistic_init(self.pop, self.lower, self.upper, self.rng, self.eta)
        self.f = self.objective(self.X)
        i = int(np.argmin(self.f))
        self.x_best, self.f_best = self.X[i].copy(), float(self.f[i])

    def _passive(self, c: np.ndarray | float, r: np.ndarray | float):
        # Paper: r > 1 - |c|.  Reference MATLAB: r > 1 - c with signed c.
        return r > 1.0 - (np.abs(c) if self.rule == "paper" else c)

    def _iterate(self, t: int) -> None:
        # mu is the start-of-iteration mean in both modes (as in the
        # reference code, which computes it once per iteration).
        mu = self.X.mean(axis=0)
        scale = 1.0 - t / self.iters
        if self.batch:
            self._iterate_batch(t, mu, scale)
        else:
            self._iterate_sequential(t, mu, scale)

    def _iterate_sequential(self, t: int, mu: np.ndarray, scale: float) -> None:
        rng, X, f, D, N = self.rng, self.X, self.f, self.dim, self.pop
        counts = self.branch_counts[t - 1]
        for i in range(N):
            c = scale * (2.0 * rng.random() - 1.0)
            if abs(c) >= self.c0:
                counts[0] += 1
                trial = X[i] + rng.random(D) * (self.x_best - self.beta * rng.random() * mu)
            elif self._passive(c, rng.random()):
                counts[1] += 1
                trial = X[i] + self.gamma * rng.random() * (self.upper - self.lower)
            else:
                counts[2] += 1
                j = int(rng.integers(N - 1))
                j += j >= i  # uniform over j != i
                d = X[j] - X[i] if f[j] < f[i] else X[i] - X[j]
                trial = X[i] + rng.random(D) * d
            trial = wrap_bounds(trial, self.lower, self.upper)
            ft = self.objective(trial[None, :])[0]
            if ft < f[i]:
                X[i], f[i] = trial, ft
                if ft < self.f_best:
                    self.x_best, self.f_best = trial.copy(), float(ft)

    def _iterate_batch(self, t: int, mu: np.ndarray, scale: float) -> None:
        rng, X, f, D, N = self.rng, self.X, self.f, self.dim, self.pop
        c = scale * (2.0 * rng.random(N) - 1.0)
        ocean = np.abs(c) >= self.c0
        passive = ~ocean & self._passive(c, rng.random(N))
        active = ~(ocean | passive)
        self.branch_counts[t - 1] = (ocean.sum(), passive.sum(), active.sum())

        r_vec = rng.random((N, D))
        r_one = rng.random(N)[:, None]
        j = rng.integers(N - 1, size=N)
        j += j >= np.arange(N)
        d = np.where((f[j] < f)[:, None], X[j] - X, X - X[j])

        trial = np.where(
            ocean[:, None], X + r_vec * (self.x_best - self.beta * r_one * mu),
            np.where(passive[:, None], X + self.gamma * r_one * (self.upper - self.lower),
                     X + r_vec * d))
        trial = wrap_bounds(trial, self.lower, self.upper)
        ft = self.objective(trial)
        better = ft < f
        X[better], f[better] = trial[better], ft[better]
        i = int(np.argmin(f))
        if f[i] < self.f_best:
            self.x_best, self.f_best = X[i].copy(), float(f[i])

    def _extra(self) -> dict[str, Any]:
        return {
            "rule": self.rule, "batch": self.batch, "pop": self.pop,
            "iters": self.iters, "beta": self.beta, "gamma": self.gamma,
            "c0": self.c0, "eta": self.eta, "branch_names": list(BRANCHES),
            # rows = iterations completed, columns = BRANCHES
            "branch_counts": self.branch_counts[:self.nit].copy(),
        }


@population_solver_doc
def jellyfish(fun: Callable[[np.ndarray], np.ndarray], lower: Any, upper: Any, *,
              pop: int = 50, iters: int = 200, seed: int | None = None,
              rule: str = "paper", beta: float = 3.0, gamma: float = 0.1,
              c0: float = 0.5, eta: float = 4.0, batch: bool = True,
              callback: Callable[[int, float], Any] | None = None) -> IdentResult:
    """Minimise `fun` over a box with Jellyfish Search.

    Parameters
    ----------
    fun : callable
        Population-vectorised objective ``fun(X) -> f``, X shape (P, D),
        f shape (P,); lower is better; NaN counts as +inf.
    lower, upper : array_like, shape (D,)
        Finite bounds, ``lower < upper``.
    pop : int
        Number of jellyfish N (>= 2).
    iters : int
        Number of iterations T (>= 1).  Total evaluations: ``pop*(iters+1)``.
    seed : int or None
        Seed for ``numpy.random.default_rng``; None draws one (reported in
        ``result.seed``).
    rule : {"paper", "reference"}
        Passive/active test; see the module docstring.
    beta, gamma, c0, eta : float
        Distribution coefficient, motion coefficient, ocean-current
        threshold and logistic-map parameter (defaults from the paper).
    batch : bool
        True: one vectorised call per iteration (synchronous variant).
        False: exact sequential reference semantics.
    %(callback)s

    Returns
    -------
    IdentResult
        ``method="jfo"``; ``extra["branch_counts"]`` holds per-iteration
        (ocean, passive, active) move counts.

    Raises
    ------
    ValueError
        Bad argument; the message starts with the argument's name.
    """
    return JellyfishSolver(fun, lower, upper, pop=pop, iters=iters, seed=seed,
                           rule=rule, beta=beta, gamma=gamma, c0=c0, eta=eta,
                           batch=batch, callback=callback).run()
