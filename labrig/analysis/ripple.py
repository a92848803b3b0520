"""A ripple locked to the shaft's angle in a model's speed residual.

A tachogenerator's commutator (or an eccentric encoder disc) modulates the speed reading
a few times per turn: the residual of any plant model then holds a spectral line whose
frequency follows the shaft, ``m`` cycles per motor turn, at every speed. A line at a
fixed frequency (the mains, a PWM) does not follow the shaft; plant physics has no line
at all. So: in every stretch where the speed has settled, the residual's strongest line
is found and divided by the rotation frequency; when stretches at clearly different
speeds agree on that ratio, the line is locked to the angle and it is the sensor's.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np
from pydantic import Field, computed_field

from labrig.core.record import Record, TupleOf

#: a stretch must hold this many samples to resolve a line
MIN_SAMPLES = 256
#: a line stands this many times above the residual's median spectral power
PROMINENCE = 25.0
#: stretches agree on the order within this share
AGREE = 0.05
#: and their speeds differ by at least this share
SPEEDS_APART = 0.2


@dataclass(frozen=True)
class Ripple(Record):
    """A line locked to the shaft: ``order`` cycles per motor turn, ``relative`` its
    amplitude over the speed, seen in ``stretches`` settled stretches at ``speeds``
    (motor rev/s)."""

    order: float
    relative: float
    stretches: int
    speeds: Annotated[TupleOf, Field(alias="speeds_rev_s")]
    share: float   # of the speed residual's variance in those stretches

    @computed_field(alias="description")
    @property
    def _description(self) -> str:
        return self.describe()

    def describe(self) -> str:
        sp = ", ".join(f"{s:.3g}" for s in self.speeds)
        return (f"the speed's residual holds a line locked to the shaft's angle: "
                f"{self.order:.2f} cycles per motor turn at every speed (settled stretches "
                f"at {sp} rev/s), {100 * self.relative:.2g} % of the speed, "
                f"{100 * self.share:.0f} % of the residual there: a ripple of the speed "
                "sensor (a tacho's commutator, an eccentric encoder disc), not the plant")


def _line(r: np.ndarray, dt: float):
    """(frequency, amplitude, prominence, share of variance) of the strongest line."""
    r = r - np.polyval(np.polyfit(np.arange(len(r)), r, 1), np.arange(len(r)))
    win = np.hanning(len(r))
    spec = np.fft.rfft(r * win)
    power = np.abs(spec) ** 2
    power[0] = 0.0
    k = int(np.argmax(power[1:])) + 1
    med = float(np.median(power[1:])) or 1e-300
    amp = 2.0 * np.abs(spec[k]) / win.sum()
    share = min(0.5 * amp ** 2 / max(float(np.mean(r ** 2)), 1e-300), 1.0)
    return k / (len(r) * dt), amp, power[k] / med, share


def ripple_line(per_run: list, runs) -> Ripple | None:
    """The line locked to the angle in the speed residuals of an evaluation's runs
    (:attr:`labrig.diagnosis.evidence.evaluation.Evaluation.per_run`, prepared ``runs`` alike); None
    when there is none."""
    found = []
    for rr, rd in zip(per_run, runs):
        ch = rr["channels"].get("speed")
        if ch is None or rd.w is None:
            continue
        lab = np.asarray(rr["labels"])
        steady = lab == "steady"
        edges = np.flatnonzero(np.diff(np.r_[0, steady.astype(int), 0]))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a < MIN_SAMPLES:
                continue
            w = np.asarray(rd.w[a:b], float)
            rot = abs(float(np.median(w))) / (2 * np.pi)
            if rot <= 0:
                continue
            f, amp, prom, share = _line(ch["residual"][a:b] * ch["sigma"], rd.dt)
            if prom >= PROMINENCE and f > 0.5 * rot:
                found.append((f / rot, amp / (2 * np.pi * rot), rot, share))
    if len(found) < 2:
        return None
    orders = np.array([x[0] for x in found])
    m = float(np.median(orders))
    agree = [x for x in found if abs(x[0] - m) <= AGREE * m]
    speeds = sorted({float(f"{x[2]:.2g}") for x in agree})
    if len(agree) < 2 or speeds[-1] < (1 + SPEEDS_APART) * speeds[0]:
        return None   # one speed only: a fixed-frequency line would look the same
    return Ripple(order=m, relative=float(np.median([x[1] for x in agree])),
                  stretches=len(agree), speeds=tuple(speeds),
                  share=float(np.median([x[3] for x in agree])))
