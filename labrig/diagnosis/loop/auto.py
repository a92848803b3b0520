"""``labrig diagnose --auto``: the missing-physics loop run to the end.

:func:`labrig.diagnosis.loop.search.search` adds, pairs, swaps and removes effects round after round
until the cross-validated error stops falling (or ``max_rounds`` effects were added).
The result holds the final model, the error ladder (in-sample and cross-validated),
the moves of the search, the thresholds of the final model stated through the effects
in front of them, and the *confusable pairs*: candidates that explain the data about
equally well, with the regime where their predictions differ most (where an experiment
should look).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any, Optional

from pydantic import Field, PlainSerializer, computed_field

from labrig.diagnosis.results.diagnosis import Candidate, Diagnosis
from labrig.diagnosis.words.explain import thresholds
from labrig.diagnosis.results.ladder import Ladder
from labrig.model.effects import get_effect
from labrig.model.model import Model
from labrig.diagnosis.evidence.residuals import REGIME_TEXT
from labrig.core.tables import Table, fmt
from labrig.core.display import Displayable
from labrig.core.record import AsJson, Record, TupleOf
from labrig.diagnosis.loop.moves import Move
from labrig.diagnosis.loop.search import search
from labrig.analysis.agreement import lag_explained
from labrig.identification.identifiability import time_constants
from labrig.diagnosis.loop.diagnose import agreement_of

#: two candidates are confusable when their errors differ by less than this (relative)
CONFUSABLE = 0.10


def _steps(ladder: Ladder) -> list[dict]:
    return ladder.to_json()["steps"]


@dataclass
class ConfusablePair(Record):
    """Two effects that explain the data about equally well."""

    readable = False   # (a summary of live objects: not read back)

    first: Annotated[str, Field(exclude=True)]
    second: Annotated[str, Field(exclude=True)]
    rmse_over_noise: TupleOf
    # {"channel", "regime", "first", "second"}: where they differ most
    differ_in: Optional[dict[str, Any]]
    round: int

    @computed_field
    @property
    def pair(self) -> list[str]:
        """The two effects."""
        return [self.first, self.second]


@dataclass(repr=False)
class AutoDiagnosis(Displayable, Record):
    """Every round's diagnosis, the final model, its ladder and the confusable pairs.

    Attributes
    ----------
    rounds : list of Diagnosis
        One per round of the search.
    model : Model
        Where the search ended.
    ladder : Ladder
        The error after each move, in-sample and held out.
    confusable : list of ConfusablePair
        Explanations the data leave about equal, with where they differ most.
    moves : list
        The search's moves (add, pair, swap, remove) with the held-out error before
        and after each.

    Examples
    --------
    >>> import labrig as lr
    >>> res = lr.auto("data/sweep_default")  # doctest: +SKIP
    >>> res.model.names, round(res.ladder.steps[-1].rmse_over_noise["overall"])  # doctest: +SKIP
    (['coulomb_friction'], 1)
    """

    readable = False   # (a summary of live objects: not read back)

    rounds: list[Diagnosis]
    model: Annotated[Model, Field(alias="final_model"), AsJson]
    # (written as its steps)
    ladder: Annotated[Ladder, PlainSerializer(_steps)]
    confusable: list[ConfusablePair] = field(default_factory=list)
    moves: list[Move] = field(default_factory=list)
    thresholds: str = ""
    #: a fitted lag that is the speed sensor's, in words ('' when none)
    sensor_lag: str = ""

    def headline(self) -> str:
        """The first line of the ``repr``: the final effects and how many rounds.

        Returns
        -------
        str
        """
        return (f"AutoDiagnosis: final effects {', '.join(self.model.names) or 'none'} after "
                f"{len(self.rounds)} round(s)")

    @computed_field
    @property
    def effects(self) -> list[str]:
        """The final model's effects."""
        return self.model.names

    @computed_field
    @property
    def noise(self) -> dict:
        """Each channel's noise floor and how it was measured (the first round's)."""
        return self.rounds[0].noise if self.rounds else {}

    @computed_field
    @property
    def weights(self) -> dict:
        """The channel weights (the first round's)."""
        return self.rounds[0].weights if self.rounds else {}

    @computed_field
    @property
    def cross_validation(self) -> Optional[dict]:
        """How the held-out folds were cut (the first round's)."""
        return self.rounds[0].cross_validation if self.rounds else None

    @computed_field
    @property
    def added(self) -> list[str]:
        """Effects added, in order (a pair adds two; swaps and removals not counted)."""
        return [e for m in self.moves if m.kind in ("add", "pair") for e in m.effects]

    @computed_field
    @property
    def verdict(self) -> str:
        """The final model and its thresholds in words, the last round's verdict when it
        recommends nothing more, and a fitted lag that is the sensor's; '' with no rounds."""
        if not self.rounds:
            return ""
        last = self.rounds[-1]
        head = (f"Final model: {', '.join(self.model.names) or 'no effects'}. "
                + (self.thresholds + " " if self.thresholds else ""))
        tail = f" {self.sensor_lag}" if self.sensor_lag else ""
        return (head + last.verdict if not last.recommendation else head.rstrip()) + tail

    def table_rows(self) -> list[Table]:
        """The error ladder and the confusable pairs.

        Returns
        -------
        list of Table
            The ladder's table (:meth:`Ladder.table_rows`), then one row per confusable
            pair: its round, rmse/noise and the regime where the two differ most.
        """
        pairs = Table("confusable pairs", ["round", "pair", "rmse/noise", "they differ most in"])
        pairs.notes.append("about equally good explanations: an experiment should decide")
        for p in self.confusable:
            d = p.differ_in
            where = (f"{REGIME_TEXT[d['regime']]} of the {d['channel']} "
                     f"({d['first']:.2f} vs {d['second']:.2f})") if d else "-"
            pairs.rows.append([str(p.round), f"{p.first} / {p.second}",
                               f"{fmt(p.rmse_over_noise[0], '.2f')} / "
                               f"{fmt(p.rmse_over_noise[1], '.2f')}", where])
        if not self.confusable:
            pairs.notes.append("none: every supported effect was clearly better than the next")
        return [self.ladder.table_rows(), pairs]

    def to_text(self) -> str:
        """What ``labrig diagnose --auto`` prints: the tables, the moves, the noise
        floors, weights and folds, the final model and the verdict.

        Returns
        -------
        str
        """
        out = [t.to_text() + "\n" for t in self.table_rows()]
        if self.moves:
            out.append("moves: " + "; ".join(f"round {m.round}: {m.label} (cross-validated "
                                              f"{m.cv_before:.2f} -> {m.cv_after:.2f})"
                                              for m in self.moves))
        if self.rounds:
            first = self.rounds[0]
            for v in first.noise.values():
                out.append(f"noise floor, {v['method']}")
            w = first.weights
            if w:
                out.append(f"channel weights: speed {w['speed']:.3g}, position "
                           f"{w['position']:.3g} in noise units; "
                           + (w["why"] if w.get("why") else "each channel has the same say at "
                              "the starting model"))
            if first.cross_validation:
                out.append(f"cross-validation: {first.cross_validation['folds']} folds, "
                           f"{first.cross_validation['kind']}")
        out.append(f"final model: {self.model.describe()}")
        out.append(self.verdict)
        return "\n".join(out)

    def plot(self, ax=None):
        """The error ladder: rmse/noise after each move against the noise floor.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            As :meth:`Ladder.plot`'s.

        Returns
        -------
        matplotlib.figure.Figure
            :meth:`Ladder.plot`'s figure of :attr:`ladder`.
        """
        return self.ladder.plot(ax=ax)


