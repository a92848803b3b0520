"""The JSON of ``labrig analyse --json`` (and ``analysis.json``): its one definition.

:meth:`labrig.analysis.result.AnalysisResult.to_json` writes it; a test checks that every
key it writes is declared here, and :meth:`AnalysisDoc.result` turns a record back into
the result, so the report renders the same tables as the CLI.
"""
from __future__ import annotations

import math
from typing import Any, Optional

from labrig.analysis.result import GAIN_TOLERANCE, AnalysisResult, Level, LineFit, RunAnalysis
from labrig.core.schemas import JsonDoc as _Doc

Num = Optional[float]


class LevelDoc(_Doc):
    v: float
    speed_rad_s: Num = None
    spread_rad_s: Num = None
    moving: Optional[bool] = None
    segments: int = 0
    settled: int = 0
    tau_s: Num = None
    km_paper: Num = None


class EdgeDoc(_Doc):
    t_s: float
    v_from: Num = None
    v_to: Num = None
    kind: str = ""
    speed_from: Num = None
    speed_to: Num = None
    tau_s: Num = None
    tau63_s: Num = None
    delay_s: Num = None
    fit_nrmse: Num = None
    note: Optional[str] = None


class RunDoc(_Doc):
    name: str
    loop: str = "open"
    sample_rate_hz: Num = None
    skipped: Optional[str] = None
    sensor: Optional[str] = None
    kt_est: Num = None
    kt_configured: Num = None
    levels: list[LevelDoc] = []
    notes: list[str] = []
    tau_s: Num = None
    edges: list[EdgeDoc] = []
    figure: Optional[str] = None


class SideDoc(_Doc):
    km: Num = None
    deadband_v: Num = None


class TrendDoc(_Doc):
    relative_change: Num = None
    threshold: Num = None
    amplitude_range_v: Optional[list[Num]] = None
    standard_error: Num = None


class AnalysisDoc(_Doc):
    """``labrig analyse --json``."""

    deadband_v: Num = None
    km: Num = None
    tau_s: Num = None
    kt: Num = None
    gain_trend: str
    runs: list[RunDoc]
    verdict: str = ""
    km_paper: dict[float, Num] = {}
    trend: TrendDoc = TrendDoc()
    tolerance: float = GAIN_TOLERANCE
    breakaway_v: Num = None
    forward: SideDoc = SideDoc()
    reverse: SideDoc = SideDoc()
    line_region: str = "linear"
    kt_configured: Num = None
    kt_mismatch: Optional[bool] = None
    source: str = "runs"
    #: forward over reverse: Km and steady speed ratios, deadband difference (V)
    asymmetry: Optional[dict[str, Num]] = None
    figures: Any = []

    def result(self) -> AnalysisResult:
        """The :class:`AnalysisResult` this JSON was written from, less what the JSON
        does not keep (the edges' fits and the tacho volts of each level)."""
        runs = [RunAnalysis(name=r.name, loop=r.loop, fs=r.sample_rate_hz or math.nan,
                            sensor=r.sensor, kt_est=r.kt_est, kt_configured=r.kt_configured,
                            skipped=r.skipped, notes=list(r.notes),
                            levels=[Level(run=r.name, v=lv.v, speed=lv.speed_rad_s,
                                          spread=lv.spread_rad_s, n_segments=lv.segments,
                                          n_settled=lv.settled, moving=lv.moving,
                                          tau_s=lv.tau_s) for lv in r.levels])
                for r in self.runs]
        line = LineFit(km=self.km, deadband_fwd=self.forward.deadband_v,
                       deadband_rev=self.reverse.deadband_v, km_fwd=self.forward.km,
                       km_rev=self.reverse.km, region=self.line_region)
        trend = {k: v for k, v in self.trend.model_dump().items() if v is not None}
        trend["km_by_amplitude"] = sorted(self.km_paper.items())
        return AnalysisResult(
            deadband_v=self.deadband_v, km=self.km, tau_s=self.tau_s, kt=self.kt,
            gain_trend=self.gain_trend, runs=runs, verdict=self.verdict, line=line,
            trend=trend, breakaway_v=self.breakaway_v, kt_configured=self.kt_configured,
            kt_mismatch=self.kt_mismatch, tolerance=self.tolerance, source=self.source,
            levels=[lv for r in runs if not r.skipped for lv in r.levels])


