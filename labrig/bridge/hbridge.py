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


def firmware_version(hello: dict) -> tuple[int, ...]:
    """The version a board's HELLO names ("labrig-fw 2.2.0 uno ms150" -> (2, 2, 0));
    (0,) when it names none."""
    import re

    m = re.search(r"\b(\d+)\.(\d+)\.(\d+)\b", str(hello.get("firmware", "")))
    return tuple(int(g) for g in m.groups()) if m else (0,)


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
    rig_file = getattr(rig, "source", "") or "FILE"
    flash = (f"flash it with `labrig flash --board {hello.get('board', 'uno')} --rig {rig_file} "
             f"--port {port}`")
    if want != have:
        raise RigError(f"the board on {port} runs the {have} firmware ({hello.get('firmware')}), "
                       f"but the rig file describes an {want} rig: {flash}, or give the "
                       "rig file that matches the board (`rig`)")
    from labrig.bridge.trips import FIRST_VERSION

    if (b.trip_speed or b.trip_position or b.estop) and firmware_version(hello) < FIRST_VERSION:
        raise RigError(f"the firmware on {port} ({hello.get('firmware')}) enforces no trips, "
                       "but the rig file sets them (bridge.trip_speed, trip_position, estop); "
                       f"{flash} ({'.'.join(map(str, FIRST_VERSION))} or later), or remove "
                       "the keys")
    if b.board and hello.get("board") not in (None, b.board):
        raise RigError(f"the board on {port} is {BOARD_NAMES[hello['board']]}, but the rig file's bench is "
                       f"built on {BOARD_NAMES[b.board]} (bridge.board): their pins differ (labrig wiring "
                       f"--rig FILE --board {hello['board']}); connect the bench's own board, or "
                       "change the rig file's board and its wiring")
    if hello.get("dac_bits") not in (None, int(b.dac_bits)):
        raise RigError(
            f"the board on {port} has a {hello['dac_bits']}-bit output word, the rig file "
            f"{int(b.dac_bits)} bits ([bridge] dac_bits{', pwm_bits' if want == 'hbridge' else ''}): "
            "give the rig file of this board (`rig`) or flash the firmware it describes")
    if want != "hbridge":
        return
    from labrig.bridge import protocol as P

    flags = hello.get("rig_flags") or 0
    got = {"pwm_bits": hello.get("pwm_bits"), "decoding": hello.get("decoding"),
           "flags": flags & ~P.FLAG_INDEX}   # (every build since 2.1 reads an index)
    need = {"pwm_bits": b.pwm_bits, "decoding": b.decoding, "flags": rig_flags(rig)}
    if got != need:
        diff = ", ".join(f"{k} {got[k]} (rig file: {need[k]})" for k in need if got[k] != need[k])
        raise RigError(f"the board on {port} was built with other H-bridge options: {diff}; "
                       f"{flash}")
    if b.index_counts and not flags & P.FLAG_INDEX:
        raise RigError(f"the firmware on {port} ({hello.get('firmware')}) reads no index pulse, "
                       "but the rig file wires one (bridge.index_counts); "
                       f"{flash} (2.1 or later), or set index_counts = 0")


def words_block(first: int, w, s, closed: bool, board: bool = False):
    """A SAMPLES frame's words (``w``, n x 4, from sample ``first``) as a block: raw volts
    from the MS150 bridge; from an H-bridge board (:func:`hbridge_block`) the output in
    volts of the supply and the encoder's signed count. ``s``: the bridge settings;
    ``closed``: the run is a closed loop; ``board``: one the MS150 board closed itself,
    whose input is then the reference it aimed at (in the axis's unit, from its pot word)
    and whose output its drive."""
    import numpy as np

    from labrig.bridge.base import SampleBlock
    from labrig.bridge.settings import adc_counts_to_volts, dac_word_to_volts

    index = np.arange(first, first + len(w))
    u = dac_word_to_volts(w[:, 0], s)
    if s.firmware == "hbridge":
        return hbridge_block(index, w, u, s, closed)
    if board:
        from labrig.bridge.settings import sensor_words

        sw = sensor_words(s)
        return SampleBlock(index=index, u=(w[:, 3] - sw["pos_zero"]) / sw["counts_per_unit"],
                           tacho=adc_counts_to_volts(w[:, 1], "tacho", s),
                           pos=adc_counts_to_volts(w[:, 2], "pos", s), drive=u)
    return SampleBlock(index=index, u=u, tacho=adc_counts_to_volts(w[:, 1], "tacho", s),
                       pos=adc_counts_to_volts(w[:, 2], "pos", s),
                       ref=adc_counts_to_volts(w[:, 3], "ref", s))


