"""Figures of the missing-physics loop: model vs measurement, residuals by regime,
whiteness tests, and the error ladder.

Every function draws and returns a ``matplotlib.figure.Figure`` (on ``ax`` when one is
given); callers save it (:func:`labrig.core.figures.save`).
"""
from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from labrig.diagnosis.evidence.residuals import AXIS_UNITS, REGIME_TEXT
from labrig.core.figures import legend_outside, tight_layout

REGIME_COLOURS = {"start": "tab:green", "reversal": "tab:red", "accel": "tab:orange",
                  "steady": "tab:blue", "coast": "tab:purple", "rest": "0.7"}


def _units(rr: dict) -> dict:
    return rr.get("units") or AXIS_UNITS["rotary"]


def plot_run_comparison(rr: dict, ax=None, title: str = ""):
    """One run: measured vs simulated (fit % in the legend), residuals in noise units
    with the +-1 noise band, the +-1 quantum band of a quantised channel (its staircase
    lies inside it) and the stretches that leave the noise band shaded by regime, and
    the residual autocorrelation / input cross-correlation with their 99 % bands.
    Legends sit above their axes, where they cannot cover data.

    With ``ax``, only the first channel's overlay is drawn there (a report thumbnail).
    """
    chans = list(rr["channels"])
    if ax is not None:
        c = rr["channels"][chans[0]]
        ax.plot(rr["t"], c["measured"], color="0.25", lw=1.0, label="measured")
        ax.plot(rr["t"], c["simulated"], color="tab:red", lw=1.0, ls="--",
                label=f"model (fit {c['fit_percent']:.1f} %)")
        ax.set_xlabel("time (s)")
        ax.set_ylabel(f"{chans[0]} {_units(rr)[chans[0]]}")
        legend_outside(ax, "right")
        ax.set_title(title or rr["name"])
        return ax.figure
    fig = plt.figure(figsize=(12, 3.8 * len(chans) + 2.8))
    gs = fig.add_gridspec(2 * len(chans) + 1, 2, height_ratios=[3, 2] * len(chans) + [2.2])
    t = rr["t"]
    units = _units(rr)
    lost = rr.get("lost")
    for i, ch in enumerate(chans):
        c = rr["channels"][ch]
        ax = fig.add_subplot(gs[2 * i, :])
        ax.plot(t, _broken(c["measured"], lost), color="0.25", lw=1.0, label="measured")
        ax.plot(t, c["simulated"], color="tab:red", lw=1.0, ls="--",
                label=f"model (fit {c['fit_percent']:.1f} %)")
        start = rr.get("start") or {}
        if start.get("moving"):   # the run's fitted initial state (labrig.model.start)
            ax.plot(t[0], c["simulated"][0], "o", color="tab:red", ms=7, mfc="none", mew=1.6,
                    label="fitted start (the run starts in motion)")
        ax.set_ylabel(f"{ch}\n{units[ch]}")
        legend_outside(ax, "above")
        ax.grid(alpha=0.3)
        ax.set_xlim(t[0], t[-1])
        ax2 = fig.add_subplot(gs[2 * i + 1, :], sharex=ax)
        ax2.plot(t, _broken(c["residual"], lost), color="0.3", lw=0.6)
        for k, (a, b) in enumerate(_runs_of(lost)):  # what the link lost: no evidence
            for axis in (ax, ax2):
                axis.axvspan(t[a], t[min(b, len(t) - 1)], color="0.6", alpha=0.35, lw=0,
                             label="lost on the link (not fitted)" if k == 0 and axis is ax2
                             else None)
        _quantum_band(ax2, c, units[ch])
        ax2.axhspan(-1, 1, color="tab:green", alpha=0.15, label="noise band (+-1 sigma)")
        seen = set()
        for s in c["stretches"]:
            reg = s["regime"]
            lbl = REGIME_TEXT.get(reg, reg) if reg not in seen else None
            seen.add(reg)
            ax2.axvspan(t[s["start"]], t[min(s["stop"], len(t) - 1)],
                        color=REGIME_COLOURS.get(reg, "0.5"), alpha=0.25, label=lbl)
        ax2.set_ylabel("residual /\nnoise")
        ax2.grid(alpha=0.3)
        legend_outside(ax2, "above", fontsize=7)
    ax2.set_xlabel("time (s)")
    # whiteness of the first channel's residual
    c = rr["channels"][chans[0]]
    a = fig.add_subplot(gs[-1, 0])
    lags = np.arange(1, len(c["autocorr"]) + 1)
    a.bar(lags, c["autocorr"], color="0.4")
    a.axhspan(-c["band"], c["band"], color="tab:blue", alpha=0.2)
    a.set_title(f"{chans[0]} residual autocorrelation (99 % band; simulation residuals are "
                "coloured even for a good model)", fontsize=8)
    a.set_xlabel("lag (samples)")
    b = fig.add_subplot(gs[-1, 1])
    ks, cc = c["crosscorr"]
    b.bar(ks, cc, color="0.4")
    b.axhspan(-c["band"], c["band"], color="tab:blue", alpha=0.2)
    b.set_title("cross-correlation with input changes (peaks at lag > 0: delay or "
                "unmodelled dynamics)", fontsize=8)
    b.set_xlabel("lag (samples)")
    fig.suptitle(title or f"{rr['name']}: model vs measurement", fontsize=11)
    tight_layout(fig)
    return fig


