"""Figures of ``labrig analyse`` (matplotlib figures; the caller saves and closes them).

- ``edges_<run>.png``: every edge of a run, speed against time from the edge, with
  the first-order fit and the 63 % point (:func:`plot_edges`);
- ``speed_vs_voltage.png``: steady speed per level with its spread, the fitted line
  and the deadband (:func:`plot_speed_vs_voltage`);
- ``km_vs_amplitude.png``: the paper's Km = w/V against amplitude with the
  tolerance band that decides the gain trend (:func:`plot_km_vs_amplitude`).

Like python-control's ``time_response_plot``, each ``plot_*`` draws on the Axes it
is given or on a new figure, returns the figure and never saves it.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import matplotlib.pyplot as plt
import numpy as np

from labrig.core.figures import legend_outside, save_all, tight_layout

MAX_EDGES = 16  # per figure; more edges would make unreadable panels
DPI = 110


class FigureMap(Mapping):
    """``{file name: Figure}`` whose figures are drawn when looked up.

    The names are known without drawing anything; each lookup draws a new figure,
    so a caller that saves and closes them one by one holds one figure at a time.
    """

    def __init__(self, makers):
        self._makers = dict(makers)

    def __getitem__(self, name):
        return self._makers[name]()

    def __iter__(self):
        return iter(self._makers)

    def __len__(self):
        return len(self._makers)


def analysis_figures(res) -> FigureMap:
    """Every figure of an :class:`~labrig.analysis.AnalysisResult` by file name: the
    edges of each run with a fitted edge, then speed against voltage and Km."""
    makers = {}
    for ra in res.runs:
        if getattr(ra, "skipped", None) is None and any(e.ok for e in getattr(ra, "edges", ())):
            makers[f"edges_{ra.name}.png"] = lambda ra=ra: plot_edges(ra)
    makers["speed_vs_voltage.png"] = lambda: plot_speed_vs_voltage(res)
    makers["km_vs_amplitude.png"] = lambda: plot_km_vs_amplitude(res)
    return FigureMap(makers)


def save_figures(figs, figdir, dpi: int = DPI) -> dict:
    """Save each figure of ``figs`` as ``figdir/name``, closing each (see
    :func:`labrig.core.figures.save_all`); returns ``{name: path}``."""
    return save_all(figs, figdir, dpi)


def plot_edges(ra, ax=None):
    """One panel per fitted edge of a run: measured speed, first-order fit, 63 % point.

    Parameters
    ----------
    ra : RunAnalysis
    ax : Axes or array of Axes, optional
        One Axes per panel (the first ``len(ax)`` edges are drawn); by default a new
        figure with a grid of up to ``MAX_EDGES`` panels.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        When the run has no fitted edge.
    """
    edges = [e for e in ra.edges if e.ok][:MAX_EDGES]
    if not edges:
        raise ValueError(f"run '{ra.name}' has no fitted edge to plot")
    n = len(edges)
    if ax is None:
        ncol = min(4, n)
        nrow = math.ceil(n / ncol)
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 2.8 * nrow), squeeze=False)
    else:
        axes = np.atleast_2d(np.asarray(ax, dtype=object))
        fig = axes.flat[0].figure
    src = {"tacho": "tacho", "speed": "imported"}.get(ra.sensor, "pot (derivative, smoothed)")
    for a, e in zip(axes.flat, edges):
        _draw_edge(a, e, src)
    for a in axes.flat[n:]:
        a.axis("off")
    for a in axes[-1]:
        a.set_xlabel("time from edge (s)", fontsize=8)
    for a in axes[:, 0]:
        a.set_ylabel(f"speed ({ra.speed_unit})", fontsize=8)
    # one legend for every panel, below them all: inside a panel it would cover data
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(handles), fontsize=7,
               frameon=False)
    if ax is None:
        more = f" (first {MAX_EDGES} of {len(ra.edges)})" if len(ra.edges) > MAX_EDGES else ""
        fig.suptitle(f"{ra.name}: edges and first-order fits{more}", fontsize=10)
        tight_layout(fig, rect=(0, 0.35 / (2.8 * axes.shape[0]), 1, 1))
    return fig


def _draw_edge(ax, e, src):
    f = e.fit
    ax.plot(f.s, f.w, ".", ms=2, color="0.5", label=f"speed ({src})")
    ax.plot(f.s, f.model, "-", color="C3", lw=1.4, label="first-order fit")
    ax.axvline(0, color="0.7", lw=0.8)
    if e.tau63_s is not None:
        y63 = e.speed_from + (1 - math.exp(-1)) * (e.speed_to - e.speed_from)
        ax.plot([e.tau63_s], [y63], "o", mfc="none", color="C0", label="63 % point")
    ax.set_title(f"{e.v_from:+.2f} -> {e.v_to:+.2f} V at {e.t_s:.2f} s\n"
                 f"tau {e.tau_s * 1e3:.0f} ms, 63 %: "
                 + (f"{e.tau63_s * 1e3:.0f} ms" if e.tau63_s is not None else "-"),
                 fontsize=8)
    # eight time constants show the whole transient and a little of the flat part
    ax.set_xlim(f.s[0], min(f.s[-1], 8 * e.tau_s))
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)


def _axes(ax, figsize):
    """(figure, axes, own): a new figure unless ``ax`` is given (its layout is then
    the caller's)."""
    if ax is None:
        fig, ax = plt.subplots(figsize=figsize)
        return fig, ax, True
    return ax.figure, ax, False


#: what every plot of a whole result takes and returns, added to its docstring
_RESULT_PLOT_DOC = """

    Parameters
    ----------
    res : AnalysisResult
    ax : Axes, optional
        Draw here; by default on a new figure.

    Returns
    -------
    matplotlib.figure.Figure
    """


def _result_plot(figsize):
    """Make ``draw(res, ax)`` a ``plot_*(res, ax=None)`` of a whole result: drawn on the
    Axes given or on a new figure of ``figsize`` (then laid out tight), finished alike
    (a grid, the legend outside on the right), the figure returned."""
    def make(draw):
        def plot(res, ax=None):
            fig, ax, own = _axes(ax, figsize)
            draw(res, ax)
            ax.grid(alpha=0.3)
            legend_outside(ax, "right")
            if own:
                tight_layout(fig)
            return fig

        # not functools.wraps: the signature shown is this one, with ax optional
        plot.__name__, plot.__qualname__ = draw.__name__, draw.__qualname__
        plot.__module__ = draw.__module__
        plot.__doc__ = draw.__doc__ and draw.__doc__ + _RESULT_PLOT_DOC
        return plot
    return make


@_result_plot(figsize=(8.4, 4.6))
def plot_speed_vs_voltage(res, ax):
    """Steady speed against input voltage, the fitted line(s) and the deadband."""
    lv = [L for L in res.levels if L.speed is not None]
    mov = [L for L in lv if L.moving]
    rest = [L for L in lv if not L.moving]
    if mov:
        ax.errorbar([L.v for L in mov], [L.speed for L in mov],
                    yerr=[L.spread or 0.0 for L in mov], fmt="o", ms=4, capsize=3,
                    color="C0", label="steady speed (spread)")
    if rest:
        ax.plot([L.v for L in rest], [L.speed for L in rest], "x", color="0.4",
                label="at rest")
    _draw_line(ax, res.line, vmax=max([abs(L.v) for L in lv] + [0.1]))
    if res.deadband_v is not None and res.deadband_v > 0:
        # where the two lines meet zero speed: a rig stronger one way has a lopsided band
        fwd = res.line.deadband_fwd if res.line.deadband_fwd is not None else res.deadband_v
        rev = res.line.deadband_rev if res.line.deadband_rev is not None else res.deadband_v
        label = (f"deadband \u00b1{res.deadband_v:.3f} V" if abs(fwd - rev) < 5e-4 else
                 f"deadband -{rev:.3f} to +{fwd:.3f} V")
        ax.axvspan(-rev, fwd, color="C1", alpha=0.2, label=label)
    if res.breakaway_v is not None:
        for sgn in (1, -1):
            ax.axvline(sgn * res.breakaway_v, color="C2", ls="--", lw=1,
                       label=f"breakaway {res.breakaway_v:.3g} V" if sgn > 0 else None)
    ax.axhline(0, color="0.6", lw=0.8)
    ax.axvline(0, color="0.6", lw=0.8)
    ax.set_xlabel("input voltage Vm (V)")
    ax.set_ylabel(f"steady speed ({res.speed_unit})")
    dz = "not measurable" if res.deadband_v is None else f"{res.deadband_v:.3f} V"
    ax.set_title(f"Speed against voltage — km {_fmt(res.km, '.4g')} {res.speed_unit} per V, "
                 f"deadband {dz}", fontsize=10)


def _draw_line(ax, line, vmax):
    """The fitted line, one branch per direction."""
    if line.km is None or not line.intercepts:
        return
    for key, sgn in (("fwd", 1), ("rev", -1)):
        c = line.intercepts.get(key)
        if c is None:
            continue
        # start each branch where it meets zero speed (the deadband edge), not at 0 V
        v0 = -c / line.km if line.km else 0.0
        v0 = v0 if v0 * sgn > 0 else 0.0
        vv = np.linspace(v0, sgn * vmax * 1.05, 50)
        ax.plot(vv, line.km * vv + c, "-", color="C3", lw=1,
                label=f"fit: slope {line.km:.4g} per V" if key == "fwd" or
                "fwd" not in line.intercepts else None)


@_result_plot(figsize=(8.4, 4.2))
def plot_km_vs_amplitude(res, ax):
    """The paper's Km = w/V per level against |V|, both directions, tolerance band."""
    pts = [L for L in res.levels if L.km_paper is not None and L.moving]
    for sgn, mk, lab in ((1, "o", "forward"), (-1, "s", "reverse")):
        p = [L for L in pts if np.sign(L.v) == sgn]
        if p:
            ax.plot([abs(L.v) for L in p], [L.km_paper for L in p], mk, mfc="none",
                    label=lab)
    kb = res.trend.get("km_by_amplitude", [])
    rel = res.trend.get("relative_change")
    title = f"Km against amplitude: {res.gain_trend}"
    if kb:
        a, k = np.array(kb).T
        ax.plot(a, k, "-", color="0.3", lw=1, label="mean per amplitude")
        thr = res.trend.get("threshold", res.tolerance)
        # the trend is w/V at the largest amplitude against w/V at the smallest: a
        # constant gain keeps the last mean inside this band around the first
        ax.axhspan(k[0] * (1 - thr), k[0] * (1 + thr), color="C2", alpha=0.15,
                   label=f"constant: within \u00b1{100 * thr:.1f} %\nof w/V at {a[0]:.3g} V")
        if rel is not None and len(kb) > 1:
            title += (f", w/V {100 * rel:+.1f} % from {a[0]:.3g} to {a[-1]:.3g} V\n"
                      "(mean w/V at the largest amplitude over that at the smallest, minus 1)")
    if res.km is not None and res.line.region == "linear":
        ax.axhline(res.km, color="C3", ls="--", lw=1, label=f"incremental km {res.km:.4g}")
    ax.set_xlabel("amplitude |Vm| (V)")
    ax.set_ylabel(f"Km = w / Vm ({res.speed_unit} per V)")
    ax.set_ylim(bottom=0)
    ax.set_title(title, fontsize=9)


def _fmt(x, fmt):
    return "-" if x is None else format(x, fmt)
