"""What a proposal weighs: the explanations fitted to the data with the sizes of each
the data cannot exclude (:class:`Hypothesis`), and each candidate input with how well it
separates them (:class:`Judged`); :mod:`labrig.design.proposal` holds the proposal."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Optional

from pydantic import Field, PlainSerializer, computed_field

from labrig.core.record import Live, NoneIfEmpty, Record
from labrig.design.inputs import InputCandidate
from labrig.model.model import Model

#: plausible sizes within this factor of each other: the data pin the size
PINNED = 2.0


def after_number(unit: str) -> str:
    """' V' after a number; nothing for a ratio (a breakaway excess, unit '-')."""
    return "" if unit in ("", "-") else f" {unit}"




def _describe(model) -> str:
    return model.describe()


@dataclass
class Hypothesis(Record):
    """One explanation, fitted to the data, and the sizes of it the data cannot exclude
    (its JSON: the model in words, the size in words, the plausible sizes)."""

    readable = False   # (a summary of live objects: not read back)

    effect: str
    model: Annotated[Model, PlainSerializer(_describe)]
    rmse_over_noise: float
    # its size parameter ("d_v", "tc_v", "a_rad", "td_s")
    key: Annotated[str, Live] = ""
    unit: Annotated[str, Live] = ""
    # [(size, Model)], plausible, best first
    members: Annotated[list, Live] = field(default_factory=list)
    # its size at a bound of the range the data allow
    degenerate: Annotated[bool, Field(alias="at_bound")] = False
    # why it is not judged as the truth ("" when it is)
    skipped: Annotated[str, Field(alias="why_not_judged_true"), NoneIfEmpty] = ""

    @computed_field(alias="size")
    @property
    def _size_text(self) -> str:
        return self.describe_size()

    @computed_field(alias="pinned")
    @property
    def _pinned(self) -> bool:
        return self.pinned

    @computed_field
    @property
    def plausible_sizes(self) -> list[Optional[float]]:
        """Every size the data allow, best first."""
        return [s for s, _ in self.members]

    @computed_field
    @property
    def judged_true(self) -> bool:
        """Whether it is judged as the truth (``skipped`` says why not)."""
        return not self.skipped

    @property
    def size(self) -> float | None:
        return self.model.effect_params[self.effect][self.key] if self.key else None

    @property
    def pinned(self) -> bool:
        """The plausible sizes lie within :data:`PINNED` of each other."""
        sizes = [s for s, _ in self.members if s is not None and s > 0]
        return len(sizes) < 2 or max(sizes) / min(sizes) <= PINNED

    def truths(self) -> list:
        """``[(label, Model)]`` it is judged true as: its best fit when the data pin its
        size, else each plausible variant (the best fit is one point of a range the data
        cannot narrow); none when it is skipped."""
        if self.skipped:
            return []
        if self.pinned:
            return [(self.effect, self.model)]
        return [(self.label(s), m) for s, m in self.members[1:]]

    def label(self, size: float) -> str:
        """How a truth of this explanation at ``size`` is named ('deadband d_v = 0.25 V')."""
        return f"{self.effect} {self.key} = {size:.3g}{self.units}"

    @property
    def units(self) -> str:
        return after_number(self.unit)

    def describe_size(self) -> str:
        if not self.key:
            return ""
        s = f"{self.key} = {self.size:.3g}{self.units}"
        if self.degenerate and self.pinned:
            return s + " (at its bound)"
        if not self.pinned:
            sizes = sorted(v for v, _ in self.members)
            return (f"{self.key} not pinned by the data: {sizes[0]:.3g}-{sizes[-1]:.3g}"
                    f"{self.units} fit as well")
        return s


@dataclass
class Judged(Record):
    """One candidate input and how well it separates the pair."""

    readable = False   # (a summary of live objects: not read back)

    candidate: Annotated[InputCandidate, Live]
    naive: float                      # predicted difference of the best fits (noise units)
    # the worst over plausible truths and rival variants
    robust: Annotated[float, Field(alias="worst_plausible")] = 0.0
    #: plausible truth -> predicted separation after the rival re-fits (leaders only)
    refit: Annotated[dict[str, float], Field(alias="separation_after_refit"),
                     NoneIfEmpty] = field(default_factory=dict)
    #: its re-fits stopped before every truth was tried, once a better input was found
    #: (its worst is then at most the value shown)
    stopped: Annotated[bool, Field(alias="stopped_below_a_better_input")] = False
    #: the hardest case judged: (truth index in the pair, truth label, truth model, the
    #: rival as re-fitted to it) -- what the figure shows
    hardest: Annotated[Optional[tuple], Live] = field(default=None, repr=False)

    @property
    def worst(self) -> float | None:
        """The predicted separation after the rival re-fits, at the hardest truth."""
        return min(self.refit.values()) if self.refit else None

    @computed_field(alias="worst_separation_after_refit")
    @property
    def _worst(self) -> Optional[float]:
        return self.worst

    # -- the input judged, as the JSON names it ------------------------------------------
    @computed_field
    @property
    def kind(self) -> str:
        """The input's family ("ramp", "pulses", ...)."""
        return self.candidate.kind

    @computed_field
    @property
    def label(self) -> str:
        """The input in words, as a plan and the tables name it (its kind, its levels,
        its length)."""
        return self.candidate.label

    @computed_field
    @property
    def duration_s(self) -> float:
        """Its length (s): the last breakpoint's time."""
        return self.candidate.duration

    @computed_field
    @property
    def points(self) -> int:
        """How many breakpoints it has (the board holds :data:`~labrig.design.inputs.MAX_POINTS`
        at most)."""
        return len(self.candidate.points)
