"""Did the proposed runs decide? Both explanations fitted with and without them.

``labrig diagnose DIR DIR/new`` calls :func:`decide` when some runs carry
``experiment.between`` (they were proposed by :func:`labrig.design.propose.propose`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

from pydantic import Field, computed_field

from labrig.core.display import Displayable
from labrig.core.record import Record, TupleOf
from labrig.core.errors import UserError
from labrig.core.tables import Table
from labrig.io.runs import Run
from labrig.diagnosis.loop.refit import refit_with, without, refit
from labrig.model.effects import catalogue_name, get_effect
from labrig.model.model import Model
from labrig.diagnosis.loop.diagnose import linear_model


#: after the proposed runs, a leader more than this many times the noise floor, and more
#: than twice what it reached before them, explains them no better than the other: what
#: the new runs show is neither of the two
NEITHER = 3.0


@dataclass(repr=False)
class Decision(Displayable, Record):
    """How well each of a pair explains the data before and after the proposed runs."""

    pair: Annotated[TupleOf, Field(alias="between")]
    # effect -> rmse/noise on the runs without the proposed ones
    before: Annotated[dict[str, float], Field(alias="rmse_over_noise_before")]
    # effect -> rmse/noise on all runs
    after: Annotated[dict[str, float], Field(alias="rmse_over_noise_after")]
    new_runs: list[str]
    #: effect -> its model fitted to all runs (what a figure draws on the new runs)
    models: Annotated[dict, Field(exclude=True)] = field(default_factory=dict, repr=False)

    @staticmethod
    def separation(r: dict) -> float:
        """The worse explanation's rmse/noise over the better one's, minus one: what every
        text line calls *separation* (a proposal's sum of squares in noise units is its
        *predicted difference*, labrig.design.propose)."""
        lo, hi = sorted(r.values())
        return hi / lo - 1.0

    @computed_field
    @property
    def separation_before(self) -> float:
        """:meth:`separation` on the runs without the proposed ones."""
        return self.separation(self.before)

    @computed_field
    @property
    def separation_after(self) -> float:
        """:meth:`separation` on all runs."""
        return self.separation(self.after)

    @computed_field
    @property
    def leader(self) -> str:
        """The effect that explains all runs better."""
        return min(self.after, key=self.after.get)

    @computed_field
    @property
    def neither(self) -> bool:
        """Neither explanation fits the proposed runs: the better one is far above the noise
        floor after them (:data:`NEITHER`) where it was not before."""
        best = self.after[self.leader]
        return best > NEITHER and best > 2.0 * min(self.before.values())

    def headline(self) -> str:
        if self.neither:
            return (f"Decision between {self.pair[0]} and {self.pair[1]}: neither explains "
                    "the new runs")
        return f"Decision between {self.pair[0]} and {self.pair[1]}: {self.leader} explains better"

    def table_rows(self) -> Table:
        t = Table("rmse/noise before and after the proposed runs",
                  ["explanation", "before", "after"], numeric=(1, 2))
        t.rows = [[e, f"{self.before[e]:.2f}", f"{self.after[e]:.2f}"] for e in self.pair]
        t.notes.append(f"separation (worse rmse/noise over better, minus one): "
                       f"{self.separation(self.before):.3f} before, "
                       f"{self.separation(self.after):.3f} after")
        return t

    def _figure_for_html(self):
        return None

    def to_text(self) -> str:
        a, b = self.pair
        sb, sa = self.separation(self.before), self.separation(self.after)
        other = b if self.leader == a else a
        grew = f", {sa / sb:.1f} times" if sb > 0.01 else ""
        head = (f"the run(s) proposed to tell {a} and {b} apart ({', '.join(self.new_runs)}): "
                f"separation {sb:.3f} before, {sa:.3f} after (worse rmse/noise over better, "
                f"minus one{grew}). ")
        if self.neither:
            return head + (f"Neither explains them: {a} at rmse/noise {self.after[a]:.2f} and "
                           f"{b} at {self.after[b]:.2f} with them, against "
                           f"{self.before[self.leader]:.2f} for {self.leader} before; what "
                           "they show is another effect than these two: diagnose all the runs "
                           "together (--auto) to find it.")
        return head + (f"{self.leader} explains the data better (rmse/noise "
                       f"{self.after[self.leader]:.2f} against {self.after[other]:.2f}).")


def _best_fit_with(runs, base: Model, effect: str, seed: int, start: Model | None):
    """The best of a re-fit from ``start`` and a fit from scanned starts on ``base``."""
    fits = [refit_with(runs, base, get_effect(effect), seed=seed)]
    if start is not None:
        fits.append(refit(runs, start, seed=seed))
        # the earlier fit's plant with the effect scanned afresh: new runs may show the
        # effect where the earlier ones could not place its parameters (a breakaway)
        fits.append(refit_with(runs, without(start, effect), get_effect(effect), seed=seed))
    return min(fits, key=lambda f: f.fitness)


def decide(runs: list[Run], model: Model | None = None, *, seed: int = 0, log=None):
    """When some runs were proposed to tell two effects apart (``experiment.between``),
    fit both explanations with and without them; None when no run was proposed."""
    new = [r for r in runs if r.experiment.get("between")]
    if not new:
        return None
    pair = tuple(catalogue_name(n) for n in new[0].experiment["between"])
    old = [r for r in runs if not r.experiment.get("between")]
    if not old:
        raise UserError("the proposed runs alone cannot show a change: give the folder they "
                        "were proposed for too (labrig diagnose DIR DIR/new)")
    say = log or (lambda s: None)
    out, prev = {}, {}
    for label, data in (("before", old), ("after", runs)):
        base = linear_model(data, seed=seed)
        if model is not None:  # the model's other effects stay (not the pair's families)
            families = {get_effect(n).family_name for n in pair}
            for e in model.effects:
                if e.name not in pair and e.family_name not in families:
                    base = _best_fit_with(data, base, e.name, seed, None).model()
        res = {}
        for name in pair:
            say(f"fitting {name} on the runs {'with' if label == 'after' else 'without'} "
                "the proposed ones")
            # after: also from the fit before, which already explains the old runs
            fit_ = _best_fit_with(data, base, name, seed, prev.get(name))
            prev[name] = fit_.model()
            res[name] = float(fit_.metrics["rmse_over_noise"]["overall"])
        out[label] = res
    return Decision(pair, out["before"], out["after"], [r.name for r in new], dict(prev))
