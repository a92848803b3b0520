"""First-order analysis of open-loop runs: deadband, Km, tau_m, Kt, gain trend.

The input of every open-loop run is taken to be piecewise constant (square waves,
steps, staircases). Levels and edges are found from ``u`` itself, never from the
sidecar, so imported runs and foreign waveforms work the same way. For each level
the steady speed comes from the flat part after the transient has died out; for
each edge a first-order step response is fitted (the 63 % point is kept as a
cross-check). The steady points then give the paper's Km = w/V per level, the
incremental gain (slope of speed against voltage), the deadband (where that line
meets zero speed) and the trend of w/V with amplitude, which tells a threshold
(deadband, Coulomb friction: w/V rises) from saturation (w/V falls); docs/physics.md,
'Effect catalogue'.

Runs with only a position pot are analysed on the motor angle
``gear_ratio * theta_out``: the edge model is integrated instead of the data being
differentiated, so pot quantisation does not turn into speed noise.

Examples
--------
>>> res = analyse("data/sweep_default")              # doctest: +SKIP
>>> res.km, res.tau_s, res.gain_trend                # doctest: +SKIP
>>> res.to_pandas()                                  # per-level table
>>> res.plot("figs")                                 # PNG figures
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from .errors import AnalysisError

#: relative change of w/V over the amplitude range still called "constant"
GAIN_TOLERANCE = 0.03
#: the flat part of a level starts this many time constants after its edge; the
#: fitted exponential tail still left there (exp(-4) = 1.8 % of the step) is removed
SETTLE_TAUS = 4.0
#: relative Kt mismatch (pot-derived vs configured) that is flagged
KT_TOLERANCE = 0.05
_Q63 = 1.0 - math.exp(-1.0)


# -- result objects --------------------------------------------------------------

@dataclass
class EdgeFit:
    """One edge of the input and the first-order fit of the speed after it.

    Attributes
    ----------
    t_s : float
        Time of the edge in the run (s): first sample at the new input level.
    v_from, v_to : float
        Input level before and after the edge (V).
    kind : str
        ``"from_rest"``, ``"to_rest"``, ``"reversal"``, ``"step_up"`` or ``"step_down"``
        (by magnitude, within one direction).
    speed_from, speed_to : float or None
        Fitted initial and final motor speed (rad/s).
    tau_s : float or None
        Time constant of the first-order fit (s); None when there was nothing to fit.
    tau63_s : float or None
        Time from the edge to 63 % of the speed change (s), from the data.
    delay_s : float or None
        Dead time of the fit (s): sampling convention, electrical lag, transport delay.
    fit_nrmse : float or None
        RMS residual of the fit relative to the size of the speed change.
    note : str
        Why an edge was not fitted, or a warning.
    """

    index: int
    t_s: float
    v_from: float
    v_to: float
    kind: str
    speed_from: float | None = None
    speed_to: float | None = None
    tau_s: float | None = None
    tau63_s: float | None = None
    delay_s: float | None = None
    fit_nrmse: float | None = None
    note: str = ""
    # arrays for the figure: time from the edge, data, fitted model (speed, rad/s)
    _plot: dict | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        return self.tau_s is not None


@dataclass
class Level:
    """The steady speed of one input level of a run (all its segments pooled)."""

    run: str
    v: float
    speed: float | None
    spread: float | None
    n_segments: int
    n_settled: int
    moving: bool | None
    tacho_v: float | None = None      # mean tacho volts on the flat parts (Kt check)
    pot_speed: float | None = None    # motor speed from the pot on the same flat parts
    tau_s: float | None = None        # median tau of the edges into this level

    @property
    def km_paper(self) -> float | None:
        """The paper's Km = w / V (eq. 5); None at 0 V or when not settled."""
        if self.speed is None or abs(self.v) < 1e-9:
            return None
        return self.speed / self.v


@dataclass
class RunAnalysis:
    """What one run gave: its levels, its edges, or why it was skipped."""

    name: str
    loop: str
    fs: float
    sensor: str | None = None
    levels: list[Level] = field(default_factory=list)
    edges: list[EdgeFit] = field(default_factory=list)
    kt_est: float | None = None
    kt_configured: float | None = None
    skipped: str | None = None
    notes: list[str] = field(default_factory=list)
    figure: str | None = None
    _trace: dict | None = field(default=None, repr=False)

    @property
    def tau_s(self) -> float | None:
        taus = [e.tau_s for e in self.edges if e.ok]
        return float(np.median(taus)) if taus else None

    def to_dict(self) -> dict:
        d = {"name": self.name, "loop": self.loop, "sample_rate_hz": self.fs,
             "skipped": self.skipped}
        if self.skipped:
            return _clean(d)
        d.update({
            "sensor": self.sensor,
            "tau_s": self.tau_s,
            "kt_est": self.kt_est,
            "levels": [{"v": lv.v, "speed_rad_s": lv.speed, "spread_rad_s": lv.spread,
                        "km_paper": lv.km_paper, "moving": lv.moving,
                        "segments": lv.n_segments, "settled": lv.n_settled,
                        "tau_s": lv.tau_s} for lv in self.levels],
            "edges": [{"t_s": e.t_s, "v_from": e.v_from, "v_to": e.v_to, "kind": e.kind,
                       "speed_from": e.speed_from, "speed_to": e.speed_to, "tau_s": e.tau_s,
                       "tau63_s": e.tau63_s, "delay_s": e.delay_s, "fit_nrmse": e.fit_nrmse,
                       "note": e.note or None} for e in self.edges],
            "notes": self.notes,
            "figure": self.figure,
        })
        return _clean(d)


