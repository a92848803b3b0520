"""Levels and edges of a piecewise-constant input, found from ``u`` itself.

Nothing here reads the sidecar: imported runs and foreign waveforms (a scope trace
of a function generator) are split the same way as the runs labrig recorded.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from labrig.core.errors import AnalysisError


def robust_std(x) -> float:
    """Standard deviation from the median absolute deviation (outliers do not count)."""
    x = np.asarray(x, float)
    if len(x) == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def find_segments(u, min_samples: int = 3):
    """Split a piecewise-constant input into segments of constant level.

    Levels are clusters of the values of ``u`` (robust to measurement noise and to
    slow edges on a scope trace); segments are runs of samples nearest to one level.

    Parameters
    ----------
    u : array
        The applied input (V).
    min_samples : int
        Shorter runs are glitches and join their neighbour.

    Returns
    -------
    starts : ndarray of int
        First sample of each segment (the first is 0).
    levels : ndarray
        Level of each segment (V): the median of ``u`` over it.

    Raises
    ------
    AnalysisError
        When ``u`` is not piecewise constant (a ramp or a sine).
    """
    u = np.asarray(u, float)
    n = len(u)
    ptp = float(np.ptp(u))
    scale = max(float(np.max(np.abs(u))), 1e-12)
    sig = 1.4826 * float(np.median(np.abs(np.diff(u)))) / math.sqrt(2) if n > 2 else 0.0
    if ptp <= max(8 * sig, 1e-6 * scale):
        return np.array([0]), np.array([float(np.median(u))])
    width = max(3 * sig, ptp / 1000.0)
    levels = _cluster_levels(u, width, min_samples)
    label = np.argmin(np.abs(u[:, None] - levels[None, :]), axis=1)
    on_level = np.abs(u - levels[label]) <= max(4 * sig, 2 * width)
    if on_level.mean() < 0.9:
        raise AnalysisError(f"the input u is not piecewise constant ({100 * (1 - on_level.mean()):.0f} % "
                            "of samples lie between levels: a ramp or a sine?); analyse needs "
                            "steps, square waves or staircases")
    # run-length encode, then let glitches join the previous segment
    change = np.flatnonzero(np.diff(label)) + 1
    starts = np.concatenate([[0], change])
    lens = np.diff(np.concatenate([starts, [n]]))
    keep = lens >= min_samples
    keep[0] = True
    starts = starts[keep]
    labs = label[starts]
    # adjacent segments with the same level (a glitch removed between them) merge
    m = np.concatenate([[True], labs[1:] != labs[:-1]])
    starts = starts[m]
    seg_levels = np.array([float(np.median(u[a:b])) for a, b in
                           zip(starts, np.concatenate([starts[1:], [n]]))])
    return starts, seg_levels


def _cluster_levels(u, width, min_samples):
    """Levels of ``u``: medians of the runs of well-occupied histogram bins."""
    n = len(u)
    ptp = float(np.ptp(u))
    nb = int(math.ceil(ptp / width)) + 1
    counts, edges = np.histogram(u, bins=nb, range=(u.min() - width / 2, u.max() + width / 2))
    occupied = counts >= max(min_samples, int(0.001 * n))
    clusters, cur = [], []
    for i, occ in enumerate(occupied):
        if occ:
            cur.append(i)
        elif cur:
            clusters.append(cur)
            cur = []
    if cur:
        clusters.append(cur)
    levels = []
    for c in clusters:
        lo, hi = edges[c[0]], edges[c[-1] + 1]
        sel = (u >= lo) & (u <= hi)
        levels.append(float(np.median(u[sel])))
    if not levels:
        raise AnalysisError("the input u has no level held for more than a few samples; "
                            "analyse needs steps, square waves or staircases")
    return np.array(levels)


def edge_kind(v0: float, v1: float, tol: float) -> str:
    """``from_rest``, ``to_rest``, ``reversal``, ``step_up`` or ``step_down``."""
    if abs(v0) <= tol:
        return "from_rest"
    if abs(v1) <= tol:
        return "to_rest"
    if np.sign(v0) != np.sign(v1):
        return "reversal"
    return "step_up" if abs(v1) > abs(v0) else "step_down"


@dataclass
class Segments:
    """The segments of one run's input and the distinct levels they hold.

    Attributes
    ----------
    starts, ends : ndarray of int
        First sample and end (exclusive) of each segment.
    volts : ndarray
        Input level of each segment (V).
    vtol : float
        Levels closer than ``vtol / 2`` are the same level; ``|V| <= vtol`` is rest.
    uniq : list of float
        The distinct levels, in order of first appearance.
    label : list of int
        Index into ``uniq`` of each segment: segments at one level pool their flat parts.
    """

    starts: np.ndarray
    ends: np.ndarray
    volts: np.ndarray
    vtol: float
    uniq: list
    label: list

    @classmethod
    def of(cls, u) -> "Segments":
        starts, volts = find_segments(u)
        ends = np.concatenate([starts[1:], [len(u)]])
        vtol = max(0.02 * float(np.max(np.abs(volts))), 1e-6)
        uniq: list[float] = []
        label = []
        for v in volts:
            j = next((k for k, w in enumerate(uniq) if abs(w - v) <= vtol / 2), None)
            if j is None:
                uniq.append(float(v))
                j = len(uniq) - 1
            label.append(j)
        return cls(starts, ends, volts, vtol, uniq, label)

    def __len__(self) -> int:
        return len(self.starts)

    def longest_after_edge(self, dt: float) -> float:
        """Longest time a level is held after an edge (s)."""
        return float(max(self.ends[1:] - self.starts[1:]) * dt)
