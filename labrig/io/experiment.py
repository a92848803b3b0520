"""One experiment of a sweep plan: the waveform a run plays, in bridge volts and seconds.

A plan file (:mod:`labrig.io.config`) is a list of these; every bridge plays them
(:mod:`labrig.bridge.base`), and a run's sidecar records the one it played.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from labrig.core.defaults import LOOP_GAINS


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
    (a position loop with tacho feedback: the bridge drives its reference, or, with
    ``closed_by = "board"``, the board closes it on the sensors it samples).
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
    #: who closes an MS150's loop: ``"analog"`` its patch panel (gains as patched, the
    #: output the reference) or ``"board"`` the board itself, at each sample from the pot
    #: and tacho it reads (the plan's gains, the output the amplifier's input); None: the
    #: rig's way (the MS150's analog loop; an H-bridge board always closes its own)
    closed_by: str | None = None

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
        if d.get("closed_by") is None:
            d.pop("closed_by")
        if d.get("duration_s") is None:
            d.pop("duration_s")
        return d