def confusable_pairs(diag: Diagnosis, round_no: int, margin: float = CONFUSABLE) -> list:
    """Candidates of one round that clearly improve the model (by the diagnosis' minimum
    gain) and lie within ``margin`` of the best one, each paired with the best, and the
    regime where their errors differ most. Members of one family (a symmetric and an
    asymmetric dead zone, Coulomb friction and stiction) are not pairs: one is the other
    with a parameter more, and the search already prefers the simpler."""
    useful = [c for c in diag.ranking if c.improvement >= diag.criteria["min_improvement"]]
    if len(useful) < 2:
        return []
    best = min(useful, key=lambda c: c.rmse_over_noise)
    out = []
    for c in useful:
        if c is best or c.rmse_over_noise > (1 + margin) * best.rmse_over_noise:
            continue
        if get_effect(c.effect).family_name == get_effect(best.effect).family_name:
            continue  # one is the other with a parameter more: not a different explanation
        out.append(ConfusablePair(best.effect, c.effect, (best.rmse_over_noise, c.rmse_over_noise),
                                  _where_they_differ(best, c), round_no))
    return out


def _where_they_differ(a: Candidate, b: Candidate) -> dict | None:
    best = None
    for ch, regs in (a.regimes or {}).get("by_regime", {}).items():
        for reg, va in regs.items():
            vb = (b.regimes or {}).get("by_regime", {}).get(ch, {}).get(reg)
            if vb is None or va["share_of_time"] < 0.005:
                continue
            gap = abs(va["rmse_over_noise"] - vb["rmse_over_noise"])
            if best is None or gap > best[0]:
                best = (gap, {"channel": ch, "regime": reg, "first": va["rmse_over_noise"],
                              "second": vb["rmse_over_noise"]})
    return best[1] if best else None


