"""The H-bridge + quadrature-encoder rig: its rig-file rules, its firmware build and its pins.

An Arduino drives the bridge with Timer1's PWM (8-10 bits, 15-62 kHz), counts the encoder
in its pin interrupts and samples on Timer2 (``firmware/labrig_bridge/src/hal_hbridge.inc``).
The host sends the output as an offset-binary word of the PWM's bits and a sign, zero at
``2**pwm_bits``, so the rig file's ``[bridge] dac_bits`` is ``pwm_bits + 1`` and its
``dac_range_v`` is the supply either way: ``volts = (word - 2**pwm_bits) * supply / 2**pwm_bits``.
"""
from __future__ import annotations

from labrig.core.errors import ConfigError, RigError

#: the sample clock of the H-bridge build: Timer2 at 10 kHz, divided in software
TIMER_HZ = 10_000
MIN_RATE_HZ, MAX_RATE_HZ = 50, 2000
#: Timer1's fast PWM without prescaler: bits -> frequency (16 MHz / 2^bits)
PWM_HZ = {8: 62_500.0, 9: 31_250.0, 10: 15_625.0}

#: the one pin map of the H-bridge build, per board: Arduino pin names (the firmware's
#: ``hal_hbridge.inc`` uses the same pins through their ports; tests/test_hbridge.py
#: checks the two agree)
PINS = {
    "uno": {"pwm_in1": "D9", "dir_in2": "D10", "enc_a": "D2", "enc_b": "D3", "current": "A0"},
    "nano": {"pwm_in1": "D9", "dir_in2": "D10", "enc_a": "D2", "enc_b": "D3", "current": "A0"},
    "mega": {"pwm_in1": "D11", "dir_in2": "D12", "enc_a": "D2", "enc_b": "D3", "current": "A0"},
}


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


def make_options(rig) -> list[str]:
    """The ``make -C firmware`` variables that build this rig's firmware."""
    b = rig.bridge
    if b.firmware != "hbridge":
        return []
    return ["RIG=hbridge", f"PWM_BITS={b.pwm_bits}", f"DRIVE={b.drive_mode}",
            f"OFF={b.off_phase}", f"DECODING={b.decoding}",
            f"CURRENT={1 if b.current_sense else 0}"]


def build_folder(rig) -> str:
    """The build folder, under ``firmware/build``, of this rig's firmware (as the Makefile
    names it)."""
    b = rig.bridge
    if b.firmware != "hbridge":
        return ""
    return (f"hbridge-{b.drive_mode}-{b.off_phase}-x{b.decoding}-pwm{b.pwm_bits}"
            + ("-current" if b.current_sense else ""))


def rig_flags(rig) -> int:
    """The HELLO rig flags a board built for this rig reports."""
    from labrig.bridge import protocol as P

    b = rig.bridge
    return ((P.FLAG_IN1_IN2 if b.drive_mode == "in1_in2" else 0)
            | (P.FLAG_BRAKE if b.off_phase == "brake" else 0)
            | (P.FLAG_CURRENT if b.current_sense else 0))


def check_board(rig, hello: dict, port: str) -> None:
    """The board on ``port`` runs the firmware this rig file describes.

    Raises
    ------
    RigError
        The board was flashed for the other rig, or with other H-bridge options; the
        message says how to flash the right one.
    """
    b = rig.bridge
    want, have = b.firmware, hello.get("rig", "ms150")
    flash = (f"flash it with `make -C firmware upload BOARD={hello.get('board', 'uno')} "
             f"PORT={port} {' '.join(make_options(rig))}`".replace("  ", " "))
    if want != have:
        raise RigError(f"the board on {port} runs the {have} firmware ({hello.get('firmware')}), "
                       f"but the rig file describes an {want} rig: {flash}, or give the "
                       "rig file that matches the board (--rig)")
    if want != "hbridge":
        return
    got = {"pwm_bits": hello.get("pwm_bits"), "decoding": hello.get("decoding"),
           "flags": hello.get("rig_flags")}
    need = {"pwm_bits": b.pwm_bits, "decoding": b.decoding, "flags": rig_flags(rig)}
    if got != need:
        diff = ", ".join(f"{k} {got[k]} (rig file: {need[k]})" for k in need if got[k] != need[k])
        raise RigError(f"the board on {port} was built with other H-bridge options: {diff}; "
                       f"{flash}")
