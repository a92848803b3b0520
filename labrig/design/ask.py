"""Ask until sure: short experiments played one at a time, each chosen on everything
recorded so far, until one explanation of a pair wins by the decision's margin or the
budget is spent (sequential design, docs/physics.md, 'Experiments that decide').

A one-shot proposal (:func:`labrig.design.propose.propose`) must separate the pair for
every truth the data allow, so it spends its whole budget on the hardest one. Asked in
steps, the rig answers for the truth it actually has: when the first short run already
decides, the rest of the budget is never played. Each step is the best input of at most
``step_s`` seconds for the data as they now stand (earlier steps included, so a step that
pinned a size lets the next aim at it), played, added, and judged by
:func:`labrig.design.decide.decide` -- the same fits and the same measure as a one-shot
decision. The rig seconds used are reported beside the one-shot plan's.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Optional

from pydantic import Field, computed_field

from labrig.core.display import Displayable
from labrig.core.record import Record, TupleOf
from labrig.core.errors import UserError
from labrig.core.tables import Table
from labrig.design.decide import Decision, decide
from labrig.design.proposal import DECISIVE, SEPARATION
from labrig.design.propose import propose
from labrig.model.model import Model

#: the shortest step worth playing (s): a lead-in and one level
MIN_STEP_S = 2.0
#: asking stops as futile after this many steps in a row that left the separation
#: below :data:`FUTILE`: the rig shows no difference where each was chosen to show one
FUTILE_STEPS = 2
FUTILE = 0.1


@dataclass
class AskStep(Record):
    """One short experiment played: what it was and where the decision stood after it
    (its JSON: the decision's separation, leader and rmse/noise after it)."""

    readable = False   # (a summary of live objects: not read back)

    label: Annotated[str, Field(alias="input")]
    duration_s: float
    # its predicted separation, worst over the plausible truths
    predicted: Annotated[Optional[float], Field(alias="predicted_separation")]
    decision: Annotated[Decision, Field(exclude=True)]

    @computed_field
    @property
    def separation_after(self) -> float:
        """The decision's separation after this step."""
        return Decision.separation(self.decision.after)

    @computed_field
    @property
    def leader(self) -> str:
        """The better explanation after this step."""
        return self.decision.leader

    @computed_field
    @property
    def rmse_over_noise(self) -> dict[str, float]:
        """Each explanation's rmse/noise on every run so far."""
        return self.decision.after


@dataclass(repr=False)
class Asking(Displayable, Record):
    """The experiments asked one at a time, the decision after each, and why it stopped."""

    readable = False   # (a summary of live objects: not read back)

    pair: Annotated[TupleOf, Field(alias="between")]
    steps: list[AskStep] = field(default_factory=list)
    budget_s: float = 20.0
    step_s: float = 5.0
    # the one-shot plan's length, for comparison
    one_shot_s: Annotated[Optional[float], Field(alias="one_shot_seconds")] = None
    stopped: str = ""

    @computed_field
    @property
    def rig_seconds(self) -> float:
        """The rig time the steps took (s)."""
        return float(sum(s.duration_s for s in self.steps))

    @property
    def decision(self) -> Decision | None:
        return self.steps[-1].decision if self.steps else None

    @computed_field
    @property
    def sure(self) -> bool:
        d = self.decision
        return d is not None and not d.neither and Decision.separation(d.after) >= DECISIVE

    @computed_field
    @property
    def leader(self) -> Optional[str]:
        """The explanation the rig chose; None until sure."""
        return self.decision.leader if self.sure else None

    def headline(self) -> str:
        a, b = self.pair
        if self.sure:
            return (f"Asked the rig: {self.leader} explains the data ({len(self.steps)} "
                    f"experiment(s), {self.rig_seconds:.1f} s of rig time)")
        return f"Asked the rig between {a} and {b}: not decided ({self.stopped})"

    def table_rows(self) -> Table:
        t = Table(f"asked the rig, one short experiment at a time ({self.pair[0]} or "
                  f"{self.pair[1]})", ["step", "input", "seconds", "separation after",
                                       "leader"], numeric=(2, 3))
        t.rows = [[str(k), s.label, f"{s.duration_s:.1f}",
                   f"{Decision.separation(s.decision.after):.2f}", s.decision.leader]
                  for k, s in enumerate(self.steps, 1)]
        t.notes.append(f"separation ({SEPARATION}); sure at {DECISIVE:g} or more")
        return t

    def _figure_for_html(self):
        return None

    def to_text(self) -> str:
        lines = [f"asked the rig between {self.pair[0]} and {self.pair[1]}, experiments of "
                 f"at most {self.step_s:g} s within {self.budget_s:g} s:"]
        for k, s in enumerate(self.steps, 1):
            d = s.decision
            lines.append(f"  {k}. {s.label} ({s.duration_s:.1f} s): separation "
                         f"{Decision.separation(d.after):.2f} after it, {d.leader} ahead "
                         f"(rmse/noise " + ", ".join(f"{e} {v:.2f}" for e, v in d.after.items())
                         + ")")
        used = f"{self.rig_seconds:.1f} s of rig time"
        if self.one_shot_s is not None:
            used += f" (the one-shot plan: {self.one_shot_s:.1f} s)"
        if self.sure:
            lines.append(f"sure: {self.leader} explains the data, the other's rmse/noise at "
                         f"least twice its own; {used}")
        else:
            lines.append(f"not decided: {self.stopped}; {used}")
        return "\n".join(lines)


def ask_until_sure(runs, model: Model, between: str, play, *, budget_s: float = 20.0,
                   step_s: float = 5.0, seed: int = 0, amax: float | None = None, rig=None,
                   loop: str = "open", log=None, on_step=None) -> Asking:
    """Play experiments of at most ``step_s`` seconds one at a time until the pair
    ``between`` (``"a,b"``) is decided or ``budget_s`` seconds of rig time are spent.

    Parameters
    ----------
    runs : list of Run
        The data so far (open-loop runs among them: the rig plays the input).
    model : Model
        The current model; the pair's effects are swapped in and out of it.
    play : callable(plan_toml: str, k: int) -> list of Run
        Plays the plan of step ``k`` (1, 2, ...) on the rig and returns its runs (none:
        the rig was stopped, and asking ends with the steps finished).
    amax, rig, loop :
        As :func:`labrig.design.propose.propose`'s (``loop``: which inputs each step
        may be: the amplifier's, the rig's position loop's reference, or either).
    on_step : callable(AskStep, runs), optional
        Each step as it is judged, with the runs it played (its decision's ``models``
        are both explanations fitted to everything so far: what a figure draws).

    Returns
    -------
    Asking
        ``sure`` when one explanation's rmse/noise is at most half the other's.
    """
    if not MIN_STEP_S <= step_s <= budget_s:
        raise UserError(f"step_s: {step_s:g} s; give {MIN_STEP_S:g} s to the budget "
                        f"({budget_s:g} s)")
    say = log or (lambda s: None)
    data = list(runs)
    # the one-shot plan first (no rig time): its length is the comparison, and when no
    # input of the whole budget separates the pair for any truth the data allow, there
    # is nothing to ask (the one-shot proposal writes no plan either)
    say("the one-shot plan of the whole budget, for comparison")
    one = propose(data, model, between, budget_s=budget_s, amax=amax, seed=seed, rig=rig,
                  loop=loop)
    out = Asking(pair=one.pair, budget_s=budget_s, step_s=step_s,
                 one_shot_s=float(one.chosen.candidate.duration) if one.separates else None)
    between = ",".join(one.pair)
    if max(one.chosen.refit.values(), default=0.0) < DECISIVE:
        out.stopped = (f"nothing to ask: no input within {budget_s:g} s is predicted to "
                       f"separate them for any truth the data allow; {one.advice}")
        return out
    k = 0
    while True:
        left = budget_s - out.rig_seconds
        if left < MIN_STEP_S:
            out.stopped = f"the budget of {budget_s:g} s is spent"
            break
        k += 1
        say(f"step {k}: the best input of at most {min(step_s, left):g} s for the data so far")
        prop = propose(data, model, between, budget_s=min(step_s, left), amax=amax,
                       seed=seed, rig=rig, loop=loop)
        c = prop.chosen
        if not prop.separates and not c.refit:
            out.stopped = f"nothing more to ask: {prop.advice}"
            break
        # (a step need not decide alone: it adds evidence, and the next is chosen on it)
        plan = prop.to_toml(name=f"asked{k}", step=True)
        say(f"step {k}: playing {c.candidate.label} ({c.candidate.duration:.1f} s)")
        new = play(plan, k)
        if not new:   # the rig was stopped: every finished step is kept
            out.stopped = f"the rig was stopped during step {k}"
            break
        data += new
        d = decide(data, model, seed=seed)
        out.steps.append(AskStep(c.candidate.label, float(c.candidate.duration), c.worst, d))
        if on_step is not None:
            on_step(out.steps[-1], new)
        say(f"step {k}: separation {Decision.separation(d.after):.2f}, {d.leader} ahead")
        if out.sure:
            out.stopped = "decided"
            break
        if d.neither:
            out.stopped = (f"neither explains step {k}'s run (rmse/noise "
                           f"{d.after[d.leader]:.2f} for the better, {d.leader}): what it shows "
                           "is another effect than these two")
            break
        if len(out.steps) >= FUTILE_STEPS and all(
                Decision.separation(st.decision.after) < FUTILE for st in out.steps[-FUTILE_STEPS:]):
            out.stopped = (f"{FUTILE_STEPS} experiments in a row showed no difference "
                           f"(separation below {FUTILE:g} after each): on this rig the two "
                           "explanations are the same model, near enough (one holds the "
                           "other at a size of zero)")
            break
    return out

