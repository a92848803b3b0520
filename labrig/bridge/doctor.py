"""Checking the chain from the PC to the sensors, one link at a time (``labrig doctor``):
the port and its permissions, who holds it, the greeting and its baud rate, the firmware
against this host, the board against the rig file, the board's id, 0 V out with every
sensor at rest in its range, and the sample rate achieved over a short run at 0 V.

Each check is one line: it passes, or says what to do. A check that fails stops the ones
that need it (they are listed as not run), so the first failure is the one to mend.
"""
from __future__ import annotations

import grp
import os
import stat
import time
from dataclasses import asdict, dataclass, field
from typing import Annotated, Optional

import numpy as np
from pydantic import Field, computed_field

from labrig.core.errors import LabrigError, UserError
from labrig.core.record import Record

#: serial speeds tried when the board does not greet at the one asked for (the firmware's
#: BAUD options first, then the usual ones of other sketches)
OTHER_BAUDS = (500000, 250000, 125000, 1000000, 115200, 57600, 230400, 38400, 19200, 9600)


@dataclass
class Check:
    """One link of the chain: its name, whether it holds, and what was found or what to do."""

    name: str
    ok: Optional[bool]   # None: not run (an earlier check it needs failed)
    text: str


@dataclass
class ChainReport(Record):
    """What ``labrig doctor`` found, check by check.

    Attributes
    ----------
    port : str or None
    checks : list of Check
    hello : dict
        The board's greeting ({} when it did not greet).
    """

    port: Optional[str]
    checks: list[Check] = field(default_factory=list)
    hello: Annotated[dict, Field(exclude=True)] = field(default_factory=dict)

    @computed_field
    @property
    def ok(self) -> bool:
        """Every check ran and passed."""
        return all(c.ok for c in self.checks)

    def add(self, name: str, ok: bool | None, text: str) -> bool:
        self.checks.append(Check(name, ok, text))
        return bool(ok)

    def skip(self, *names: str) -> None:
        for n in names:
            self.add(n, None, "not run (an earlier check failed)")

    def to_pandas(self):
        import pandas as pd

        return pd.DataFrame([asdict(c) for c in self.checks])

    def __str__(self) -> str:
        mark = {True: "ok  ", False: "FAIL", None: "-   "}
        return "\n".join(f"{mark[c.ok]} {c.name:<12} {c.text}" for c in self.checks)


def _port_access(report: ChainReport, port: str) -> bool:
    try:
        st = os.stat(port)
    except OSError:
        raise UserError(f"port: {port} does not exist: plug the board in (labrig ports lists "
                        "the serial ports)") from None
    if not stat.S_ISCHR(st.st_mode):
        raise UserError(f"port: {port} is not a serial device (labrig ports lists them)")
    report.add("port", True, f"{port} is a serial device")
    if not os.access(port, os.R_OK | os.W_OK):
        try:
            group = grp.getgrgid(st.st_gid).gr_name
        except KeyError:
            group = str(st.st_gid)
        if st.st_mode & 0o060 == 0o060 and st.st_gid != 0:
            return report.add("permissions", False,
                              f"you may not open {port} (it belongs to group {group}): "
                              f"sudo usermod -aG {group} $USER, then log out and in")
        return report.add("permissions", False,
                          f"only its owner may open {port} (mode {stat.S_IMODE(st.st_mode):o}): "
                          "give serial ports to the dialout group with a udev rule "
                          "(docs/hardware.md, 'Troubleshooting'), or run as that user")
    return report.add("permissions", True, "read and write")


