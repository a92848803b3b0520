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
from typing import Annotated

import numpy as np
from pydantic import Field, computed_field

from labrig.core.record import Record

#: drift beyond this many noise floors of the position weighs the position down
DRIFT = 2.0
#: where a speed's window is declared (then it is modelled)
WINDOW_DECLARED_IN = "(sensors.speed_window_s in the run's sidecar, or labrig import --speed-window S)"


@dataclass(frozen=True)
class ChannelAgreement(Record):
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
    declared_lag_s : float
        The lag the runs' declared speed windows explain (half a window; 0: none
        declared). Only the rest is unexplained.
    lag_error : float
        rms of the speed error the unexplained lag makes (lag x acceleration), beyond
        what the noise explains, in speed units.
    sigma_speed : float
        The speed's noise floor.
    unit, speed_unit : str
        Position and speed units (rad, rad/s; m, m/s).
    runs : int
        Runs with both channels.
    """

    readable = False   # (a summary of live objects: not read back)

    drift: float
    sigma_pos: Annotated[float, Field(exclude=True)]
    lag_s: float
    unit: str
    runs: int
    declared_lag_s: float = 0.0
    lag_error: float = 0.0
    sigma_speed: Annotated[float, Field(exclude=True)] = 1.0
    speed_unit: str = "rad/s"

    @computed_field(alias="drift_over_noise")
    @property
    def _ratio(self) -> float:
        return self.ratio

    @computed_field(alias="lag_error_over_noise")
    @property
    def _lag_ratio(self) -> float:
        return self.lag_ratio

    @property
    def ratio(self) -> float:
        """Drift in noise floors of the position."""
        return self.drift / max(self.sigma_pos, 1e-300)

    @computed_field
    @property
    def drifts(self) -> bool:
        """True when the drift is more than :data:`DRIFT` noise floors."""
        return self.ratio > DRIFT

    @property
    def position_factor(self) -> float:
        """The position's effective floor over its noise floor: sqrt(1 + ratio^2)."""
        return float(np.sqrt(1.0 + self.ratio ** 2))

    @property
    def unexplained_lag_s(self) -> float:
        return self.lag_s - self.declared_lag_s

    @property
    def lag_ratio(self) -> float:
        """The speed error of the unexplained lag, in noise floors of the speed."""
        return self.lag_error / max(self.sigma_speed, 1e-300)

    @computed_field
    @property
    def lags(self) -> bool:
        """True when the speed reads late by more than :data:`DRIFT` of its noise floors
        at its accelerations (and the position does not drift: then that says more)."""
        return self.lag_ratio > DRIFT and self.unexplained_lag_s > 0 and not self.drifts

    @property
    def speed_factor(self) -> float:
        """The speed's effective floor over its noise floor: sqrt(1 + lag_ratio^2)."""
        return float(np.sqrt(1.0 + self.lag_ratio ** 2))

    def describe(self) -> str:
        return (f"the position strays from the integral of the speed by {self.drift:.3g} "
                f"{self.unit} rms ({self.ratio:.1f} x its noise floor {self.sigma_pos:.3g} "
                f"{self.unit}; over {self.runs} run(s))")

    def describe_lag(self) -> str:
        lag = self.unexplained_lag_s
        declared = (f" beyond the {1e3 * self.declared_lag_s:.3g} ms its declared window "
                    "explains" if self.declared_lag_s else "")
        return (f"the speed reads {1e3 * lag:.3g} ms late against the position{declared} "
                f"({self.lag_ratio:.1f} x its noise floor at its accelerations): a filtered "
                f"speed, as a moving window of about {2e3 * lag:.3g} ms reads it")


