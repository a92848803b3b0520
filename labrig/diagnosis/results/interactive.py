"""The model against one run as interactive (Bokeh) figures: what the lab page shows and
a notebook gets from ``Evaluation.view()``.

Per channel (speed, position, current where present), the measurement and the model on
one figure and the residual in noise units below it, every time axis linked (zoom into a
reversal on one and the others follow); the residual's +-1 noise band, the +-1 quantum of
a quantised sensor (a staircase inside it is the sensor's resolution) and the stretches
that leave the band shaded by regime, as the PNG of :func:`labrig.diagnosis.results.plots.
plot_run_comparison`; hovering gives the time, the measured and model values and the
residual. :meth:`RunView.show` redraws it from a new evaluation in place (a slider's move),
without building new figures.

What is drawn is the samples in view, at most :data:`MAX_POINTS` per line (every
sample once the student zooms in that far): a zoom or a pan asks for the samples of
the new window. A slider's move sends only the model's columns of that window: a
browser re-drawing six lines of 8500 points (a 1 kHz run) took most of the move's whole
budget (0.1 s); at 1000, about one per pixel of the page's figure, it keeps within it.
"""
from __future__ import annotations

import numpy as np
from bokeh.events import RangesUpdate, Reset
from bokeh.layouts import column
from bokeh.models import (BoxAnnotation, ColumnDataSource, DataRange1d, FactorRange, HoverTool,
                          Legend, LegendItem, Range1d, Span)
from bokeh.plotting import figure

from labrig.diagnosis.evidence.residuals import AXIS_UNITS, REGIME_TEXT

#: the regimes' colours, as the PNG figures draw them (matplotlib's tab10)
REGIME_COLOURS = {"start": "#2ca02c", "reversal": "#d62728", "accel": "#ff7f0e",
                  "steady": "#1f77b4", "coast": "#9467bd", "rest": "#b3b3b3"}
#: at most this many points per line are drawn (rmse/noise is computed on every sample)
MAX_POINTS = 1000


def drawn_channels(rr: dict) -> tuple:
    """The channels a :class:`RunView` draws for the run ``rr``: its own, and the
    measured current beside them where the run has one."""
    return tuple(rr["channels"]) + (("current",) if rr.get("current") else ())


def _channel(rr: dict, ch: str):
    return rr.get("current") if ch == "current" else rr["channels"].get(ch)