def _greeting(report: ChainReport, port: str, baud: int) -> dict:
    from labrig.bridge.ports import greet

    try:
        hello = greet(port, baud=baud)   # reads the id only: the bridge below gives one
    except LabrigError as e:
        report.add("greeting", False, str(e))
        return {}
    if hello:
        report.add("greeting", True, f"{hello.get('firmware')} at {baud} baud")
        return hello
    for other in OTHER_BAUDS:
        if other == baud:
            continue
        try:
            if greet(port, baud=other, timeout=1.2):
                report.add("greeting", False,
                           f"the board greets at {other} baud, not {baud}: give --baud {other} "
                           f"(its firmware was built with BAUD={other}), or flash one built for "
                           f"{baud}")
                return {}
        except LabrigError:
            break
    report.add("greeting", False, f"no labrig greeting at {baud} baud or any other: is the "
                                  "labrig firmware on the board (labrig flash --board BOARD)?")
    return {}


def _firmware(report: ChainReport, hello: dict, port: str, rig) -> bool:
    from labrig.bridge.flash import FIRMWARE_VERSION
    from labrig.bridge.hbridge import check_board, firmware_version
    from labrig.bridge.protocol import PROTOCOLS

    have = firmware_version(hello)
    want = tuple(int(x) for x in FIRMWARE_VERSION.split("."))
    if hello.get("protocol") not in PROTOCOLS or have < want:
        report.add("firmware", False, f"{hello.get('firmware')}; this labrig ships "
                   f"{FIRMWARE_VERSION}: flash it (labrig flash --board {hello.get('board')})")
    elif have > want:
        report.add("firmware", False, f"{hello.get('firmware')} is newer than this labrig's "
                   f"{FIRMWARE_VERSION}: update labrig")
    else:
        report.add("firmware", True, f"{FIRMWARE_VERSION}, as this labrig's")
    try:
        check_board(rig, hello, port)
    except LabrigError as e:
        return report.add("rig", False, str(e))
    return report.add("rig", True, f"{hello.get('rig')} firmware on the {hello.get('board')}, "
                                   "as the rig file describes")


def _rails(lo: float, hi: float, q: float, values: np.ndarray, what: str) -> str:
    """What is wrong with a sensor's readings at rest (empty: nothing)."""
    if not values.size:
        return ""
    at = float(np.median(values))
    edge = "top" if at >= hi - 1.5 * q else "bottom" if at <= lo + 1.5 * q else ""
    return (f"{what} reads the {edge} of its range ({at:+.2f} V) at rest: a broken wire or a "
            "sensor at its rail; check its wiring (labrig wiring)") if edge else ""


def _at_rest(report: ChainReport, bridge, rig, seconds: float) -> None:
    """A run at 0 V: the output word, every sensor at rest, the rate achieved."""
    from labrig.bridge.settings import adc_counts_to_volts, bridge_settings, volts_to_dac_word
    from labrig.bridge.sweep import acquire
    from labrig.io.experiment import Experiment

    b = rig.bridge
    exp = Experiment(name="doctor", loop="open", waveform="constant", amplitude_v=0.0,
                     offset_v=0.0, lead_in_s=0.0, duration_s=seconds,
                     sample_rate_hz=b.sample_rate_hz)
    t0 = time.monotonic()
    run = acquire(bridge, exp, rig)
    wall = time.monotonic() - t0
    counters = bridge.counters()
    s = bridge_settings(rig)
    got = run.measured
    n, lost = exp.n_samples, int((~got).sum())
    u = run.u[got]
    step = (s.dac_range_v[1] - s.dac_range_v[0]) / 2 ** s.dac_bits
    if np.all(np.abs(u) <= step):
        report.add("0 V out", True, f"every sample's output word at 0 V (word "
                                    f"{volts_to_dac_word(0.0, s)})")
    else:
        report.add("0 V out", False, f"the output read back {np.max(np.abs(u)):.3f} V from 0 V: "
                                     "the board does not hold its output at zero; flash it again")
    problems = []
    if s.firmware == "hbridge":
        counts = run.data["pos"].to_numpy(float)[got]
        if counts.size and np.ptp(counts) > 2:
            problems.append(f"the encoder counted {int(np.ptp(counts))} counts with the motor at "
                            "0 V: a noisy or loose encoder wire, or a shaft that is turning")
    else:
        lo = float(adc_counts_to_volts(0, "pos", s))
        hi = float(adc_counts_to_volts(2 ** s.adc_bits - 1, "pos", s))
        q = (hi - lo) / (2 ** s.adc_bits - 1)
        for ch, what in (("tacho", "the tacho (A0)"), ("pos", "the output pot (A1)"),
                         ("ref", "the reference input (A2)")):
            if ch not in run.data:
                continue
            vals = run.data[ch].to_numpy(float)[got]
            msg = _rails(lo, hi, q, vals, what)
            if not msg and ch == "tacho" and abs(np.median(vals)) > max(10 * q, 0.1):
                msg = (f"the tacho reads {np.median(vals):+.2f} V with the motor at 0 V: a "
                       "shaft that turns, or an offset in its wiring")
            if msg:
                problems.append(msg)
    report.add("sensors", not problems, "; ".join(problems) or "every sensor at rest, within "
                                                              "its range")
    rate = (n - lost) / wall if wall > 0 else 0.0
    overruns = counters.get("board_sample_overruns", 0)
    if lost or overruns:
        report.add("sample rate", False,
                   f"{n - lost} of {n} samples at {b.sample_rate_hz:g} Hz ({lost} lost, "
                   f"{overruns} overrun on the board): lower [bridge] sample_rate_hz, or check "
                   "the cable (docs/hardware.md, 'Maximum sustained sample rate')")
    else:
        report.add("sample rate", True, f"{n} of {n} samples at {b.sample_rate_hz:g} Hz in "
                                        f"{wall:.2f} s ({rate:.0f} samples/s received)")


