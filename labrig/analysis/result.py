"""The result objects of ``labrig analyse``: one fitted edge, one steady level, one
run, the speed-vs-voltage line, and the whole answer with its outputs (JSON, pandas,
tables, figures)."""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from typing import Annotated, Any, Optional, Union

import pandas as pd
from pydantic import Field, PlainSerializer, computed_field, model_validator
from typing_extensions import TypedDict

from labrig.analysis.run_result import LineFit, RunAnalysis
from labrig.core.display import Displayable
from labrig.core.record import Live, Num, Record
from labrig.analysis.text import summary_text, table_rows

#: relative change of w/V over the amplitude range still called "constant"
GAIN_TOLERANCE = 0.03




class Side(TypedDict):
    """One side's gain (rad/s per V) and deadband (V) of the speed-vs-voltage line."""

    km: Num
    deadband_v: Num


def _trend_json(trend: dict) -> dict[str, Any]:
    # (the gains by amplitude are written as km_paper, the asymmetry as asymmetry)
    return {k: v for k, v in trend.items() if k not in ("asymmetry", "km_by_amplitude")}


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

    # (a record read back may lack what it can do without: pydantic defaults)
    deadband_v: Annotated[Num, Field(default=None)]
    km: Annotated[Num, Field(default=None)]
    tau_s: Annotated[Num, Field(default=None)]
    kt: Annotated[Num, Field(default=None)]
    gain_trend: str
    # (a table's analysis gives one plain dict)
    runs: list[Union[RunAnalysis, dict]]
    verdict: str = ""
    # (written as its parts: forward, reverse, line_region)
    line: Annotated[LineFit, Live] = field(default_factory=LineFit)
    # (written without what km_paper and asymmetry say)
    trend: Annotated[dict, PlainSerializer(_trend_json)] = field(default_factory=dict)
    breakaway_v: Num = None
    kt_configured: Num = None
    kt_mismatch: Optional[bool] = None
    tolerance: float = GAIN_TOLERANCE
    source: str = "runs"
    # (the runs' levels, pooled; the JSON has them under each run)
    levels: Annotated[list, Live] = field(default_factory=list)
    figure_paths: Annotated[list[str], Field(alias="figures")] = field(default_factory=list)
    #: the axis's speed unit (rad/s on a rotary axis, m/s on a linear one)
    speed_unit: Annotated[str, Live] = "rad/s"

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
        """The first line of the ``repr``.

        Returns
        -------
        str
            How many runs, and where the whole text is (:meth:`summary`).
        """
        return f"AnalysisResult: {len(self.runs)} run(s); .summary() for the whole text"

    # -- data outputs ----------------------------------------------------------
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
