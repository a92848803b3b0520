"""The trend of w/V with amplitude, and the verdict that explains it.

A threshold (deadband, Coulomb friction) makes w/V rise with amplitude, saturation
makes it fall (docs/physics.md, 'Effect catalogue'). The verdict names the likely cause and the
experiment that separates the candidates which give the same steady-state line.
"""
from __future__ import annotations

import math

import numpy as np

from labrig.analysis.levels import group_amplitudes, moving_points
from labrig.analysis.result import GAIN_TOLERANCE

#: relative difference of reversal and from-rest tau that still counts as "the same"
TAU_SAME = 0.04


def gain_trend(v, w, tol):
    """Trend of w/V with amplitude from the steady points (moving, |V| > 0).

    The change is the plain one a student can check by hand: the mean w/V at the
    largest amplitude over the mean w/V at the smallest, minus 1 (the paper's Table 1:
    2600 -> 1260 rpm/V between 1.2 and 2.5 V, -51.5 %).

    Returns
    -------
    trend : {"constant", "rising", "falling"}
    info : dict
        ``km_by_amplitude`` [(|V|, mean w/V)] by rising amplitude, ``relative_change``
        (that plain change), its ``standard_error``, the ``threshold`` it was judged
        against and the ``amplitude_range_v`` it spans.
    """
    v, w = np.asarray(v, float), np.asarray(w, float)
    km = w / v
    a = np.abs(v)
    groups = group_amplitudes(a)
    by_amp = [(float(np.mean(a[g])), float(np.mean(km[g]))) for g in groups]
    info = {"km_by_amplitude": by_amp, "threshold": tol}
    if len(groups) < 2:
        info["relative_change"] = None
        info["note"] = "one amplitude only: the trend with amplitude cannot be judged"
        return "constant", info
    (a0, k0), (a1, k1) = by_amp[0], by_amp[-1]
    r = float(k1 / k0 - 1.0)
    se = None
    if len(a) > 2:
        # the scatter of w/V about a straight line in |V| (noise, and any curvature:
        # conservative), carried to the two end means and their ratio
        A = np.column_stack([a, np.ones_like(a)])
        coef, *_ = np.linalg.lstsq(A, km, rcond=None)
        resid = km - A @ coef
        s2 = float(resid @ resid) / (len(a) - 2)
        n0, n1 = len(groups[0]), len(groups[-1])
        se = float(abs(k1 / k0) * math.sqrt(s2 / n0 / k0 ** 2 + s2 / n1 / k1 ** 2))
    # a noisy trend needs more than the tolerance: two standard errors
    thr = max(tol, 2 * se) if se is not None else tol
    info.update({"relative_change": r, "standard_error": se, "threshold": thr,
                 "amplitude_range_v": [a0, a1]})
    if abs(r) <= thr:
        return "constant", info
    return ("rising" if r > 0 else "falling"), info


def tau_by_kind(runs) -> dict:
    """Median tau of the fitted edges of each kind (from_rest, reversal, ...)."""
    taus = {}
    for r in runs:
        for e in getattr(r, "edges", None) or []:
            if e.ok:
                taus.setdefault(e.kind, []).append(e.tau_s)
    return {k: float(np.median(v)) for k, v in taus.items()}


def verdict(res) -> str:
    """The verdict of an :class:`~labrig.analysis.AnalysisResult` (all but the verdict
    filled in): the cause of the gain trend, then stiction, asymmetry and Kt."""
    s = [_trend_sentence(res)]
    if res.line.region == "saturated" and res.gain_trend == "falling":
        s.append("No level lies in the linear region, so the motor's Km cannot be read "
                 "from these data; the reported km is the incremental gain of the "
                 "saturated levels.")
    if res.breakaway_v is not None:
        s.append(f"The motor stayed at rest at {res.trend['at_rest_above_deadband_v']:.3g} V "
                 f"although the line predicts motion above {res.deadband_v:.3g} V: stiction, "
                 f"breakaway at {res.breakaway_v:.3g} V or less.")
    asym = _asymmetry_sentence(res.line)
    if asym:
        s.append(asym)
    if res.kt_mismatch:
        s.append(f"The tacho sensitivity measured from the pot is {res.kt:.4g} V per rad/s, "
                 f"not the configured {res.kt_configured:.4g}: check sensors.tacho_v_per_rad_s, "
                 "rig.gear_ratio and sensors.pos_v_per_rad in the sidecar (speeds and km "
                 "above use the configured value).")
    return " ".join(s)


