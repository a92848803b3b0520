"""Do the position and the speed channel tell the same story?

A model moves the shaft by integrating its own speed, so the position it predicts is
the integral of the speed it predicts. Two sensors that disagree about that integral
cannot both be fitted to their noise floors, whatever the model: the disagreement
``d = theta - theta0 - integral(w / N)`` is measured on the data alone, before any fit.

It has two parts that mean different things:

- a **lag**, ``d`` proportional to the speed and gone when the shaft stops: the speed
  reads late (a speed computed over a moving window of counts reads half a window
  late), or the position early;
- a **drift**, what is left: the disagreement accumulates (a position channel that
  wanders, a speed scale that does not match the position's, a position that is not the
  integral of that speed). A position logged over thousands of radians drifts by many of
  its noise floors; fitted at its noise floor it outweighs the speed and pulls the
  plant's inertia towards its wander.

Where the consistent part is expected: the position's own noise and the speed's noise
integrated (a random walk). Only the excess over both is called drift.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: drift beyond this many noise floors of the position weighs the position down
DRIFT = 2.0


@dataclass(frozen=True)
class ChannelAgreement:
    """How far the measured position strays from the integral of the measured speed.

    Attributes
    ----------
    drift : float
        rms of the accumulated disagreement beyond what the two noises explain, in
        position units (0 when the channels agree).
    sigma_pos : float
        The position's noise floor (the unit ``ratio`` is counted in).
    lag_s : float
        The part of the disagreement proportional to the speed, as a time: > 0 when
        the speed reads late against the position.
    unit : str
        Position unit (rad, m).
    runs : int
        Runs with both channels.
    """

    drift: float
    sigma_pos: float
    lag_s: float
    unit: str
    runs: int

    @property
    def ratio(self) -> float:
        """Drift in noise floors of the position."""
        return self.drift / max(self.sigma_pos, 1e-300)

    @property
    def drifts(self) -> bool:
        """True when the drift is more than :data:`DRIFT` noise floors."""
        return self.ratio > DRIFT

    @property
    def position_factor(self) -> float:
        """The position's effective floor over its noise floor: sqrt(1 + ratio^2)."""
        return float(np.sqrt(1.0 + self.ratio ** 2))

    def describe(self) -> str:
        return (f"the position strays from the integral of the speed by {self.drift:.3g} "
                f"{self.unit} rms ({self.ratio:.1f} x its noise floor {self.sigma_pos:.3g} "
                f"{self.unit}; over {self.runs} run(s))")

    def to_json(self) -> dict:
        return {"drift": self.drift, "drift_over_noise": self.ratio, "lag_s": self.lag_s,
                "unit": self.unit, "runs": self.runs, "drifts": self.drifts}


def channel_agreement(runs, sigma_w: float, sigma_pos: float,
                      unit: str = "rad") -> ChannelAgreement | None:
    """The agreement of position and speed over prepared runs
    (:class:`labrig.model.simulate.RunData`); None when no run has both channels."""
    ds, ws, expect = [], [], []
    for rd in runs:
        if rd.w is None or rd.theta is None or len(rd.u) < 3:
            continue
        keep = rd.keep()
        # a lost sample is interpolated in both channels: integrate through it, count it not
        v = np.asarray(rd.w, float) / rd.N
        integral = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1])) * rd.dt])
        d = np.asarray(rd.theta, float) - rd.theta0 - integral
        k = np.arange(len(d))
        ds.append(d[keep])
        ws.append(v[keep])
        # the speed's noise, integrated: a random walk of sigma_w dt / N per sample
        expect.append(((sigma_w * rd.dt / rd.N) ** 2 * k)[keep])
    if not ds:
        return None
    d, v, rw = np.concatenate(ds), np.concatenate(ws), np.concatenate(expect)
    vv = float(np.dot(v, v))
    lag = float(np.dot(d, v) / vv) if vv > 0 else 0.0
    rest = d - lag * v
    excess = float(np.mean(rest ** 2) - sigma_pos ** 2 - np.mean(rw))
    return ChannelAgreement(drift=float(np.sqrt(max(excess, 0.0))), sigma_pos=float(sigma_pos),
                            lag_s=lag, unit=unit, runs=len(ds))
