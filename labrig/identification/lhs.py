"""Latin-hypercube start points: ``scipy.stats.qmc.LatinHypercube`` to the last bit,
without importing ``scipy.stats``.

In scipy 1.17 ``import scipy.stats`` costs most of a second (its array-API layer reads
every docstring), which every multi-started fit paid before its first start: a third of
the linear fit that opens ``diagnose --auto``. The sampler is a few lines: here they are
as scipy writes them (a child generator spawned from the caller's, uniform jitter, one
shuffled permutation of the strata per dimension, then ``qmc.scale``), so the same seed
gives the same starts; a test holds them equal to scipy's with ``==``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["latin_hypercube"]


def latin_hypercube(n: int, lower: np.ndarray, upper: np.ndarray,
                    rng: np.random.Generator) -> np.ndarray:
    """Draw `n` Latin-hypercube points inside the box [lower, upper].

    ``scipy.stats.qmc.scale(qmc.LatinHypercube(d, rng=rng).random(n), lower, upper)``.

    Parameters
    ----------
    n : int
        Number of points (``n == 0`` returns an empty (0, D) array).
    lower, upper : ndarray, shape (D,)
        Finite bounds with ``lower < upper``.
    rng : numpy.random.Generator
        Source of randomness; the sampler's own generator is spawned from it (as scipy
        spawns it) so the caller's single seed controls everything.

    Returns
    -------
    ndarray, shape (n, D)
        Points, one per row; each dimension's n strata are each hit once.
    """
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    if n <= 0:
        return np.empty((0, lower.size))
    if not np.all(lower < upper):
        raise ValueError("Bounds are not consistent 'l_bounds' < 'u_bounds'")
    d = lower.size
    bg = rng.bit_generator  # scipy's _rng_spawn: a child of the caller's seed sequence
    own = np.random.Generator(type(bg)(bg.seed_seq.spawn(1)[0]))
    jitter = own.uniform(size=(n, d))
    perms = np.tile(np.arange(1, n + 1), (d, 1))
    for i in range(d):
        own.shuffle(perms[i, :])
    unit = (perms.T - jitter) / n
    return unit * (upper - lower) + lower
