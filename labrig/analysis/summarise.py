"""From the steady levels of a whole dataset to the headline numbers and verdict."""
from __future__ import annotations

import numpy as np

from labrig.core.errors import AnalysisError
from labrig.analysis.levels import fit_line, moving_points
from labrig.analysis.result import AnalysisResult
from labrig.analysis.run_result import LineFit, RunAnalysis
from labrig.analysis.verdict import gain_trend, verdict

#: relative Kt mismatch (pot-derived vs configured) that is flagged
KT_TOLERANCE = 0.05


def summarise(runs, levels, tol, *, kt_configured=None, kt_est=None,
              source="runs", speed_unit="rad/s") -> AnalysisResult:
    """Line fit, gain trend, deadband, stiction, Kt check and verdict of pooled levels.

    Parameters
    ----------
    runs : list
        :class:`RunAnalysis` objects (or plain dicts for a table), kept in the result.
    levels : list of Level
        Every steady level of every run.
    tol : float
        Relative change of w/V over the amplitude range still called constant.
    kt_configured, kt_est : float or None
        Tacho sensitivity from the sidecars and measured from the pot.
    source : str
        ``"runs"`` or ``"table"``.

    Raises
    ------
    AnalysisError
        When no level moved the motor.
    """
    pts = moving_points(levels)
    if not pts:
        raise AnalysisError("no input level moved the motor; raise the amplitude above the "
                            "deadband (try 1-2 V) and record again")
    v = np.array([L.v for L in pts])
    w = np.array([L.speed for L in pts])
    trend, info = gain_trend(v, w, tol)
    info["asymmetry"] = _speed_asymmetry(pts)
    line = _choose_line(v, w, trend, tol)
    deadband = _plausible_deadband(line.deadband, v)
    breakaway = _breakaway(levels, pts, deadband, v, info)
    taus = [e.tau_s for r in runs if isinstance(r, RunAnalysis) for e in r.edges if e.ok]
    kt_mismatch = None
    if kt_est is not None and kt_configured is not None:
        kt_mismatch = bool(abs(kt_est / kt_configured - 1) > KT_TOLERANCE)
    res = AnalysisResult(deadband_v=deadband, km=line.km,
                         tau_s=float(np.median(taus)) if taus else None, kt=kt_est,
                         gain_trend=trend, runs=runs, verdict="", line=line, trend=info,
                         breakaway_v=breakaway, kt_configured=kt_configured,
                         kt_mismatch=kt_mismatch, tolerance=tol, source=source,
                         levels=levels)
    res.speed_unit = speed_unit
    res.verdict = verdict(res)
    return res


def _speed_asymmetry(pts) -> dict:
    """Forward/reverse ratio of the steady speed at matching amplitudes."""
    fw = {round(abs(L.v), 2): abs(L.speed) for L in pts if L.v > 0}
    rv = {round(abs(L.v), 2): abs(L.speed) for L in pts if L.v < 0}
    ratios = [fw[a] / rv[a] for a in sorted(set(fw) & set(rv)) if rv[a] > 0]
    return {"speed_ratio_fwd_rev": float(np.mean(ratios))} if ratios else {}


def _choose_line(v, w, trend, tol) -> LineFit:
    """The line through the unsaturated levels (all of them unless w/V falls)."""
    use = np.ones(len(v), bool)
    if trend == "falling":
        # above a saturation the slope is not the motor's: keep the levels whose w/V
        # is near the best of their direction
        km_app = w / v
        for sgn in (1, -1):
            m = np.sign(v) == sgn
            if m.any():
                use[m] = km_app[m] >= (1 - 2 * tol) * km_app[m].max()
    line = fit_line(v[use], w[use])
    if trend == "falling" and line.region == "single_level":
        # no linear region observed: the incremental gain of what was measured
        line = fit_line(v, w)
        line.region = "saturated"
        line.deadband_fwd = line.deadband_rev = None
    return line


def _plausible_deadband(deadband, v):
    """None when the line meets zero far outside the data (no deadband reading)."""
    if deadband is not None and (deadband < -0.25 * np.abs(v).min() or
                                 deadband > np.abs(v).max()):
        return None
    return deadband


def _breakaway(levels, pts, deadband, v, info):
    """Stiction: the lowest moving |V| above a level at rest that the line says moves.

    Records the highest such resting level in ``info["at_rest_above_deadband_v"]``.
    """
    if deadband is None:
        return None
    still = [abs(L.v) for L in levels if L.speed is not None and L.moving is False
             and abs(L.v) > max(deadband, 0.0) + 0.02 * np.abs(v).max()]
    if not still:
        return None
    info["at_rest_above_deadband_v"] = float(max(still))
    moving = [abs(L.v) for L in pts if abs(L.v) > max(still)]
    return float(min(moving)) if moving else None
