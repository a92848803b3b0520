"""The serial bridge: the labrig firmware on an Arduino (or under simavr).

Implements :class:`labrig.bridge.base.Bridge` over the framed protocol of
``firmware/PROTOCOL.md``. The board owns the timing; the host configures an experiment in
DAC words (computed by :mod:`labrig.bridge.settings` from the rig's ``[bridge]`` ranges and
calibration), starts it, and receives sample-indexed, CRC-checked batches which it converts
to raw volts. Bytes move through a :class:`~labrig.bridge.transport.Transport`: a serial
port by default, a scripted board in tests.
"""
from __future__ import annotations

import time
from collections import deque
from os import PathLike
from typing import TYPE_CHECKING

from labrig.bridge import protocol as P
from labrig.bridge.base import Bridge, SampleBlock
from labrig.bridge.serial_record import RunRecord
from labrig.io.experiment import Experiment
from labrig.bridge.settings import bridge_settings, experiment_body, volts_to_dac_word  # noqa: F401 (tests import volts_to_dac_word from here)
from labrig.bridge import identity
from labrig.bridge.hbridge import check_board, firmware_version
from labrig.bridge.trips import limits as trip_limits, limits_body
from labrig.bridge.transport import SerialTransport, Transport, link_faults, link_hint
from labrig.core.errors import LabrigError, RigError, UserError

if TYPE_CHECKING:   # annotation only: labrig.io.config imports the bridge package
    from labrig.io.config import RigConfig

# the conversions lived here before settings.py; importers of this module keep working
__all__ = ["SerialBridge", "SerialTransport", "TIMER_HZ", "Transport", "adc_counts_to_volts",
           "bridge_settings", "dac_word_to_volts", "volts_to_dac_word"]

#: board STATUS counters that count since the board's reset; reported per run as differences


