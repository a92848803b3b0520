"""What a verb reports while it works: one event type for every verb and every front end.

A verb (:mod:`labrig.verbs`) takes ``progress=``, a callable that receives an
:class:`Event` at each step of its work: an identifier's iteration, a candidate's re-fit
starting or done, a rung of the search's ladder, a line of its log, samples arriving in a
sweep. The command line turns the events into its progress bars and log lines
(``commands.progress.Progress.hook``), the lab station into the lines and rungs it
streams to the page: the same events, whoever listens.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

#: the kinds of step, and what ``done``/``total``/``data`` hold for each
KINDS = {
    "iteration": "an identifier's iteration (done of total) or a start of CO's; text: the best fitness",
    "candidate": "a candidate effect's re-fit starting (done: its index; data: its name)",
    "fitted": "a candidate's re-fit done (text: its label and rmse/noise; data: the Candidate)",
    "validated": "a candidate's held-out error known (done: the cross-validated rmse/noise; "
                 "data: the Candidate)",
    "rung": "a rung of the ladder (done: its index; data: its model, info holding its errors)",
    "experiment": "a sweep's experiment starting (text: its name; data: the experiment)",
    "samples": "samples arrived in a sweep (done: how many more)",
    "run": "a run written (text: its name; data: the run)",
    "note": "a line of the verb's log (text)",
}


@dataclass(frozen=True)
class Event:
    """One step of a verb's work (:data:`KINDS` says what each kind carries)."""

    verb: str
    kind: str
    done: float | None = None
    total: float | None = None
    text: str = ""
    data: Any = None


Hook = Callable[[Event], None]


def note(progress: Hook | None, verb: str) -> Callable[[str], None] | None:
    """A ``log(line)`` callable that reports each line as a ``note`` event (None when
    nobody listens)."""
    if progress is None:
        return None
    return lambda text: progress(Event(verb, "note", text=str(text)))


def both(*fns):
    """One callable that calls each of ``fns`` that is not None (None when none is)."""
    fns = [f for f in fns if f is not None]
    if not fns:
        return None
    if len(fns) == 1:
        return fns[0]

    def call(*args, **kw):
        for f in fns:
            f(*args, **kw)
    return call
