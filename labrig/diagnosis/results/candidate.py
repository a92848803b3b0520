"""One candidate of a diagnosis (an effect tried on the data: re-fitted, scored and
explained) and the shapes of a diagnosis's nested records, each declared once as its JSON
form (:mod:`labrig.core.record`); :mod:`labrig.diagnosis.results.diagnosis` holds the
diagnosis."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any, Literal, Optional

from pydantic import Field, computed_field
from typing_extensions import NotRequired, TypedDict

from labrig.core.record import Num, Record, empty, keeps_extra_keys, unset
from labrig.diagnosis.evidence.evaluation import Evaluation
from labrig.diagnosis.evidence.residuals import REGIMES
from labrig.model import drive_units
from labrig.model.effects import CATALOGUE, get_effect
from labrig.model.model import Model

Regime = Literal[REGIMES]


# -- the shapes of the JSON's nested records ------------------------------------------------

@keeps_extra_keys
class RegimeStat(TypedDict):
    rmse_over_noise: float
    share_of_time: float
    share_of_error: NotRequired[Num]


@keeps_extra_keys
class Worst(TypedDict):
    channel: str
    regime: Regime
    rmse_over_noise: NotRequired[Num]


@keeps_extra_keys
class Regimes(TypedDict):
    """A model's error by regime and by run amplitude, per channel, and the worst."""

    by_regime: dict[str, dict[Regime, RegimeStat]]
    by_amplitude: NotRequired[dict[str, dict[str, float]]]
    worst: NotRequired[Optional[Worst]]
    noise: NotRequired[dict[str, Num]]


@keeps_extra_keys
class CrossValidated(TypedDict):
    """A candidate's held-out evidence against the model it changes."""

    baseline: float
    with_effect: float
    improvement: NotRequired[Num]
    folds_improved: NotRequired[int]
    folds: NotRequired[int]
    per_fold: NotRequired[list[dict]]
    not_counted: NotRequired[list[dict]]
    evidence: NotRequired[list[dict]]


@keeps_extra_keys
class Baseline(TypedDict, total=False):
    """The diagnosed model's error and size."""

    source: str
    effects: list[str]
    rmse_over_noise: dict[str, Num]
    fit_percent: dict[str, Num]
    fitness: Num
    bic: Num
    n: Optional[int]
    n_effective: Num
    cross_validated: Num
    #: each run's fitted start where it is not rest (labrig.model.start)
    starts: dict[str, dict[str, float]]


@keeps_extra_keys
class Criteria(TypedDict, total=False):
    min_improvement: Num
    max_delta_bic: Num
    floor: Num


@dataclass
class Candidate(Record):
    """One catalogue effect tried on the data: re-fitted, scored and explained.

    Its fields are its record in ``labrig diagnose --json`` (``ranking``), but for the
    live ones (the re-fitted model, its evaluation and cross-validation); ``params`` is
    written in the drive's units (:meth:`shown_params`) and ``label`` is the move.
    """

    # (a record read back may lack what it can do without: pydantic defaults)
    effect: str
    rmse_over_noise: float
    improvement: float
    delta_bic: Annotated[Num, Field(default=None)]
    # (written as shown_params(): the drive's units)
    params: Annotated[dict[str, Num], Field(exclude=True, default_factory=dict)]
    fit_percent: Annotated[dict[str, Num], Field(default_factory=dict)]
    #: held-out evidence: baseline and candidate cross-validated rmse/noise, the folds
    #: it improved, and the regimes that carry the gain
    cross_validated: Annotated[Optional[CrossValidated], Field(exclude_if=unset)] = None
    supported: bool = False
    #: not cross-validated: its in-sample error is beyond reach of this held-out score of
    #: the best supported candidate (criteria.out_of_reach); None: not so judged
    out_of_reach: Annotated[Num, Field(exclude_if=unset)] = None
    explanation: str = ""
    #: parameters whose fit ended at a bound of the search space
    at_bound: list[str] = field(default_factory=list)
    #: "add" (``effect`` added), "remove" (``effect`` taken out) or "replace"
    #: (``replaces`` taken out, ``effect`` put in its place)
    move: Literal["add", "remove", "replace"] = "add"
    replaces: Annotated[Optional[str], Field(exclude_if=empty)] = None
    #: parameters the move adds to the model (negative: takes away)
    extra_params: Annotated[int, Field(exclude=True)] = 1
    #: why the effect's fitted size is not resolved by the data (None: it is)
    unresolved: Annotated[Optional[str], Field(exclude_if=empty)] = None
    #: the share of the candidate's error the effect itself carries (the error with the
    #: effect switched off, the rest unchanged, is ``off_fitness``); None: not checked
    carried: Annotated[Num, Field(exclude_if=unset)] = None
    off_fitness: Annotated[Num, Field(exclude=True)] = field(default=None, repr=False)
    #: starts of its re-fit that diverged (their simulation overflowed) and were dropped
    failed_starts: Annotated[int, Field(exclude_if=empty)] = 0
    #: screened out (:func:`labrig.diagnosis.evidence.criteria.screen`): its re-fit was ended
    #: after this many iterations, stalled below the screen's gain; its numbers are
    #: where the re-fit stood then. None: re-fitted to the end
    screened: Annotated[Optional[int], Field(alias="screened_after_iterations",
                                             exclude_if=unset)] = None
    #: live, not in the JSON: the re-fitted model and its evaluation on all runs
    model: Annotated[Optional[Model], Field(exclude=True)] = field(default=None, repr=False)
    evaluation: Annotated[Optional[Evaluation], Field(exclude=True)] = field(default=None,
                                                                             repr=False)
    #: live, not in the JSON: its cross-validation (the next round's baseline when the
    #: search takes it)
    held_out: Annotated[Any, Field(exclude=True)] = field(default=None, repr=False)

    @computed_field
    @property
    def label(self) -> str:
        """The move in the ranking and the recommendation: ``deadband`` (add it),
        ``- deadband`` (remove it), ``coulomb_friction -> deadband`` (replace)."""
        if self.move == "remove":
            return f"- {self.effect}"
        if self.move == "replace":
            return f"{self.replaces} -> {self.effect}"
        return self.effect

    @property
    def action(self) -> str:
        """The move in words: 'Add deadband', 'Remove deadband', 'Replace X by Y'."""
        return {"add": f"Add {self.effect}", "remove": f"Remove {self.effect}",
                "replace": f"Replace {self.replaces} by {self.effect}"}[self.move]

    @property
    def regimes(self) -> dict | None:
        return self.evaluation.regimes if self.evaluation is not None else None

    def shown_params(self) -> dict:
        """The effect's parameters in the drive's units (:mod:`labrig.model.drive_units`)."""
        m = self.model
        if m is None or m.plant == "voltage":
            return dict(self.params)
        eff = m.effects.by_name(self.effect) if self.effect in m.names else None
        if eff is None:
            eff = get_effect(self.effect) if self.effect in CATALOGUE else None
        if eff is None:
            return dict(self.params)

        return drive_units.to_drive([eff], {self.effect: self.params}, m.plant,
                                    m.constants)[self.effect]

    @computed_field(alias="params")
    @property
    def _params_shown(self) -> dict[str, Num]:
        return self.shown_params()
