"""Work a front end computes elsewhere: a named job and the function that does it.

The library computes every number in its own process unless a front end hands a job to
something faster: the command line hands the position loop's step metrics to a helper
process that imports python-control on the other core while the fit runs
(``labrig.step_helper``). Light on purpose: registering must not import numpy
(the command line registers before its heavy imports, and their order is kept).
"""
from __future__ import annotations

_handlers: dict = {}


def hand(job: str, fn) -> None:
    """Compute ``job`` with ``fn`` from now on (None: in this process again)."""
    if fn is None:
        _handlers.pop(job, None)
    else:
        _handlers[job] = fn


def handler(job: str):
    """The function ``job`` is handed to, or None (compute it here)."""
    return _handlers.get(job)