def hbridge_block(index, w, u, s, closed: bool):
    """An H-bridge board's SAMPLES words as a block: the output in volts of the supply
    (``u``) and the encoder's signed count (the rig's ``pos`` unit is counts:
    ``sensors.encoder_counts_per_unit``); in a closed loop the input is the reference the
    board's PD used (in the axis's unit) and the output its logged drive; with current
    sense, A0 against the board's own 5 V reference."""
    from labrig.bridge import protocol as P
    from labrig.bridge.base import SampleBlock
    from labrig.bridge.settings import REF_ZERO

    pos = P.encoder_counts(w).astype(float)
    if closed and not s.current_sense:
        return SampleBlock(index=index, u=(w[:, 3] - REF_ZERO) / s.counts_per_unit,
                           tacho=None, pos=pos, drive=u)
    return SampleBlock(index=index, u=u, tacho=None, pos=pos,
                       current=w[:, 3] * (5.0 / 1024) - s.current_zero_v
                       if s.current_sense else None)


def encoder_record(events: list, faults, index_counts: int, decoding: int,
                   travel_counts: float) -> dict:
    """What a run's encoder says of its own counts, for the run's ``bridge.encoder`` block.

    Parameters
    ----------
    events : list of dict
        The run's INDEX messages (``sample``, ``count``, ``pulse``), in order.
    faults : int or None
        Edges the board's decoder could not decode during the run (None: its STATUS was lost).
    index_counts : int
        The rig file's ``bridge.index_counts`` (0: no index wired).
    decoding : int
        Counts a quadrature cycle (``bridge.decoding``): an index pulse's edge may sit
        anywhere within one cycle, by how the encoder gates it and the way the shaft turns.
    travel_counts : float
        How far the count ran in the run (its largest minus its smallest).

    Returns
    -------
    dict
        ``faults``; with an index, ``index_pulses``, the first pulse's ``index_sample`` and
        ``index_count``, and ``slip_counts`` (the largest distance of a pulse from a whole
        number of turns after the first); ``problems``: one sentence each, when the counts
        cannot be trusted.
    """
    rec = {"faults": faults}
    problems = []
    if faults:
        problems.append(f"{faults} encoder edge(s) the board could not decode (both channels "
                        "changed between two interrupts: the shaft outran the chip), each a "
                        "count or two lost")
    if index_counts:
        rec["index_pulses"] = int(events[-1]["pulse"]) if events else 0
        if events:
            c0 = int(events[0]["count"])
            half = index_counts // 2
            slip = max(abs((int(e["count"]) - c0 + half) % index_counts - half) for e in events)
            rec.update(index_sample=int(events[0]["sample"]), index_count=c0, slip_counts=slip)
            if slip > decoding:
                problems.append(f"an index pulse came {slip} counts off a whole number of turns "
                                f"({index_counts} counts each, bridge.index_counts): counts were "
                                "lost or gained between two pulses")
        elif travel_counts > 1.5 * index_counts:
            problems.append(f"no index pulse while the shaft turned {travel_counts / index_counts:.1f} "
                            "turns of the encoder (bridge.index_counts): is the index wired?")
    if problems:
        rec["problems"] = problems
    return rec
