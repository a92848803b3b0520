"""The normalised residuals of a population, written in place by one compiled loop.

The optimisers' residual vector (:meth:`labrig.identification.objective.Objective._stack`)
is, per run and channel, ``(measured - simulated) * scale`` over the kept samples, clipped
to +-1e6 with a NaN as 1e6 (a wild candidate must not poison the optimiser's sums). As
numpy expressions that is five passes over (candidates x samples) arrays under the GIL;
here it is one pass without it, so that two fits on two threads overlap. The arithmetic is
the same: one subtraction, one multiplication, the clip.
"""
from __future__ import annotations

import numba

#: the clip of a residual (a NaN becomes +CLIP)
CLIP = 1e6


@numba.njit(cache=True, nogil=True)
def residual_rows(R, o, meas, sim, idx, scale):
    """``R[p, o + i] = clip((meas[i] - sim[p, idx[i]]) * scale)`` for every candidate p."""
    for p in range(sim.shape[0]):
        for i in range(meas.shape[0]):
            r = (meas[i] - sim[p, idx[i]]) * scale
            if r != r:
                r = CLIP
            elif r > CLIP:
                r = CLIP
            elif r < -CLIP:
                r = -CLIP
            R[p, o + i] = r
