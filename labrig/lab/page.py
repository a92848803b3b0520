"""The lab page: Panel components over a :class:`~labrig.lab.station.Station`.

A thin view: every number and figure on it comes from the library through the station
(the sweep, and the jobs' results of the public verbs). Three tabs follow the lab: watch
the runs come in, close the loop (fit, diagnose, add / remove / replace, auto, the
ladder always in view), and ask the rig. A periodic callback (10 per second) moves the
live samples and finished jobs onto the page, so the page never waits on the rig or a fit.
"""
from __future__ import annotations

import math
import time

import panel as pn
from bokeh.models import ColumnDataSource
from bokeh.plotting import figure

from labrig.core.display import png_html as _img
from labrig.core.errors import LabrigError
import labrig.verbs as lr
import labrig.verbs.figures as lrf
from labrig.lab.explore import Explorer, under_lock
from labrig.lab.plan_form import PlanForm
from labrig.lab.live import LIVE_POINTS
from labrig.lab.station import Station
from labrig.lab.words import (asking_html, esc, evidence_html, forming_html, set_text,
                              why_not)

#: display refresh period (ms): at least 10 updates per second
REFRESH_MS = 100


class LabPage:
    """One browser session's page. ``owner``: this session may drive the rig.

    ``may_drive``: False for a watcher who never drives, even when the rig is free (a
    class's instructor or another student looking on); every action checks it here, on
    the server, not only by a disabled button (a page's requests can be edited)."""

    def __init__(self, station: Station, session: str, *, may_drive: bool = True,
                 refused=None):
        self.st = station
        #: told the name of each action refused to this page (the class server logs it)
        self.refused = refused or (lambda what: None)
        self.session = session
        self.may_drive = may_drive
        self.owner = may_drive and station.claim(session)
        self._seen = None
        self._build()

    # -- layout ----------------------------------------------------------------------
    def _build(self) -> None:
        st = self.st
        b = st.rig.bridge
        self._plays = (f"rig that plays: {st.rig_name} · bridge ±{b.output_limit_v:g} V, "
                       f"{b.sample_rate_hz:g} Hz")
        self.banner = pn.pane.Alert(
            "Another page drives this rig: you are watching (read-only).",
            alert_type="warning", visible=not self.owner)
        self.error = pn.pane.Alert("", alert_type="danger", visible=False,
                                   css_classes=["lab-error"])
        self.heading = pn.pane.Markdown(self._heading(), css_classes=["lab-heading"])
        header = pn.Column(self.heading, self.banner, self.error)
        self.tabs = pn.Tabs(("Acquire", self._acquire_tab()), ("The loop", self._loop_tab()),
                            ("Ask the rig", self._ask_tab()), dynamic=False)
        self.view = pn.Column(header, self.tabs, sizing_mode="stretch_width")
        self.set_owner(self.owner)

    def _heading(self) -> str:
        # what is looked at (the folder's runs, from their sidecars) apart from what plays
        return (f"## labrig lab\nfolder: {self.st.folder} · {self.st.holds()}  \n"
                f"{self._plays}")

    def _acquire_tab(self):
        self.form = PlanForm(self.st.rig, self.st.folder)
        self.start = pn.widgets.Button(name="Start", button_type="primary",
                                       css_classes=["lab-start"])
        self.stop = pn.widgets.Button(name="Stop", button_type="danger", css_classes=["lab-stop"])
        self.start.on_click(self._on_start)
        self.stop.on_click(lambda e: self._do(self.st.stop))
        self.counters = pn.pane.Markdown("", css_classes=["lab-counters"])
        self.sweep_note = pn.pane.Markdown(self.st.foreign(), css_classes=["lab-sweep-note"])
        self.runs_list = pn.pane.Markdown("", css_classes=["lab-runs"])
        self.src = ColumnDataSource({"t": [], "u": [], "speed": [], "pos": []})
        plots = []
        for key, label in (("u", "input u (V)"), ("speed", "speed (rad/s)"),
                           ("pos", "position (rad)")):
            f = figure(height=170, sizing_mode="stretch_width", title=label,
                       toolbar_location=None, x_axis_label="time (s)" if key == "pos" else None)
            f.line("t", key, source=self.src, line_width=1.2)
            plots.append(pn.pane.Bokeh(f, sizing_mode="stretch_width"))
        self._drivers = [self.start, self.stop]
        return pn.Row(pn.Column(self.form.view, pn.Row(self.start, self.stop), self.counters,
                                self.sweep_note, self.runs_list, width=380),
                      pn.Column(*plots, sizing_mode="stretch_width"),
                      sizing_mode="stretch_width")

    def _loop_tab(self):
        self.fit_btn = pn.widgets.Button(name="Fit the linear model", button_type="primary",
                                         css_classes=["lab-fit"])
        self.auto_btn = pn.widgets.Button(name="Auto (diagnose --auto)", css_classes=["lab-auto"])
        self.cancel_btn = pn.widgets.Button(name="Cancel", button_type="warning",
                                            css_classes=["lab-cancel"])
        self.fit_btn.on_click(lambda e: self._do(self.st.fit_linear))
        self.auto_btn.on_click(lambda e: self._do(self.st.auto))
        self.cancel_btn.on_click(lambda e: self._do(self.st.cancel))
        # (what runs, and for how long, is said in words: an animated progress bar beside
        # it cost the browser 0.3-0.6 s of a core during a 4.5 s click, taken from the fits)
        self.status = pn.pane.Markdown("", css_classes=["lab-status"])
        self.now = pn.pane.Markdown("", css_classes=["lab-rmse"])
        self.forming = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["lab-forming"])
        self.run_pick = pn.widgets.Select(name="run", options=[], width=200,
                                          css_classes=["lab-run-pick"])
        self.run_pick.param.watch(lambda e: self._show_overlay(), "value")
        self.overlay = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["lab-compare-figure"])
        self.ladder = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["lab-ladder"])
        self.ladder_plot = pn.pane.Bokeh(None, sizing_mode="stretch_width",
                                         css_classes=["lab-ladder-plot"])
        self.ranking_plot = pn.pane.Bokeh(None, sizing_mode="stretch_width",
                                          css_classes=["lab-ranking-plot"])
        self.show_pick = pn.widgets.Select(name="show a candidate's re-fit on the runs",
                                           options=[], width=260, css_classes=["lab-show-pick"])
        self.show_btn = pn.widgets.Button(name="Show", css_classes=["lab-show"])
        self.show_btn.on_click(lambda e: self._show_candidate())
        self.evidence = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["lab-evidence"])
        self.add_pick = pn.widgets.Select(name="add", options=[], width=200)
        self.add_btn = pn.widgets.Button(name="Add", button_type="success", css_classes=["lab-add"])
        self.rm_pick = pn.widgets.Select(name="remove", options=[], width=200)
        self.rm_btn = pn.widgets.Button(name="Remove", css_classes=["lab-remove"])
        self.rep_new = pn.widgets.Select(name="by", options=[], width=200)
        self.rep_btn = pn.widgets.Button(name="Replace", css_classes=["lab-replace"])
        self.refined_btn = pn.widgets.Button(
            name="Take the better-placed values", button_type="success", visible=False,
            css_classes=["lab-take-refined"])
        self.refined_btn.on_click(lambda e: self._do(self.st.take_refined))
        self.add_btn.on_click(lambda e: self._do(self.st.add, self.add_pick.value))
        self.rm_btn.on_click(lambda e: self._do(self.st.remove, self.rm_pick.value))
        self.rep_btn.on_click(lambda e: self._do(self.st.replace, self.rm_pick.value,
                                                 self.rep_new.value))
        self.save_name = pn.widgets.TextInput(name="save the current model as",
                                              value="model.json", width=200)
        self.save_force = pn.widgets.Checkbox(name="replace", value=False)
        self.save_btn = pn.widgets.Button(name="Save model", css_classes=["lab-save"])
        self.save_btn.on_click(self._on_save)
        self.save_note = pn.pane.Markdown("")
        self.explore = Explorer(self.st.folders, lambda doc: self._do(self.st.fit_from, doc))
        self._explored = None
        self._drivers += [self.fit_btn, self.auto_btn, self.cancel_btn, self.add_btn,
                          self.refined_btn, self.rm_btn, self.rep_btn, self.save_btn,
                          *self.explore.drivers]
        actions = pn.Column(
            pn.Row(self.fit_btn, self.auto_btn, self.cancel_btn), self.status,
            self.forming,
            self.now, pn.pane.Markdown("#### The error falls"), self.ladder_plot, self.ladder,
            pn.Row(self.add_pick, self.add_btn, self.refined_btn),
            pn.Row(self.rm_pick, self.rm_btn, self.rep_new, self.rep_btn),
            self.ranking_plot, self.evidence, pn.Row(self.show_pick, self.show_btn),
            pn.Row(self.save_name, self.save_force, self.save_btn),
            self.save_note, sizing_mode="stretch_width")
        hand = pn.Column(pn.pane.Markdown(
            "#### Try it by hand\nDrag a parameter and watch the curves and the error move; "
            "try an effect at a size you choose before any fit says; then fit from there."),
            self.explore.view, sizing_mode="stretch_width", css_classes=["lab-try"])
        return pn.Column(hand, pn.Row(pn.Column(
            pn.pane.Markdown("#### The figure `labrig compare` draws"), self.run_pick,
            self.overlay, sizing_mode="stretch_width"), actions, sizing_mode="stretch_width"),
            sizing_mode="stretch_width")

    def _ask_tab(self):
        self.pair_pick = pn.widgets.Select(name="between", options=[], width=320)
        self.propose_btn = pn.widgets.Button(name="Propose the experiment",
                                             css_classes=["lab-propose"])
        self.propose_btn.on_click(lambda e: self._do(self.st.propose, self.pair_pick.value,
                                                     self.loop_pick.value))
        # which inputs: to the amplifier, or position steps through the rig's own loop
        self.loop_pick = pn.widgets.RadioButtonGroup(
            name="inputs", options={"open loop": "open", "through the loop": "closed",
                                    "either": "any"}, value="open", button_type="light",
            css_classes=["lab-loop"])
        self.proposal = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["lab-proposal"])
        self.which = pn.widgets.RadioButtonGroup(name="which", options=["-"], button_type="light",
                                                 css_classes=["lab-which"])
        self.why = pn.widgets.TextInput(name="why (one line)", placeholder="because ...",
                                        width=420, css_classes=["lab-why"])
        self.predict_btn = pn.widgets.Button(name="Record my prediction",
                                             css_classes=["lab-predict"])
        self.predict_btn.on_click(self._on_predict)
        self.play_btn = pn.widgets.Button(name="Play it on the rig", button_type="primary",
                                          disabled=True, css_classes=["lab-play"])
        self.play_btn.on_click(lambda e: self._do(self.st.play_proposal))
        self.prediction = pn.pane.Markdown("", css_classes=["lab-prediction"])
        self.decision = pn.pane.HTML("", css_classes=["lab-decision"])
        self.ask_note = pn.pane.Markdown("", css_classes=["lab-ask-note"])
        self.sure_btn = pn.widgets.Button(name="Ask until sure (experiments of 5 s)",
                                          css_classes=["lab-ask-sure"])
        self.sure_btn.on_click(lambda e: self._do(self.st.ask_until_sure, self.pair_pick.value,
                                                  loop=self.loop_pick.value))
        self.asking = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["lab-asking"])
        # both explanations on the last step's run, redrawn after each step
        self.asking_plot = pn.pane.Bokeh(None, sizing_mode="stretch_width",
                                         css_classes=["lab-asking-plot"])
        self._drivers += [self.propose_btn, self.predict_btn, self.play_btn, self.sure_btn]
        return pn.Column(pn.Row(self.pair_pick, self.loop_pick, self.propose_btn, self.sure_btn),
                         self.ask_note,
                         self.asking, self.asking_plot, self.proposal,
                         pn.Row(self.which, self.why, self.predict_btn, self.play_btn),
                         pn.Row(self.prediction, self.decision), sizing_mode="stretch_width")

    # -- actions ---------------------------------------------------------------------
    def _do(self, action, *args, **kw) -> None:
        if not self.owner:
            return self.refused(getattr(action, "__name__", "an action"))
        self._page_error = ""
        try:
            action(*args, **kw)
        except (LabrigError, RuntimeError, ValueError) as exc:
            self._show_error(str(exc))

    _page_error = ""

    def _show_error(self, text: str) -> None:
        """One line on the page, never a traceback; it stays until the next action."""
        self._page_error = text.splitlines()[0] if text else ""
        self._paint_error()

    def _paint_error(self) -> None:
        text = self._page_error or (self.st.error if self.st.error != "cancelled" else "")
        if self.error.object != text:
            self.error.object = text
        self.error.visible = bool(text)

    def _on_start(self, event) -> None:
        plan = self.form.plan()
        if plan is not None:
            self._do(self.st.start_sweep, plan)

    def _on_save(self, event) -> None:
        from labrig.lab.jobs import save_model

        if not self.owner:
            return self.refused("save")
        if not self.st.rungs:
            return self._show_error("no model yet: fit one first")
        name = self.save_name.value.strip()
        if not name or "/" in name or name.startswith("."):
            return self._show_error("save: a file name inside the folder, e.g. model.json")
        try:
            path = save_model(self.st.model(), self.st.folder / name, self.save_force.value)
            self.save_note.object = f"saved to {path}"
        except LabrigError as exc:
            self._show_error(str(exc))

    def _on_predict(self, event) -> None:
        if not self.owner:
            return self.refused("predict")
        if self.which.value in (None, "-") or not self.why.value.strip():
            return self._show_error("say which explanation you expect, and why, in one line")
        self.st.predict(self.which.value, self.why.value)

    # -- refresh ---------------------------------------------------------------------
    def set_owner(self, owner: bool) -> None:
        self.owner = owner
        self.banner.visible = not owner
        for w in self._drivers:
            w.disabled = not owner

    def refresh(self) -> None:
        st = self.st
        if not self.owner and self.may_drive and st.claim(self.session):   # the owner left
            self.set_owner(True)
        live = st.live
        # only what changed goes to the browser (a slider's move should not wait behind an
        # unchanged run): a new run whole, then only its new points, streamed (a class's
        # thirty pages resent 4000 points each ten times a second)
        if live is not self._live_shown or live.points != self._points:
            new_run = live is not self._live_shown   # (the object itself: an id is reused)
            self._live_shown = live
            cols, self._points = live.since(0 if new_run else self._points)
            if new_run:
                self.src.data = cols
            elif len(cols["t"]):
                self.src.stream(cols, rollover=LIVE_POINTS)
        c = live.counters
        set_text(self.counters, (
            f"**{live.name or 'no run yet'}** · samples {live.samples}/{live.n_planned} · gaps "
            f"{c.get('dropped_samples', 0)} · CRC errors {c.get('crc_errors', 0)} · "
            f"retries {c.get('retries', 0)}" + (" · **running**" if st.sweeping else "")))
        if self._ticks % 5 == 0:   # the folder's listing and what it holds: twice a second
            set_text(self.runs_list, "runs in the folder: " + (", ".join(st.runs_on_disk()) or "none"))
            set_text(self.heading, self._heading())
            self._foreign = st.foreign()
        set_text(self.sweep_note, st.sweep_note or self._foreign)
        self._ticks += 1
        if self.owner and st.poll():
            self._show_loop()
        elif self._seen != self._state() or self._hand_view_behind():
            self._show_loop()
        busy = st.busy()
        self._show_stream()
        rungs = [line for line in st.log if line.startswith("rung ")]
        waiting = st.waiting_note()
        set_text(self.status, waiting or (
            f"working: {st.worker.name} ({time.monotonic() - st.worker.started:.0f} s)"
            + "".join(f"  \n{line}" for line in rungs[-6:])
            + (f"  \n{st.log[-1].splitlines()[0]}" if st.log and st.log[-1] not in rungs[-6:]
               else "")) if busy else (
            "drawing the model on the other runs" if st.drawing() else ""))
        self._paint_error()
        # each widget set once, to its final state: a button that flipped in every
        # refresh (Propose: enabled, then disabled again) sent two changes ten times a
        # second, and each made the browser lay out the whole page again (~30 ms)
        # (and set only when it changes: a class's thirty pages each setting twelve
        # unchanged widgets ten times a second cost the server's process a core's third)
        idle = bool(self.owner and not busy and not st.sweeping)
        for w in (self.fit_btn, self.auto_btn, self.add_btn, self.refined_btn, self.rm_btn,
                  self.rep_btn, self.start, self.explore.fit_btn):
            _disable(w, not idle)
        _disable(self.propose_btn, not idle or not self.pair_pick.options)
        _disable(self.sure_btn, self.propose_btn.disabled)
        set_text(self.asking, asking_html(st))
        self._show_asked_step()
        _disable(self.cancel_btn, not self.owner or not busy)
        _disable(self.play_btn, bool(
            not self.owner or busy or st.sweeping or st.proposal is None
            or st.proposal.get("plan") is None or st.prediction is None))
        note = why_not(st, bool(self.pair_pick.options))
        if self.ask_note.object != note:
            self.ask_note.object = note
        if st.proposal and st.prediction and not st.sweeping and st.written \
                and st.decision is None and not busy and self.owner and self._asked:
            self._asked = False
            self._do(st.decide)
        if st.sweeping and st.proposal and st.prediction:
            self._asked = True

    def _hand_view_behind(self) -> bool:
        """The last rung's hand view waits for its chain of jobs (:meth:`_show_loop`),
        which has ended without a new state to show: cancelled, say."""
        st = self.st
        return bool(st.rungs) and self._explored is not st.rungs[-1] and not st.busy()

    _asked = False
    _live_shown = None
    _points = 0
    _ticks = 0
    _foreign = ""   # why this rig may not play into the folder, as of the last listing
    _asked_drawn = None

    def _show_asked_step(self) -> None:
        """After each step asked of the rig: both explanations, as fitted to everything
        so far, drawn on that step's run (the library's comparison of each)."""
        steps = [e for e in self.st.stream if e.get("kind") == "ask_step"]
        if not steps or steps[-1] is self._asked_drawn:
            return
        e = self._asked_drawn = steps[-1]
        try:
            runs = lr.read_runs([e["folder"]])
            evs = {name: lr.compare(runs, lr.model_from_json(doc, "the asked step's model"))
                   for name, doc in e["models"].items()}
        except LabrigError as exc:
            self._show_error(str(exc))
            return
        self.asking_plot.object = lrf.pair_view(evs)
    _drawn_diagnosis = None
    _drawn_ladder = None

    def _state(self) -> tuple:
        st = self.st
        return (len(st.rungs), len(st.rungs[-1]["overlays"]) if st.rungs else 0,
                id(st.diagnosis), id(st.ladder), id(st.proposal), id(st.prediction),
                id(st.decision))

    def _show_loop(self) -> None:
        st = self.st
        self._seen = self._state()
        if st.rungs:
            r = st.rungs[-1]
            rm = r["rmse_over_noise"]
            self.now.object = (f"### rmse/noise {rm['overall']:.2f}\n"
                               f"model: {' + '.join(['linear'] + r['effects'])} "
                               "(1.00 is the noise floor)")
            runs = list(r["runs"])
            if self.run_pick.options != runs:
                self.run_pick.options = runs
                self.run_pick.value = r["worst"]
            self._show_overlay()
            # a new rung: the sliders start from its fit, once its chain of jobs (the
            # diagnosis, the ladder) is done: built beside the diagnosis (this process's
            # work and the browser's drawing) they took a core from it and slowed it; the
            # rung's number and its curve on the worst run are shown at once
            if self._hand_view_behind():
                self._explored = r
                self.rm_pick.options = list(r["effects"])
                self.explore.set_model(r["model"], fitted=True)
        # the diagnosis and the ladder are drawn once each, when they arrive: redrawn on
        # every change of state (an overlay arriving) they reset the student's picks and
        # replaced the ranking under a click
        if st.diagnosis is None and self._drawn_diagnosis is not None:
            self._drawn_diagnosis = None
            self.pair_pick.options = []   # nothing to ask about until the next diagnosis
            self.refined_btn.visible = False
        if st.diagnosis and st.diagnosis is not self._drawn_diagnosis:
            d = self._drawn_diagnosis = st.diagnosis
            adds = [row["effect"] for row in d["rows"] if row.get("move", "add") == "add"]
            self.add_pick.options = adds
            self.rep_new.options = list(dict.fromkeys(
                row["effect"] for row in d["rows"] if row.get("move", "add") != "remove"))
            rec = next((row for row in d["rows"] if row.get("label", row["effect"])
                        == d["recommendation"]), None)
            if rec is not None and rec.get("move", "add") == "add":
                self.add_pick.value = rec["effect"]
            elif rec is not None:   # remove X, or replace X by Y: the pickers say which
                self.rm_pick.value = rec["replaces"] or rec["effect"]
                if rec["move"] == "replace":
                    self.rep_new.value = rec["effect"]
            self.refined_btn.visible = d.get("refined") is not None
            self.evidence.object = evidence_html(d)
            self.show_pick.options = [row["label"] for row in d["rows"] if row.get("model")]
            fig = lrf.ranking_view(d["rows"])
            # a click on a candidate's row: the click's y is the row (factor k spans k..k+1)
            fig.on_event("tap", lambda event, fig=fig: self._on_tap(fig, event))
            self.ranking_plot.object = fig
            self.pair_pick.options = [",".join(p["pair"]) for p in d["pairs"]]
        if st.ladder and st.ladder is not self._drawn_ladder:
            self._drawn_ladder = st.ladder
            self.ladder_plot.object = lrf.ladder_view(st.ladder["json"]["steps"])
            self.ladder.object = "".join(st.ladder["tables"])
        if st.proposal:
            p = st.proposal
            self.proposal.object = (_img(p["figure"], 1100) + "<pre style=\"white-space:pre-wrap\">"
                                    + esc(p["text"]) + "</pre>")
            self.which.options = list(p["pair"])
        if st.prediction:
            pr = st.prediction
            self.prediction.object = f"**your prediction:** {pr['which']} — {pr['why']}"
        if st.decision:
            self.decision.object = ("<b>the rig says:</b> " + esc(st.decision["text"])
                                    + "".join(st.decision.get("tables", [])))

    def _on_tap(self, fig, event) -> None:
        factors = list(fig.y_range.factors)
        k = math.floor(event.y) if event.y is not None else -1
        if not 0 <= k < len(factors):
            return
        under_lock(fig, lambda: self._tapped(factors[k]))

    def _tapped(self, label: str) -> None:
        """A candidate's row of the ranking clicked: that candidate shown, as *Show* does."""
        if label in self.show_pick.options:
            self.show_pick.value = label
            self._show_candidate()

    def _show_candidate(self) -> None:
        """A candidate of the ranking, as the diagnosis re-fitted it, on the runs (the
        hand view: its curves, its sliders)."""
        d = self.st.diagnosis
        row = next((r for r in (d or {}).get("rows", []) if r["label"] == self.show_pick.value),
                   None)
        if row is not None and row.get("model"):
            self.explore.set_model(row["model"], why=f"{row['label']}, as the diagnosis "
                                                     "re-fitted it")

    def _show_stream(self) -> None:
        """While a job runs: the ranking as its candidates come back, and each rung of the
        search's ladder, its model drawn on the runs by the hand view."""
        st = self.st
        if len(st.stream) < self._streamed:   # a new job: its own stream
            self._streamed = 0
        if not st.stream:
            set_text(self.forming, "")
            return
        if len(st.stream) == self._streamed:
            return
        rungs = [e for e in st.stream[self._streamed:] if e["kind"] == "rung"]
        if rungs:   # (several since the last look: the newest is the one to draw)
            self.explore.set_model(rungs[-1]["model"], fitted=True)
        self._streamed = len(st.stream)
        self.forming.object = forming_html(st.stream)

    _streamed = 0

    def _show_overlay(self) -> None:
        if self.owner:
            self.st.wanted = self.run_pick.value
        if not self.st.rungs:
            return
        pngs = self.st.rungs[-1]["overlays"]
        if self.run_pick.value in pngs:
            self.overlay.object = _img(pngs[self.run_pick.value])
            return
        self.overlay.object = f"<p>drawing the model on {esc(self.run_pick.value)}…</p>"
        if self.owner and self.st.idle():   # a Cancel stopped the drawing: again
            self.st.draw_overlays()


def _disable(widget, disabled: bool) -> None:
    """``widget.disabled``, set only when it changes."""
    if widget.disabled != disabled:
        widget.disabled = disabled

