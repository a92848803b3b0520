"""The rules an H-bridge rig file's ``[bridge]`` must meet: what the board's timers give.

Read where the rig file is read (:mod:`labrig.io.config`); the firmware build and the
board's greeting are :mod:`labrig.bridge.hbridge`'s.
"""
from __future__ import annotations

import math

from labrig.core.errors import ConfigError

#: the sample clock of the H-bridge build: Timer2 at 10 kHz, divided in software
TIMER_HZ = 10_000
MIN_RATE_HZ, MAX_RATE_HZ = 50, 2000
#: Timer1's fast PWM without prescaler: bits -> frequency (16 MHz / 2^bits)
PWM_HZ = {8: 62_500.0, 9: 31_250.0, 10: 15_625.0}


def check_rig(rig, path, given: dict) -> None:
    """The ``[bridge]`` of an H-bridge rig file, against what the board can do.

    Parameters
    ----------
    rig : labrig.io.config.RigConfig
        The rig as read; ``rig.bridge.dac_bits`` is set from ``pwm_bits`` when the file
        leaves it out.
    path : str or Path
        The file, for the messages.
    given : dict
        The ``[bridge]`` keys the file sets.

    Raises
    ------
    ConfigError
        Naming the file, the key and the fix.
    """
    b, s = rig.bridge, rig.sensors
    if b.pwm_bits not in PWM_HZ:
        slow = 16e6 / 2 ** b.pwm_bits
        raise ConfigError(
            f"{path}: key 'bridge.pwm_bits' = {b.pwm_bits}: the board's Timer1 gives 8 to 10 "
            f"bits at 15 kHz or more (at {b.pwm_bits} bits it would run at {slow / 1e3:.3g} kHz"
            f"{', in hearing' if slow < 15e3 else ''}); use 8, 9 or 10")
    if "dac_bits" in given and b.dac_bits != b.pwm_bits + 1:
        raise ConfigError(f"{path}: key 'bridge.dac_bits' = {b.dac_bits}, but an H-bridge "
                          f"board's output word is its {b.pwm_bits} PWM bits and a sign "
                          f"({b.pwm_bits + 1}); set {b.pwm_bits + 1} or remove the key")
    b.dac_bits = b.pwm_bits + 1
    lo, hi = b.dac_range_v
    if not (hi > 0 and abs(lo + hi) <= 1e-9 * hi):
        raise ConfigError(f"{path}: key 'bridge.dac_range_v' = [{lo:g}, {hi:g}]: an H-bridge "
                          "drives the supply either way; give [-V, V] with V the supply")
    if b.output_limit_v > hi + 1e-9:
        raise ConfigError(f"{path}: key 'bridge.output_limit_v' = {b.output_limit_v:g} V is "
                          f"above the supply ({hi:g} V, bridge.dac_range_v); lower the limit or "
                          "raise the supply")
    if s.encoder_counts_per_unit <= 0:
        raise ConfigError(f"{path}: key 'sensors.encoder_counts_per_unit' = "
                          f"{s.encoder_counts_per_unit:g}: the H-bridge board reads an encoder; "
                          "give its counts per rad of the output shaft (lines x decoding x gear "
                          "/ 2 pi)")
    rate = b.sample_rate_hz
    if rate != int(rate) or TIMER_HZ % int(rate) or not MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
        raise ConfigError(f"{path}: key 'bridge.sample_rate_hz' = {rate:g}: the H-bridge board "
                          f"samples at divisors of {TIMER_HZ} Hz from {MIN_RATE_HZ} to "
                          f"{MAX_RATE_HZ} Hz (100, 200, 250, 500, 1000...)")
    if b.current_sense and s.current_v_per_a <= 0:
        raise ConfigError(f"{path}: key 'bridge.current_sense' is on but "
                          "'sensors.current_v_per_a' is 0; give the shunt amplifier's V per A")
    if b.current_sense and not 0.0 <= s.current_zero_v <= 5.0:
        raise ConfigError(f"{path}: key 'sensors.current_zero_v' = {s.current_zero_v:g}: the "
                          "board reads the sense output on A0 from 0 to 5 V; give its output at "
                          "zero current (2.5 V for a bidirectional sense amplifier at mid-supply)")
    if b.index_counts:
        _check_index(rig, path)


def _check_index(rig, path) -> None:
    """An index pulse comes once a turn of the shaft the encoder sits on: its counts are that
    turn's counts by the file's own resolution and gear, on the motor or the output shaft."""
    b, s = rig.bridge, rig.sensors
    per_output_turn = s.encoder_counts_per_unit * 2 * math.pi
    shafts = {"the output shaft": per_output_turn,
              "the motor shaft": per_output_turn / rig.gear_ratio}
    if not any(abs(b.index_counts - c) <= 0.002 * c for c in shafts.values()):
        turns = " or ".join(f"{c:.6g} ({name})" for name, c in shafts.items())
        raise ConfigError(f"{path}: key 'bridge.index_counts' = {b.index_counts}: an index "
                          "pulse comes once a turn of the encoder's shaft, which by "
                          "sensors.encoder_counts_per_unit and rig.gear_ratio is "
                          f"{turns} counts; set the one the encoder sits on, or 0 for none")
