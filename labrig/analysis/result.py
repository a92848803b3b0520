"""The result objects of ``labrig analyse``: one fitted edge, one steady level, one
run, the speed-vs-voltage line, and the whole answer with its outputs (JSON, pandas,
tables, figures)."""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from typing import Annotated, Any, Optional, Union

import numpy as np
import pandas as pd
from pydantic import Field, PlainSerializer, computed_field, model_serializer, model_validator
from typing_extensions import TypedDict

from labrig.analysis.stepfit import StepFit
from labrig.core.display import Displayable
from labrig.core.record import Record
from labrig.analysis.text import summary_text, table_rows

#: relative change of w/V over the amplitude range still called "constant"
GAIN_TOLERANCE = 0.03


#: what an edge's time constant at a bound of the search means, by bound
TAU_BOUND_NOTES = {
    "lower": "time constant at its lower bound, a quarter of a sample: faster than this "
             "sampling can show",
    "upper": "time constant at its upper bound, 20 segment lengths: the speed barely moved",
}


Num = Optional[float]
#: not in the JSON
_live = Field(exclude=True)


class Side(TypedDict):
    """One side's gain (rad/s per V) and deadband (V) of the speed-vs-voltage line."""

    km: Num
    deadband_v: Num


def _trend_json(trend: dict) -> dict[str, Any]:
    # (the gains by amplitude are written as km_paper, the asymmetry as asymmetry)
    return {k: v for k, v in trend.items() if k not in ("asymmetry", "km_by_amplitude")}


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
    too_short: Annotated[bool, _live] = False
    no_response: Annotated[bool, _live] = False
    fit_failed: Annotated[bool, _live] = False
    not_settled: Annotated[bool, _live] = False
    tau_at_bound: Annotated[bool, _live] = False
    poor_fit: Annotated[bool, _live] = False
    t63_disagrees: Annotated[bool, _live] = False
    fit: Annotated[Optional[StepFit], _live] = field(default=None, repr=False, compare=False)

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

    def _old_to_json(self) -> dict:
        return {"t_s": self.t_s, "v_from": self.v_from, "v_to": self.v_to, "kind": self.kind,
                "speed_from": self.speed_from, "speed_to": self.speed_to, "tau_s": self.tau_s,
                "tau63_s": self.tau63_s, "delay_s": self.delay_s, "fit_nrmse": self.fit_nrmse,
                "note": self.note or None}


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
    tacho_v: Annotated[Num, _live] = None
    # motor speed from the pot on the same flat parts
    pot_speed: Annotated[Num, _live] = None
    tau_s: Num = None        # median tau of the edges into this level

    @computed_field
    @property
    def km_paper(self) -> float | None:
        """The paper's Km = w / V (eq. 5); None at 0 V or when not settled."""
        if self.speed is None or abs(self.v) < 1e-9:
            return None
        return self.speed / self.v

    def _old_to_json(self) -> dict:
        return {"v": self.v, "speed_rad_s": self.speed, "spread_rad_s": self.spread,
                "km_paper": self.km_paper, "moving": self.moving,
                "segments": self.n_segments, "settled": self.n_settled, "tau_s": self.tau_s}


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
    kt_configured: Annotated[Num, _live] = None
    skipped: Optional[str] = None
    notes: list[str] = field(default_factory=list)
    figure: Optional[str] = None      # where its edges figure was saved, if it was
    speed_unit: Annotated[str, _live] = "rad/s"   # the axis's (m/s on a linear axis)

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

    def _old_to_json(self) -> dict:
        d = {"name": self.name, "loop": self.loop, "sample_rate_hz": self.fs,
             "skipped": self.skipped}
        if self.skipped:
            return clean_json(d)
        d.update({"sensor": self.sensor, "tau_s": self.tau_s, "kt_est": self.kt_est,
                  "levels": [lv._old_to_json() for lv in self.levels],
                  "edges": [e._old_to_json() for e in self.edges],
                  "notes": self.notes, "figure": self.figure})
        return clean_json(d)

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


