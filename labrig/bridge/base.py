"""The one bridge interface; the simulated rig and the serial bridge implement it.

The acquisition code (``labrig.bridge.sweep``) drives any bridge through exactly these
methods, so a sweep on the simulated rig and on the board is the same code path.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from labrig.io.experiment import Experiment


@dataclass
class SampleBlock:
    """A batch of consecutive samples in raw volts. ``index`` counts from 0 at start."""

    index: np.ndarray
    u: np.ndarray
    tacho: np.ndarray | None   # None: the rig has no tacho
    pos: np.ndarray
    ref: np.ndarray | None = None
    current: np.ndarray | None = None
    #: a digital loop's output, applied by the board (then ``u`` is its reference)
    drive: np.ndarray | None = None


class Bridge(abc.ABC):
    """What every bridge (simulated rig, serial board) offers the acquisition code.

    Life cycle: ``open()`` -> [``configure(exp)`` -> ``start()`` -> ``read()`` ...
    until it returns ``None`` -> ``stop()``]* -> ``close()``. ``zero()`` sets the
    output to 0 V at any time and must be safe to call on every exit path.
    """

    #: what goes into a run's ``source`` key
    source: str = "sim"

    @abc.abstractmethod
    def open(self) -> dict:
        """Connect; return bridge info (``firmware``, ``capabilities``...)."""

    @abc.abstractmethod
    def configure(self, exp: Experiment) -> None:
        """Load an experiment; raises ``UserError`` if it is beyond the bridge's limits."""

    @abc.abstractmethod
    def start(self) -> None:
        """Start the configured experiment."""

    @abc.abstractmethod
    def read(self, timeout: float = 2.0) -> SampleBlock | None:
        """Next block of samples; ``None`` once the experiment has finished."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop the experiment and return the output to 0 V."""

    @abc.abstractmethod
    def zero(self) -> None:
        """Set the output to 0 V now (safe to call at any time, never raises on a dead link)."""

    @abc.abstractmethod
    def counters(self) -> dict:
        """``{"firmware": ..., "samples": n, "dropped_samples": n, "crc_errors": n, ...}`` for the
        run's ``bridge`` key: counts of the current run only (since ``configure``), so
        ``dropped_samples`` equals the run's ``gap`` rows."""

    def close(self) -> None:
        """Release the link (default: nothing to release)."""

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        try:
            self.zero()
        finally:
            self.close()
        return False
