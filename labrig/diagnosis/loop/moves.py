"""The search's record: the moves it made (add, pair, swap, remove), a move it considers
(:class:`Step`), what it returns, and its log's lines."""
from __future__ import annotations

import textwrap
from dataclasses import dataclass, field
from typing import Annotated

from pydantic import Field, computed_field

from labrig.diagnosis.results.ladder import Ladder
from labrig.core.record import Record, empty
from labrig.model.model import Model

#: log lines are wrapped at this width (words whole, never cut)
LOG_WIDTH = 100


def wrap_log(text: str, width: int = LOG_WIDTH) -> str:
    """One log message, wrapped at word boundaries with a hanging indent: continuation
    lines line up under the text after the leading spaces and a label ending in ": "
    (``round 2: ...``), so a long verdict is shown whole, never cut mid-word."""
    body = text.lstrip(" ")
    lead = text[:len(text) - len(body)]
    label, sep, _ = body.partition(": ")
    hang = lead + " " * (len(label) + len(sep) if sep and len(label) <= 12 else 4)
    return textwrap.fill(body, width=width, initial_indent=lead, subsequent_indent=hang,
                         break_long_words=False, break_on_hyphens=False)


def say(log, text: str) -> None:
    if log:
        log(wrap_log(text))


@dataclass
class Move(Record):
    """One step of the search: what changed and the cross-validated error after it."""

    kind: str            # "add", "pair", "swap", "remove"
    # the effect(s) added, or [old, new] for a swap, [old] for a removal
    effects: list[str]
    cv_before: Annotated[float, Field(alias="cross_validated_before")]
    cv_after: Annotated[float, Field(alias="cross_validated_after")]
    round: int
    # a pair fitted in place of these
    replaces: Annotated[list[str], Field(exclude_if=empty)] \
        = field(default_factory=list)

    @computed_field
    @property
    def label(self) -> str:
        """The move in words: ``+ deadband``, ``- deadband``, ``old -> new``."""
        e = self.effects
        if self.kind == "swap":
            return f"{e[0]} -> {e[1]}"
        if self.replaces:
            return f"{', '.join(self.replaces)} -> {' + '.join(e)}"
        return ("- " if self.kind == "remove" else "+ ") + ", ".join(e)


@dataclass
class SearchResult:
    rounds: list
    ladder: Ladder
    model: Model
    moves: list = field(default_factory=list)


@dataclass
class Step:
    """A move the search considers: its kind ("add" or "pair"), the effects it adds (and
    those it takes out in their place), the fitted model, its evaluation and its
    cross-validated error."""

    kind: str
    names: list
    model: Model
    evaluation: object
    cv: float
    replaced: list = field(default_factory=list)