class SerialBridge(RunRecord, Bridge):
    """The labrig board on a serial port (USB ``/dev/ttyACM0`` or an emulator's pty).

    Parameters
    ----------
    port_or_transport : str, path or Transport
        Serial device, opened through :class:`SerialTransport`, or a transport to use
        as it is (e.g. a :class:`~labrig.bridge.transport.ScriptedTransport` in tests).
    rig : labrig.io.config.RigConfig
        Rig configuration; only ``rig.bridge`` is used (see :func:`bridge_settings`).
    baudrate : int
        Link speed of a serial device; the firmware runs at 500000.
    hello_timeout : float
        Seconds to wait for the board's HELLO after opening (the Uno resets on open).
    heartbeat_s : float
        Interval of heartbeats while streaming; must be well below the watchdog time. 50 ms
        against the default 500 ms: only ~10 heartbeats lost in a row trip the watchdog,
        which even a link damaging 1 % of its bytes (7 % of heartbeats) does not do.
    tries : int
        Transmissions of a command (CONFIGURE, START, STOP, ZERO, STATUS_REQ) before giving
        up; twice as many once the link has delivered a damaged frame (a board is there,
        behind a bad link: patience pays, while a silent port fails fast).
    ack_timeout : float
        Seconds to wait for the answer to one transmission. A pty answers in a few ms and a
        USB board within ~20 ms; 4 x 0.3 s keeps the old 1 s budget for a silent board.
    tail_s : float
        Once the planned end of a run has passed, this long without a sample frame ends the
        run even without its DONE (which may have been lost); the rest becomes a gap.

    Attributes
    ----------
    link : Transport
        The byte link the frames travel on.
    samples, dropped_samples, stale_frames, bad_frames, retries : int
        Cumulative over the session: samples received, samples missing (index gaps and a
        lost tail), frames that arrived too late or twice, CRC-valid frames whose body does
        not parse, command retransmissions. :meth:`counters` gives them per run.
    """

    source = "serial"

    def __init__(self, port_or_transport: str | PathLike | Transport, rig: RigConfig, *,
                 baudrate: int = 500000, hello_timeout: float = 3.0, heartbeat_s: float = 0.05,
                 tries: int = 4, ack_timeout: float = 0.3, tail_s: float = 0.5,
                 board_id: int | None = None):
        if isinstance(port_or_transport, Transport):
            self.link = port_or_transport
        else:
            self.link = SerialTransport(port_or_transport, baudrate)
        self.port = self.link.name   # what messages and counters() call the link
        self.settings = bridge_settings(rig)
        self._rig = rig
        self.hello_timeout = hello_timeout
        self.heartbeat_s = min(heartbeat_s, self.settings.watchdog_ms / 10000.0)
        self.tries, self.ack_timeout, self.tail_s = max(1, int(tries)), ack_timeout, tail_s
        self._dec = P.StreamDecoder()
        self._link_base = (0, 0)   # the link's frame counts at the last greeting
        self._seq = 0
        self._last_tx = 0.0
        self._pending: deque = deque()
        self.hello: dict = {}
        #: the board's id (labrig.bridge.identity), and the one the station is bound to
        self.board_id: int | None = None
        self.expected_board_id = board_id
        self._exp: Experiment | None = None
        self._n_samples = 0
        self._next_index = 0
        self._streaming = False
        self._started = False
        self._finished = False
        self._index_events: list[dict] = []   # the run's INDEX messages
        #: how the board ended the run on its own (a trip, a reset), None: it did not
        self.trip: dict | None = None
        self._count_range: tuple[int, int] | None = None   # its lowest and highest count
        self._t_end = self._last_sample_t = 0.0
        self._tail = tail_s
        self.samples = self.dropped_samples = self.stale_frames = self.bad_frames = 0
        self.retries = 0
        self._mark = self._totals()
        self.board_status: dict = {}
        self._board_mark: dict = {}
        self.board_errors: list[str] = []
        self._errors_mark = 0

    # ---- link ------------------------------------------------------------------------
    def _next_seq(self) -> int:
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFF
        return seq

    def _send(self, type_: int, body: bytes = b"") -> int:
        seq = self._next_seq()
        # the leading 0x00 ends any partial frame the board holds (garbage, a reset)
        self._write(b"\x00" + P.encode_frame(type_, seq, body))
        return seq

    def _write(self, data: bytes) -> None:
        if not self.link.is_open:
            raise RigError(f"{self.port} is not open")
        with link_faults(self.port, " while writing"):
            self.link.write(data)
        self._last_tx = time.monotonic()

    def _poll(self, wait: float) -> None:
        """Read what is there (waiting up to ``wait`` s for a first byte) into the queue."""
        with link_faults(self.port):
            data = self.link.read(max(1, self.link.in_waiting), wait)
            if data and self.link.in_waiting:
                data += self.link.read(self.link.in_waiting, wait)
        if data:
            for f in self._dec.feed(data):
                # checked once, on arrival: a body that does not parse is counted, dropped
                try:
                    self._pending.append(P.parse_message(f))
                except P.BodyError:
                    self.bad_frames += 1

    def _heartbeat(self) -> None:
        if time.monotonic() - self._last_tx >= self.heartbeat_s:
            self._send(P.HEARTBEAT)

    def _totals(self) -> dict:
        return {"samples": self.samples, "dropped_samples": self.dropped_samples,
                "crc_errors": self._dec.crc_errors, "framing_errors": self._dec.framing_errors,
                "stale_frames": self.stale_frames, "bad_frames": self.bad_frames,
                "retries": self.retries}

    def _link_state(self) -> tuple[int, int]:
        """(damaged, intact) frames received since the last greeting, to tell a garbling
        link from a dead one. Bytes before a greeting do not count: opening a port mid-frame
        or across a board's reset leaves a fragment on any good link."""
        damaged, intact = self._link_counts()
        return damaged - self._link_base[0], intact - self._link_base[1]

    def _link_counts(self) -> tuple[int, int]:
        """(damaged, intact) frames received since the port was opened."""
        return self._dec.crc_errors + self._dec.framing_errors + self.bad_frames, self._dec.frames_ok

    def _tries(self) -> int:
        return self.tries * (2 if self._link_state()[0] else 1)

    def _hint(self, since: tuple[int, int]) -> str:
        """Why nothing useful arrived since ``since`` (a :meth:`_link_state`), and what to do."""
        return link_hint(since, self._link_state())

    def _board_error(self, err: dict) -> RigError:
        msg = f"board on {self.port} reported {err['name']}: {err['text']}"
        self.board_errors.append(msg)
        return RigError(msg)

    def _command(self, type_: int, body: bytes = b"") -> None:
        """Send a command and wait for its ACK, retransmitting it on silence.

        A retransmission is the identical frame (same ``seq``): a late ACK of an earlier
        try matches, and the firmware recognises a repeated START instead of restarting
        the experiment. A START has also taken effect when its samples arrive (the lost
        frame was its ACK); those frames stay queued for :meth:`read`.

        Raises
        ------
        UserError
            The board refused the experiment (LIMIT, RATE, BAD_CONFIG).
        RigError
            No ACK after ``tries`` transmissions, or a board error that no retry can fix.
        """
        seq = self._next_seq()
        wire = b"\x00" + P.encode_frame(type_, seq, body)
        since = self._link_state()
        name = P.TYPE_NAMES[type_]
        attempt = 0
        while attempt < self._tries():
            if attempt:
                self.retries += 1
            self._write(wire)
            deadline = time.monotonic() + self.ack_timeout
            while True:
                if self._take_answer(type_, seq, attempt):
                    return
                now = time.monotonic()
                if now >= deadline:
                    break
                self._heartbeat()   # a running board must not trip its watchdog meanwhile
                self._poll(min(0.05, deadline - now))
            attempt += 1
        raise RigError(f"no answer from {self.port} to {name} after {attempt} tries "
                       f"({attempt * self.ack_timeout:.1f} s): {self._hint(since)}")

    def _take_answer(self, type_: int, seq: int, attempt: int) -> bool:
        """Consume queued frames looking for the answer to command (type_, seq)."""
        keep: deque = deque()
        found = False
        while self._pending:
            f = self._pending.popleft()
            if found:
                keep.append(f)
            elif f.type == P.ACK:
                found = f.fields == {"type": type_, "seq": seq}
            elif type_ == P.START and f.type in (P.SAMPLES, P.DONE):
                keep.append(f)
                found = True
            elif f.type == P.ERROR:
                err = f.fields
                if err["name"] in ("LIMIT", "RATE", "BAD_CONFIG"):
                    raise UserError(f"board on {self.port} refused the experiment: {err['text']}")
                if type_ == P.START and attempt and err["name"] == "BUSY":
                    found = True   # an earlier try started it (firmware without START dedup)
                elif err["name"] == "BAD_FRAME" or (err["name"] == "WATCHDOG"
                                                    and type_ in (P.STOP, P.ZERO)):
                    # one of our frames arrived damaged, or the board has already stopped
                    # itself: the ACK or a retransmission settles it
                    self.board_errors.append(f"board on {self.port} reported {err['name']}: "
                                             f"{err['text']}")
                else:
                    raise self._board_error(err)
            # anything else here is stale: a duplicate ACK, a late STATUS or HELLO
        self._pending = keep
        return found

    def _fetch_status(self) -> dict:
        """Ask for STATUS (a few tries); {} when no answer came."""
        return self._ask(P.STATUS_REQ, P.STATUS) or {}

    def _ask(self, type_: int, answer: int, body: bytes = b"", *,
             refusable: bool = False) -> dict | None:
        """Send ``type_`` (a few tries) and return the fields of the first ``answer``; None
        when none came (or, ``refusable``, the board answered ERROR: an older firmware)."""
        wire = b"\x00" + P.encode_frame(type_, self._next_seq(), body)
        for attempt in range(self._tries()):
            if attempt:
                self.retries += 1
            self._write(wire)
            deadline = time.monotonic() + self.ack_timeout
            while time.monotonic() < deadline:
                self._poll(0.05)
                while self._pending:
                    f = self._pending.popleft()
                    if f.type == answer:
                        self._pending.clear()
                        return f.fields
                    if refusable and f.type == P.ERROR:
                        return None
        return None

    # ---- Bridge interface ------------------------------------------------------------
    def open(self) -> dict:
        """Open the link and handshake; return the board's HELLO fields."""
        try:
            self.link.open()
        except LabrigError:
            raise   # the transport's own message, with its cure
        except Exception as e:
            raise RigError(f"cannot open {self.port}: {e}") from e
        # The Uno resets when the port opens and greets after its bootloader (~1-2 s);
        # its greeting may be lost, so ask again every 0.5 s.
        since = self._link_state()
        deadline = time.monotonic() + self.hello_timeout
        extended = False
        next_ask = 0.0
        while not self.hello:
            now = time.monotonic()
            if now >= deadline and not extended and self._link_state()[0] > since[0]:
                # damaged frames arrive: a board is there behind a bad link; ask a while longer
                deadline, extended = deadline + self.hello_timeout, True
            if now >= deadline:
                hint = self._hint(since)
                self.close()
                if hint.startswith("is the board"):
                    hint = "is the labrig firmware on the board and nothing else using the port?"
                raise RigError(f"no hello from {self.port} within {self.hello_timeout:.1f} s: {hint}")
            if now >= next_ask:
                self._send(P.HELLO_REQ)
                next_ask = now + 0.5
            self._poll(0.05)
            while self._pending:
                f = self._pending.popleft()
                if f.type == P.HELLO:
                    self.hello = f.fields
        self._link_base = self._link_counts()
        if self.hello["protocol"] not in P.PROTOCOLS:
            self.close()
            raise RigError(f"board on {self.port} speaks protocol {self.hello['protocol']}, "
                           f"labrig speaks {', '.join(map(str, P.PROTOCOLS))}: reflash the "
                           "firmware (labrig flash --board BOARD)")
        try:   # the board was built for the rig the file describes, at its resolution
            check_board(self._rig, self.hello, self.port)
            self.board_id = identity.settle(
                lambda body: (self._ask(P.BOARD_ID, P.ID, body, refusable=True) or {}).get("board_id"),
                firmware_version(self.hello), expected=self.expected_board_id, port=self.port)
        except RigError:
            self.close()
            raise
        # stop whatever a previous host left running
        self._command(P.ZERO)
        self.board_status = self._fetch_status()   # the baseline of the first run's counters
        self._pending.clear()
        return {"firmware": self.hello["firmware"], "board": self.hello["board"],
                "protocol": self.hello["protocol"], "rig": self.hello["rig"],
                "capabilities": ["square", "step", "staircase", "constant"]
                + (["pwl"] if self.hello["capabilities"] & P.CAP_PWL else []),
                "max_rate_hz": self.hello["max_rate_hz"], "port": self.port,
                "board_id": P.format_board_id(self.board_id)}

    def configure(self, exp: Experiment) -> None:
        """Check the experiment against the limits and load it into the board."""
        body = experiment_body(exp, self.settings, self.hello)
        # the run's counters start here: a sidecar reports this run, not the session
        self._mark, self._board_mark = self._totals(), dict(self.board_status)
        self._errors_mark = len(self.board_errors)
        self._started = self._finished = False
        self._command(P.CONFIGURE, body)
        self._exp, self._n_samples = exp, int(exp.n_samples)
        self.trip, bounds = None, trip_limits(exp, self._rig, self.settings)
        if bounds is not None:   # (a CONFIGURE clears the board's limits: each run sends its own)
            self._command(P.LIMITS, limits_body(bounds))

    def start(self) -> None:
        """Start the configured experiment; samples follow from index 0."""
        if self._exp is None:
            raise UserError("start() before configure()")
        self._pending.clear()
        self._next_index = 0
        self._finished = False
        self._index_events, self._count_range = [], None
        t0 = time.monotonic()
        self._command(P.START)
        self._started = self._streaming = True
        rate = float(self._exp.sample_rate_hz)
        self._t_end = t0 + self._n_samples / rate
        self._last_sample_t = t0
        self._tail = self.tail_s + 3 * P.BATCH / rate   # a few frame intervals at any rate

    def _ended_on_its_own(self, f) -> bool:
        """Whether frame ``f`` says the board ended the run itself: a trip on a limit (ERROR
        TRIP) or a reset (an unasked HELLO mid-run; a reset starts at 0 V). Recorded; the
        samples it never took are the run's lost tail."""
        if f.type == P.ERROR and f.fields["name"] == "TRIP":
            fault, text = "TRIP", f.fields["text"]
        elif f.type == P.HELLO and self._next_index > 0:
            fault, text = "RESET", "the board restarted mid-run (its watchdog or its supply)"
        else:
            return False
        self.trip = {"fault": fault, "text": text, "after_sample": self._next_index - 1}
        self.board_errors.append(f"board on {self.port} reported {fault}: {text}")
        self._finish()
        return True

    def _finish(self) -> None:
        """End the run: whatever did not arrive up to the planned length is dropped."""
        self.dropped_samples += max(0, self._n_samples - self._next_index)
        self._next_index = max(self._next_index, self._n_samples)
        self._finished = True
        self._streaming = False

    def read(self, timeout: float = 2.0) -> SampleBlock | None:
        """Next batch of samples in raw volts; ``None`` once the run is over.

        The run is over at DONE, at the last planned sample, or -- when DONE and the last
        frames were lost -- once the planned end has passed and no samples came for
        ``tail_s``. Gaps in the sample index and a lost tail are counted in
        ``dropped_samples`` (the block's ``index`` shows them); no valid samples for
        ``timeout`` s raises :class:`RigError`.
        """
        if self._finished or not self._streaming:
            return None
        deadline = time.monotonic() + timeout
        since = self._link_state()
        while True:
            while self._pending:
                f = self._pending.popleft()
                if f.type == P.SAMPLES:
                    first, w = f.fields
                    if first < self._next_index or first + len(w) > self._n_samples:
                        self.stale_frames += 1   # a duplicate or a previous run's tail
                        continue
                    self.dropped_samples += first - self._next_index
                    self._next_index = first + len(w)
                    self.samples += len(w)
                    self._last_sample_t = time.monotonic()
                    return self._block(first, w)
                if f.type == P.INDEX:
                    if f.fields["sample"] <= self._n_samples:   # (a previous run's: dropped)
                        self._index_events.append(f.fields)
                    continue
                if f.type == P.DONE:
                    if f.fields["n_samples"] != self._n_samples:
                        self.stale_frames += 1   # not this run's DONE
                        continue
                    self._finish()
                    return None
                if self._ended_on_its_own(f):
                    return None
                if f.type == P.ERROR:
                    err = f.fields
                    if err["name"] == "BAD_FRAME":   # a heartbeat arrived damaged: harmless
                        self.board_errors.append(f"board on {self.port} reported BAD_FRAME: "
                                                 f"{err['text']}")
                        continue
                    self._streaming = False
                    raise self._board_error(err)
            now = time.monotonic()
            if self._next_index >= self._n_samples or (
                    now >= self._t_end and now - self._last_sample_t >= self._tail
                    and self._next_index > 0):
                self._finish()   # DONE lost or not needed: the board has finished
                return None
            if now >= deadline:
                self._streaming = False
                raise RigError(f"no data from {self.port} for {timeout:.1f} s: {self._hint(since)}")
            self._heartbeat()
            self._poll(min(0.05, deadline - now))

    def stop(self) -> None:
        """Stop the experiment (the board returns to 0 V) and fetch the board's counters."""
        self._streaming = False
        ran, self._started = self._started, False
        if ran and not self._finished:
            self._finish()
        self._command(P.STOP)
        if ran:   # the run's board counters; a repeated stop() only makes sure of 0 V
            self.board_status = self._fetch_status()

    def zero(self) -> None:
        """Command 0 V now; never raises (a dead link is already safe: the watchdog zeroes)."""
        self._streaming = False
        try:
            if self.link.is_open:
                self.link.write(b"\x00" + P.encode_frame(P.ZERO, self._seq))
                self._seq = (self._seq + 1) & 0xFF
                self.link.flush()
        except Exception:
            pass

    def close(self) -> None:
        """Close the link (never raises)."""
        try:
            self.link.close()
        except Exception:
            pass
