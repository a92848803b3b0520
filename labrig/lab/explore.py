"""Try the model by hand: a slider for every parameter of the current model, the model
redrawn on the runs as the student drags, an effect tried at a hand-set size before any
fit says, and a fit started from the hand-set values.

A thin view over the verbs: each move is ``lr.compare(runs, model)`` on every run (the
rmse/noise it shows is the library's, every sample counted), and the run on screen is
redrawn in place (:class:`labrig.diagnosis.results.interactive.RunView`, through
``labrig.verbs.figures``). It runs in the page's own process: a simulation of the six-run
sweep takes milliseconds, so a move does not wait for the worker that fits.
"""
from __future__ import annotations

import math
from pathlib import Path

import panel as pn
from bokeh.models import PrintfTickFormatter

import labrig.verbs as lr
import labrig.verbs.figures as lrf
from labrig.core.errors import LabrigError

#: a slider spans the fitted value divided and multiplied by this (within the
#: parameter's own bounds): the range a hand can explore around what the data say
SPAN = 4.0
#: positions of a slider
STEPS = 400


class Explorer:
    """The hand-set model on the page. ``fit_from(model_doc)`` is the station's fit."""

    def __init__(self, folders, fit_from, css: str = "lab-try"):
        self.folders, self.fit_from = folders, fit_from
        self.model = None          # the hand-set Model
        self.fitted = None         # the rung's Model the sliders started from
        self._runs, self._runs_key = None, None
        self._view = None
        self.ev = None
        self.number = pn.pane.Markdown("", css_classes=[f"{css}-rmse"])
        self.run_pick = pn.widgets.Select(name="run", options=[], width=220,
                                          css_classes=[f"{css}-run"])
        self.run_pick.param.watch(lambda e: self._show(), "value")
        self.plots = pn.Column(sizing_mode="stretch_width",
                               css_classes=[f"{css}-plots", "lab-overlay"])
        self.sliders = pn.Column(width=330, css_classes=[f"{css}-sliders"])
        self.try_pick = pn.widgets.Select(name="try an effect (unfitted)", options=[],
                                          width=220, css_classes=[f"{css}-pick"])
        self.try_btn = pn.widgets.Button(name="Try", width=80, css_classes=[f"{css}-add"])
        self.reset_btn = pn.widgets.Button(name="Back to the fit", width=130,
                                           css_classes=[f"{css}-reset"])
        self.fit_btn = pn.widgets.Button(name="Fit from here", button_type="primary",
                                         width=130, css_classes=[f"{css}-fit"])
        self.error = pn.pane.Alert("", alert_type="danger", visible=False)
        self.try_btn.on_click(lambda e: self._try())
        self.reset_btn.on_click(lambda e: self.set_model(self.fitted))
        self.fit_btn.on_click(lambda e: self._fit_here())
        self.view = pn.Row(
            pn.Column(self.number, self.run_pick, self.sliders,
                      pn.Row(self.try_pick, self.try_btn), pn.Row(self.reset_btn, self.fit_btn),
                      self.error, width=350),
            self.plots, sizing_mode="stretch_width")
        self.drivers = [self.try_btn, self.reset_btn, self.fit_btn]

    # -- the data and the model ------------------------------------------------------
    def runs(self, look: bool = True):
        """The runs of the station's folders; ``look``: read the folders' listing again
        (a new model, a tried effect), else the runs already read (a slider's move)."""
        if not look and self._runs is not None:
            return self._runs
        folders = [str(f) for f in self.folders()]
        key = tuple((f, tuple(sorted(p.name for p in Path(f).glob("*.csv")))) for f in folders)
        if key != self._runs_key:
            self._runs, self._runs_key = lr.read_runs(folders), key
        return self._runs

    def set_model(self, model, fitted: bool = False, why: str = "") -> None:
        """Start from ``model`` (a Model, or a rung's JSON; ``fitted``: a rung's fit, the
        one the sliders mark and *Back to the fit* returns to; ``why``: what it is, when
        neither that nor set by hand): its sliders, its curves."""
        if model is None:
            return
        if isinstance(model, dict):
            model = lr.model_from_json(model, "the lab page's model")
        if fitted or self.fitted is None:
            self.fitted = model
        self.model, self._why = model, why
        self._look = True   # a sweep may have added runs since: the next redraw looks
        self._build_sliders()
        names = set(model.names)
        self.try_pick.options = [n for n in lr.effects() if n not in names]
        self.redraw()

    def _build_sliders(self) -> None:
        m, rows = self.model, []
        plant = m.plant_class
        items = [(k, m.params[k], plant.units.get(k, ""), plant.bounds.get(k)) for k in plant.names]
        for e in m.effects:
            for p in e.params:
                items.append((f"{e.name}.{p.name}", m.effect_params[e.name][p.name], p.unit,
                              (p.lower, p.upper)))
        fitted = self.fitted.flat() if self.fitted is not None else {}
        shown = lr.drive_units(m)   # an effect's level in N m or N on such a drive
        self._generation += 1   # a move still queued on the sliders replaced is dropped
        gen = self._generation
        for key, value, unit, bounds in items:
            label, f = key, 1.0
            if key in shown:
                label, f, unit = shown[key]
                bounds = tuple(b * f for b in bounds) if bounds else bounds
            value = float(value) * f
            lo, hi = _span(value, bounds)
            mark = fitted.get(key)
            s = LiveSlider(
                name=f"{label} ({unit})" + (f", fitted {mark * f:.4g}" if mark is not None
                                            else ", unfitted"),
                start=lo, end=hi, step=(hi - lo) / STEPS, value=min(max(float(value), lo), hi),
                format=PrintfTickFormatter(format="%.4g"), width=320,
                css_classes=["lab-param", f"lab-param-{_css(key)}"])
            s.param.watch(lambda e, key=key, f=f, gen=gen: self._slide(key, e.new / f, gen),
                          "value")
            rows.append(s)
        self.sliders.objects = rows

    # -- moves -----------------------------------------------------------------------
    _generation = 0
    _why = ""
    _look = True
    _detailed = False   # self.ev has the regimes (not a slider's quick evaluation)

    def _slide(self, key: str, value: float, gen: int) -> None:
        if gen != self._generation:
            return
        self.model, self._why = self.model.with_value(key, value), ""
        self.redraw(moved=True)

    def redraw(self, moved: bool = False) -> None:
        """The hand-set model on every run (the library's numbers), the picked run drawn.
        ``moved``: a slider's move, handled under the document's lock (a
        :class:`LiveSlider`'s change): the numbers and the model's curves only, drawn
        at once (the run's regimes are the data's, and stay as drawn)."""
        self.error.visible = False
        try:
            self.ev = lr.compare(self.runs(look=self._look), self.model, detail=not moved)
            self._look, self._detailed = False, not moved
        except LabrigError as exc:
            self.error.object, self.error.visible = str(exc).splitlines()[0], True
            return
        rm = self.ev.metrics["rmse_over_noise"]
        label = " + ".join(["linear"] + self.model.names)
        hand = ("" if self.model is self.fitted else f" ({self._why})" if self._why
                else " (set by hand, not fitted)")
        # (a Bokeh Div here went out with the curves, but its every change made the
        # browser lay out the whole page again: slower)
        self.number.object = (f"### rmse/noise {rm['overall']:.2f}\n{label}{hand}; "
                              + ", ".join(f"{ch} {v:.2f}" for ch, v in rm.items()
                                          if ch != "overall"))
        names = [rr["name"] for rr in self.ev.per_run]
        if self.run_pick.options != names:
            self.run_pick.options = names
            self.run_pick.value = self.ev.worst_run()["name"]
        self._show(moved)

    def _show(self, moved: bool = False) -> None:
        if self.ev is None or self.run_pick.value is None:
            return
        if not moved and not self._detailed:   # another run after a move: its regimes
            self.ev, self._detailed = lr.compare(self.runs(look=False), self.model), True
        rr = self.ev.run(self.run_pick.value)
        if self._view is None or self._view.channels != lrf.drawn_channels(rr):
            self._view = lrf.run_view(rr)
            self.plots.objects = [pn.pane.Bokeh(self._view.layout, sizing_mode="stretch_width")]
        elif moved:
            self._view.show(rr)
        else:
            view = self._view
            under_lock(view.layout, lambda: view.show(rr))

    def _try(self) -> None:
        if self.model is None or not self.try_pick.value:
            return
        try:
            self.set_model(lr.try_effect(self.runs(), self.model, self.try_pick.value))
        except LabrigError as exc:
            self.error.object, self.error.visible = str(exc).splitlines()[0], True

    def _fit_here(self) -> None:
        if self.model is not None:
            self.fit_from(self.model.to_json())


