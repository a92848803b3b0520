"""The trips a board enforces on its own: the rig file's speed and position limits as the
words the board compares each sample with (the LIMITS message), and what a tripped run
records.

The host cannot stop a motor in time: it hears of a sample a frame or more later, and a
host that hangs hears nothing. So the board checks every sample it takes against the
run's limits and, past one, puts the output at 0 V before its next sample (an H-bridge
board coasts or brakes as its off phase says), ends the run and reports the fault
(ERROR ``TRIP``). The run is kept up to that sample and recorded as tripped; the samples it
never took are gaps, never fitted.

- **Speed** (``[bridge] trip_speed``, the motor's rad/s or the carriage's m/s): on the
  MS150 the tacho's ADC word must stay inside the words of +-trip_speed; on an H-bridge
  board the encoder's count may change by at most trip_speed's counts per sample.
- **Position** (``[bridge] trip_position = [low, high]``, closed-loop runs only: an open
  loop may spin the shaft past a pot's wrap): the pot's word inside the words of the
  window; an encoder's count, from the run's start, inside the window's counts.
- **E-stop** (``[bridge] estop = true``): a normally-closed switch from D7 to GND; the pin
  rising (pressed, or its wire broken) stops the run before the next sample's output, and
  the board refuses to start another until the host's ZERO finds it closed again (every
  sweep greets the board with one).
"""
from __future__ import annotations

import math
import struct

from labrig.core.errors import ConfigError

#: LIMITS flags (the firmware's LR_TRIP_SPEED, LR_TRIP_POSITION, LR_TRIP_ESTOP)
SPEED, POSITION, ESTOP = 0x01, 0x02, 0x04
#: the LIMITS body: flags, then the speed's and the position's i32 windows
_LIMITS = struct.Struct("<Biiii")
#: the firmware that enforces trips (LIMITS, ERROR TRIP)
FIRST_VERSION = (2, 2, 0)


def _adc_word(volts: float, channel: str, s) -> float:
    """The ADC word (fractional) of ``volts`` at ``channel``, the calibration undone."""
    lo, hi = s.adc_range_v
    nominal = (volts - getattr(s, f"{channel}_offset_v")) / getattr(s, f"{channel}_gain")
    return (nominal - lo) * 2 ** s.adc_bits / (hi - lo)


def _words(v_lo: float, v_hi: float, channel: str, s, what: str, path: str) -> tuple[int, int]:
    """The ADC words that stay inside [v_lo, v_hi] volts; refused when the window reaches
    past the converter's range (the sensor would saturate before the board could trip)."""
    a, b = sorted((_adc_word(v_lo, channel, s), _adc_word(v_hi, channel, s)))
    top = 2 ** s.adc_bits - 1
    if a < 0 or b > top:
        lo, hi = s.adc_range_v
        raise ConfigError(f"{path}: key 'bridge.{what}': its {channel} volts ({v_lo:.3g} .. "
                          f"{v_hi:.3g} V) reach past the ADC's range ({lo:g} .. {hi:g} V): the "
                          "sensor saturates before the board could trip; set it inside")
    return math.ceil(a), math.floor(b)


def limits(exp, rig, s) -> tuple[int, int, int, int, int] | None:
    """The LIMITS of experiment ``exp`` on ``rig`` (flags, speed low/high, position
    low/high in the board's words); None when the rig file sets no trip for it.

    Parameters
    ----------
    exp : labrig.io.experiment.Experiment
    rig : labrig.io.config.RigConfig
    s : labrig.bridge.settings.BridgeSettings
        The rig's bridge settings (calibration filled in).
    """
    b, path = rig.bridge, rig.source or "<rig>"
    flags, speed, pos = 0, (0, 0), (0, 0)
    gear = rig.gear_ratio if rig.axis == "rotary" else 1.0
    if b.trip_speed > 0:
        flags |= SPEED
        if s.firmware == "hbridge":
            per_sample = b.trip_speed / gear * s.counts_per_unit / s.sample_rate_hz
            n = max(1, math.floor(per_sample))
            speed = (-n, n)
        else:
            v = rig.sensors.tacho_v_per_rad_s * b.trip_speed
            if v <= 0:
                raise ConfigError(f"{path}: key 'bridge.trip_speed': the MS150 bridge trips on "
                                  "its tacho, and the rig has none (sensors.tacho_v_per_rad_s "
                                  "= 0); remove the key")
            speed = _words(-v, v, "tacho", s, "trip_speed", path)
    if b.trip_position is not None and exp.loop == "closed":
        flags |= POSITION
        lo, hi = b.trip_position
        if s.firmware == "hbridge":
            pos = (math.ceil(lo * s.counts_per_unit), math.floor(hi * s.counts_per_unit))
        else:
            k, off = rig.sensors.pos_v_per_rad, rig.sensors.pos_offset_v
            pos = _words(k * lo + off, k * hi + off, "pos", s, "trip_position", path)
    if b.estop:
        flags |= ESTOP
    return (flags, *speed, *pos) if flags else None


def limits_body(values: tuple[int, int, int, int, int]) -> bytes:
    """The LIMITS message's body."""
    return _LIMITS.pack(*values)


def parse_limits(body: bytes) -> dict:
    """A LIMITS body as its fields (the emulator's and the tests' reading)."""
    flags, s_lo, s_hi, p_lo, p_hi = _LIMITS.unpack(body)
    return {"flags": flags, "speed": (s_lo, s_hi), "position": (p_lo, p_hi)}


def check(rig, plan=None) -> None:
    """Every experiment's limits computed once, before anything moves: a window the
    sensors cannot show is refused here (exit 2), not mid-sweep."""
    from labrig.bridge.settings import bridge_settings
    from labrig.io.experiment import Experiment

    s = bridge_settings(rig)
    # (a closed-loop run checks the position window too, whether the plan has one or not)
    for exp in list(plan or []) + [Experiment(name="check", loop="closed")]:
        limits(exp, rig, s)


#: the board's words for each trip (its ERROR TRIP text)
TEXTS = {SPEED: "over-speed", POSITION: "position limit", ESTOP: "E-stop"}


def first_trip(bounds, speed=None, position=None) -> tuple[int, int] | None:
    """The first sample a board with ``bounds`` (:func:`limits`) trips at, and why
    (:data:`SPEED` or :data:`POSITION`); None when none does.

    ``speed``: per sample, the tacho's ADC words (MS150) or the count's change since the
    previous sample (H-bridge: the first sample is not checked, as the board's is not);
    ``position``: the pot's words or the count from the run's start."""
    import numpy as np

    flags, s_lo, s_hi, p_lo, p_hi = bounds
    hits = []
    if flags & SPEED and speed is not None:
        s = np.asarray(speed, dtype=float)
        hits.append((SPEED, (s < s_lo) | (s > s_hi)))
    if flags & POSITION and position is not None:
        p = np.asarray(position, dtype=float)
        hits.append((POSITION, (p < p_lo) | (p > p_hi)))
    best = None
    for why, bad in hits:   # (speed first at the same sample, as the board checks it)
        k = np.flatnonzero(bad)
        if len(k) and (best is None or k[0] < best[0]):
            best = (int(k[0]), why)
    return best


def adc_words(volts, channel: str, s):
    """The ADC words a bridge reads for sensor ``volts`` at ``channel`` (rounded)."""
    import numpy as np

    return np.round(_adc_word(np.asarray(volts, dtype=float), channel, s))