def channel_agreement(runs, sigma_w: float, sigma_pos: float, unit: str = "rad",
                      speed_unit: str = "rad/s") -> ChannelAgreement | None:
    """The agreement of position and speed over prepared runs
    (:class:`labrig.model.simulate.RunData`); None when no run has both channels."""
    ds, ws, expect, acc, declared = [], [], [], [], []
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
        acc.append((np.gradient(np.asarray(rd.w, float), rd.dt), rd.dt, keep))
        declared.append(0.5 * rd.speed_window * rd.dt if rd.speed_window >= 1 else 0.0)
    if not ds:
        return None
    d, v, rw = np.concatenate(ds), np.concatenate(ws), np.concatenate(expect)
    vv = float(np.dot(v, v))
    lag = float(np.dot(d, v) / vv) if vv > 0 else 0.0
    rest = d - lag * v
    excess = float(np.mean(rest ** 2) - sigma_pos ** 2 - np.mean(rw))
    declared_lag = float(np.mean(declared))
    # the speed error of the unexplained lag: lag x acceleration, less what the noise
    # makes of a derivative (sigma / (sqrt(2) dt) per sample, times the lag)
    extra = lag - declared_lag
    err = [np.mean((extra * a[keep]) ** 2) - (extra * sigma_w) ** 2 / (2 * dt ** 2)
           for a, dt, keep in acc]
    lag_error = float(np.sqrt(max(float(np.mean(err)), 0.0)))
    return ChannelAgreement(drift=float(np.sqrt(max(excess, 0.0))), sigma_pos=float(sigma_pos),
                            lag_s=lag, unit=unit, runs=len(ds), declared_lag_s=declared_lag,
                            lag_error=lag_error, sigma_speed=float(sigma_w),
                            speed_unit=speed_unit)


#: a fitted lag within this factor of the speed's is taken for it
LAG_MATCH = 3.0
#: an electrical pole above this share of the mechanical one is suspect on a brushed
#: motor (L/R 0.1-5 ms, tau_m 10-500 ms)
TAU_E_SHARE = 0.1


def lag_explained(agree: ChannelAgreement | None, tau_e: float | None = None,
                  delay: float | None = None, tau_m: float | None = None,
                  declared_s: float = 0.0) -> str:
    """A sentence when a fitted lag (an electrical pole ``tau_e``, a transport ``delay``)
    is the speed sensor's, not the plant's: it matches the speed's unexplained lag
    against the position (within :data:`LAG_MATCH`), or, with no position to compare,
    the pole is a large share of ``tau_m`` and no window is declared; '' otherwise."""
    fitted = [(f"tau_e = {1e3 * tau_e:.3g} ms", tau_e) if tau_e else None,
              (f"the delay of {1e3 * delay:.3g} ms", delay) if delay else None]
    fitted = [f for f in fitted if f is not None]
    if agree is not None and agree.lags:
        lag = agree.unexplained_lag_s
        said = [t for t, v in fitted if lag / LAG_MATCH <= v <= LAG_MATCH * lag]
        if said:
            return (f"{' and '.join(said)} {'is' if len(said) == 1 else 'are'} about the "
                    f"speed's own lag against the position ({1e3 * lag:.3g} ms): a sensor "
                    "filter, not the armature's L/R or a transport delay. Declare the speed's "
                    f"window {WINDOW_DECLARED_IN} and it is modelled.")
        return ""
    if agree is not None or declared_s:
        return ""
    said, lag = [], 0.0
    if tau_e and tau_m and tau_e > TAU_E_SHARE * tau_m:
        said.append(f"tau_e = {1e3 * tau_e:.3g} ms is {tau_e / tau_m:.2f} of tau_m (a brushed "
                    "motor's L/R is rarely so long: 0.1-5 ms)")
        lag += tau_e
    if said and delay:
        said.append(f"the delay of {1e3 * delay:.3g} ms adds to it")
        lag += delay
    if not said:
        return ""
    return ("The fitted " + "; ".join(said) + ". A filtered speed reads "
            f"like this (a moving window of about {2e3 * lag:.3g} ms): if the speed is "
            f"computed over a window, declare it {WINDOW_DECLARED_IN} and it is modelled; "
            "log the position too and labrig "
            "measures the speed's lag itself.")
