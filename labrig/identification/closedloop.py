"""Closed-loop runs: two ways to identify the plant, and which one a data set allows.

``loop``   through the loop: the reference is the input and the controller (its gains
           from the run's sidecar) is part of the simulated model. Needs nothing else,
           but a stiff loop hides the plant: its response is set mostly by the
           controller, so the plant's parameters barely change the fit.
``input``  from the controller's logged output (the run's ``drive`` column) as the
           plant's input, as if the run were open loop: the plant is seen directly,
           whatever the controller. What a benchmark's own method does when the drive
           command was recorded.

``auto`` takes ``input`` when every closed-loop run logged its controller output, else
``loop``; the reason is reported with the fit.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Annotated

from pydantic import Field

from labrig.core.errors import UserError
from labrig.core.record import Record
from labrig.io.runs import Run

WAYS = ("auto", "loop", "input")


@dataclass
class Way(Record):
    """How the closed-loop runs of a data set are fitted, and why."""

    way: str          # "loop", "input" or "open" (no closed-loop run)
    why: str
    # closed-loop runs concerned
    runs: Annotated[int, Field(alias="closed_loop_runs")] = 0
    #: worth saying: a digital controller or a logged controller output (an MS150's analog
    #: loop has only one way and is fitted through it as always)
    told: Annotated[bool, Field(exclude=True)] = False


def as_open_loop(run: Run) -> Run:
    """A closed-loop run with its logged controller output as the plant's input."""
    data = run.data.copy()
    data["ref"] = data["u"]
    data["u"] = data.pop("drive")
    exp = {k: v for k, v in run.experiment.items()
           if k not in ("controller", "position_gain", "velocity_gain")}
    # (the loop it was played through stays known: a proposal may plan through it)
    meta = {**run.meta, "experiment": {**exp, "loop": "open", "fitted_from": "controller output",
                                       "played_closed": dict(run.experiment)}}
    return replace(run, data=data, meta=meta, _cache={})


def choose_way(runs: list[Run], through: str = "auto") -> tuple[list[Run], Way]:
    """The runs as they will be fitted, and the way chosen (see the module text)."""
    if through not in WAYS:
        raise UserError(f"`through`: '{through}' unknown; choose {', '.join(WAYS)}")
    closed = [r for r in runs if r.loop == "closed"]
    if not closed:
        return runs, Way("open", "open-loop runs: the input drives the plant directly")
    logged = [r for r in closed if "drive" in r.data]
    told = bool(logged) or any(r.controller for r in closed)
    if through == "auto":
        through = "input" if len(logged) == len(closed) else "loop"
    if through == "input":
        if len(logged) < len(closed):
            missing = next(r.name for r in closed if "drive" not in r.data)
            raise UserError(f"`through=input`: run '{missing}' has no logged controller output "
                            "(column 'drive'); fit it through the loop (`through=loop`) or "
                            "import the controller output with `mapping=u=COLUMN,ref=COLUMN`")
        why = ("fitted from the logged controller output as the plant's input: the plant "
               "is seen directly, whatever the controller (a stiff loop hides the plant "
               "when fitted through it)")
        return [as_open_loop(r) if r.loop == "closed" else r for r in runs], \
            Way("input", why, len(closed), told)
    for r in closed:
        c = r.controller or {}
        if c.get("ki"):
            raise UserError(f"run '{r.name}': its controller has an integral term (ki = "
                            f"{c['ki']:g}), which labrig does not simulate through the loop; fit "
                            "from the logged controller output (`through=input`)")
    why = ("fitted through the loop: the reference is the input and the controller's gains "
           "are part of the model" + ("" if logged else
                                      "; no controller output was logged") +
           " (a stiff loop hides the plant: check the intervals)")
    if any((r.controller or {}).get("output_limit_v") for r in closed):
        why += "; the controller's output limit is not simulated through the loop"
    return runs, Way("loop", why, len(closed), told)
