"""What a sensor reads of the simulated motion: the model's outputs as the rig's channels
see them."""
from __future__ import annotations

import numpy as np


def windowed_speed(w: np.ndarray, window: int, dt: float,
                   travel: np.ndarray | None = None) -> np.ndarray:
    """The speed a moving window of ``window`` samples reads (a count over the window, one
    sample's included): the travel over the last ``window`` sample periods over
    ``window * dt``, the shaft at rest before the run. It reads half a window late, and
    smooth. ``travel``: the shaft's angle at each sample as the simulation integrated it
    (the exact travel: a motor faster than the sample period bends within one), else the
    trapezoid integral of ``w``."""
    w = np.asarray(w, float)
    if travel is None:
        travel = np.zeros(w.shape)
        travel[..., 1:] = np.cumsum(0.5 * (w[..., 1:] + w[..., :-1]), axis=-1) * dt
    else:
        travel = np.asarray(travel, float) - np.asarray(travel, float)[..., :1]
    before = np.zeros(w.shape)
    before[..., window:] = travel[..., :-window]
    return (travel - before) / (window * dt)


#: how much a logger's counting window may jitter (a share of its length)
JITTER = 0.02
#: a still stretch: this many readings in a row within one quantum of zero
STILL = 5
#: a speed on a lattice is a count when at most this share of its successive nonzero
#: still readings change sign (an ADC's noise at rest flips about half of them)
FLIPS = 0.1


def quantisation_step(y: np.ndarray) -> float:
    """The smallest regular step between the signal's levels (5th percentile of the
    gaps between distinct values; 0 for an unquantised signal)."""
    levels = np.unique(np.round(np.asarray(y, float), 12))
    steps = np.diff(levels)
    steps = steps[steps > 1e-12]
    if len(steps) == 0:
        return 0.0
    q = float(np.percentile(steps, 5))
    # an unquantised noisy signal has gaps far below its spread: no quantisation step
    return q if q > 1e-6 * max(np.ptp(levels), 1e-300) else 0.0


def count_quantum(y: np.ndarray) -> float:
    """The speed one encoder count over the window reads, when ``y`` is such a speed (a
    count over a window: every reading a whole number of quanta, the window's own length
    jittering each a little); 0 otherwise.

    Candidates: divisors of the slowest readings (a few counts), then the smallest regular
    gap between levels (:func:`quantisation_step`: a motor that never runs slowly reads
    hundreds of counts). A candidate holds where 98 % of the readings of under 15 counts
    lie within a tenth of a quantum of a whole number of them, and 2 % of themselves (a
    logger's window jitters: at 15 counts that is 0.3 of one, still short of the half a
    random reading would pass); with fewer than 10 such readings, where every reading lies
    within a tenth of a quantum of one."""
    y = np.asarray(y, float)
    y = y[np.isfinite(y)]
    z = np.abs(y[y != 0.0])
    if len(z) < 10:
        return 0.0
    low = float(np.percentile(z, 2))
    for q in [low / m for m in range(1, 9)] + [quantisation_step(y)]:
        if q <= 0.0:
            continue
        k = np.maximum(np.round(z / q), 1.0)
        off = np.abs(z - k * q)
        few = k < 15
        if few.sum() >= 10:
            holds = np.mean(off[few] <= 0.1 * q + JITTER * z[few]) >= 0.98
            use = few
        else:
            holds = np.mean(off <= 0.1 * q) >= 0.98
            use = np.ones(len(z), bool)
        if holds:
            return float(np.median(z[use] / k[use]))
    return 0.0


def still_reads_like_a_count(signals, q: float) -> bool:
    """Whether a speed whose readings are whole multiples of ``q`` (:func:`count_quantum`)
    is a count over a window rather than an ADC's codes, told where the shaft is still.

    A count at rest reads exactly zero, and a creeping shaft one count at a time, always
    the same way (or once the other way, where it turns round); an ADC's noise at rest
    flips between the codes above and below zero. Still stretches are :data:`STILL` or
    more readings in a row within one quantum of zero; the speed is a count where they
    hold at least 10 readings of exactly zero (a shaft at rest: a steady speed of one
    count is no evidence) and at most :data:`FLIPS` of the successive nonzero readings
    within a stretch change sign beyond the one turn a stretch may hold. A record that is
    never still cannot tell: not a count (declare the window to say it is)."""
    still, pairs, flips = 0, 0, 0
    for y in signals:
        y = np.asarray(y, float)
        near = np.isfinite(y) & (np.abs(y) <= 1.5 * q)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], near.astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a < STILL:
                continue
            still += int(np.sum(y[a:b] == 0.0))
            s = np.sign(y[a:b][y[a:b] != 0.0])
            pairs += max(len(s) - 1, 0)
            # one change of sign is the shaft turning round through rest
            flips += max(int(np.sum(s[1:] != s[:-1])) - 1, 0)
    return still >= 10 and flips <= FLIPS * pairs


def found_count(speeds) -> float:
    """The speed one count reads where undeclared speed readings are a count over a
    window (:func:`count_quantum`, told from an ADC's codes by
    :func:`still_reads_like_a_count`); 0 otherwise."""
    speeds = [np.asarray(y, float) for y in speeds if y is not None]
    if not speeds:
        return 0.0
    q = count_quantum(np.concatenate(speeds))
    return q if q and still_reads_like_a_count(speeds, q) else 0.0


def exact_grid(y: np.ndarray, flips: float = FLIPS) -> float:
    """The step of ``y`` when it is an exact count (every reading within a hundredth of a
    step of one grid, at least 20 moves between readings, and at most ``flips`` of its
    successive moves reversing the one before: a count turns round only where the shaft
    does, an ADC's noise flips about half its moves); 0 otherwise."""
    y = np.asarray(y, float)
    y = y[np.isfinite(y)]
    if len(y) < 50:
        return 0.0
    # the step: the smallest gap between levels that recurs (a fast shaft skips counts
    # between readings, but it starts from rest through single ones)
    gaps = np.diff(np.unique(np.round(y, 12)))
    gaps = np.sort(gaps[gaps > 1e-12])
    q = next((float(g) for g in gaps if np.sum(np.abs(gaps - g) < 0.01 * g) >= 3), 0.0)
    if q <= 0.0:
        return 0.0
    # the step refined over every move (a log's decimals round each level a little, and
    # a run spans thousands of steps)
    d = np.diff(y)
    d = np.abs(d[np.abs(d) > 0.5 * q])
    n = np.round(d / q)
    if len(d) < 20 or np.any(n < 1):
        return 0.0
    q = float(np.sum(d) / np.sum(n))
    k = (y - y[0]) / q
    if np.mean(np.abs(k - np.round(k)) < 0.01) < 0.999:
        return 0.0
    d = np.diff(np.round(k))
    s = np.sign(d[d != 0])
    if len(s) < 20:
        return 0.0
    return float(q) if np.sum(s[1:] != s[:-1]) <= flips * (len(s) - 1) else 0.0
