"""The serial bridge: the labrig firmware on an Arduino (or under simavr) via pyserial.

Implements :class:`labrig.bridge.base.Bridge` over the framed protocol of
``firmware/PROTOCOL.md``. The board owns the timing; the host configures an experiment in
DAC words (computed here from the rig's ``[bridge]`` ranges and calibration), starts it,
and receives sample-indexed, CRC-checked batches which it converts to raw volts.
"""
from __future__ import annotations

import time
from collections import deque
from types import SimpleNamespace

import numpy as np

from labrig.bridge import protocol as P
from labrig.bridge.base import Bridge, Experiment, SampleBlock
from labrig.errors import RigError, UserError

TIMER_HZ = 2_000_000   # Timer1 count rate: only rates dividing it are exact

_CAL_KEYS = ("dac", "tacho", "pos", "ref")


def _get(obj, name, default=None):
    """Attribute or mapping lookup, so a config dataclass and a plain dict both work."""
    if obj is None:
        return default
    if isinstance(obj, dict):
        return obj.get(name, default)
    return getattr(obj, name, default)


def bridge_settings(rig) -> SimpleNamespace:
    """Read ``rig.bridge`` (attributes or a dict; defaults of configs/rig_default.toml).

    Parameters
    ----------
    rig : object
        Anything with a ``bridge`` attribute or key holding ``sample_rate_hz``,
        ``output_limit_v``, ``dac_bits``, ``dac_range_v``, ``adc_bits``, ``adc_range_v``,
        ``watchdog_ms`` and an optional ``calibration`` mapping.

    Returns
    -------
    types.SimpleNamespace
        The same fields as floats/ints/tuples, with calibration gains and offsets filled in.
    """
    b = _get(rig, "bridge", rig)
    cal = dict(_get(b, "calibration", None) or {})
    ns = SimpleNamespace(
        sample_rate_hz=float(_get(b, "sample_rate_hz", 1000.0)),
        output_limit_v=float(_get(b, "output_limit_v", 2.5)),
        dac_bits=int(_get(b, "dac_bits", 12)),
        dac_range_v=tuple(float(v) for v in _get(b, "dac_range_v", (-5.0, 5.0))),
        adc_bits=int(_get(b, "adc_bits", 10)),
        adc_range_v=tuple(float(v) for v in _get(b, "adc_range_v", (-10.0, 10.0))),
        watchdog_ms=int(_get(b, "watchdog_ms", 500)),
    )
    for k in _CAL_KEYS:
        setattr(ns, f"{k}_gain", float(cal.get(f"{k}_gain", 1.0)))
        setattr(ns, f"{k}_offset_v", float(cal.get(f"{k}_offset_v", 0.0)))
    return ns


def dac_word_to_volts(words, s: SimpleNamespace) -> np.ndarray:
    """Bridge output volts for DAC words: nominal from the range, then the calibration."""
    lo, hi = s.dac_range_v
    nominal = lo + np.asarray(words, dtype=float) * (hi - lo) / 2 ** s.dac_bits
    return s.dac_gain * nominal + s.dac_offset_v


def volts_to_dac_word(v: float, s: SimpleNamespace) -> int:
    """DAC word whose calibrated output is closest to ``v`` volts (clipped to the DAC)."""
    lo, hi = s.dac_range_v
    nominal = (v - s.dac_offset_v) / s.dac_gain
    w = int(round((nominal - lo) * 2 ** s.dac_bits / (hi - lo)))
    return min(max(w, 0), 2 ** s.dac_bits - 1)


def adc_counts_to_volts(counts, channel: str, s: SimpleNamespace) -> np.ndarray:
    """Sensor volts for ADC counts of ``channel`` (``tacho``, ``pos`` or ``ref``)."""
    lo, hi = s.adc_range_v
    nominal = lo + np.asarray(counts, dtype=float) * (hi - lo) / 2 ** s.adc_bits
    return getattr(s, f"{channel}_gain") * nominal + getattr(s, f"{channel}_offset_v")