@dataclass(repr=False)
class AnalysisResult(Displayable, Record):
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
        no run has both a tacho and a pot (or the data give it otherwise, e.g. a table),
        e.g. when the speed was imported in physical units.
    gain_trend : {"constant", "rising", "falling"}
        How w/V changes with amplitude, judged with ``tolerance``.
    runs : list of RunAnalysis
        (a table gives one plain dict instead)
    verdict : str
        One or two sentences: the likely physical cause and the experiment that
        separates the candidates.
    figure_paths : list of str
        Where the figures were saved (:meth:`record_figures`); ``"figures"`` in the JSON.

    Examples
    --------
    >>> import labrig as lr
    >>> res = lr.analyse("data/sweep_default")
    >>> round(res.deadband_v, 2), res.gain_trend
    (..., '...')
    >>> res.to_json()["deadband_v"] == res.deadband_v
    True
    """

    finite_json = True

    deadband_v: Num
    km: Num
    tau_s: Num
    kt: Num
    gain_trend: str
    # (a table's analysis gives one plain dict)
    runs: list[Union[RunAnalysis, dict]]
    verdict: str = ""
    # (written as its parts: forward, reverse, line_region)
    line: Annotated[LineFit, _live] = field(default_factory=LineFit)
    # (written without what km_paper and asymmetry say)
    trend: Annotated[dict, PlainSerializer(_trend_json)] = field(default_factory=dict)
    breakaway_v: Num = None
    kt_configured: Num = None
    kt_mismatch: Optional[bool] = None
    tolerance: float = GAIN_TOLERANCE
    source: str = "runs"
    # (the runs' levels, pooled; the JSON has them under each run)
    levels: Annotated[list, _live] = field(default_factory=list)
    figure_paths: Annotated[list[str], Field(alias="figures")] = field(default_factory=list)
    #: the axis's speed unit (rad/s on a rotary axis, m/s on a linear one)
    speed_unit: Annotated[str, _live] = "rad/s"

    # -- the JSON's keys derived from the fields --------------------------------------------
    @computed_field
    @property
    def km_paper(self) -> dict[str, Num]:
        """w / V by amplitude (V, as text) (rad/s per V)."""
        return {f"{a:g}": k for a, k in self.trend.get("km_by_amplitude", [])}

    @computed_field
    @property
    def forward(self) -> Side:
        """The forward side's gain and deadband."""
        return {"km": self.line.km_fwd, "deadband_v": self.line.deadband_fwd}

    @computed_field
    @property
    def reverse(self) -> Side:
        """The reverse side's gain and deadband."""
        return {"km": self.line.km_rev, "deadband_v": self.line.deadband_rev}

    @computed_field
    @property
    def asymmetry(self) -> dict[str, Num]:
        """Forward over reverse: Km and steady speed ratios, deadband difference (V)."""
        asym = {}
        if self.line.km_fwd is not None and self.line.km_rev is not None:
            asym["km_ratio_fwd_rev"] = self.line.km_fwd / self.line.km_rev
        if self.line.deadband_fwd is not None and self.line.deadband_rev is not None:
            asym["deadband_diff_v"] = self.line.deadband_fwd - self.line.deadband_rev
        asym.update(self.trend.get("asymmetry", {}))
        return asym

    @computed_field
    @property
    def line_region(self) -> str:
        """Where the line was fitted: "linear", "saturated" or "single_level"."""
        return self.line.region

    @model_validator(mode="before")
    @classmethod
    def _from_record(cls, d):
        # a record read back: the line from its parts, the trend with its gains by amplitude
        if not isinstance(d, dict) or "line" in d:
            return d
        fwd, rev = d.get("forward") or {}, d.get("reverse") or {}
        line = LineFit(km=d.get("km"), deadband_fwd=fwd.get("deadband_v"),
                       deadband_rev=rev.get("deadband_v"), km_fwd=fwd.get("km"),
                       km_rev=rev.get("km"), region=d.get("line_region", "linear"))
        trend = {k: v for k, v in (d.get("trend") or {}).items() if v is not None}
        trend["km_by_amplitude"] = sorted((float(a), k) for a, k in (d.get("km_paper") or {}).items())
        own = {k: v for k, v in (d.get("asymmetry") or {}).items()
               if k not in ("km_ratio_fwd_rev", "deadband_diff_v")}
        if own:
            trend["asymmetry"] = own
        return {**d, "line": line, "trend": trend}

    @model_validator(mode="after")
    def _levels_of_the_runs(self):
        if not self.levels:
            self.levels = [lv for r in self.runs if isinstance(r, RunAnalysis) and not r.skipped
                           for lv in r.levels]
        return self

    def headline(self) -> str:
        """The first line of the ``repr``: how many runs, and where the whole text is.

        Returns
        -------
        str
        """
        return f"AnalysisResult: {len(self.runs)} run(s); .summary() for the whole text"

    # -- data outputs ----------------------------------------------------------
    def _old_to_json(self) -> dict:
        """JSON-safe dict printed by ``--json`` (docs/design.md, 'Commands'; NaN, inf -> None)."""
        asym = {}
        if self.line.km_fwd is not None and self.line.km_rev is not None:
            asym["km_ratio_fwd_rev"] = self.line.km_fwd / self.line.km_rev
        if self.line.deadband_fwd is not None and self.line.deadband_rev is not None:
            asym["deadband_diff_v"] = self.line.deadband_fwd - self.line.deadband_rev
        asym.update(self.trend.get("asymmetry", {}))
        d = {
            "deadband_v": self.deadband_v, "km": self.km, "tau_s": self.tau_s, "kt": self.kt,
            "gain_trend": self.gain_trend,
            "runs": [r.to_json() if isinstance(r, RunAnalysis) else r for r in self.runs],
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
            "figures": self.figure_paths,
        }
        return clean_json(d)

    def to_dict(self) -> dict:
        """The older name of :meth:`to_json`, still used by ``labrig demo`` and the report."""
        return self.to_json()

    def to_pandas(self) -> pd.DataFrame:
        """Per-level table (one row per run and input level), like the paper's Table 1.

        Returns
        -------
        pandas.DataFrame
            Columns ``run``, ``input_v`` (V), ``speed_rpm``, ``omega_rad_s``,
            ``spread_rad_s``, ``tacho_v`` (V), ``km_paper``, ``tau_s`` (s), ``moving``,
            ``segments``, ``settled``; None where a level has no such value.
        """
        rows = []
        for lv in self.levels:
            rows.append({"run": lv.run, "input_v": lv.v,
                         "speed_rpm": None if lv.speed is None else lv.speed * 30 / math.pi,
                         "omega_rad_s": lv.speed, "spread_rad_s": lv.spread,
                         "tacho_v": lv.tacho_v, "km_paper": lv.km_paper, "tau_s": lv.tau_s,
                         "moving": lv.moving, "segments": lv.n_segments,
                         "settled": lv.n_settled})
        return pd.DataFrame(rows)

    def table_rows(self) -> list:
        """The per-level table and the summary table, as :class:`labrig.core.tables.Table`.

        Returns
        -------
        list of Table
            The steady speed per run and level (skipped runs as notes), then the summary
            quantities.
        """
        return table_rows(self)

    def summary(self) -> str:
        """The readable summary: the tables, the verdict, the saved figures.

        Returns
        -------
        str
            Plain text, 110 columns wide.
        """
        return summary_text(self)

    # -- figures ------------------------------------------------------------------
    def plot(self, ax=None):
        """Steady speed against input voltage, the fitted line and the deadband.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Draw here; by default on a new figure. (A folder path, deprecated, saves
            every figure there as :meth:`save_figures` does and returns its paths.)

        Returns
        -------
        matplotlib.figure.Figure
            Not saved: the caller saves (and closes) it.
        """
        if isinstance(ax, (str, os.PathLike)):
            # the old ``plot(figdir)``: kept for callers not yet moved to figures()
            warnings.warn("AnalysisResult.plot(figdir) is deprecated; save the figures of "
                          "figures() instead", DeprecationWarning, stacklevel=2)
            return self.save_figures(ax)
        from labrig.analysis.plots import plot_speed_vs_voltage  # matplotlib: ~0.2 s more

        return plot_speed_vs_voltage(self, ax=ax)

    def figures(self):
        """Every figure by file name: ``edges_<run>.png`` per run with a fitted edge,
        ``speed_vs_voltage.png`` and ``km_vs_amplitude.png``.

        Returns
        -------
        Mapping of str to matplotlib.figure.Figure
            Names are known without drawing; each access draws a new figure, so that
            saving and closing one at a time keeps one figure in memory.
        """
        from labrig.analysis.plots import analysis_figures  # matplotlib: ~0.2 s more to import

        return analysis_figures(self)

    def save_figures(self, figdir) -> list[str]:
        """Save every figure of :meth:`figures` as PNG into ``figdir`` (closing each)
        and record the paths (:meth:`record_figures`).

        Parameters
        ----------
        figdir : str or Path
            The folder to save into; made if missing, files of the same names replaced.

        Returns
        -------
        list of str
            The saved files' paths (:attr:`figure_paths`).
        """
        from labrig.analysis.plots import save_figures  # matplotlib: ~0.2 s more to import

        self.record_figures(save_figures(self.figures(), figdir))
        return self.figure_paths

    def record_figures(self, saved) -> None:
        """Remember where figures were saved for the JSON: the ``figures`` list and each
        run's ``figure``.

        Parameters
        ----------
        saved : dict
            ``{file name: path}`` as saving gives it (``edges_<run>.png`` sets that
            run's ``figure``).
        """
        self.figure_paths = [str(p) for p in saved.values()]
        for r in self.runs:
            if isinstance(r, RunAnalysis) and f"edges_{r.name}.png" in saved:
                r.figure = str(saved[f"edges_{r.name}.png"])


def clean_json(o):
    """NaN/inf -> None, numpy scalars -> Python, recursively."""
    if isinstance(o, dict):
        return {str(k): clean_json(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [clean_json(v) for v in o]
    if isinstance(o, (np.bool_,)):
        return bool(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (float, np.floating)):
        f = float(o)
        return f if math.isfinite(f) else None
    if isinstance(o, np.ndarray):
        return clean_json(o.tolist())
    return o
