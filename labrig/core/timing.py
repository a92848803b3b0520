"""Where a command's time goes, for the whole-process benchmarks.

With ``LABRIG_LAUNCHED_AT`` set to the launcher's ``time.time()`` just before it started
``labrig``, :func:`mark` prints ``labrig-timing PHASE SECONDS`` (seconds since launch) on
stderr; without it, nothing. ``benchmarks/`` uses it to tell start-up, compilation and
fitting apart in one whole-process run.
"""
from __future__ import annotations

import os
import sys
import time


def mark(phase: str) -> None:
    """Report that ``phase`` is reached (only when the launcher asked for it)."""
    t0 = os.environ.get("LABRIG_LAUNCHED_AT")
    if t0:
        try:
            print(f"labrig-timing {phase} {time.time() - float(t0):.4f}", file=sys.stderr)
        except ValueError:  # not a number: no timing, never a failure
            pass


_ONCE: set[str] = set()


def mark_once(phase: str) -> None:
    """:func:`mark`, the first time ``phase`` is reached in this process only."""
    if phase not in _ONCE:
        _ONCE.add(phase)
        mark(phase)