class SerialBridge(Bridge):
    """The labrig board on a serial port (USB ``/dev/ttyACM0`` or an emulator's pty).

    Parameters
    ----------
    port : str
        Serial device.
    rig : object
        Rig configuration; only ``rig.bridge`` is used (see :func:`bridge_settings`).
    baudrate : int
        Link speed; the firmware runs at 500000.
    hello_timeout : float
        Seconds to wait for the board's HELLO after opening (the Uno resets on open).
    heartbeat_s : float
        Interval of heartbeats while streaming; must be well below the watchdog time.
    """

    source = "serial"

    def __init__(self, port: str, rig, *, baudrate: int = 500000, hello_timeout: float = 3.0,
                 heartbeat_s: float = 0.1):
        self.port = port
        self.settings = bridge_settings(rig)
        self.baudrate = baudrate
        self.hello_timeout = hello_timeout
        self.heartbeat_s = min(heartbeat_s, self.settings.watchdog_ms / 4000.0)
        self._ser = None
        self._dec = P.StreamDecoder()
        self._seq = 0
        self._last_tx = 0.0
        self._pending: deque = deque()
        self.hello: dict = {}
        self._exp: Experiment | None = None
        self._n_samples = 0
        self._next_index = 0
        self._streaming = False
        self._finished = False
        self.dropped_samples = 0
        self.stale_frames = 0
        self.board_status: dict = {}
        self.board_errors: list[str] = []

    # ---- link ------------------------------------------------------------------------
    def _send(self, type_: int, body: bytes = b"") -> int:
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFF
        # the leading 0x00 ends any partial frame the board holds (garbage, a reset)
        self._write(b"\x00" + P.encode_frame(type_, seq, body))
        return seq

    def _write(self, data: bytes) -> None:
        if self._ser is None:
            raise RigError(f"{self.port} is not open")
        try:
            self._ser.write(data)
        except Exception as e:  # pyserial raises SerialException/OSError subclasses
            raise RigError(f"lost {self.port} while writing: {e}") from e
        self._last_tx = time.monotonic()

    def _poll(self, wait: float) -> None:
        """Read what is there (waiting up to ``wait`` s for a first byte) into the queue."""
        try:
            self._ser.timeout = wait
            data = self._ser.read(max(1, self._ser.in_waiting))
            if data and self._ser.in_waiting:
                data += self._ser.read(self._ser.in_waiting)
        except Exception as e:
            raise RigError(f"lost {self.port}: {e}") from e
        if data:
            self._pending.extend(self._dec.feed(data))

    def _heartbeat(self) -> None:
        if time.monotonic() - self._last_tx >= self.heartbeat_s:
            self._send(P.HEARTBEAT)

    def _board_error(self, frame: P.Frame) -> RigError:
        e = P.parse_error(frame.body)
        msg = f"board on {self.port} reported {e['name']}: {e['text']}"
        self.board_errors.append(msg)
        return RigError(msg)

    def _wait_ack(self, type_: int, seq: int, timeout: float = 1.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            while self._pending:
                f = self._pending.popleft()
                if f.type == P.ACK and f.body[:2] == bytes([type_, seq]):
                    return
                if f.type == P.ERROR:
                    err = P.parse_error(f.body)
                    if err["name"] in ("LIMIT", "RATE", "BAD_CONFIG"):
                        raise UserError(f"board on {self.port} refused the experiment: {err['text']}")
                    raise self._board_error(f)
            self._poll(0.05)
        raise RigError(f"no answer from {self.port} to {P.TYPE_NAMES[type_]} within {timeout:.1f} s: "
                       "is the board plugged in?")

    # ---- Bridge interface ------------------------------------------------------------
    def open(self) -> dict:
        """Open the port and handshake; return the board's HELLO fields."""
        import serial  # pyserial; imported here so the module loads without it

        ser = serial.Serial()
        ser.port = self.port
        ser.baudrate = self.baudrate
        ser.timeout = 0.05
        ser.write_timeout = 2.0
        try:
            ser.open()   # pyserial ignores ENOTTY from DTR/RTS on a pty itself
        except Exception as e:
            raise RigError(f"cannot open {self.port} ({getattr(e, 'strerror', None) or e}): is the "
                           "board plugged in and is this its port? (ls /dev/ttyACM* /dev/ttyUSB*)") from e
        self._ser = ser
        # The Uno resets when the port opens and greets after its bootloader (~1-2 s);
        # its greeting may be lost, so ask again every 0.5 s.
        deadline = time.monotonic() + self.hello_timeout
        next_ask = 0.0
        while not self.hello:
            now = time.monotonic()
            if now >= deadline:
                self.close()
                raise RigError(f"no hello from {self.port} within {self.hello_timeout:.1f} s: "
                               "is the labrig firmware on the board and nothing else using the port?")
            if now >= next_ask:
                self._send(P.HELLO_REQ)
                next_ask = now + 0.5
            self._poll(0.05)
            while self._pending:
                f = self._pending.popleft()
                if f.type == P.HELLO:
                    self.hello = P.parse_hello(f.body)
        if self.hello["protocol"] != P.PROTOCOL_VERSION:
            self.close()
            raise RigError(f"board on {self.port} speaks protocol {self.hello['protocol']}, "
                           f"labrig needs {P.PROTOCOL_VERSION}: reflash the firmware")
        # stop whatever a previous host left running
        self._wait_ack(P.ZERO, self._send(P.ZERO))
        self._pending.clear()
        return {"firmware": self.hello["firmware"], "board": self.hello["board"],
                "capabilities": ["square", "step", "staircase", "constant"],
                "max_rate_hz": self.hello["max_rate_hz"], "port": self.port}

    def _levels(self, exp: Experiment) -> list[float]:
        if exp.waveform == "square":
            return [exp.offset_v + exp.amplitude_v, exp.offset_v - exp.amplitude_v]
        if exp.waveform in ("step", "constant"):
            return [exp.amplitude_v + exp.offset_v]
        if exp.waveform == "staircase":
            if not exp.levels:
                raise UserError(f"experiment {exp.name!r}: a staircase needs levels")
            return [v + exp.offset_v for v in exp.levels]
        raise UserError(f"experiment {exp.name!r}: the board cannot generate a {exp.waveform!r} waveform "
                        "(square, step, staircase or constant)")

    def configure(self, exp: Experiment) -> None:
        """Check the experiment against the limits and load it into the board."""
        s = self.settings
        limit = s.output_limit_v
        peak = exp.peak_v()
        if peak > limit + 1e-9:
            raise UserError(f"experiment {exp.name!r} peaks at {peak:.3g} V, beyond the bridge output "
                            f"limit of {limit:.3g} V ([bridge] output_limit_v)")
        if exp.loop not in P.LOOPS:
            raise UserError(f"experiment {exp.name!r}: loop must be 'open' or 'closed'")
        rate = int(round(exp.sample_rate_hz))
        max_rate = self.hello.get("max_rate_hz", 1000)
        if abs(rate - exp.sample_rate_hz) > 1e-9 or TIMER_HZ % rate or not 50 <= rate <= max_rate:
            raise UserError(f"experiment {exp.name!r}: sample rate {exp.sample_rate_hz:g} Hz is not "
                            f"available; the board runs 50..{max_rate} Hz at divisors of 2 MHz "
                            "(e.g. 500, 1000, 2000)")
        levels_v = self._levels(exp)
        if len(levels_v) > P.MAX_LEVELS:
            raise UserError(f"experiment {exp.name!r}: at most {P.MAX_LEVELS} staircase levels")
        levels = [volts_to_dac_word(v, s) for v in levels_v]
        zero = volts_to_dac_word(0.0, s)
        wmin, wmax = sorted((volts_to_dac_word(-limit, s), volts_to_dac_word(limit, s)))
        fw_min, fw_max = self.hello.get("fw_dac_min", 0), self.hello.get("fw_dac_max", 2 ** s.dac_bits - 1)
        wmin, wmax = max(wmin, fw_min), min(wmax, fw_max)
        if any(not wmin <= w <= wmax for w in levels + [zero]):
            lo_v, hi_v = dac_word_to_volts([fw_min, fw_max], s)
            raise UserError(f"experiment {exp.name!r} needs DAC words beyond the firmware limit "
                            f"({lo_v:.3g}..{hi_v:.3g} V with this calibration)")
        if exp.waveform == "square":
            segment = int(round(rate / (2.0 * exp.frequency_hz)))
        elif exp.waveform == "staircase":
            segment = int(round(exp.step_s * rate))
        else:
            segment = 0
        n = int(exp.n_samples)
        body = P.configure_body(
            loop=exp.loop, waveform=exp.waveform, sample_rate_hz=rate, n_samples=n,
            lead_in_samples=int(round(exp.lead_in_s * rate)), segment_samples=segment,
            dac_zero=zero, dac_min=wmin, dac_max=wmax, watchdog_ms=s.watchdog_ms, levels=levels,
            position_gain=exp.position_gain if exp.loop == "closed" else 0.0,
            velocity_gain=exp.velocity_gain if exp.loop == "closed" else 0.0)
        self._wait_ack(P.CONFIGURE, self._send(P.CONFIGURE, body))
        self._exp, self._n_samples = exp, n

    def start(self) -> None:
        """Start the configured experiment; samples follow from index 0."""
        if self._exp is None:
            raise UserError("start() before configure()")
        self._pending.clear()
        self._next_index = 0
        self._finished = False
        self._wait_ack(P.START, self._send(P.START))
        self._streaming = True

    def read(self, timeout: float = 2.0) -> SampleBlock | None:
        """Next batch of samples in raw volts; ``None`` once the board reports DONE.

        Gaps in the sample index are counted in ``dropped_samples`` (the block's ``index``
        shows them); a silent link for ``timeout`` s raises :class:`RigError`.
        """
        if self._finished or not self._streaming:
            return None
        deadline = time.monotonic() + timeout
        while True:
            while self._pending:
                f = self._pending.popleft()
                if f.type == P.SAMPLES:
                    try:
                        first, w = P.parse_samples(f.body)
                    except P.FrameError:
                        self.stale_frames += 1
                        continue
                    if first < self._next_index or first + len(w) > self._n_samples:
                        self.stale_frames += 1   # a duplicate or a previous run's tail
                        continue
                    self.dropped_samples += first - self._next_index
                    self._next_index = first + len(w)
                    s = self.settings
                    return SampleBlock(
                        index=np.arange(first, first + len(w)),
                        u=dac_word_to_volts(w[:, 0], s),
                        tacho=adc_counts_to_volts(w[:, 1], "tacho", s),
                        pos=adc_counts_to_volts(w[:, 2], "pos", s),
                        ref=adc_counts_to_volts(w[:, 3], "ref", s))
                if f.type == P.DONE:
                    self.dropped_samples += max(0, self._n_samples - self._next_index)
                    self._next_index = self._n_samples
                    self._finished = True
                    self._streaming = False
                    return None
                if f.type == P.ERROR:
                    self._streaming = False
                    raise self._board_error(f)
            now = time.monotonic()
            if now >= deadline:
                self._streaming = False
                raise RigError(f"no data from {self.port} for {timeout:.1f} s: is the board plugged in?")
            self._heartbeat()
            self._poll(min(0.05, deadline - now))

    def stop(self) -> None:
        """Stop the experiment (the board returns to 0 V) and fetch the board's counters."""
        self._streaming = False
        self._wait_ack(P.STOP, self._send(P.STOP))
        self._send(P.STATUS_REQ)
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline and not self.board_status:
            self._poll(0.05)
            while self._pending:
                f = self._pending.popleft()
                if f.type == P.STATUS:
                    self.board_status = P.parse_status(f.body)

    def zero(self) -> None:
        """Command 0 V now; never raises (a dead link is already safe: the watchdog zeroes)."""
        self._streaming = False
        try:
            if self._ser is not None and self._ser.is_open:
                self._ser.write(b"\x00" + P.encode_frame(P.ZERO, self._seq))
                self._seq = (self._seq + 1) & 0xFF
                self._ser.flush()
        except Exception:
            pass

    def counters(self) -> dict:
        """Link and board counters for the run's ``bridge`` metadata."""
        c = {"firmware": self.hello.get("firmware", "unknown"), "board": self.hello.get("board"),
             "port": self.port, "dropped_samples": int(self.dropped_samples),
             "crc_errors": int(self._dec.crc_errors), "framing_errors": int(self._dec.framing_errors),
             "stale_frames": int(self.stale_frames)}
        if self.board_status:
            for k in ("rx_crc_errors", "rx_overruns", "watchdog_trips", "sample_overruns"):
                c[f"board_{k}"] = int(self.board_status[k])
        if self.board_errors:
            c["board_errors"] = list(self.board_errors)
        return c

    def close(self) -> None:
        """Close the port (never raises)."""
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:
                pass