def hand_view(source, model) -> Explorer:
    """*Try it by hand* in a notebook: the lab page's hand view (a slider for every
    parameter, the curves and rmse/noise redrawn as one moves, an effect tried
    unfitted) on the runs of ``source`` (a folder or a list of folders), starting from
    ``model`` (a Model, a model file or a fit); *Fit from here* fits in this process
    from the hand-set values (``labrig identify --model ... --starts 1``). Display its
    ``view`` (``pn.extension()`` first); ``model`` and ``ev`` are the hand-set model
    and its :class:`~labrig.diagnosis.evidence.evaluation.Evaluation`."""
    folders = [source] if isinstance(source, (str, Path)) else list(source)

    def fit_from(doc):
        start = lr.model_from_json(doc, "the hand-set model")
        ex.set_model(lr.model_of(lr.identify(folders, model=start, starts=1)), fitted=True)

    ex = Explorer(lambda: folders, fit_from)
    ex.set_model(lr.model_of(model), fitted=True)
    return ex


class LiveSlider(pn.widgets.FloatSlider):
    """A slider whose every move is handled at the next turn of the server's loop.
    Panel waits 50 ms after a widget's change (``Syncable._debounce``) to gather the
    ones that follow: half the 0.1 s a move may take to redraw. Moves that arrive while
    one is handled are still gathered into one (Panel's queue of pending events), so a
    drag never queues more than one re-simulation. The change is handled as a timeout
    callback of the session, under the document's lock, so the curves are redrawn from
    it directly (``Explorer.redraw(moved=True)``). (Panel's ``_priority_changes``, the
    other way to skip the wait, handles the change without the lock: Bokeh refused the
    curves' change from there.)"""

    _debounce = 0


def under_lock(model, job) -> None:
    """Run ``job`` (a change to the Bokeh ``model`` or its page) now when ``model`` is on
    no page, else at its document's next tick, under the document's lock: a Bokeh figure
    already on the page changes only under it, and a button's click or a figure's event is
    handled without it (Bokeh refused the change, and the curves stayed as they were)."""
    doc = model.document
    doc.add_next_tick_callback(job) if doc is not None else job()


def _span(value: float, bounds) -> tuple[float, float]:
    """The slider's range: the value divided and multiplied by :data:`SPAN` (a value at
    or below zero: as far either side), within the parameter's bounds."""
    lo_b, hi_b = bounds if bounds else (-math.inf, math.inf)
    if value > 0:
        lo, hi = value / SPAN, value * SPAN
    else:
        w = max(abs(value) * SPAN, 0.1 if hi_b == math.inf else 0.1 * (hi_b - lo_b))
        lo, hi = value - w, value + w
    lo, hi = max(lo, lo_b), min(hi, hi_b)
    return (lo, hi) if hi > lo else (lo_b, hi_b)


def _css(key: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in key)
