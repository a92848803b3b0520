"""The first-order fit of every edge of a run.

After each edge the speed is fitted with ``y1 + (y0 - y1) exp(-(s - td) / tau)``.
With only a position pot the same model is integrated and fitted to the motor angle,
so pot quantisation is never differentiated into speed noise. The 63 % point of the
(smoothed) data is kept as a cross-check of the fitted ``tau``.
"""
from __future__ import annotations

import math
import numpy as np

from labrig.analysis.run_result import EdgeFit
from labrig.analysis.savgol import savgol_filter
from labrig.analysis.stepfit import StepFit
from labrig.analysis.segments import edge_kind

_Q63 = 1.0 - math.exp(-1.0)


# -- models and signal helpers -------------------------------------------------------

def _model_speed(s, y0, y1, tau):
    return np.where(s < 0, y0, y1 + (y0 - y1) * np.exp(-np.clip(s, 0, None) / tau))


def _model_angle(s, c, y0, y1, tau):
    sp = np.clip(s, 0, None)
    return np.where(s < 0, c + y0 * s, c + y1 * sp - (y1 - y0) * tau * (1 - np.exp(-sp / tau)))


def _smooth_derivative(y, dt, window):
    """Speed from an angle: local quadratic (Savitzky-Golay) derivative."""
    window = int(window) | 1
    window = max(window, 5)
    if window >= len(y):
        window = (len(y) - 1) | 1
        if window < 5:
            return np.gradient(y, dt)
    return savgol_filter(y, window, 2, deriv=1, delta=dt)