@dataclass
class LineFit:
    """Steady speed against input voltage: w = k (V - d) forward, k (V + d) reverse."""

    km: float | None = None
    deadband_fwd: float | None = None
    deadband_rev: float | None = None
    km_fwd: float | None = None
    km_rev: float | None = None
    intercepts: dict = field(default_factory=dict)   # {"fwd": c, "rev": c} of w = k V + c
    region: str = "linear"                            # or "saturated" / "single_level"
    n_points: int = 0

    @property
    def deadband(self) -> float | None:
        ds = [d for d in (self.deadband_fwd, self.deadband_rev) if d is not None]
        return float(np.mean(ds)) if ds else None


@dataclass
class AnalysisResult:
    """The answer of ``labrig analyse``: summary figures plus everything behind them.

    Attributes
    ----------
    deadband_v : float or None
        Input voltage where the steady speed-vs-voltage line meets zero speed (V).
    km : float or None
        Incremental gain: slope of steady motor speed against bridge voltage above
        the deadband (rad/s per V).
    tau_s : float or None
        Median first-order time constant over the fitted edges (s); None for
        steady-state-only data.
    kt : float or None
        Tacho sensitivity measured from the position pot (V per rad/s); None where
        no run has both sensors (or the data give it otherwise, e.g. a table).
    gain_trend : {"constant", "rising", "falling"}
        How w/V changes with amplitude, judged with ``tolerance``.
    runs : list of RunAnalysis
    verdict : str
        One or two sentences: the likely physical cause and the experiment that
        separates the candidates.
    """

    deadband_v: float | None
    km: float | None
    tau_s: float | None
    kt: float | None
    gain_trend: str
    runs: list
    verdict: str
    line: LineFit = field(default_factory=LineFit)
    trend: dict = field(default_factory=dict)
    breakaway_v: float | None = None
    kt_configured: float | None = None
    kt_mismatch: bool | None = None
    tolerance: float = GAIN_TOLERANCE
    source: str = "runs"
    levels: list = field(default_factory=list)
    figures: list = field(default_factory=list)

    # -- outputs ------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-safe dict (docs/design.md, 'Commands'; NaN and inf become None)."""
        asym = {}
        if self.line.km_fwd is not None and self.line.km_rev is not None:
            asym["km_ratio_fwd_rev"] = self.line.km_fwd / self.line.km_rev
        if self.line.deadband_fwd is not None and self.line.deadband_rev is not None:
            asym["deadband_diff_v"] = self.line.deadband_fwd - self.line.deadband_rev
        asym.update(self.trend.get("asymmetry", {}))
        d = {
            "deadband_v": self.deadband_v, "km": self.km, "tau_s": self.tau_s, "kt": self.kt,
            "gain_trend": self.gain_trend,
            "runs": [r.to_dict() if isinstance(r, RunAnalysis) else r for r in self.runs],
            "verdict": self.verdict,
            "km_paper": {f"{a:g}": k for a, k in self.trend.get("km_by_amplitude", [])},
            "trend": {k: v for k, v in self.trend.items() if k not in ("asymmetry",
                                                                      "km_by_amplitude")},
            "tolerance": self.tolerance,
            "breakaway_v": self.breakaway_v,
            "forward": {"km": self.line.km_fwd, "deadband_v": self.line.deadband_fwd},
            "reverse": {"km": self.line.km_rev, "deadband_v": self.line.deadband_rev},
            "asymmetry": asym,
            "line_region": self.line.region,
            "kt_configured": self.kt_configured,
            "kt_mismatch": self.kt_mismatch,
            "source": self.source,
            "figures": self.figures,
        }
        return _clean(d)

    def to_pandas(self) -> pd.DataFrame:
        """Per-level table (one row per run and input level), like the paper's Table 1."""
        rows = []
        for lv in self.levels:
            rows.append({"run": lv.run, "input_v": lv.v,
                         "speed_rpm": None if lv.speed is None else lv.speed * 30 / math.pi,
                         "omega_rad_s": lv.speed, "spread_rad_s": lv.spread,
                         "tacho_v": lv.tacho_v, "km_paper": lv.km_paper, "tau_s": lv.tau_s,
                         "moving": lv.moving, "segments": lv.n_segments,
                         "settled": lv.n_settled})
        return pd.DataFrame(rows)

    def plot(self, figdir) -> list[str]:
        """Write the figures (PNG) into ``figdir``; returns their paths."""
        from .report.analyse_plots import plot_analysis

        self.figures = [str(p) for p in plot_analysis(self, Path(figdir))]
        return self.figures

    def summary(self) -> str:
        """The readable summary: a table like the paper's Table 1, then the figures."""
        df = self.to_pandas()
        lines = []
        hdr = f"{'run':<16}{'Vm (V)':>8}{'n (rpm)':>9}{'w (rad/s)':>11}{'spread':>8}" \
              f"{'Vt (V)':>8}{'Km=w/V':>9}{'tau (ms)':>9}"
        lines += [hdr, "-" * len(hdr)]
        for _, r in df.iterrows():
            def f(x, fmt):
                w = int(fmt.split(".")[0])
                return format(x, fmt) if x is not None and not pd.isna(x) else "-".rjust(w)
            flag = "" if r["moving"] is not False else "  (at rest)"
            if not r["settled"]:
                flag = "  (not settled)"
            lines.append(f"{str(r['run'])[:15]:<16}{f(r['input_v'], '8.3f')}"
                         f"{f(r['speed_rpm'], '9.0f')}{f(r['omega_rad_s'], '11.2f')}"
                         f"{f(r['spread_rad_s'], '8.2f')}{f(r['tacho_v'], '8.3f')}"
                         f"{f(r['km_paper'], '9.2f')}"
                         f"{f(None if r['tau_s'] is None or pd.isna(r['tau_s']) else r['tau_s'] * 1e3, '9.1f')}"
                         + flag)
        for r in self.runs:
            if isinstance(r, RunAnalysis) and r.skipped:
                lines.append(f"{r.name}: skipped ({r.skipped})")
        lines.append("")

        def g(x, fmt, unit=""):
            return "not measurable" if x is None else format(x, fmt) + unit
        lines.append(f"km (incremental)  {g(self.km, '.4g', ' rad/s per V')}"
                     + (f"   [forward {self.line.km_fwd:.4g}, reverse {self.line.km_rev:.4g}]"
                        if self.line.km_fwd is not None and self.line.km_rev is not None else ""))
        lines.append(f"deadband          {g(self.deadband_v, '.3f', ' V')}"
                     + (f"   [forward {self.line.deadband_fwd:.3f}, reverse "
                        f"{self.line.deadband_rev:.3f}]" if self.line.deadband_fwd is not None
                        and self.line.deadband_rev is not None else ""))
        if self.breakaway_v is not None:
            lines.append(f"breakaway         {self.breakaway_v:.3f} V (stiction)")
        lines.append(f"tau_m             {g(None if self.tau_s is None else self.tau_s * 1e3, '.1f', ' ms')}")
        kt_txt = g(self.kt, '.4g', ' V per rad/s')
        if self.kt_configured is not None:
            kt_txt += f" (configured {self.kt_configured:.4g}" + \
                      (", MISMATCH)" if self.kt_mismatch else ")")
        lines.append(f"kt                {kt_txt}")
        thr = self.trend.get("threshold", self.tolerance)
        lines.append(f"gain trend        {self.gain_trend} (w/V changes by "
                     + (f"{self.trend['relative_change'] * 100:+.1f} %"
                        if self.trend.get("relative_change") is not None else "-")
                     + f" over the amplitude range; tolerance {self.tolerance * 100:.0f} %"
                     + (f", 2 standard errors = {thr * 100:.1f} %" if thr > self.tolerance else "")
                     + ")")
        lines.append("")
        lines.append(self.verdict)
        if self.figures:
            lines.append("")
            lines += [f"figure: {p}" for p in self.figures]
        return "\n".join(lines)


