"""Latin-hypercube start points (thin wrapper over ``scipy.stats.qmc``)."""

from __future__ import annotations

import numpy as np

__all__ = ["latin_hypercube"]


def latin_hypercube(n: int, lower: np.ndarray, upper: np.ndarray,
                    rng: np.random.Generator) -> np.ndarray:
    """Draw `n` Latin-hypercube points inside the box [lower, upper].

    Parameters
    ----------
    n : int
        Number of points (``n == 0`` returns an empty (0, D) array).
    lower, upper : ndarray, shape (D,)
        Finite bounds with ``lower < upper``.
    rng : numpy.random.Generator
        Source of randomness; the sampler is seeded from it so the caller's
        single seed controls everything.

    Returns
    -------
    ndarray, shape (n, D)
        Points, one per row; each dimension's n strata are each hit once.
    """
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    if n <= 0:
        return np.empty((0, lower.size))
    from scipy.stats import qmc  # ~0.4 s to import: only when a hypercube is drawn

    sampler = qmc.LatinHypercube(d=lower.size, rng=rng)
    return qmc.scale(sampler.random(n), lower, upper)
