"""The one bridge interface; the simulated rig and the serial bridge implement it.

The acquisition code (``labrig.acquire``) drives any bridge through exactly these
methods, so a sweep on the simulated rig and on the board is the same code path.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass, field, asdict

import numpy as np

from ..defaults import LOOP_GAINS


#: breakpoints of a ``pwl`` waveform (the firmware's table holds as many)
PWL_MAX_POINTS = 64


def pwl_values(points, k: np.ndarray, fs: float) -> np.ndarray:
    """A piecewise-linear waveform at sample counts ``k`` (0 at the first breakpoint's
    time, i.e. after the lead-in): linear between breakpoints, held after the last.

    Breakpoint times are rounded to whole samples, as the firmware's table holds them.
    """
    ks = np.array([round(float(t) * fs) for t, _ in points], dtype=float)
    us = np.array([float(u) for _, u in points], dtype=float)
    return np.interp(np.asarray(k, dtype=float), ks, us)


@dataclass
class Experiment:
    """One experiment of a sweep plan, in bridge volts and seconds.

    ``loop`` is ``"open"`` (the bridge drives the amplifier input) or ``"closed"``
    (the bridge drives the reference of a position loop with tacho feedback).
    ``waveform`` is ``square`` (+-amplitude about offset, starting positive),
    ``step`` (0 -> amplitude after the lead-in), ``staircase`` (``levels`` in turn,
    each held for ``step_s``), ``constant`` or ``pwl`` (piecewise linear through
    ``points`` ``[[t_s, u_v], ...]`` after the lead-in, at most :data:`PWL_MAX_POINTS`,
    held after the last).
    """

    name: str
    loop: str = "open"
    waveform: str = "square"
    amplitude_v: float = 1.5
    frequency_hz: float = 0.25
    offset_v: float = 0.0
    lead_in_s: float = 0.5
    periods: float = 2.0
    duration_s: float | None = None
    levels: list[float] = field(default_factory=list)
    step_s: float = 1.0
    sample_rate_hz: float = 1000.0
    position_gain: float = LOOP_GAINS["position_gain"]
    velocity_gain: float = LOOP_GAINS["velocity_gain"]
    points: list = field(default_factory=list)
    #: the two effects this experiment was proposed to tell apart (``labrig propose``)
    between: list = field(default_factory=list)

    @property
    def total_s(self) -> float:
        """Length of the whole record (lead-in included)."""
        if self.duration_s is not None:
            return float(self.duration_s)
        if self.waveform == "pwl":
            return self.lead_in_s + float(self.points[-1][0]) if self.points else self.lead_in_s
        if self.waveform == "square":
            return self.lead_in_s + self.periods / self.frequency_hz
        if self.waveform == "staircase":
            return self.lead_in_s + len(self.levels) * self.step_s
        return self.lead_in_s + self.periods / self.frequency_hz

    @property
    def n_samples(self) -> int:
        return int(round(self.total_s * self.sample_rate_hz))

    def waveform_at(self, t: np.ndarray) -> np.ndarray:
        """The commanded bridge voltage at times ``t`` (s), as the board generates it.

        Computed on integer sample counts, like the firmware, so an edge falls on
        exactly the same sample on the board and in the simulated rig.
        """
        fs = self.sample_rate_hz
        k = np.round(np.asarray(t, dtype=float) * fs).astype(np.int64)
        kk = k - int(round(self.lead_in_s * fs))
        out = np.zeros(k.shape)
        if self.waveform == "square":
            period = int(round(fs / self.frequency_hz))
            half = period // 2
            out = np.where(np.mod(kk, period) < half, self.amplitude_v, -self.amplitude_v) + self.offset_v
        elif self.waveform in ("step", "constant"):
            out = np.full(k.shape, self.amplitude_v + self.offset_v)
        elif self.waveform == "staircase":
            per = int(round(self.step_s * fs))
            idx = np.clip(kk // per, 0, max(len(self.levels) - 1, 0))
            lv = np.asarray(self.levels, dtype=float) if self.levels else np.zeros(1)
            out = lv[idx] + self.offset_v
        elif self.waveform == "pwl":
            out = pwl_values(self.points, kk, fs) + self.offset_v
        return np.where(kk >= 0, out, 0.0)

    def peak_v(self) -> float:
        if self.waveform == "staircase":
            return max((abs(v + self.offset_v) for v in self.levels), default=0.0)
        if self.waveform == "pwl":
            return max((abs(u + self.offset_v) for _, u in self.points), default=0.0)
        return abs(self.amplitude_v) + abs(self.offset_v)

    def to_sidecar(self) -> dict:
        d = {k: v for k, v in asdict(self).items() if k not in ("name",)}
        if self.loop == "open":
            d.pop("position_gain"), d.pop("velocity_gain")
        if self.waveform != "staircase":
            d.pop("levels"), d.pop("step_s")
        if self.waveform == "pwl":
            d["points"] = [[float(t), float(u)] for t, u in self.points]
            for k in ("amplitude_v", "frequency_hz", "periods"):
                d.pop(k)
        else:
            d.pop("points")
        if not self.between:
            d.pop("between")
        if d.get("duration_s") is None:
            d.pop("duration_s")
        return d


@dataclass
class SampleBlock:
    """A batch of consecutive samples in raw volts. ``index`` counts from 0 at start."""

    index: np.ndarray
    u: np.ndarray
    tacho: np.ndarray | None   # None: the rig has no tacho
    pos: np.ndarray
    ref: np.ndarray | None = None
    current: np.ndarray | None = None


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
