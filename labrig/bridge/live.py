"""A bridge watched as it plays: every block handed to a viewer, paced to real time if
asked, and stoppable from another thread (the lab page's Stop button).

:class:`LiveBridge` wraps any :class:`~labrig.bridge.base.Bridge`; the sweep drives it
like the bridge itself, so a run written while watched is byte for byte the run
``labrig sweep`` writes. A stop raises :class:`~labrig.core.errors.Interrupted` inside
the sweep, whose ``finally`` sends STOP and ZERO and keeps every finished run.
"""
from __future__ import annotations

import threading
import time
from typing import Callable

from labrig.core.errors import Interrupted

STOPPED = "stopped; finished runs are kept, the output is at 0 V"


class LiveBridge:
    """``inner`` with ``on_block(block)`` after every read, optional real-time pacing and
    a ``stop`` event checked before every read."""

    def __init__(self, inner, on_block: Callable | None = None, *, realtime: bool = False,
                 stop: threading.Event | None = None):
        self._inner = inner
        self.source = inner.source
        self.on_block = on_block
        self.realtime = realtime
        self.stop_event = stop or threading.Event()
        self._exp = None

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def configure(self, exp) -> None:
        self._exp = exp
        self._inner.configure(exp)

    def read(self, timeout: float = 2.0):
        if self.stop_event.is_set():
            raise Interrupted(STOPPED)
        blk = self._inner.read(timeout)
        if blk is not None:
            if self.realtime and self._exp is not None:
                time.sleep(len(blk.index) / self._exp.sample_rate_hz)
            if self.on_block:
                self.on_block(blk)
        return blk

    # the sweep's exit path goes to the real bridge, whatever the viewer does
    def stop(self) -> None:
        self._inner.stop()

    def zero(self) -> None:
        self._inner.zero()

    def close(self) -> None:
        self._inner.close()