def _smooth(y, window):
    window = max(int(window), 1)
    if window <= 1 or window >= len(y):
        return np.asarray(y, float)
    k = np.ones(window) / window
    ypad = np.pad(y, (window // 2, window - 1 - window // 2), mode="edge")
    return np.convolve(ypad, k, mode="valid")


def _crossing(s, y, target, rising):
    """First time where ``y`` crosses ``target`` (linear interpolation), or None."""
    hit = (y >= target) if rising else (y <= target)
    idx = np.flatnonzero(hit & (s >= 0))
    if len(idx) == 0:
        return None
    i = idx[0]
    if i == 0 or s[i - 1] < 0:
        return float(max(s[i], 0.0))
    y0, y1 = y[i - 1], y[i]
    frac = 0.0 if y1 == y0 else (target - y0) / (y1 - y0)
    return float(s[i - 1] + frac * (s[i] - s[i - 1]))


# -- one edge ----------------------------------------------------------------------------

def fit_edge(t, y, i_edge, i_end, pre, *, kind="speed", sigma=0.0, min_step=0.0,
             measured=None) -> StepFit:
    """Fit a first-order step response to one edge.

    Parameters
    ----------
    t, y : array
        Time (s) and the measured signal: motor speed (rad/s) for ``kind="speed"``,
        motor angle (rad) for ``kind="angle"`` (the model is then integrated).
    i_edge, i_end : int
        First sample at the new input level and end of the segment (exclusive).
    pre : int
        Samples before the edge used to anchor the initial speed.
    sigma : float
        Noise of ``y`` (robust loss scale).
    min_step : float
        Smaller speed changes are not fitted (the motor did not move).
    measured : bool array, optional
        False for samples the link lost (``gap`` rows): they carry no weight in the fit.

    Returns
    -------
    StepFit
        ``too_short`` or ``no_response`` (with the guessed speeds) when there was
        nothing to fit.
    """
    a = max(i_edge - pre, 0)
    tt, yy = t[a:i_end], y[a:i_end]
    # a lost sample is interpolated: zero weight, and no say in the fit's quality
    wt = np.ones(len(yy)) if measured is None else np.asarray(measured[a:i_end], float)
    dt = float(t[1] - t[0])
    s = tt - t[i_edge]
    seg_dur = float(t[i_end - 1] - t[i_edge]) + dt
    post = s >= 0
    if post.sum() < 6:
        return StepFit(too_short=True)
    # speed for the guesses and the 63 % cross-check
    w = yy if kind == "speed" else _smooth_derivative(yy, dt, max(5, post.sum() // 20))
    tail = w[post][-max(3, post.sum() // 5):]
    y1g = float(np.median(tail))
    y0g = float(np.median(w[~post])) if (~post).sum() else float(w[post][0])
    step = y1g - y0g
    if abs(step) < max(min_step, 1e-12):
        return StepFit(y0=y0g, y1=y1g, no_response=True)
    ws = _smooth(w, max(1, post.sum() // 200)) if kind == "speed" else w
    t63 = _crossing(s, ws, y0g + _Q63 * step, rising=step > 0)
    tau0 = t63 if t63 and t63 > dt else seg_dur / 8
    tau0 = min(max(tau0, dt), seg_dur)
    fscale = max(2 * sigma, 1e-3 * abs(step) * (1 if kind == "speed" else dt))

    if kind == "speed":
        def res(x):
            return (_model_speed(s - x[3], x[0], x[1], math.exp(x[2])) - yy) * wt
        x0 = [y0g, y1g, math.log(tau0), 0.0]
    else:
        c0 = float(np.interp(0.0, s, yy))

        def res(x):
            return (_model_angle(s - x[4], x[0], x[1], x[2], math.exp(x[3])) - yy) * wt
        x0 = [c0, y0g, y1g, math.log(tau0), 0.0]
    # log tau between dt/4 and 20 segments; dead time from -3 samples to 30 % of the segment
    lo_td, hi_td = -3 * dt, max(0.3 * seg_dur, 3 * dt)
    lo = [-np.inf] * (len(x0) - 2) + [math.log(dt / 4), lo_td]
    hi = [np.inf] * (len(x0) - 2) + [math.log(20 * seg_dur), hi_td]
    try:
        # scipy.optimize costs ~0.22 s to import; the fits import this package (noise
        # floors) without fitting an edge, and test_startup keeps it off their path
        from scipy.optimize import least_squares

        sol = least_squares(res, x0, bounds=(lo, hi), loss="soft_l1", f_scale=fscale,
                            x_scale="jac", method="trf", max_nfev=400)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return StepFit(error=str(exc))
    x = sol.x
    if kind == "speed":
        y0, y1, tau, td = x[0], x[1], math.exp(x[2]), x[3]
        fit = _model_speed(s - td, y0, y1, tau)
        r = fit - yy
    else:
        c, y0, y1, tau, td = x[0], x[1], x[2], math.exp(x[3]), x[4]
        fit = _model_speed(s - td, y0, y1, tau)
        # residual of an angle fit in speed units: angle error over the fit window
        r = (_model_angle(s - td, c, y0, y1, tau) - yy) / max(seg_dur, dt)
    r = r[wt > 0] if (wt > 0).any() else r
    nrmse = float(np.sqrt(np.mean(r ** 2)) / max(abs(y1 - y0), 1e-12))
    bound = ("lower" if math.log(tau) <= lo[-2] + 1e-6 else
             "upper" if math.log(tau) >= hi[-2] - 1e-6 else "")
    if kind == "angle":
        # the derivative smoothed over ~tau/3 for the cross-check
        ws = _smooth_derivative(yy, dt, max(5, int(tau / dt / 3)))
        t63 = _crossing(s, ws, y0 + _Q63 * (y1 - y0), rising=y1 > y0)
    return StepFit(y0=float(y0), y1=float(y1), tau=float(tau), td=float(td), tau63=t63,
                   nrmse=nrmse, seg_dur=seg_dur, s=s, w=ws, model=fit,
                   not_settled=tau > seg_dur / 2,
                   tau_bound=bound,
                   poor_fit=nrmse > 0.15)


# -- every edge of a run --------------------------------------------------------------

def fit_run_edges(t, y, seg, *, kind, sigma, min_step, measured=None) -> list[EdgeFit]:
    """Fit every edge of a run (each segment after the first starts with one).

    Parameters
    ----------
    t, y : array
        Time (s) and motor speed (``kind="speed"``) or motor angle (``"angle"``).
    seg : Segments
        The run's input segments.
    sigma, min_step, measured : float, float, bool array or None
        As for :func:`fit_edge`.
    """
    edges = []
    starts, ends, volts = seg.starts, seg.ends, seg.volts
    for i in range(1, len(starts)):
        a, b = starts[i], ends[i]
        # anchor the initial speed on the end of the previous segment, not all of it
        pre = max(3, min((starts[i] - starts[i - 1]) // 5, (b - a) // 5))
        f = fit_edge(t, y, a, b, pre, kind=kind, sigma=sigma, min_step=min_step,
                     measured=measured)
        edges.append(edge_from_fit(int(a), float(t[a]), float(volts[i - 1]), float(volts[i]),
                                   edge_kind(volts[i - 1], volts[i], seg.vtol), f))
    return edges


def edge_from_fit(index, t_s, v_from, v_to, kind, f: StepFit) -> EdgeFit:
    """An :class:`EdgeFit` from a raw fit: accepted values, conditions as booleans."""
    e = EdgeFit(index=index, t_s=t_s, v_from=v_from, v_to=v_to, kind=kind, fit=f,
                too_short=f.too_short, no_response=f.no_response,
                fit_failed=f.error is not None, not_settled=f.not_settled,
                tau_at_bound=f.tau_at_bound, poor_fit=f.poor_fit)
    e.speed_from, e.speed_to = f.y0, f.y1
    if f.accepted:
        e.tau_s, e.tau63_s, e.delay_s, e.fit_nrmse = f.tau, f.tau63, f.td, f.nrmse
        # the data's 63 % point should sit at tau after the dead time
        e.t63_disagrees = bool(e.tau63_s is not None and
                               abs(e.tau63_s - (e.tau_s + max(e.delay_s, 0))) > 0.25 * e.tau_s)
    return e