def _broken(y, lost):
    """``y`` with the samples the link lost left out of the line (NaN breaks it)."""
    return y if lost is None else np.where(lost, np.nan, y)


def _runs_of(mask) -> list:
    """(start, stop) of each stretch where ``mask`` is True."""
    if mask is None or not mask.any():
        return []
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _quantum_band(ax, c: dict, unit: str) -> None:
    """+-1 quantisation step of the channel in noise units: a quantised reading is up to
    one step off what it measures, so a residual staircase inside this band is the
    sensor's resolution, not the model's error."""
    q, sigma = c.get("quantum") or 0.0, c.get("sigma") or 0.0
    if q <= 0 or sigma <= 0:
        return
    qn = q / sigma
    unit = unit.split(" (")[0]  # "rad/s (motor)": the qualifier is on the axis already
    for sgn, lbl in ((1, f"+-1 quantum ({c.get('quantum_kind', 'sensor step')} {q:.3g} {unit} "
                         f"= {qn:.2g} sigma): steps inside it are the sensor's resolution"),
                     (-1, None)):
        ax.axhline(sgn * qn, color="k", ls="--", lw=0.9, label=lbl)


def plot_ladder(ladder, ax=None):
    """The error ladder: rmse/noise after each added effect, against the noise floor.

    ``ladder``: a :class:`labrig.diagnosis.results.ladder.Ladder` (or its list of steps as dicts).
    """
    steps = [s.to_json() if hasattr(s, "to_json") else s
             for s in getattr(ladder, "steps", ladder)]
    fig, ax = plt.subplots(figsize=(8.5, 4)) if ax is None else (ax.figure, ax)
    x = np.arange(len(steps))
    for ch, mk in (("overall", "o-"), ("speed", "s--"), ("position", "^--")):
        y = [s["rmse_over_noise"].get(ch, np.nan) for s in steps]
        ax.plot(x, y, mk, label=ch, lw=2 if ch == "overall" else 1)
    cv = [s.get("cross_validated") for s in steps]
    if any(v is not None for v in cv):  # the error on data each fit did not see
        ax.plot(x, [np.nan if v is None else v for v in cv], "D:", color="tab:red",
                label="cross-validated (weighted)", lw=1.5)
    ax.axhline(1.0, color="k", ls=":", label="noise floor")
    ax.set_yscale("log")
    ax.set_xticks(x, [s["label"] for s in steps], rotation=15)
    ax.set_ylabel("rmse / noise")
    ax.set_title("The error ladder: adding the missing physics")
    for xi, s in zip(x, steps):
        ax.annotate(f"{s['rmse_over_noise']['overall']:.2f}", (xi, s["rmse_over_noise"]["overall"]),
                    textcoords="offset points", xytext=(6, 6), fontsize=9)
    ax.grid(alpha=0.3, which="both")
    legend_outside(ax, "right")
    tight_layout(fig)
    return fig


def plot_regimes(table: dict, ax=None, title="Where the model fails"):
    """rmse/noise by regime for each channel, with the share of time (with ``ax``: the
    first channel only, on that axes)."""
    chans = list(table["by_regime"])
    if ax is None:
        fig, axes = plt.subplots(1, len(chans), figsize=(5 * len(chans), 3.5), squeeze=False)
        pairs = list(zip(axes[0], chans))
    else:
        fig, pairs = ax.figure, [(ax, chans[0])]
    for ax, ch in pairs:
        regs = table["by_regime"][ch]
        names = list(regs)
        vals = [regs[n]["rmse_over_noise"] for n in names]
        ax.bar([REGIME_TEXT[n] for n in names], vals,
               color=[REGIME_COLOURS[n] for n in names])
        ax.axhline(1.0, color="k", ls=":")
        ax.set_title(ch)
        ax.set_ylabel("rmse / noise")
        ax.tick_params(axis="x", rotation=30, labelsize=8)
        for i, n in enumerate(names):
            ax.annotate(f"{100 * regs[n]['share_of_time']:.0f}% of time", (i, vals[i]),
                        ha="center", fontsize=7, textcoords="offset points", xytext=(0, 3))
    fig.suptitle(title)
    tight_layout(fig)
    return fig
