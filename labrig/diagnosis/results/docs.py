"""The JSON of ``labrig diagnose --json`` (``diagnosis.json``) and ``labrig ladder
--json`` (``ladder.json``): their one definition. :meth:`~labrig.diagnosis.results.diagnosis.Diagnosis.to_json`
and :meth:`~labrig.diagnosis.results.ladder.Ladder.to_json` write them; a test checks that every key
they write is declared here, and ``result()`` turns a record back into the result.
"""
from __future__ import annotations

from typing import Literal, Optional

from labrig.core.schemas import JsonDoc as _Doc
from labrig.diagnosis.results.ladder import Ladder, LadderStep
from labrig.diagnosis.results.diagnosis import Candidate, Diagnosis
from labrig.diagnosis.evidence.residuals import REGIMES

Num = Optional[float]
Regime = Literal[REGIMES]


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
    per_fold: list[dict] = []
    not_counted: list[dict] = []
    evidence: list[dict] = []


class CandidateDoc(_Doc):
    effect: str
    move: Literal["add", "remove", "replace"] = "add"
    label: str = ""
    replaces: Optional[str] = None
    unresolved: Optional[str] = None
    carried: Num = None
    rmse_over_noise: float
    improvement: float
    delta_bic: Num = None
    params: dict[str, Num] = {}
    fit_percent: dict[str, Num] = {}
    cross_validated: Optional[CrossValidated] = None
    at_bound: list[str] = []
    failed_starts: int = 0
    supported: bool = False
    explanation: str = ""


class Baseline(_Doc):
    source: str = "the model"
    effects: list[str] = []
    rmse_over_noise: dict[str, Num] = {}
    fit_percent: dict[str, Num] = {}
    fitness: Num = None
    bic: Num = None
    n: Optional[int] = None
    n_effective: Num = None
    cross_validated: Num = None
    #: each run's fitted start where it is not rest (labrig.model.start)
    starts: dict[str, dict[str, float]] = {}


class Criteria(_Doc):
    min_improvement: Num = None
    max_delta_bic: Num = None
    floor: Num = None


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
    diverged: list[str] = []

    def result(self) -> Diagnosis:
        """The :class:`Diagnosis` (without its live models: the JSON has none)."""
        ranking = [Candidate(effect=c.effect, rmse_over_noise=c.rmse_over_noise,
                             improvement=c.improvement, delta_bic=c.delta_bic,
                             params=dict(c.params), fit_percent=dict(c.fit_percent),
                             cross_validated=(c.cross_validated.model_dump()
                                              if c.cross_validated else None),
                             at_bound=list(c.at_bound), move=c.move, replaces=c.replaces,
                             unresolved=c.unresolved, carried=c.carried,
                             supported=c.supported, explanation=c.explanation,
                             failed_starts=c.failed_starts)
                   for c in self.ranking]
        return Diagnosis(baseline=self.baseline.model_dump(), regimes=self.regimes.model_dump(),
                         ranking=ranking, recommendation=self.recommendation,
                         verdict=self.verdict, cross_validation=self.cross_validation,
                         noise=dict(self.noise), weights=dict(self.weights),
                         criteria=self.criteria.model_dump(), seconds=self.seconds,
                         diverged=list(self.diverged))


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