class RunView:
    """Figures for the channels ``channels`` of one run at a time (``show`` fills them)."""

    def __init__(self, channels=("speed", "position"), width: int | None = None,
                 height: int = 190):
        self.channels = tuple(channels)
        self.sources, self.stretches, self.quanta, self.figures = {}, {}, {}, []
        self._shown, self._length = None, 0
        self._full, self._window, self._t = {}, slice(0, 0), np.zeros(0)
        self.x_range = Range1d(0.0, 1.0, name="run-view-time")
        size = dict(width=width) if width else dict(sizing_mode="stretch_width")
        for ch in self.channels:
            src = ColumnDataSource({"t": [], "measured": [], "model": [], "residual": []},
                                   name=f"run-view-{ch}")
            f = figure(height=height, x_range=self.x_range, tools="xpan,xwheel_zoom,box_zoom,reset",
                       active_scroll="xwheel_zoom", title=ch, **size)
            m = f.line("t", "measured", source=src, color="#404040", line_width=1.2)
            s = f.line("t", "model", source=src, color="#d62728", line_width=1.4,
                       line_dash="dashed")
            f.add_layout(Legend(items=[LegendItem(label="measured", renderers=[m]),
                                       LegendItem(label="model", renderers=[s])],
                                location="top_left", orientation="horizontal"), "above")
            f.add_tools(HoverTool(renderers=[m], mode="vline", tooltips=[
                ("t", "@t{0.000} s"), ("measured", "@measured{0.000}"),
                ("model", "@model{0.000}"), ("residual", "@residual{0.00} noise")]))
            r = figure(height=int(height * 0.7), x_range=self.x_range,
                       tools="xpan,xwheel_zoom,box_zoom,reset", active_scroll="xwheel_zoom",
                       y_axis_label="residual / noise", **size)
            r.add_layout(BoxAnnotation(bottom=-1.0, top=1.0, fill_color="#2ca02c",
                                       fill_alpha=0.15, line_alpha=0.0))
            quanta = (Span(location=0.0, dimension="width", line_dash="dashed", line_color="black",
                           line_width=1, visible=False),
                      Span(location=0.0, dimension="width", line_dash="dashed", line_color="black",
                           line_width=1, visible=False))
            for q in quanta:
                r.add_layout(q)
            band = ColumnDataSource({"left": [], "right": [], "color": [], "regime": []})
            r.quad(left="left", right="right", bottom=-1e6, top=1e6, color="color",
                   alpha=0.22, source=band, line_alpha=0.0)
            line = r.line("t", "residual", source=src, color="#4d4d4d", line_width=0.8)
            # the residual and its noise band set the scale, not the regimes' shading
            band_edges = r.scatter(x=[0.0, 0.0], y=[-1.2, 1.2], alpha=0.0, size=0)
            r.y_range = DataRange1d(renderers=[line, band_edges])
            r.add_tools(HoverTool(renderers=[line], mode="vline", tooltips=[
                ("t", "@t{0.000} s"), ("residual", "@residual{0.00} noise")]))
            self.sources[ch], self.stretches[ch], self.quanta[ch] = src, band, quanta
            self.figures += [f, r]
        for f in self.figures:
            f.on_event(RangesUpdate, self._zoomed)
            f.on_event(Reset, self._reset)
        self.figures[-1].xaxis.axis_label = "time (s)"
        # one toolbar in view, above the first figure: each figure's own, at its side, was
        # too short to show its tools (reset hid behind "..."); the others' tools still
        # act (the time axis is shared: a zoom or a reset on one is on all)
        self.figures[0].toolbar_location = "above"
        for f in self.figures[1:]:
            f.toolbar_location = None
        self.layout = column(*self.figures, **({} if width else {"sizing_mode": "stretch_width"}))

    def show(self, rr: dict) -> None:
        """Draw the run ``rr`` (an entry of :attr:`Evaluation.per_run`)."""
        t = np.asarray(rr["t"], float)
        units = rr.get("units") or AXIS_UNITS["rotary"]
        same = rr["name"] == self._shown and len(t) == self._length
        if len(t) and not same:   # the same run again (a slider's move): the zoom stays
            self.x_range.start, self.x_range.end = float(t[0]), float(t[-1])
            # (what the toolbar's reset returns to: else the first run the view showed)
            self.x_range.reset_start, self.x_range.reset_end = float(t[0]), float(t[-1])
        self._shown, self._length, self._t = rr["name"], len(t), t
        for i, ch in enumerate(self.channels):
            c = _channel(rr, ch)
            if c is None:
                self._full.pop(ch, None)
                continue
            self.figures[2 * i].title.text = (
                f"{ch} ({units.get(ch, 'A')}): fit {c['fit_percent']:.1f} %, "
                f"rmse/noise {c['rmse_over_noise']:.2f}")
            self._full[ch] = {k: np.asarray(c[v], float) for k, v in
                              (("measured", "measured"), ("model", "simulated"),
                               ("residual", "residual"))}
            if same:   # the run's noise, quantum and regimes are the data's: unchanged
                continue
            q, sigma = c.get("quantum") or 0.0, c.get("sigma") or 0.0
            for sgn, span in zip((1, -1), self.quanta[ch]):
                span.visible = q > 0 and sigma > 0
                span.location = sgn * q / sigma if span.visible else 0.0
            st = c.get("stretches") or []
            self.stretches[ch].data = {
                "left": [float(t[s["start"]]) for s in st],
                "right": [float(t[min(s["stop"], len(t) - 1)]) for s in st],
                "color": [REGIME_COLOURS.get(s["regime"], "#808080") for s in st],
                "regime": [REGIME_TEXT.get(s["regime"], s["regime"]) for s in st]}
        if same:   # only the model's columns change: only they go to the browser
            self._draw(self._window, only_model=True)
        else:
            self._draw(self._window_of(self.x_range.start, self.x_range.end))

    @property
    def drawn(self) -> slice:
        """The samples of the run drawn now: the time in view with its margins, one in
        ``step``."""
        return self._window

    def _window_of(self, start: float, end: float) -> slice:
        """The samples drawn for the time ``start``-``end`` in view: half as much again
        either side (a short pan needs nothing new), one in ``step`` so that the view
        holds at most :data:`MAX_POINTS`."""
        t = self._t
        if not len(t):
            return slice(0, 0)
        i0, i1 = np.searchsorted(t, [start, end])
        width = max(int(i1 - i0), 1)
        step = max(1, -(-width // MAX_POINTS))
        i0, i1 = max(0, int(i0) - width // 2), min(len(t), int(i1) + width // 2 + 1)
        return slice(i0 - i0 % step, i1, step)

    def _draw(self, window: slice, only_model: bool = False) -> None:
        self._window = window
        for ch in self.channels:
            full = self._full.get(ch)
            if full is None:
                self.sources[ch].data = {"t": [], "measured": [], "model": [], "residual": []}
            elif only_model:
                self.sources[ch].data.update(model=full["model"][window],
                                             residual=full["residual"][window])
            else:
                self.sources[ch].data = {"t": self._t[window],
                                         **{k: v[window] for k, v in full.items()}}

    def _reset(self, event) -> None:
        """The toolbar's reset: the whole run (the browser resets the axes themselves)."""
        if len(self._t):
            self._draw(self._window_of(self._t[0], self._t[-1]))

    def _zoomed(self, event) -> None:
        """A zoom or a pan: the samples of the new window, if it needs others."""
        if event.x0 is None or event.x1 is None or not len(self._t):
            return
        window = self._window_of(event.x0, event.x1)
        inside = (window.step == self._window.step and window.start >= self._window.start
                  and window.stop <= self._window.stop)
        # the window drawn still covers the view at the resolution it needs
        if not inside or (window.stop - window.start) * 4 < (self._window.stop
                                                             - self._window.start):
            self._draw(window)


#: the two explanations of a pair, as the decision's figures colour them
PAIR_COLOURS = ("#d62728", "#1f77b4")


def pair_view(evaluations: dict, run: str | None = None, width: int | None = None,
              height: int = 200):
    """Two explanations of a pair on one run (``evaluations``: ``{effect: Evaluation}``
    of the same runs; ``run``: default the last): the measurement and each
    explanation's model per channel, its rmse/noise on those runs in the legend, time
    axes linked. What the lab page redraws after each experiment asked of the rig (on
    that experiment's run)."""
    size = dict(width=width) if width else dict(sizing_mode="stretch_width")
    evs = list(evaluations.items())
    first = evs[0][1]
    name = run or first.per_run[-1]["name"]
    rr0 = first.run(name)
    t = np.asarray(rr0["t"], float)
    step = max(1, -(-len(t) // MAX_POINTS))
    x_range = Range1d(float(t[0]), float(t[-1]) if len(t) > 1 else 1.0)
    figs = []
    for ch, c0 in rr0["channels"].items():
        f = figure(height=height, x_range=x_range, tools="xpan,xwheel_zoom,box_zoom,reset",
                   active_scroll="xwheel_zoom", title=f"{name}: {ch}", **size)
        items = [LegendItem(label="measured", renderers=[f.line(
            t[::step], np.asarray(c0["measured"], float)[::step], color="#404040",
            line_width=1.2)])]
        for (effect, ev), colour in zip(evs, PAIR_COLOURS):
            c = ev.run(name)["channels"][ch]
            r = f.line(t[::step], np.asarray(c["simulated"], float)[::step], color=colour,
                       line_width=1.4, line_dash="dashed")
            items.append(LegendItem(label=f"{effect} (rmse/noise "
                                          f"{ev.metrics['rmse_over_noise']['overall']:.2f})",
                                    renderers=[r]))
        f.add_layout(Legend(items=items, location="top_left", orientation="horizontal"),
                     "above")
        figs.append(f)
    figs[-1].xaxis.axis_label = "time (s)"
    return column(*figs, **({} if width else {"sizing_mode": "stretch_width"}))


def run_view(rr: dict, **size) -> RunView:
    """A :class:`RunView` of the run ``rr``'s channels, drawn."""
    view = RunView(drawn_channels(rr), **size)
    view.show(rr)
    return view


def ladder_figure(steps, width: int | None = None, height: int = 260):
    """The error ladder as an interactive figure: rmse/noise after each rung (overall and
    per channel), the cross-validated error where known and the noise floor at 1, on a
    log scale; hover gives each rung's numbers. ``steps``: a Ladder's ``to_json()["steps"]``
    (or its :class:`~labrig.diagnosis.results.ladder.LadderStep` objects)."""
    steps = [s.to_json() if hasattr(s, "to_json") else s for s in steps]
    labels = [f"{k}: {s['label']}" for k, s in enumerate(steps)]
    size = dict(width=width) if width else dict(sizing_mode="stretch_width")
    f = figure(x_range=FactorRange(*labels), y_axis_type="log", height=height,
               y_axis_label="rmse / noise", title="The error falls: rmse/noise after each rung",
               tools="hover,reset,save", **size)
    data = {"x": labels, "overall": [], "cv": [], "speed": [], "position": []}
    for s in steps:
        r = s.get("rmse_over_noise") or {}
        data["overall"].append(r.get("overall", np.nan))
        data["speed"].append(r.get("speed", np.nan))
        data["position"].append(r.get("position", np.nan))
        cv = s.get("cross_validated")
        data["cv"].append(np.nan if cv is None else cv)
    src = ColumnDataSource(data)
    f.line("x", "overall", source=src, line_width=2, color="#1f77b4", legend_label="overall")
    f.scatter("x", "overall", source=src, size=9, color="#1f77b4", legend_label="overall")
    for key, colour, marker in (("speed", "#ff7f0e", "square"), ("position", "#2ca02c",
                                                                  "triangle")):
        f.scatter("x", key, source=src, size=7, color=colour, marker=marker, legend_label=key)
    f.scatter("x", "cv", source=src, size=8, color="#d62728", marker="diamond",
              legend_label="cross-validated")
    f.add_layout(Span(location=1.0, dimension="width", line_dash="dotted", line_color="black"))
    f.hover.tooltips = [("rung", "@x"), ("rmse/noise", "@overall{0.00}"),
                        ("speed", "@speed{0.00}"), ("position", "@position{0.00}"),
                        ("cross-validated", "@cv{0.00}")]
    f.legend.location = "top_right"
    f.xaxis.major_label_orientation = 0.25
    return f


def ranking_figure(rows, width: int | None = None):
    """The diagnosis' ranking as an interactive figure: each move's rmse/noise after its
    re-fit (a bar, log scale; green when supported), its cross-validated error where
    known (a diamond) and the noise floor at 1; hover gives the numbers (the lab page
    draws the candidate whose row is clicked). ``rows``: the
    candidates (``Diagnosis.ranking``) or their dicts (``label``, ``rmse_over_noise``,
    ``cross_validated``, ``supported``)."""
    rows = [_row(r) for r in rows]
    labels = [r["label"] for r in rows][::-1]            # the best at the top
    size = dict(width=width) if width else dict(sizing_mode="stretch_width")
    f = figure(y_range=FactorRange(*labels), x_axis_type="log",
               height=40 + 26 * max(len(rows), 1), x_axis_label="rmse / noise after the move",
               title="The ranking: each candidate's error after its re-fit (click one to "
                     "see it)", tools="hover,tap,reset,save", **size)
    src = ColumnDataSource({
        "label": labels,
        "rmse": [r["rmse_over_noise"] for r in rows][::-1],
        "cv": [np.nan if r["cross_validated"] is None else r["cross_validated"]
               for r in rows][::-1],
        "colour": ["#2ca02c" if r["supported"] else "#9e9e9e" for r in rows][::-1],
        "supported": ["yes" if r["supported"] else "no" for r in rows][::-1]})
    f.hbar(y="label", right="rmse", left=0.5, height=0.6, color="colour", source=src,
           alpha=0.7)
    f.scatter(x="cv", y="label", marker="diamond", size=10, color="#d62728", source=src,
              legend_label="cross-validated")
    f.add_layout(Span(location=1.0, dimension="height", line_dash="dotted",
                      line_color="black"))
    f.hover.tooltips = [("move", "@label"), ("rmse/noise", "@rmse{0.00}"),
                        ("cross-validated", "@cv{0.00}"), ("supported", "@supported")]
    f.legend.location = "bottom_right"
    return f


def _row(r) -> dict:
    if isinstance(r, dict):
        return r
    cv = r.cross_validated
    return {"label": r.label, "rmse_over_noise": r.rmse_over_noise,
            "cross_validated": cv["with_effect"] if cv else None, "supported": r.supported}
