"""The plan form of the lab page: the plan schema's fields with their ranges, checked by
the same reader as a plan file (:func:`labrig.verbs.load_plan`), so a bad value gets
the command line's words, shown beside its field."""
from __future__ import annotations

import tempfile
from pathlib import Path

import panel as pn

import labrig.verbs as lr
from labrig.core.errors import LabrigError

#: form field -> the plan key its errors name
KEYS = {"waveform": "waveform", "loop": "loop", "amplitudes": "amplitudes_v",
        "frequency": "frequency_hz", "periods": "periods", "rate": "sample_rate_hz",
        "name": "name"}


class PlanForm:
    """A plan file to choose (the lab's, or one in the folder), or one ``[[experiment]]``
    table with one run per amplitude, edited in the form."""

    def __init__(self, rig, folder=None):
        self.rig = rig
        lim = rig.bridge.output_limit_v
        files = lr.plan_files() + \
            (sorted(Path(folder).glob("*.toml")) if folder else [])
        self.source = pn.widgets.Select(
            name="plan", options={"the form below": "", **{f.name: str(f) for f in files}},
            width=340, css_classes=["lab-plan"])
        self.w = {
            "waveform": pn.widgets.Select(name="waveform", options=["square", "step"],
                                          width=340),
            "loop": pn.widgets.Select(name="loop", options=["open", "closed"], width=340),
            "amplitudes": pn.widgets.TextInput(
                name=f"amplitudes (V, comma separated; at most ±{lim:g} V)",
                value="1.2, 2.0", width=340, css_classes=["lab-amplitudes"]),
            "frequency": pn.widgets.FloatInput(name="frequency (Hz, 0.001 to 1000)", value=0.25,
                                               start=0.001, end=1000, width=340),
            "periods": pn.widgets.FloatInput(name="periods (0.01 to 10000)", value=1.0,
                                             start=0.01, end=1e4, width=340,
                                             css_classes=["lab-periods"]),
            "rate": pn.widgets.FloatInput(name="sample rate (Hz)",
                                          value=rig.bridge.sample_rate_hz, start=1, end=1e5,
                                          width=340),
        }
        self.msg = {k: pn.pane.Alert("", alert_type="danger", visible=False, width=340,
                                     css_classes=[f"lab-form-error-{k}"]) for k in self.w}
        self.source_msg = pn.pane.Alert("", alert_type="danger", visible=False, width=340)
        self.view = pn.Column(self.source, self.source_msg,
                              *[x for k in self.w for x in (self.w[k], self.msg[k])])

    def toml(self) -> str:
        w = {k: v.value for k, v in self.w.items()}
        amps = [a.strip() for a in str(w["amplitudes"]).split(",") if a.strip()]
        lines = ["[[experiment]]", f'loop = "{w["loop"]}"',
                 f'waveform = "{w["waveform"]}"', f"amplitudes_v = [{', '.join(amps)}]",
                 f"frequency_hz = {w['frequency']}", f"periods = {w['periods']}",
                 f"sample_rate_hz = {w['rate']}", "lead_in_s = 0.5"]
        return "\n".join(lines) + "\n"

    def plan(self):
        """The experiments, or None with the error shown beside its field."""
        for m in [*self.msg.values(), self.source_msg]:
            m.visible = False
        try:
            [float(a) for a in str(self.w["amplitudes"].value).split(",") if a.strip()]
        except ValueError:
            return self._refuse("amplitudes", f"amplitudes: {self.w['amplitudes'].value!r} is "
                                "not a list of numbers; write e.g. 1.2, 2.0")
        if self.source.value:   # a plan file, read as `labrig sweep --plan` reads it
            try:
                plan = lr.load_plan(self.source.value, self.rig)
                lr.check_plan(plan, self.rig)
                return plan
            except LabrigError as exc:
                self.source_msg.object = str(exc).splitlines()[0]
                self.source_msg.visible = True
                return None
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "plan.toml"
            path.write_text(self.toml())
            try:
                plan = lr.load_plan(path, self.rig)
                lr.check_plan(plan, self.rig)
                return plan
            except LabrigError as exc:
                text = str(exc).replace(str(path), "plan").splitlines()[0]
                return self._refuse(next((k for k, key in KEYS.items() if key in text),
                                         "amplitudes"), text)

    def _refuse(self, field: str, text: str) -> None:
        self.msg[field].object = text
        self.msg[field].visible = True
        return None