# -- levels and edges from u -------------------------------------------------------

def _robust_std(x) -> float:
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
    nb = int(math.ceil(ptp / width)) + 1
    counts, edges = np.histogram(u, bins=nb, range=(u.min() - width / 2, u.max() + width / 2))
    occupied = counts >= max(min_samples, int(0.001 * n))
    # clusters = runs of occupied bins
    centres, cur = [], []
    for i, occ in enumerate(occupied):
        if occ:
            cur.append(i)
        elif cur:
            centres.append(cur)
            cur = []
    if cur:
        centres.append(cur)
    levels = []
    for c in centres:
        lo, hi = edges[c[0]], edges[c[-1] + 1]
        sel = (u >= lo) & (u <= hi)
        levels.append(float(np.median(u[sel])))
    levels = np.array(levels)
    if len(levels) == 0:
        raise AnalysisError("the input u has no level held for more than a few samples; "
                            "analyse needs steps, square waves or staircases")
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
    starts, labs = starts[m], labs[m]
    seg_levels = np.array([float(np.median(u[a:b])) for a, b in
                           zip(starts, np.concatenate([starts[1:], [n]]))])
    return starts, seg_levels


def _edge_kind(v0: float, v1: float, tol: float) -> str:
    if abs(v0) <= tol:
        return "from_rest"
    if abs(v1) <= tol:
        return "to_rest"
    if np.sign(v0) != np.sign(v1):
        return "reversal"
    return "step_up" if abs(v1) > abs(v0) else "step_down"


# -- the first-order edge fit ----------------------------------------------------------

def _model_speed(s, y0, y1, tau):
    return np.where(s < 0, y0, y1 + (y0 - y1) * np.exp(-np.clip(s, 0, None) / tau))


def _model_angle(s, c, y0, y1, tau):
    sp = np.clip(s, 0, None)
    return np.where(s < 0, c + y0 * s, c + y1 * sp - (y1 - y0) * tau * (1 - np.exp(-sp / tau)))


def _smooth_derivative(y, dt, window):
    """Speed from an angle: local quadratic (Savitzky-Golay) derivative."""
    from scipy.signal import savgol_filter

    window = int(window) | 1
    window = max(window, 5)
    if window >= len(y):
        window = (len(y) - 1) | 1
        if window < 5:
            return np.gradient(y, dt)
    return savgol_filter(y, window, 2, deriv=1, delta=dt, mode="interp")


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