def _trend_sentence(res) -> str:
    kb = res.trend.get("km_by_amplitude", [])
    rng = ""
    if len(kb) >= 2:
        rng = (f"w/V goes from {kb[0][1]:.4g} to {kb[-1][1]:.4g} {res.speed_unit} per V between "
               f"{kb[0][0]:.3g} and {kb[-1][0]:.3g} V")
    thr = res.trend.get("threshold", GAIN_TOLERANCE) * 100
    rel = res.trend.get("relative_change")
    if rng and rel is not None:
        rng += f", {100 * rel:+.1f} %"
    if res.gain_trend == "constant":
        if len(kb) < 2:
            return ("Only one amplitude was recorded, so the trend of w/V with amplitude "
                    "cannot be judged; record square waves at three or more amplitudes.")
        return (f"{rng} (constant: within {thr:.1f} %): the plant is linear over this "
                "range; a deadband, friction or saturation, if any, lies outside it — "
                "a staircase from 0.1 V upwards would reveal a threshold.")
    if res.gain_trend == "rising":
        d = f"about {res.deadband_v:.2f} V" if res.deadband_v is not None else "a threshold voltage"
        return (f"{rng} (rising: more than the {thr:.1f} % a constant gain may wander): each "
                f"level loses {d} before the "
                "motor turns — a deadband (amplifier input stage, brushes) or Coulomb "
                "friction, which give the same steady-state line." + _lean(res) +
                " To separate them, apply a slow ramp of u through zero while recording "
                "the amplifier output voltage and a step to 0 V: a deadband shows in the "
                "amplifier output itself and lets the speed coast down exponentially, "
                "friction leaves the amplifier output linear and stops the motor in "
                "finite time with a kink at zero speed.")
    wsat = max(abs(L.speed) for L in moving_points(res.levels))
    top = (f"{wsat:.0f} rad/s ({wsat * 30 / math.pi:.0f} rpm)" if res.speed_unit == "rad/s"
           else f"{wsat:.3g} {res.speed_unit}")
    return (f"{rng} (falling: more than the {thr:.1f} % a constant gain may wander) while "
            "the speed levels off near "
            f"{top}: saturation — the "
            "amplifier's output rail, a current limit or a clipped speed readout. "
            "To separate them, measure the amplifier output voltage and the armature "
            "current at the highest level (a rail clips the voltage, a current limit "
            "shows as a constant-slope start of each edge, a readout clip leaves both "
            "rising) and repeat at lower voltages to find where the linear region ends.")


def _lean(res) -> str:
    """Which of deadband and Coulomb friction the edges lean towards, if any."""
    tbk = tau_by_kind(res.runs)
    if "reversal" not in tbk or "from_rest" not in tbk:
        return ""
    # Coulomb friction flips sign at zero speed inside a reversal and shortens its
    # apparent tau; a start from rest stays first-order; a deadband leaves both alike
    tr, tf = tbk["reversal"], tbk["from_rest"]
    if tr < (1 - TAU_SAME) * tf:
        return (f" Reversals look faster than starts from rest (tau {tr * 1e3:.0f} vs "
                f"{tf * 1e3:.0f} ms), which leans towards Coulomb friction.")
    if abs(tr / tf - 1) <= TAU_SAME:
        return (f" Reversals and starts from rest have the same tau ({tr * 1e3:.0f} vs "
                f"{tf * 1e3:.0f} ms), which leans towards a deadband.")
    return ""


def _asymmetry_sentence(line) -> str:
    if line.region == "saturated":
        return ""   # the slopes of saturated levels say nothing about the amplifier
    if line.km_fwd and line.km_rev and abs(line.km_fwd / line.km_rev - 1) > GAIN_TOLERANCE:
        return (f"Forward and reverse gains differ ({line.km_fwd:.4g} vs {line.km_rev:.4g} "
                "rad/s per V): an asymmetric amplifier or brush timing.")
    if line.deadband_fwd is not None and line.deadband_rev is not None and \
            abs(line.deadband_fwd - line.deadband_rev) > 0.05:
        return (f"The deadband differs by direction ({line.deadband_fwd:.3f} V forward, "
                f"{line.deadband_rev:.3f} V reverse): an amplifier offset of about "
                f"{(line.deadband_fwd - line.deadband_rev) / 2:.3f} V.")
    return ""
