"""The JSON artefacts of the earlier stages, validated once where the report reads them.

``analysis.json``, ``identify_all.json`` (and ``model0.json``'s fit record),
``diagnosis.json`` and ``ladder.json`` are parsed into the pydantic models below; a file
that does not fit is ignored with a note on the page, never half-used. The models are
lax about numbers (an int is a float, ``null`` where a value may be missing) but every
key the page reads has its type. Where the stage has a result object, the record turns
into it (:meth:`AnalysisDoc.result`, :meth:`DiagnosisDoc.result`,
:meth:`LadderDoc.result`), so the page renders the same ``table_rows()`` as the CLI.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from labrig.analysis.result import GAIN_TOLERANCE, AnalysisResult, Level, LineFit, RunAnalysis
from labrig.loop.ranking import Candidate, Diagnosis
from labrig.identification.result import IdentResult
from labrig.loop.ladder import Ladder, LadderStep
from labrig.loop.residuals import REGIMES
from labrig.core.schemas import MAX_JSON_BYTES, describe

Num = Optional[float]
Regime = Literal[REGIMES]


class _Doc(BaseModel):
    """Declared keys are typed; any other key is carried along (newer writers)."""

    model_config = ConfigDict(extra="allow")


# -- analysis.json --------------------------------------------------------------------

class LevelDoc(_Doc):
    v: float
    speed_rad_s: Num = None
    spread_rad_s: Num = None
    moving: Optional[bool] = None
    segments: int = 0
    settled: int = 0
    tau_s: Num = None


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


class SideDoc(_Doc):
    km: Num = None
    deadband_v: Num = None


class TrendDoc(_Doc):
    relative_change: Num = None
    threshold: Num = None
    amplitude_range_v: Optional[list[Num]] = None


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


# -- identify --json, identify_all.json, model0.json ----------------------------------

class Combination(_Doc):
    value: Num = None
    identifiable: Optional[bool] = None
    interval95: Optional[list[Num]] = None


class ParamInfo(_Doc):
    value: Num = None
    identifiable: Optional[bool] = None
    fixed: Optional[bool] = None


class Identifiable(_Doc):
    km: Optional[Combination] = None
    tau_m_s: Optional[Combination] = None
    tau_e_s: Optional[Combination] = None
    parameters: dict[str, ParamInfo] = {}
    warnings: list[str] = []


class IdentRecord(_Doc):
    """One identification as ``labrig identify --json`` writes it (a model file
    carries the same fit keys)."""

    method: str = "?"
    params: dict[str, Num]
    effects: list[str] = []
    effect_params: dict[str, dict[str, Num]] = {}
    fitness: float = math.inf
    rmse_over_noise: dict[str, Num] = {}
    fit_percent: dict[str, Num] = {}
    identifiable: Identifiable = Identifiable()
    step_info: dict[str, Num] = {}
    nfev: Optional[int] = None
    nit: Optional[int] = None
    seconds: Num = None
    seed: Optional[int] = None
    message: str = ""
    history: list[Num] = []
    per_run: dict[str, Any] = {}
    dataset: dict[str, Any] = {}

    @field_validator("fitness", mode="before")
    @classmethod
    def _no_fitness_is_worst(cls, v):
        # a fit that reported none ranks last when the best method is chosen
        return math.inf if v is None else v

    @property
    def result(self) -> IdentResult:
        """The optimiser's record (what ``plot_convergence`` draws from)."""
        return IdentResult(x=np.empty(0), fun=self.fitness, nfev=self.nfev or 0,
                           nit=self.nit or 0, seed=self.seed, message=self.message,
                           method=self.method, history=[h for h in self.history if h is not None])

    @property
    def run_names(self) -> set[str]:
        """The runs it was fitted on, as far as the record says."""
        return set(self.per_run) | set(self.dataset.get("runs") or ())


class IdentifyAllDoc(IdentRecord):
    """``identify --method all``: the best fit's keys at the top, every method under
    ``results``; or the JSON of a single method."""

    params: dict[str, Num] = {}
    best: Optional[str] = None
    results: dict[str, IdentRecord] = {}

    def records(self) -> tuple[list[IdentRecord], str | None]:
        """Each method's record (named by its key when it does not say) and the best."""
        if self.results:
            return ([r if "method" in r.model_fields_set else r.model_copy(update={"method": k})
                     for k, r in self.results.items()], self.best)
        if "params" in self.model_fields_set:
            return [IdentRecord.model_validate(self.model_dump(exclude={"best", "results"}))], \
                self.method
        return [], None


# -- diagnosis.json -------------------------------------------------------------------

class RegimeStat(_Doc):
    rmse_over_noise: float
    share_of_time: float
    share_of_error: Num = None


class Worst(_Doc):
    channel: str
    regime: Regime
    rmse_over_noise: Num = None


