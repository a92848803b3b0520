"""The H-bridge + quadrature-encoder rig: its firmware build, its greeting and its pins (the
rig file's rules are labrig.io.hbridge_rig's).

An Arduino drives the bridge with Timer1's PWM (8-10 bits, 15-62 kHz), counts the encoder
in its pin interrupts and samples on Timer2 (``firmware/labrig_bridge/src/hal_hbridge.inc``).
The host sends the output as an offset-binary word of the PWM's bits and a sign, zero at
``2**pwm_bits``, so the rig file's ``[bridge] dac_bits`` is ``pwm_bits + 1`` and its
``dac_range_v`` is the supply either way: ``volts = (word - 2**pwm_bits) * supply / 2**pwm_bits``.
"""
from __future__ import annotations

from labrig.core.errors import RigError
from labrig.io.board_pins import BOARD_NAMES, HBRIDGE_PINS
from labrig.io.hbridge_rig import TIMER_HZ  # noqa: F401  (the board's sample clock, for callers of this module)

#: the one pin map of the H-bridge build, per board: Arduino pin names (the firmware's
#: ``hal_hbridge.inc`` uses the same pins through their ports; tests/test_hbridge_rig.py
#: checks the two agree)
PINS = HBRIDGE_PINS


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
        The board was flashed for the other rig, or with other H-bridge options (the
        message says how to flash the right one), or is not the board the rig file names.
    """
    b = rig.bridge
    want, have = b.firmware, hello.get("rig", "ms150")
    flash = (f"flash it with `make -C firmware upload BOARD={hello.get('board', 'uno')} "
             f"PORT={port} {' '.join(make_options(rig))}`".replace("  ", " "))
    if want != have:
        raise RigError(f"the board on {port} runs the {have} firmware ({hello.get('firmware')}), "
                       f"but the rig file describes an {want} rig: {flash}, or give the "
                       "rig file that matches the board (--rig)")
    if b.board and hello.get("board") not in (None, b.board):
        raise RigError(f"the board on {port} is {BOARD_NAMES[hello['board']]}, but the rig file's bench is "
                       f"built on {BOARD_NAMES[b.board]} (bridge.board): their pins differ (labrig wiring "
                       f"--rig FILE --board {hello['board']}); connect the bench's own board, or "
                       "change the rig file's board and its wiring")
    if want != "hbridge":
        return
    got = {"pwm_bits": hello.get("pwm_bits"), "decoding": hello.get("decoding"),
           "flags": hello.get("rig_flags")}
    need = {"pwm_bits": b.pwm_bits, "decoding": b.decoding, "flags": rig_flags(rig)}
    if got != need:
        diff = ", ".join(f"{k} {got[k]} (rig file: {need[k]})" for k in need if got[k] != need[k])
        raise RigError(f"the board on {port} was built with other H-bridge options: {diff}; "
                       f"{flash}")
