"""Steady levels and the speed-vs-voltage line: Km, deadband, Kt.

The steady speed of a segment comes from its flat part, which starts
``SETTLE_TAUS`` time constants after the edge; the exponential tail still left there
(fitted on the edge) is removed first. Segments at the same voltage are pooled into
one :class:`~labrig.analysis.Level`. Across levels, one line ``w = k V + c`` per
direction gives the incremental gain and where the line meets zero speed (deadband).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from labrig.analysis.run_result import Level, LineFit

#: the flat part of a level starts this many time constants after its edge; the
#: fitted exponential tail still left there (exp(-4) = 1.8 % of the step) is removed
SETTLE_TAUS = 4.0


@dataclass
class Signal:
    """What a run measures of the motor.

    Attributes
    ----------
    kind : {"speed", "angle"}
        Motor speed from the tacho or an imported speed column (rad/s), else motor
        angle from the pot (rad).
    y : ndarray
    sigma : float
        Noise of one sample of ``y``.
    """

    kind: str
    y: np.ndarray
    sigma: float


@dataclass
class FlatPart:
    """The steady part of one segment: its speed, or ``settled=False``."""

    settled: bool = False
    speed: float | None = None
    spread: float | None = None
    n: int = 0
    pot_speed: float | None = None
    tacho_v: float | None = None


def flat_speed(kind, t, y, a, b, tail=None, keep=None):
    """Steady speed and spread over samples [a, b).

    ``tail`` = (t_edge, y0, y1, tau) of the fitted edge: the little transient still
    left on the flat part (exp(-4) of a reversal is 4 % of the speed) is removed
    with it, so the steady speed is not biased towards the previous level. ``keep``:
    False for samples the link lost (left out).
    """
    tt, yy = t[a:b], y[a:b].astype(float)
    if keep is not None and not keep[a:b].all() and keep[a:b].sum() >= 3:
        tt, yy = tt[keep[a:b]], yy[keep[a:b]]
        b = a + len(tt)
    if tail is not None:
        te, y0, y1, tau = tail
        e = np.exp(-np.clip(tt - te, 0, None) / tau)
        yy = yy - ((y0 - y1) * e if kind == "speed" else (y1 - y0) * tau * e)
    if kind == "speed":
        return float(np.mean(yy)), float(np.std(yy, ddof=1)) if b - a > 1 else 0.0
    slope = float(np.polyfit(tt - tt[0], yy, 1)[0])
    # spread: how much the slope of sub-windows wanders (noise, ripple)
    nch = min(5, (b - a) // 5)
    if nch >= 2:
        sl = [np.polyfit(c - c[0], d, 1)[0] for c, d in
              zip(np.array_split(tt, nch), np.array_split(yy, nch))]
        spread = float(np.std(sl, ddof=1))
    else:
        spread = None
    return slope, spread


def _flat_start(t, i, a, edges, tau_run):
    """Start time of the flat part of segment ``i`` (first sample ``a``), and the
    tail of its edge to remove; (None, None) when it cannot be placed."""
    f = edges[i - 1].fit if i >= 1 else None
    if i == 0:
        # the record starts here: the state before is unknown, so use the time
        # constant of the run; with none, only a level at rest is trusted
        return (t[0] + (SETTLE_TAUS + 3) * tau_run if tau_run else None), None
    if f is not None and f.ran:
        ok = edges[i - 1].ok
        tau_i = f.tau if ok else tau_run
        start = t[a] + max(f.td, 0.0) + SETTLE_TAUS * (tau_i or 0)
        return start, ((t[a] + f.td, f.y0, f.y1, f.tau) if ok else None)
    if tau_run is not None:
        return t[a] + SETTLE_TAUS * tau_run, None
    return None, None


def segment_flat_parts(run, seg, sig: Signal, edges, tau_run, min_step) -> list[FlatPart]:
    """The steady part of every segment of a run (``settled=False`` where none)."""
    t, y, kind = run.t, sig.y, sig.kind
    # the pot gives the Kt cross-check where a tacho gives the speed
    pot = run.position * run.gear_ratio if (run.has_pos and kind == "speed") else None
    need = max(5, int(round(0.5 * (tau_run or 0) / run.dt)))
    keep = run.measured if run.n_gaps else None  # samples the link lost are left out
    parts = []
    for i, (a, b) in enumerate(zip(seg.starts, seg.ends)):
        start, tail = _flat_start(t, i, a, edges, tau_run)
        part = FlatPart()
        if start is not None:
            fa = int(np.searchsorted(t, start))
            if b - fa >= need:
                sp, spr = flat_speed(kind, t, y, fa, b, tail, keep)
                part = FlatPart(True, sp, spr, b - fa)
                if pot is not None and b - fa >= 5:
                    part.pot_speed = flat_speed("angle", t, pot, fa, b, tail)[0]
                if run.has_tacho:  # imported speed has no tacho volts to show or check
                    part.tacho_v = sp * run.kt
        if not part.settled and b - a >= 10:
            # a level where the motor never moves (lead-in, inside the deadband) is
            # steady from its start: both halves at rest
            h = a + (b - a) // 2
            sp1 = flat_speed(kind, t, y, a, h, keep=keep)[0]
            sp, spr = flat_speed(kind, t, y, h, b, keep=keep)
            if abs(sp) < min_step and abs(sp1) < min_step:
                part = FlatPart(True, sp, spr, b - h)
        parts.append(part)
    return parts


def pool_levels(run_name, seg, parts, edges, min_step) -> list[Level]:
    """One :class:`Level` per distinct voltage, pooling its segments; sorted by V."""
    levels = []
    for j, v in enumerate(seg.uniq):
        idx = [i for i, lab in enumerate(seg.label) if lab == j]
        ok = [parts[i] for i in idx if parts[i].settled]
        into = [edges[i - 1].tau_s for i in idx if i >= 1 and edges[i - 1].ok]
        lvl = Level(run=run_name, v=v, speed=None, spread=None, n_segments=len(idx),
                    n_settled=len(ok), moving=None,
                    tau_s=float(np.median(into)) if into else None)
        if ok:
            _pool_into(lvl, ok, min_step)
        levels.append(lvl)
    levels.sort(key=lambda L: L.v)
    return levels


def _pool_into(lvl: Level, ok: list[FlatPart], min_step) -> None:
    n = np.array([p.n for p in ok], float)
    sp = np.array([p.speed for p in ok])
    lvl.speed = float(np.sum(n * sp) / n.sum())
    # spread: noise within the flat parts and disagreement between them
    sprs = [p.spread for p in ok if p.spread is not None]
    within = float(np.sqrt(np.mean(np.square(sprs)))) if sprs else 0.0
    between = float(np.std(sp, ddof=1)) if len(sp) > 1 else 0.0
    lvl.spread = float(math.hypot(within, between)) if (sprs or len(sp) > 1) else None
    lvl.moving = bool(abs(lvl.speed) > max(min_step, 3 * (between or 0.0)))
    tv = [p.tacho_v for p in ok if p.tacho_v is not None]
    lvl.tacho_v = float(np.mean(tv)) if tv else None
    ps = [p.pot_speed for p in ok if p.pot_speed is not None]
    lvl.pot_speed = float(np.mean(ps)) if ps else None


def kt_from_levels(levels) -> float | None:
    """Tacho volts against pot speed on the moving levels (least squares through 0)."""
    pairs = [(L.tacho_v, L.pot_speed) for L in levels
             if L.tacho_v is not None and L.pot_speed is not None and L.moving]
    if not pairs:
        return None
    vt, wp = np.array(pairs).T
    if np.sum(wp ** 2) > 0:
        return float(np.sum(vt * wp) / np.sum(wp ** 2))
    return None


def moving_points(levels) -> list:
    """The levels that give a point of the line: settled, moving and |V| > 0."""
    return [L for L in levels if L.speed is not None and L.moving and abs(L.v) > 1e-9]


# -- the line across levels -----------------------------------------------------------

def group_amplitudes(absv, rel=0.02):
    """Cluster |V| values that differ by less than ``rel`` (same amplitude)."""
    order = np.argsort(absv)
    groups, cur = [], [order[0]]
    for i in order[1:]:
        if absv[i] - absv[cur[-1]] <= rel * max(absv[i], 1e-12):
            cur.append(i)
        else:
            groups.append(cur)
            cur = [i]
    groups.append(cur)
    return groups


def fit_line(v, w) -> LineFit:
    """w = k V + c_fwd [V > 0] + c_rev [V < 0] with one slope; per-direction slopes too."""
    v, w = np.asarray(v, float), np.asarray(w, float)
    lf = LineFit(n_points=len(v))
    fwd, rev = v > 0, v < 0

    def ndistinct(mask):
        return len(group_amplitudes(np.abs(v[mask]))) if mask.any() else 0
    nf, nr = ndistinct(fwd), ndistinct(rev)
    if nf < 2 and nr < 2:
        if nf and nr:
            # one level each way: the slope through both, no deadband information
            wf, wr = w[fwd].mean(), w[rev].mean()
            vf, vr = v[fwd].mean(), v[rev].mean()
            lf.km = float((wf - wr) / (vf - vr))
        elif nf or nr:
            lf.km = float(np.mean(w / v))
        lf.region = "single_level"
        return lf
    cols, names = [v], []
    for m, nm in ((fwd, "fwd"), (rev, "rev")):
        if m.any():
            cols.append(m.astype(float))
            names.append(nm)
    coef, *_ = np.linalg.lstsq(np.column_stack(cols), w, rcond=None)
    k = float(coef[0])
    lf.km = k
    lf.intercepts = {nm: float(c) for nm, c in zip(names, coef[1:])}
    if abs(k) > 0:
        if "fwd" in lf.intercepts:
            lf.deadband_fwd = -lf.intercepts["fwd"] / k
        if "rev" in lf.intercepts:
            lf.deadband_rev = lf.intercepts["rev"] / k
    for m, nm, n in ((fwd, "fwd", nf), (rev, "rev", nr)):
        if n >= 2:
            setattr(lf, f"km_{nm}", float(np.polyfit(v[m], w[m], 1)[0]))
    return lf