def fit_edge(t, y, i_edge, i_end, pre, *, kind="speed", sigma=0.0, min_step=0.0):
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

    Returns
    -------
    dict with ``y0``, ``y1`` (rad/s), ``tau``, ``td``, ``tau63``, ``nrmse`` and the
    plot arrays, or ``{"note": ...}`` when there is nothing to fit.
    """
    a = max(i_edge - pre, 0)
    tt, yy = t[a:i_end], y[a:i_end]
    dt = float(t[1] - t[0])
    s = tt - t[i_edge]
    seg_dur = float(t[i_end - 1] - t[i_edge]) + dt
    post = s >= 0
    if post.sum() < 6:
        return {"note": "segment too short to fit"}
    # speed for guesses and the 63 % cross-check
    if kind == "speed":
        w = yy
    else:
        w = _smooth_derivative(yy, dt, max(5, post.sum() // 20))
    tail = w[post][-max(3, post.sum() // 5):]
    y1g = float(np.median(tail))
    y0g = float(np.median(w[~post])) if (~post).sum() else float(w[post][0])
    step = y1g - y0g
    if abs(step) < max(min_step, 1e-12):
        return {"note": "no speed change (the motor did not respond)", "y0": y0g, "y1": y1g}
    ws = _smooth(w, max(1, post.sum() // 200)) if kind == "speed" else w
    t63 = _crossing(s, ws, y0g + _Q63 * step, rising=step > 0)
    tau0 = t63 if t63 and t63 > dt else seg_dur / 8
    tau0 = min(max(tau0, dt), seg_dur)
    fscale = max(2 * sigma, 1e-3 * abs(step) * (1 if kind == "speed" else dt))

    if kind == "speed":
        def res(x):
            return _model_speed(s - x[3], x[0], x[1], math.exp(x[2])) - yy
        x0 = [y0g, y1g, math.log(tau0), 0.0]
    else:
        c0 = float(np.interp(0.0, s, yy))

        def res(x):
            return _model_angle(s - x[4], x[0], x[1], x[2], math.exp(x[3])) - yy
        x0 = [c0, y0g, y1g, math.log(tau0), 0.0]
    lo_td, hi_td = -3 * dt, max(0.3 * seg_dur, 3 * dt)
    lo = [-np.inf] * (len(x0) - 2) + [math.log(dt / 4), lo_td]
    hi = [np.inf] * (len(x0) - 2) + [math.log(20 * seg_dur), hi_td]
    try:
        sol = least_squares(res, x0, bounds=(lo, hi), loss="soft_l1", f_scale=fscale,
                            x_scale="jac", method="trf", max_nfev=400)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return {"note": f"fit failed ({exc})"}
    x = sol.x
    if kind == "speed":
        y0, y1, tau, td = x[0], x[1], math.exp(x[2]), x[3]
        fit = _model_speed(s - td, y0, y1, tau)
        r = fit - yy
    else:
        c, y0, y1, tau, td = x[0], x[1], x[2], math.exp(x[3]), x[4]
        fit = _model_speed(s - td, y0, y1, tau)
        r = _model_angle(s - td, c, y0, y1, tau) - yy
        # residual of an angle fit in speed units: angle error over the fit window
        r = r / max(seg_dur, dt)
    nrmse = float(np.sqrt(np.mean(r ** 2)) / max(abs(y1 - y0), 1e-12))
    if kind == "speed":
        t63d = t63
    else:
        # the derivative smoothed over ~tau/3 for the cross-check
        wd = _smooth_derivative(yy, dt, max(5, int(tau / dt / 3)))
        t63d = _crossing(s, wd, y0 + _Q63 * (y1 - y0), rising=y1 > y0)
        ws = wd
    out = {"y0": float(y0), "y1": float(y1), "tau": float(tau), "td": float(td),
           "tau63": t63d, "nrmse": nrmse, "seg_dur": seg_dur,
           "plot": {"s": s, "w": ws, "fit": fit}}
    notes = []
    if tau > seg_dur / 2:
        notes.append("time constant longer than half the segment: not settled")
    if math.log(tau) <= lo[-2] + 1e-6 or math.log(tau) >= hi[-2] - 1e-6:
        notes.append("time constant at its bound")
    if nrmse > 0.15:
        notes.append(f"poor first-order fit (residual {100 * nrmse:.0f} % of the step)")
    if notes:
        out["note"] = "; ".join(notes)
    return out


# -- one run ------------------------------------------------------------------------

def _signal(run):
    """(kind, y, sigma): motor speed from the tacho, else motor angle from the pot."""
    if run.speed is not None:
        y = run.speed
        sig = _robust_std(np.diff(y)) / math.sqrt(2)
        return "speed", y, sig
    y = run.position * run.gear_ratio
    # noise of an angle that moves: second differences remove the slope
    sig = _robust_std(np.diff(y, 2)) / math.sqrt(6)
    return "angle", y, sig


def _flat_speed(kind, t, y, a, b, tail=None):
    """Steady speed and spread over samples [a, b).

    ``tail`` = (t_edge, y0, y1, tau) of the fitted edge: the little transient still
    left on the flat part (exp(-4) of a reversal is 4 % of the speed) is removed
    with it, so the steady speed is not biased towards the previous level.
    """
    tt, yy = t[a:b], y[a:b].astype(float)
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


def analyse_run(run) -> RunAnalysis:
    """Levels, edges and steady speeds of one open-loop run.

    Raises
    ------
    AnalysisError
        When the run has no edges, a constant input or never settles.
    """
    ra = RunAnalysis(name=run.name, loop=run.loop, fs=run.fs)
    if run.loop != "open":
        ra.skipped = "closed-loop run: analyse uses open-loop runs only (identify uses both)"
        return ra
    t, u = run.t, run.u
    dt = run.dt
    where = f"run '{run.name}'" + (f" ({run.path})" if run.path else "")
    if len(t) < 20:
        raise AnalysisError(f"{where}: only {len(t)} samples; record at least a few time "
                            "constants per level")
    starts, lv = find_segments(u)
    ends = np.concatenate([starts[1:], [len(u)]])
    if len(starts) < 2:
        raise AnalysisError(f"{where}: the input u is constant at {lv[0]:.3g} V (no edges); "
                            "analyse needs steps, square waves or staircases with a lead-in "
                            "or reversals")
    kind, y, sig = _signal(run)
    ra.sensor = "tacho" if kind == "speed" else "pos"
    ra.kt_configured = run.kt if run.has_tacho else None
    vtol = max(0.02 * float(np.max(np.abs(lv))), 1e-6)
    # level identity: segments at the same voltage pool their flat parts
    uniq: list[float] = []
    lab = []
    for v in lv:
        j = next((k for k, w in enumerate(uniq) if abs(w - v) <= vtol / 2), None)
        if j is None:
            uniq.append(float(v))
            j = len(uniq) - 1
        lab.append(j)

    # rough speed scale for "did it move": the largest tail speed of any segment
    def tail_speed(a, b):
        n = max(3, (b - a) // 5)
        if kind == "speed":
            return float(np.median(y[b - n:b]))
        return float(np.polyfit(t[b - n:b], y[b - n:b], 1)[0]) if n >= 3 else 0.0
    wmax = max(abs(tail_speed(a, b)) for a, b in zip(starts, ends))
    sig_w = sig if kind == "speed" else sig / dt  # speed noise of one sample
    min_step = max(0.05 * wmax, 5 * (sig if kind == "speed" else 0.0), 1e-9)

    # first pass: fit every edge
    fits = {}
    for i in range(1, len(starts)):
        a, b = starts[i], ends[i]
        pre = max(3, min((starts[i] - starts[i - 1]) // 5, (b - a) // 5))
        e = EdgeFit(index=int(a), t_s=float(t[a]), v_from=float(lv[i - 1]), v_to=float(lv[i]),
                    kind=_edge_kind(lv[i - 1], lv[i], vtol))
        f = fit_edge(t, y, a, b, pre, kind=kind, sigma=sig, min_step=min_step)
        fits[i] = f
        if "tau" in f and "not settled" not in f.get("note", "") and "bound" not in f.get("note", ""):
            e.tau_s, e.tau63_s, e.delay_s = f["tau"], f.get("tau63"), f["td"]
            e.fit_nrmse = f["nrmse"]
            e.speed_from, e.speed_to = f["y0"], f["y1"]
            e._plot = f["plot"]
            if e.tau63_s is not None and abs(e.tau63_s - (e.tau_s + max(e.delay_s, 0))) > \
                    0.25 * e.tau_s:
                f["note"] = (f.get("note", "") + "; " if f.get("note") else "") + \
                    "63 % point disagrees with the fit"
        elif "y0" in f:
            e.speed_from, e.speed_to = f["y0"], f["y1"]
        e.note = f.get("note", "")
        ra.edges.append(e)
    taus = [e.tau_s for e in ra.edges if e.ok]
    tau_run = float(np.median(taus)) if taus else None
    if tau_run is None:
        raw = [f["tau"] for f in fits.values() if "tau" in f]
        if raw and min(raw) > 0:
            longest = float(max(ends[1:] - starts[1:]) * dt)
            raise AnalysisError(
                f"{where}: the speed never settles: after its edges the input is held at most "
                f"{longest:.3g} s but "
                f"the time constant is about {np.median(raw):.3g} s; hold each level for at "
                f"least {SETTLE_TAUS + 1:.0f} time constants (a lower frequency or longer steps)")

    # second pass: flat parts and steady speeds per segment
    pot = run.position * run.gear_ratio if (run.has_pos and kind == "speed") else None
    per_level: dict[int, list] = {}
    for i, (a, b) in enumerate(zip(starts, ends)):
        f = fits.get(i)
        tail = None
        if f is not None and "tau" in f:
            tau_i = f["tau"] if (ra.edges[i - 1].ok) else tau_run
            start = t[a] + max(f.get("td", 0.0), 0.0) + SETTLE_TAUS * (tau_i or 0)
            if ra.edges[i - 1].ok:
                tail = (t[a] + f["td"], f["y0"], f["y1"], f["tau"])
        elif tau_run is not None:
            start = t[a] + SETTLE_TAUS * tau_run
        else:
            start = None
        if i == 0 and a == 0:
            # the record starts here: the state before is unknown, so use the time
            # constant of the run; with none, only a level at rest is trusted
            start = t[0] + (SETTLE_TAUS + 3) * tau_run if tau_run else None
        entry = {"settled": False}
        need = max(5, int(round(0.5 * (tau_run or 0) / dt)))
        if start is not None:
            fa = int(np.searchsorted(t, start))
            if b - fa >= need:
                sp, spr = _flat_speed(kind, t, y, fa, b, tail)
                entry = {"settled": True, "speed": sp, "spread": spr, "n": b - fa}
                if pot is not None and b - fa >= 5:
                    entry["pot_speed"] = _flat_speed("angle", t, pot, fa, b, tail)[0]
                    entry["tacho_v"] = sp * run.kt
                elif run.has_tacho:
                    entry["tacho_v"] = sp * run.kt
        if not entry["settled"] and b - a >= 10:
            # a level where the motor never moves (lead-in, inside the deadband) is
            # steady from its start: both halves at rest
            h = a + (b - a) // 2
            sp1 = _flat_speed(kind, t, y, a, h)[0]
            sp, spr = _flat_speed(kind, t, y, h, b)
            if abs(sp) < min_step and abs(sp1) < min_step:
                entry = {"settled": True, "speed": sp, "spread": spr, "n": b - h}
        per_level.setdefault(lab[i], []).append((i, entry))

    for j, v in enumerate(uniq):
        items = per_level.get(j, [])
        ok = [e for _, e in items if e["settled"]]
        into = [ra.edges[i - 1].tau_s for i, _ in items if i >= 1 and ra.edges[i - 1].ok]
        lvl = Level(run=run.name, v=v, speed=None, spread=None, n_segments=len(items),
                    n_settled=len(ok), moving=None,
                    tau_s=float(np.median(into)) if into else None)
        if ok:
            n = np.array([e["n"] for e in ok], float)
            sp = np.array([e["speed"] for e in ok])
            lvl.speed = float(np.sum(n * sp) / n.sum())
            sprs = [e["spread"] for e in ok if e["spread"] is not None]
            within = float(np.sqrt(np.mean(np.square(sprs)))) if sprs else 0.0
            between = float(np.std(sp, ddof=1)) if len(sp) > 1 else 0.0
            lvl.spread = float(math.hypot(within, between)) if (sprs or len(sp) > 1) else None
            lvl.moving = bool(abs(lvl.speed) > max(min_step, 3 * (between or 0.0)))
            tv = [e["tacho_v"] for e in ok if "tacho_v" in e]
            lvl.tacho_v = float(np.mean(tv)) if tv else None
            ps = [e["pot_speed"] for e in ok if "pot_speed" in e]
            lvl.pot_speed = float(np.mean(ps)) if ps else None
        ra.levels.append(lvl)
    ra.levels.sort(key=lambda L: L.v)
    if not any(L.speed is not None and abs(L.v) > vtol for L in ra.levels):
        longest = float(max(ends[1:] - starts[1:]) * dt)
        raise AnalysisError(
            f"{where}: no level settles: after its edges the input is held at most {longest:.3g} s "
            "but the speed needs "
            f"about {SETTLE_TAUS:g} time constants ({SETTLE_TAUS * (tau_run or 0):.3g} s) to "
            "settle; use longer levels (a lower square-wave frequency or longer steps)")

    # Kt cross-check: tacho volts against motor speed from the pot on the flat parts
    pairs = [(L.tacho_v, L.pot_speed) for L in ra.levels
             if L.tacho_v is not None and L.pot_speed is not None and L.moving]
    if pairs:
        vt, wp = np.array(pairs).T
        if np.sum(wp ** 2) > 0:
            ra.kt_est = float(np.sum(vt * wp) / np.sum(wp ** 2))
    ra._trace = {"t": t, "u": u, "kind": kind, "y": y, "starts": starts, "ends": ends,
                 "levels": lv}
    return ra


# -- across runs ----------------------------------------------------------------------

def _group_amplitudes(absv, rel=0.02):
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


def _gain_trend(v, w, tol):
    """Trend of w/V with amplitude from the steady points (moving, |V| > 0)."""
    v, w = np.asarray(v, float), np.asarray(w, float)
    km = w / v
    a = np.abs(v)
    groups = _group_amplitudes(a)
    by_amp = [(float(np.mean(a[g])), float(np.mean(km[g]))) for g in groups]
    info = {"km_by_amplitude": by_amp, "threshold": tol}
    if len(groups) < 2:
        info["relative_change"] = None
        info["note"] = "one amplitude only: the trend with amplitude cannot be judged"
        return "constant", info
    # straight line of w/V against |V|: relative change over the amplitude range
    A = np.column_stack([a, np.ones_like(a)])
    coef, *_ = np.linalg.lstsq(A, km, rcond=None)
    span = a.max() - a.min()
    mean = float(np.mean(km))
    r = float(coef[0] * span / mean)
    se = None
    if len(a) > 2:
        resid = km - A @ coef
        s2 = float(resid @ resid) / (len(a) - 2)
        cov = s2 * np.linalg.pinv(A.T @ A)
        se = float(math.sqrt(max(cov[0, 0], 0.0)) * span / abs(mean))
    thr = max(tol, 2 * se) if se is not None else tol
    info.update({"relative_change": r, "standard_error": se, "threshold": thr,
                 "amplitude_range_v": [float(a.min()), float(a.max())]})
    if abs(r) <= thr:
        return "constant", info
    return ("rising" if r > 0 else "falling"), info


def _fit_line(v, w):
    """w = k V + c_fwd [V > 0] + c_rev [V < 0] with one slope; per-direction slopes too."""
    v, w = np.asarray(v, float), np.asarray(w, float)
    lf = LineFit(n_points=len(v))
    fwd, rev = v > 0, v < 0

    def ndistinct(mask):
        return len(_group_amplitudes(np.abs(v[mask]))) if mask.any() else 0
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
    A = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(A, w, rcond=None)
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
            kk = float(np.polyfit(v[m], w[m], 1)[0])
            setattr(lf, f"km_{nm}", kk)
    return lf


def _summarise(ra_list, levels, tol, kt_configured=None, kt_est=None, source="runs",
               tau_by_kind=None, extra_verdict=""):
    """Line fit, trend, deadband, verdict from the pooled steady levels."""
    pts = [L for L in levels if L.speed is not None and L.moving and abs(L.v) > 1e-9]
    if not pts:
        raise AnalysisError("no input level moved the motor; raise the amplitude above the "
                            "deadband (try 1-2 V) and record again")
    v = np.array([L.v for L in pts])
    w = np.array([L.speed for L in pts])
    trend, info = _gain_trend(v, w, tol)
    # direction asymmetry of the steady speed at matching amplitudes
    asym = {}
    fw = {round(abs(L.v), 2): abs(L.speed) for L in pts if L.v > 0}
    rv = {round(abs(L.v), 2): abs(L.speed) for L in pts if L.v < 0}
    common = sorted(set(fw) & set(rv))
    if common:
        ratios = [fw[a] / rv[a] for a in common if rv[a] > 0]
        if ratios:
            asym["speed_ratio_fwd_rev"] = float(np.mean(ratios))
    info["asymmetry"] = asym

    # above a saturation the slope is not the motor's: keep the unsaturated levels
    use = np.ones(len(v), bool)
    if trend == "falling":
        km_app = w / v
        for sgn in (1, -1):
            m = np.sign(v) == sgn
            if m.any():
                use[m] = km_app[m] >= (1 - 2 * tol) * km_app[m].max()
    line = _fit_line(v[use], w[use])
    if trend == "falling" and line.region == "single_level":
        # no linear region observed: the incremental gain of what was measured
        line = _fit_line(v, w)
        line.region = "saturated"
        line.deadband_fwd = line.deadband_rev = None
    deadband = line.deadband
    if deadband is not None and (deadband < -0.25 * np.abs(v).min() or
                                 deadband > np.abs(v).max()):
        deadband = None   # the line meets zero far outside the data: no deadband reading

    # stiction: a level at rest although the line predicts motion
    breakaway = None
    if deadband is not None:
        still = [abs(L.v) for L in levels if L.speed is not None and L.moving is False
                 and abs(L.v) > max(deadband, 0.0) + 0.02 * np.abs(v).max()]
        if still:
            moving = [abs(L.v) for L in pts if abs(L.v) > max(still)]
            breakaway = float(min(moving)) if moving else None
            info["at_rest_above_deadband_v"] = float(max(still))

    taus = [e.tau_s for r in ra_list if isinstance(r, RunAnalysis) for e in r.edges if e.ok]
    tau = float(np.median(taus)) if taus else None
    kt_mismatch = None
    if kt_est is not None and kt_configured is not None:
        kt_mismatch = bool(abs(kt_est / kt_configured - 1) > KT_TOLERANCE)
    verdict = _verdict(trend, info, line, deadband, breakaway, tau, kt_est, kt_configured,
                       kt_mismatch, tau_by_kind, pts) + extra_verdict
    return AnalysisResult(deadband_v=deadband, km=line.km, tau_s=tau, kt=kt_est,
                          gain_trend=trend, runs=ra_list, verdict=verdict, line=line,
                          trend=info, breakaway_v=breakaway, kt_configured=kt_configured,
                          kt_mismatch=kt_mismatch, tolerance=tol, source=source,
                          levels=levels)


def _verdict(trend, info, line, deadband, breakaway, tau, kt_est, kt_cfg, kt_mismatch,
             tau_by_kind, pts) -> str:
    kb = info.get("km_by_amplitude", [])
    rng = ""
    if len(kb) >= 2:
        rng = (f"w/V goes from {kb[0][1]:.4g} to {kb[-1][1]:.4g} rad/s per V between "
               f"{kb[0][0]:.3g} and {kb[-1][0]:.3g} V")
    thr = info.get("threshold", GAIN_TOLERANCE) * 100
    s = []
    if trend == "constant":
        if len(kb) < 2:
            s.append("Only one amplitude was recorded, so the trend of w/V with amplitude "
                     "cannot be judged; record square waves at three or more amplitudes.")
        else:
            s.append(f"{rng} (constant within {thr:.1f} %): the plant is linear over this "
                     "range; a deadband, friction or saturation, if any, lies outside it — "
                     "a staircase from 0.1 V upwards would reveal a threshold.")
    elif trend == "rising":
        d = f"about {deadband:.2f} V" if deadband is not None else "a threshold voltage"
        lean = ""
        if tau_by_kind and "reversal" in tau_by_kind and "from_rest" in tau_by_kind:
            # Coulomb friction flips sign at zero speed inside a reversal and shortens
            # its apparent tau; a start from rest stays first-order (tau unchanged);
            # a deadband leaves both alike
            tr, tf = tau_by_kind["reversal"], tau_by_kind["from_rest"]
            if tr < (1 - 0.04) * tf:
                lean = (f" Reversals look faster than starts from rest (tau {tr * 1e3:.0f} vs "
                        f"{tf * 1e3:.0f} ms), which leans towards Coulomb friction.")
            elif abs(tr / tf - 1) <= 0.04:
                lean = (f" Reversals and starts from rest have the same tau ({tr * 1e3:.0f} vs "
                        f"{tf * 1e3:.0f} ms), which leans towards a deadband.")
        s.append(f"{rng} (rising by more than {thr:.1f} %): each level loses {d} before the "
                 "motor turns — a deadband (amplifier input stage, brushes) or Coulomb "
                 "friction, which give the same steady-state line." + lean +
                 " To separate them, apply a slow ramp of u through zero while recording "
                 "the amplifier output voltage and a step to 0 V: a deadband shows in the "
                 "amplifier output itself and lets the speed coast down exponentially, "
                 "friction leaves the amplifier output linear and stops the motor in "
                 "finite time with a kink at zero speed.")
    else:
        wsat = max(abs(L.speed) for L in pts)
        s.append(f"{rng} (falling by more than {thr:.1f} %) while the speed levels off near "
                 f"{wsat:.0f} rad/s ({wsat * 30 / math.pi:.0f} rpm): saturation — the "
                 "amplifier's output rail, a current limit or a clipped speed readout. "
                 "To separate them, measure the amplifier output voltage and the armature "
                 "current at the highest level (a rail clips the voltage, a current limit "
                 "shows as a constant-slope start of each edge, a readout clip leaves both "
                 "rising) and repeat at lower voltages to find where the linear region ends.")
        if line.region == "saturated":
            s.append("No level lies in the linear region, so the motor's Km cannot be read "
                     "from these data; the reported km is the incremental gain of the "
                     "saturated levels.")
    if breakaway is not None:
        s.append(f"The motor stayed at rest at {info['at_rest_above_deadband_v']:.3g} V although "
                 f"the line predicts motion above {deadband:.3g} V: stiction, breakaway at "
                 f"{breakaway:.3g} V or less.")
    if line.region == "saturated":
        pass
    elif line.km_fwd and line.km_rev and abs(line.km_fwd / line.km_rev - 1) > GAIN_TOLERANCE:
        s.append(f"Forward and reverse gains differ ({line.km_fwd:.4g} vs {line.km_rev:.4g} "
                 "rad/s per V): an asymmetric amplifier or brush timing.")
    elif line.deadband_fwd is not None and line.deadband_rev is not None and \
            abs(line.deadband_fwd - line.deadband_rev) > 0.05:
        s.append(f"The deadband differs by direction ({line.deadband_fwd:.3f} V forward, "
                 f"{line.deadband_rev:.3f} V reverse): an amplifier offset of about "
                 f"{(line.deadband_fwd - line.deadband_rev) / 2:.3f} V.")
    if kt_mismatch:
        s.append(f"The tacho sensitivity measured from the pot is {kt_est:.4g} V per rad/s, "
                 f"not the configured {kt_cfg:.4g}: check sensors.tacho_v_per_rad_s, "
                 "rig.gear_ratio and sensors.pos_v_per_rad in the sidecar (speeds and km "
                 "above use the configured value).")
    return " ".join(s)


def analyse(paths, *, tolerance: float = GAIN_TOLERANCE) -> AnalysisResult:
    """Analyse a dataset (folders and/or run files) or a steady-state table.

    Parameters
    ----------
    paths : str, Path, list of them, or list of Run
        Runs to analyse; a single steady-state table CSV (like
        ``data/paper_table1.csv``) is analysed as such.
    tolerance : float
        Relative change of w/V over the amplitude range still called constant.

    Returns
    -------
    AnalysisResult

    Raises
    ------
    AnalysisError, RunFileError
        With the file or run name and how to fix it.
    """
    from .runs import Run, read_dataset
    from .table1 import is_table

    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = list(paths)
    if len(paths) == 1 and not isinstance(paths[0], Run) and is_table(Path(paths[0])):
        return analyse_table(paths[0], tolerance=tolerance)
    runs = paths if paths and all(isinstance(p, Run) for p in paths) else read_dataset(paths)
    results: list[RunAnalysis] = []
    errors = []
    for run in runs:
        try:
            results.append(analyse_run(run))
        except AnalysisError as exc:
            if len(runs) == 1:
                raise
            errors.append(str(exc))
            results.append(RunAnalysis(name=run.name, loop=run.loop, fs=run.fs,
                                       skipped=str(exc)))
    good = [r for r in results if not r.skipped]
    if not good:
        why = "; ".join(errors) if errors else "every run is closed-loop"
        raise AnalysisError(f"{', '.join(map(str, paths))}: no open-loop run could be "
                            f"analysed ({why}); record open-loop square waves or steps "
                            "(`labrig sweep`)")
    levels = [L for r in good for L in r.levels]
    # Kt: pooled over runs with both sensors
    pairs = [(L.tacho_v, L.pot_speed) for L in levels
             if L.tacho_v is not None and L.pot_speed is not None and L.moving]
    kt_est = None
    if pairs:
        vt, wp = np.array(pairs).T
        kt_est = float(np.sum(vt * wp) / np.sum(wp ** 2))
    kcfg = [r.kt_configured for r in good if r.kt_configured is not None]
    kt_cfg = float(np.median(kcfg)) if kcfg else None
    tbk = {}
    for r in good:
        for e in r.edges:
            if e.ok:
                tbk.setdefault(e.kind, []).append(e.tau_s)
    tau_by_kind = {k: float(np.median(v)) for k, v in tbk.items()}
    return _summarise(results, levels, tolerance, kt_configured=kt_cfg, kt_est=kt_est,
                      tau_by_kind=tau_by_kind)


def analyse_table(path, *, tolerance: float = GAIN_TOLERANCE) -> AnalysisResult:
    """Analyse a steady-state table (input_v, speed_rpm[, tacho_v]) like the paper's Table 1.

    Only steady states: ``tau_s`` is None; ``kt`` is the median of tacho_v / w when
    the table has a tacho voltage column.
    """
    from .table1 import read_table1

    path = Path(path)
    df = read_table1(path)
    name = path.stem
    levels = []
    for _, r in df.iterrows():
        w = float(r["omega_rad_s"])
        lv = Level(run=str(r.get("test", name)), v=float(r["input_v"]), speed=w, spread=None,
                   n_segments=1, n_settled=1, moving=bool(abs(w) > 0),
                   tacho_v=float(r["tacho_v"]) if "tacho_v" in df and not pd.isna(r["tacho_v"])
                   else None)
        levels.append(lv)
    if len(levels) < 1:
        raise AnalysisError(f"{path}: the table has no rows")
    kt = None
    kt_cfg = None
    if "tacho_v" in df:
        ok = df["omega_rad_s"].abs() > 0
        if ok.any():
            kt = float(np.median(df.loc[ok, "tacho_v"] / df.loc[ok, "omega_rad_s"]))
    for c in ("kt_v_per_rad_s", "kt"):
        if c in df and df[c].notna().any():
            kt_cfg = float(df[c].median())
    extra = ""
    if "tacho_v" in df and len(df) >= 2:
        tv = df["tacho_v"].abs()
        if tv.max() - tv.min() < 0.05 * tv.max():
            extra = (f" The tacho voltage is flat too ({tv.min():.3f} to {tv.max():.3f} V), so "
                     "the limit is in the drive, not in the rpm display.")
    run_entry = {"name": name, "loop": "open", "skipped": None, "sensor": "table",
                 "tau_s": None, "kt_est": kt,
                 "levels": [{"v": L.v, "speed_rad_s": L.speed, "speed_rpm": L.speed * 30 / math.pi,
                             "km_paper": L.km_paper, "tacho_v": L.tacho_v, "test": L.run}
                            for L in levels],
                 "notes": ["steady-state table: no transients, so no time constant"]}
    res = _summarise([run_entry], levels, tolerance, kt_configured=kt_cfg, kt_est=kt,
                     source="table", extra_verdict=extra)
    res.tau_s = None
    return res


# -- JSON safety -----------------------------------------------------------------------

def _clean(o):
    """NaN/inf -> None, numpy scalars -> Python, recursively."""
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, (np.bool_,)):
        return bool(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (float, np.floating)):
        f = float(o)
        return f if math.isfinite(f) else None
    if isinstance(o, np.ndarray):
        return _clean(o.tolist())
    return o


__all__ = ["analyse", "analyse_run", "analyse_table", "find_segments", "fit_edge",
           "AnalysisResult", "RunAnalysis", "EdgeFit", "Level", "LineFit", "GAIN_TOLERANCE"]