class Regimes(_Doc):
    """The error of a model by regime and by run amplitude, per channel."""

    by_regime: dict[str, dict[Regime, RegimeStat]]
    by_amplitude: dict[str, dict[str, float]] = {}
    worst: Optional[Worst] = None
    noise: dict[str, Num] = {}


class CrossValidated(_Doc):
    baseline: float
    with_effect: float
    improvement: Num = None
    folds_improved: int = 0
    folds: int = 0
    evidence: list[dict] = []


class CandidateDoc(_Doc):
    effect: str
    rmse_over_noise: float
    improvement: float
    delta_bic: Num = None
    params: dict[str, Num] = {}
    fit_percent: dict[str, Num] = {}
    cross_validated: Optional[CrossValidated] = None
    at_bound: list[str] = []
    supported: bool = False
    explanation: str = ""


class Baseline(_Doc):
    source: str = "the model"
    effects: list[str] = []
    rmse_over_noise: dict[str, Num] = {}
    fit_percent: dict[str, Num] = {}
    fitness: Num = None


class Criteria(_Doc):
    min_improvement: Num = None
    max_delta_bic: Num = None


class DiagnosisDoc(_Doc):
    """``labrig diagnose --json``."""

    baseline: Baseline = Baseline()
    regimes: Regimes
    ranking: list[CandidateDoc] = []
    recommendation: Optional[str] = None
    verdict: str = ""
    cross_validation: Optional[dict] = None
    noise: dict = {}
    weights: dict = {}
    criteria: Criteria = Criteria()
    seconds: Num = None

    def result(self) -> Diagnosis:
        """The :class:`Diagnosis` (without its live models: the JSON has none)."""
        ranking = [Candidate(effect=c.effect, rmse_over_noise=c.rmse_over_noise,
                             improvement=c.improvement, delta_bic=c.delta_bic,
                             params=dict(c.params), fit_percent=dict(c.fit_percent),
                             cross_validated=(c.cross_validated.model_dump()
                                              if c.cross_validated else None),
                             at_bound=list(c.at_bound),
                             supported=c.supported, explanation=c.explanation)
                   for c in self.ranking]
        return Diagnosis(baseline=self.baseline.model_dump(), regimes=self.regimes.model_dump(),
                         ranking=ranking, recommendation=self.recommendation,
                         verdict=self.verdict, cross_validation=self.cross_validation,
                         noise=dict(self.noise), weights=dict(self.weights),
                         criteria=self.criteria.model_dump(), seconds=self.seconds)


# -- ladder.json ----------------------------------------------------------------------

class Rmse(_Doc):
    overall: float
    speed: Num = None
    position: Num = None


class StepDoc(_Doc):
    label: str = ""
    effects: list[str] = []
    rmse_over_noise: Rmse
    fit_percent: dict[str, Num] = {}
    fitness: Num = None
    cross_validated: Num = None
    model: Optional[str] = None


class LadderDoc(_Doc):
    """``labrig ladder --json``."""

    steps: list[StepDoc]

    def result(self) -> Ladder:
        return Ladder([LadderStep(label=s.label, effects=list(s.effects),
                                  rmse_over_noise=s.rmse_over_noise.model_dump(),
                                  fit_percent=dict(s.fit_percent), fitness=s.fitness,
                                  model=s.model, cross_validated=s.cross_validated)
                       for s in self.steps])


# -- reading --------------------------------------------------------------------------

#: the one-line reasons the page has always given for the two shapes a stage's file
#: is most often wrong in: (schema, key, only when the key itself is wrong)
_REASONS = {(DiagnosisDoc, "regimes"): ("no 'regimes' key", True),
            (LadderDoc, "steps"): ("'steps' is not a list of steps", False)}


def read_artefact(path: Path, schema: type[_Doc], notes: list):
    """``path`` validated as ``schema``, or None when it is absent or does not fit
    (then a note on the page says why).

    Parameters
    ----------
    path : Path
        The artefact in the work folder.
    schema : type
        One of the document models above.
    notes : list of str
        Receives one sentence per ignored file.
    """
    if not path.is_file():
        return None
    try:
        if path.stat().st_size > MAX_JSON_BYTES:
            raise ValueError(f"larger than {MAX_JSON_BYTES // 2 ** 20} MiB")
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError, RecursionError) as exc:
        notes.append(f"{path} was ignored: not valid JSON ({exc}).")
        return None
    if not isinstance(data, dict):
        notes.append(f"{path} was ignored: not a JSON object.")
        return None
    try:
        return schema.model_validate(data)
    except ValidationError as exc:
        loc = exc.errors()[0]["loc"]
        why, whole = _REASONS.get((schema, loc[0] if loc else None), (None, False))
        if why is None or (whole and len(loc) > 1):
            why = describe(schema, exc)
        notes.append(f"{path} was ignored: {why}.")
        return None
    except RecursionError:
        notes.append(f"{path} was ignored: nested too deeply.")
        return None
