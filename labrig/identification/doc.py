"""The JSON of ``labrig identify --json`` (``identify_all.json``, and the fit record of
a model file): its one definition. :func:`labrig.identification.table.identification_dict`
writes it; a test checks that every key it writes is declared here.
"""
from __future__ import annotations

import math
from typing import Any, Optional, Union

import numpy as np
from pydantic import field_validator

from labrig.core.schemas import JsonDoc as _Doc
from labrig.identification.result import IdentResult

Num = Optional[float]


class Combination(_Doc):
    value: Num = None
    unit: Optional[str] = None
    identifiable: Optional[bool] = None
    interval95: Optional[list[Num]] = None


class ParamInfo(_Doc):
    value: Num = None
    identifiable: Optional[bool] = None
    fixed: Optional[bool] = None
    interval95: Optional[list[Num]] = None


class Physical(_Doc):
    value: Num = None
    unit: str = ""
    interval95: Optional[list[Num]] = None


class Identifiable(_Doc):
    km: Optional[Combination] = None
    tau_m_s: Optional[Combination] = None
    tau_e_s: Optional[Combination] = None
    parameters: dict[str, ParamInfo] = {}
    warnings: list[str] = []
    current_measured: Optional[bool] = None
    structural_rank: Optional[int] = None
    free_plant_parameters: Optional[int] = None
    all_identifiable: Optional[bool] = None
    #: the model's exact symmetry, when the data leave one (kind, direction, size)
    symmetry: Optional[dict[str, Any]] = None
    relative_singular_values: list[Num] = []
    null_directions: list[dict[str, Any]] = []
    correlated_pairs: list[dict[str, Any]] = []


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
    #: each run's start where it is not rest (labrig.model.start)
    starts: dict[str, Any] = {}
    dataset: dict[str, Any] = {}
    plant: Optional[str] = None
    axis: Optional[str] = None
    units: dict[str, str] = {}
    physical: dict[str, Physical] = {}
    fixed: list[str] = []
    #: each channel's noise floor (its units: ``units``, on a linear axis m and m/s)
    noise: dict[str, Union[Num, dict[str, str]]] = {}
    warnings: list[str] = []

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