def auto_diagnose(runs, model: Model | None = None, *, max_rounds: int = 3, seed: int = 0,
                  fixed: dict | None = None, weights=None, log=None,
                  on_step=None, screen: bool = True, on_candidate=None) -> AutoDiagnosis:
    """Run the search (:func:`labrig.diagnosis.loop.search.search`) and name the confusable pairs of
    every round.

    Parameters
    ----------
    runs : list of Run
    model : Model, optional
        Where to start (default: the linear model, identified by the first round).
    max_rounds : int
        At most this many effects are added.
    seed : int
    fixed : dict, optional
        Parameters known from other measurements.
    weights : Weights, optional
        Channel weights (default: balanced on the starting model).
    log : callable(str), optional
    on_step : callable(k, model), optional
        Called for every rung of the ladder as the search climbs it (k = 0: the start).
    screen : bool
        End a candidate's re-fit early when it stalls without gaining (default True;
        :func:`labrig.diagnosis.evidence.criteria.screen`).
    on_candidate : callable(candidate, cv), optional
        Each round's candidates as they are re-fitted (cv None) and cross-validated.
    """
    res = search(runs, model, max_rounds=max_rounds, seed=seed, fixed=fixed, weights=weights,
                 log=log, on_step=on_step, screen=screen, on_candidate=on_candidate)
    pairs = [p for k, diag in enumerate(res.rounds, 1) for p in confusable_pairs(diag, k)]
    return AutoDiagnosis(rounds=res.rounds, model=res.model, ladder=res.ladder,
                         confusable=pairs, moves=res.moves,
                         thresholds=thresholds(res.model, runs),
                         sensor_lag=sensor_lag(res.model, runs, res.rounds[0].evaluation))


def sensor_lag(model: Model, runs, ev) -> str:
    """A sentence when the model's fitted lag (electrical pole, delay) is the speed
    sensor's (:func:`labrig.analysis.agreement.lag_explained`); '' otherwise."""
    if "speed" not in ev.floors:
        return ""
    agree = agreement_of(runs, ev) if "position" in ev.floors else None
    tc = time_constants(model.plant_class, model.params, model.constants)
    # a window the import found is its guess (the sample before), not the owner's word
    declared = max((r.speed_window_s for r in runs
                    if not r.sensors.get("speed_window_found")), default=0.0)
    return lag_explained(agree, tc.get("tau_e_s"),
                         model.effect_params.get("delay", {}).get("td_s"), tc.get("tau_m_s"),
                         declared)