def check_chain(port: str | None = None, rig=None, *, baud: int = 500000,
                board_id: int | None = None, seconds: float = 2.0) -> ChainReport:
    """Check the chain from this PC to the rig's sensors (``labrig doctor``).

    Parameters
    ----------
    port : str, optional
        The board's serial device; default the one labrig board connected (or the one whose
        id is ``board_id``).
    rig : RigConfig, optional
        The rig file the board should match (default the MS150 rig).
    baud : int
        The serial speed to greet at (the firmware's BAUD; 500000 by default).
    board_id : int, optional
        The board the station is bound to.
    seconds : float
        The length of the run at 0 V.

    Returns
    -------
    ChainReport
        One check per line; ``report.ok`` when all passed.

    Raises
    ------
    UserError
        ``port`` is not there or not a serial device; no labrig board is found without it.
    """
    from labrig.bridge.ports import list_ports, the_board
    from labrig.bridge.serial import SerialBridge
    from labrig.bridge.transport import lease, release
    from labrig.io.config import RigConfig

    rig = rig if rig is not None else RigConfig()
    later = ("permissions", "in use", "greeting", "firmware", "rig", "board id", "0 V out",
             "sensors", "sample rate")
    if port is None:
        port = the_board(list_ports(), board_id)
    report = ChainReport(port)
    if not _port_access(report, port):
        report.skip(*later[1:])
        return report
    try:
        lease(port)
    except LabrigError as e:
        report.add("in use", False, str(e))
        report.skip(*later[2:])
        return report
    try:
        report.add("in use", True, "no other program holds it")
        hello = report.hello = _greeting(report, port, baud)
        if not hello or not _firmware(report, hello, port, rig):
            report.skip(*[n for n in later[3:] if n not in {c.name for c in report.checks}])
            return report
        bridge = SerialBridge(port, rig, baudrate=baud, board_id=board_id)
        try:
            bridge.open()
        except LabrigError as e:
            report.add("board id", False, str(e))
            report.skip(*later[6:])
            return report
        try:
            from labrig.bridge.protocol import format_board_id

            report.add("board id", True, format_board_id(bridge.board_id) if bridge.board_id
                       else "none (firmware before 2.3 keeps no id)")
            _at_rest(report, bridge, rig, seconds)
        finally:
            try:
                bridge.zero()
            finally:
                bridge.close()
    finally:
        release(port)
    return report
