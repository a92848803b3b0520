"""One run's analysis: its fitted edges, its steady levels, and the speed-vs-voltage line
over all runs; each part declared once as its JSON form (:mod:`labrig.core.record`).
:mod:`labrig.analysis.result` holds the whole answer."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated, Optional

import numpy as np
from pydantic import Field, computed_field, model_serializer, model_validator

from labrig.analysis.stepfit import StepFit
from labrig.core.record import Live, Num, Record



#: what an edge's time constant at a bound of the search means, by bound
TAU_BOUND_NOTES = {
    "lower": "time constant at its lower bound, a quarter of a sample: faster than this "
             "sampling can show",
    "upper": "time constant at its upper bound, 20 segment lengths: the speed barely moved",
}


@dataclass
class EdgeFit(Record):
    """One edge of the input and the first-order fit of the speed after it.

    Attributes
    ----------
    index : int
        Sample index of the edge in the run.
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
        Time constant of the first-order fit (s); None when the edge was not fitted
        or its fit was rejected (``not_settled``, ``tau_at_bound``).
    tau63_s : float or None
        Time from the edge to 63 % of the speed change (s), from the data.
    delay_s : float or None
        Dead time of the fit (s): sampling convention, electrical lag, transport delay.
    fit_nrmse : float or None
        RMS residual of the fit relative to the size of the speed change.
    too_short : bool
        Fewer than six samples after the edge: nothing was fitted.
    no_response : bool
        The speed did not change (the motor did not move): nothing was fitted.
    fit_failed : bool
        The optimiser raised; ``fit.error`` says why.
    not_settled : bool
        The fitted time constant is longer than half the segment (fit rejected).
    tau_at_bound : bool
        The fitted time constant sits at a bound of the search (fit rejected).
    poor_fit : bool
        The residual exceeds 15 % of the step (fit kept, with a warning).
    t63_disagrees : bool
        The 63 % point and ``tau + delay`` differ by more than 25 % of tau (warning).
    fit : StepFit or None
        The raw fit (also when rejected) with the arrays for the figure.
    """

    # (the JSON keeps the numbers and the note, not the flags behind the note)
    finite_json = True

    index: Annotated[int, Field(exclude=True, default=0)]
    t_s: float
    v_from: Num
    v_to: Num
    kind: str
    speed_from: Num = None
    speed_to: Num = None
    tau_s: Num = None
    tau63_s: Num = None
    delay_s: Num = None
    fit_nrmse: Num = None
    too_short: Annotated[bool, Live] = False
    no_response: Annotated[bool, Live] = False
    fit_failed: Annotated[bool, Live] = False
    not_settled: Annotated[bool, Live] = False
    tau_at_bound: Annotated[bool, Live] = False
    poor_fit: Annotated[bool, Live] = False
    t63_disagrees: Annotated[bool, Live] = False
    fit: Annotated[Optional[StepFit], Live] = field(default=None, repr=False, compare=False)

    @property
    def ok(self) -> bool:
        """The edge has an accepted first-order fit."""
        return self.tau_s is not None

    @property
    def note(self) -> str:
        """Why the edge was not fitted, or its warnings ("" when none); the JSON text."""
        if self.too_short:
            return "segment too short to fit"
        if self.no_response:
            return "no speed change (the motor did not respond)"
        if self.fit_failed:
            return f"fit failed ({self.fit.error if self.fit else ''})"
        notes = []
        if self.not_settled:
            notes.append("time constant longer than half the segment: not settled")
        if self.tau_at_bound:
            side = self.fit.tau_bound if self.fit is not None else ""
            notes.append(TAU_BOUND_NOTES.get(side, "time constant at a bound of the search"))
        if self.poor_fit:
            notes.append(f"poor first-order fit (residual {100 * self.fit.nrmse:.0f} % of the step)")
        if self.t63_disagrees:
            notes.append("63 % point disagrees with the fit")
        return "; ".join(notes)

    @computed_field(alias="note")
    @property
    def _note_or_none(self) -> Optional[str]:
        return self.note or None


@dataclass
class Level(Record):
    """The steady speed of one input level of a run (all its segments pooled)."""

    finite_json = True

    # (a run's JSON holds its levels: the run's name is the run's)
    run: Annotated[str, Field(exclude=True, default="")]
    v: float
    speed: Annotated[Num, Field(alias="speed_rad_s", default=None)]
    spread: Annotated[Num, Field(alias="spread_rad_s", default=None)]
    n_segments: Annotated[int, Field(alias="segments", default=0)]
    n_settled: Annotated[int, Field(alias="settled", default=0)]
    moving: Annotated[Optional[bool], Field(default=None)]
    # mean tacho volts on the flat parts (Kt check)
    tacho_v: Annotated[Num, Live] = None
    # motor speed from the pot on the same flat parts
    pot_speed: Annotated[Num, Live] = None
    tau_s: Num = None        # median tau of the edges into this level

    @computed_field
    @property
    def km_paper(self) -> float | None:
        """The paper's Km = w / V (eq. 5); None at 0 V or when not settled."""
        if self.speed is None or abs(self.v) < 1e-9:
            return None
        return self.speed / self.v


@dataclass
class RunAnalysis(Record):
    """What one run gave: its levels, its edges, or why it was skipped (then its JSON
    says only its name, loop, rate and why)."""

    finite_json = True

    name: str
    loop: str = "open"
    fs: Annotated[float, Field(alias="sample_rate_hz", default=math.nan)] = math.nan
    sensor: Optional[str] = None      # "tacho", "speed" (imported, no tacho) or "pos"
    levels: list[Level] = field(default_factory=list)
    edges: list[EdgeFit] = field(default_factory=list)
    kt_est: Num = None
    kt_configured: Annotated[Num, Live] = None
    skipped: Optional[str] = None
    notes: list[str] = field(default_factory=list)
    figure: Optional[str] = None      # where its edges figure was saved, if it was
    speed_unit: Annotated[str, Live] = "rad/s"   # the axis's (m/s on a linear axis)

    @computed_field
    @property
    def tau_s(self) -> Num:
        """The median time constant of its fitted edges (s); None without one."""
        taus = [e.tau_s for e in self.edges if e.ok]
        return float(np.median(taus)) if taus else None

    @model_serializer(mode="wrap")
    def _skipped_says_why(self, handler):
        d = handler(self)
        return {k: d[k] for k in ("name", "loop", "sample_rate_hz", "skipped")} \
            if self.skipped else d

    @model_validator(mode="before")
    @classmethod
    def _levels_are_the_runs(cls, d):
        # (read back without its edges: the JSON keeps no fit behind them)
        if isinstance(d, dict):
            d = {k: v for k, v in d.items() if k != "edges"}
            d["levels"] = [{**lv, "run": d.get("name", "")} for lv in d.get("levels", ())]
        return d

    def to_dict(self) -> dict:
        """The older name of :meth:`to_json`."""
        return self.to_json()


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
