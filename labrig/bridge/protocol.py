"""Frame codec of the labrig bridge protocol (see ``firmware/PROTOCOL.md``).

A frame on the wire is ``COBS(type, seq, body..., crc_hi, crc_lo) + b"\\x00"``; the CRC is
CRC-16/CCITT-FALSE over type, seq and body. Multi-byte body fields are little-endian.
The same layout is implemented in C in ``firmware/labrig_bridge/src/lr_proto.c``; both
are checked against ``firmware/test_vectors.json``.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

#: the version this host's firmware speaks; :data:`PROTOCOLS` are all it understands
PROTOCOL_VERSION = 2
#: 1: firmware 1.x (the MS150 bridge only); 2: HELLO names the build's rig, and an
#: H-bridge board's SAMPLES carry a signed 32-bit encoder count
PROTOCOLS = (1, 2)
MAX_BODY = 200
MAX_RAW = MAX_BODY + 4
BATCH = 10
MAX_LEVELS = 32

# host -> board
HELLO_REQ, CONFIGURE, START, STOP, HEARTBEAT, STATUS_REQ, ZERO = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
#: the run's trip limits (firmware 2.2: labrig.bridge.trips), after its CONFIGURE
LIMITS = 0x08
#: ask the board's id (empty), or give it one it keeps in EEPROM (u32; firmware 2.3)
BOARD_ID = 0x09
# board -> host
ACK, HELLO, SAMPLES, STATUS, DONE, ERROR, INDEX = 0x80, 0x81, 0x82, 0x83, 0x84, 0x85, 0x86
#: the board's id (u32; 0: none given yet), the answer to BOARD_ID
ID = 0x87

TYPE_NAMES = {
    HELLO_REQ: "HELLO_REQ", CONFIGURE: "CONFIGURE", START: "START", STOP: "STOP",
    HEARTBEAT: "HEARTBEAT", STATUS_REQ: "STATUS_REQ", ZERO: "ZERO", LIMITS: "LIMITS",
    BOARD_ID: "BOARD_ID", ID: "ID", ACK: "ACK",
    HELLO: "HELLO", SAMPLES: "SAMPLES", STATUS: "STATUS", DONE: "DONE", ERROR: "ERROR",
    INDEX: "INDEX",
}
#: ``board``: the MS150 build closes the position loop itself on the pot and tacho words
#: it samples (firmware 2.4); ``closed`` on the MS150 is the rig's analog loop, on the
#: H-bridge the board's PD on its count
LOOPS = {"open": 0, "closed": 1, "board": 2}
#: HELLO capability bit of the pwl waveform (bits 0-3: constant, square, step, staircase)
CAP_PWL = 0x10
#: HELLO capability bit of the board's own loop on its sensors (loop ``board``)
CAP_BOARD_LOOP = 0x20
#: the longest pwl piece the firmware plays (samples between two breakpoints)
MAX_PIECE = 0x7FFF


def pwl_words(levels: list[int], pieces: list[int], n: int) -> list[int]:
    """The words a board plays for a pwl after its lead-in, ``n`` samples: in piece i
    (length L from word a to word b) sample j is ``a + trunc((b - a) j / L)``; the last
    breakpoint is held."""
    out = []
    for a, b, L in zip(levels, levels[1:], pieces):
        d = b - a
        out += [a + (d * j // L if d >= 0 else -((-d * j) // L)) for j in range(L)]
    out += [levels[-1]] * max(0, n - len(out))
    return out[:n]


WAVEFORMS = {"constant": 0, "square": 1, "step": 2, "staircase": 3, "pwl": 4}
ERROR_CODES = {1: "BAD_FRAME", 2: "BAD_CONFIG", 3: "LIMIT", 4: "NOT_CONFIGURED",
               5: "BUSY", 6: "WATCHDOG", 7: "RATE", 8: "TRIP"}
BOARDS = {1: "uno", 2: "mega", 3: "nano"}
#: the hardware layer a firmware was built for (HELLO, protocol 2; protocol 1 is the MS150's)
RIG_KINDS = {1: "ms150", 2: "hbridge"}
#: HELLO rig flags of an H-bridge build
FLAG_IN1_IN2, FLAG_BRAKE, FLAG_CURRENT, FLAG_INDEX = 0x01, 0x02, 0x04, 0x08
STATES = {0: "idle", 1: "configured", 2: "running", 3: "finishing"}

_CONFIGURE_FIXED = struct.Struct("<BBHIIIHHHHHHB")  # 29 bytes, then n_levels x u16
_HELLO_FIXED = struct.Struct("<BBHHBBBBBHHHH")      # 19 bytes, then the firmware id
_HELLO_V2 = struct.Struct("<BIBBBH")                # protocol 2: 10 more bytes before the id
_SAMPLES_HEAD = struct.Struct("<IB")
_STATUS = struct.Struct("<IIIIIIBHH")               # the last u16: encoder faults (H-bridge)
_INDEX = struct.Struct("<IiH")
_ID = struct.Struct("<I")
_DONE = struct.Struct("<II")
_ACK = struct.Struct("<BB")


class FrameError(ValueError):
    """A frame that must be rejected (bad COBS, too short, too long, bad CRC)."""


class BodyError(FrameError):
    """A frame with a valid CRC whose body does not parse (wrong length, unknown code).

    Only a corruption that slipped past the CRC or a firmware/host mismatch produces one;
    the host counts such frames and carries on.
    """


def _unpack(fmt: struct.Struct, body: bytes, what: str, exact: bool = False) -> tuple:
    """``fmt.unpack_from(body)``, raising :class:`BodyError` on a short (or, with ``exact``,
    a longer) body instead of ``struct.error``."""
    if len(body) < fmt.size or (exact and len(body) != fmt.size):
        raise BodyError(f"{what} body of {len(body)} bytes, expected "
                        f"{'' if exact else 'at least '}{fmt.size}")
    return fmt.unpack_from(body)


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor)."""
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing, canonical form, without the delimiter."""
    out = bytearray([0])
    code_at, code = 0, 1
    for i, b in enumerate(data):
        if b == 0:
            out[code_at] = code
            code_at, code = len(out), 1
            out.append(0)
        else:
            out.append(b)
            code += 1
            if code == 0xFF:
                out[code_at] = code
                code = 1
                if i + 1 < len(data):
                    code_at = len(out)
                    out.append(0)
                else:
                    return bytes(out)
    out[code_at] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`FrameError` on malformed input."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        i += 1
        if code == 0 or i + code - 1 > n:
            raise FrameError("malformed COBS block")
        block = data[i:i + code - 1]
        if 0 in block:
            raise FrameError("zero byte inside a COBS block")
        out += block
        i += code - 1
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


@dataclass(frozen=True)
class Frame:
    """One decoded frame: message ``type``, sender's sequence number ``seq``, ``body``."""

    type: int
    seq: int
    body: bytes

    @property
    def name(self) -> str:
        return TYPE_NAMES.get(self.type, f"0x{self.type:02X}")


def encode_frame(type_: int, seq: int, body: bytes = b"") -> bytes:
    """Whole wire frame, trailing ``0x00`` delimiter included."""
    if len(body) > MAX_BODY:
        raise ValueError(f"body of {len(body)} bytes exceeds {MAX_BODY}")
    raw = bytes([type_ & 0xFF, seq & 0xFF]) + bytes(body)
    return cobs_encode(raw + crc16(raw).to_bytes(2, "big")) + b"\x00"


def decode_frame(wire: bytes) -> Frame:
    """Decode one frame (with or without its trailing delimiter); raise on any fault."""
    if wire.endswith(b"\x00"):
        wire = wire[:-1]
    if b"\x00" in wire:
        raise FrameError("delimiter inside frame")
    raw = cobs_decode(wire)
    if len(raw) < 4:
        raise FrameError("frame too short")
    if len(raw) > MAX_RAW:
        raise FrameError("frame too long")
    if crc16(raw[:-2]) != int.from_bytes(raw[-2:], "big"):
        raise FrameError("CRC mismatch")
    return Frame(raw[0], raw[1], bytes(raw[2:-2]))


class StreamDecoder:
    """Split a byte stream into valid frames; count and skip everything else.

    After garbage or a corrupted frame it resynchronises on the next ``0x00``. Back-to-back
    delimiters (empty frames) are used to flush a link and are not errors.

    Attributes
    ----------
    frames_ok, crc_errors, framing_errors : int
        Valid frames, frames with a CRC mismatch, and other rejected frames (bad COBS,
        too short, too long).
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._overflow = False
        self.frames_ok = 0
        self.crc_errors = 0
        self.framing_errors = 0

    def feed(self, data: bytes) -> list[Frame]:
        """Feed received bytes; return the valid frames they complete, in order."""
        frames = []
        start = 0
        while True:
            end = data.find(b"\x00", start)
            if end < 0:
                chunk = data[start:]
                if len(self._buf) + len(chunk) > 2 * MAX_RAW:
                    self._overflow = True   # keep memory bounded while skipping garbage
                    self._buf.clear()
                else:
                    self._buf += chunk
                return frames
            self._buf += data[start:end]
            start = end + 1
            wire, overflow = bytes(self._buf), self._overflow
            self._buf.clear()
            self._overflow = False
            if overflow:
                self.framing_errors += 1
                continue
            if not wire:
                continue
            try:
                frames.append(decode_frame(wire))
                self.frames_ok += 1
            except FrameError as e:
                if "CRC" in str(e):
                    self.crc_errors += 1
                else:
                    self.framing_errors += 1


# ---- message bodies -----------------------------------------------------------------

def configure_body(*, loop: str, waveform: str, sample_rate_hz: int, n_samples: int,
                   lead_in_samples: int, segment_samples: int, dac_zero: int, dac_min: int,
                   dac_max: int, watchdog_ms: int, levels: list[int],
                   position_gain: float = 0.0, velocity_gain: float = 0.0,
                   pieces: list[int] | None = None,
                   gain_words: tuple[int, int] | None = None,
                   board_loop: tuple[int, int] | None = None) -> bytes:
    """Body of a CONFIGURE message; all levels and limits in DAC words. A ``pwl``
    waveform's ``levels`` are its breakpoints and ``pieces`` the samples between them.
    ``gain_words`` are a digital loop's PD gains as the board takes them (Q8.8), in place
    of the gains x 100 an MS150 run records. A ``board`` loop's levels are pot words and
    ``board_loop`` its tail: the lead-in's reference word and the tacho's word at rest."""
    if not 1 <= len(levels) <= MAX_LEVELS:
        raise ValueError(f"1..{MAX_LEVELS} levels, got {len(levels)}")
    pieces = list(pieces or [])
    if waveform == "pwl" and (len(pieces) != len(levels) - 1 or len(levels) < 2
                              or not all(1 <= L <= MAX_PIECE for L in pieces)):
        raise ValueError(f"a pwl needs 2..{MAX_LEVELS} breakpoints and one piece of "
                         f"1..{MAX_PIECE} samples between each two")
    head = _CONFIGURE_FIXED.pack(
        LOOPS[loop], WAVEFORMS[waveform], int(sample_rate_hz), int(n_samples),
        int(lead_in_samples), int(segment_samples), int(dac_zero), int(dac_min), int(dac_max),
        int(watchdog_ms),
        *(gain_words if gain_words is not None else
          (int(round(position_gain * 100)) & 0xFFFF, int(round(velocity_gain * 100)) & 0xFFFF)),
        len(levels))
    if (loop == "board") != (board_loop is not None):
        raise ValueError("a board loop, and only it, ends with its lead-in and tacho words")
    tail = struct.pack("<2H", *board_loop) if board_loop is not None else b""
    return (head + struct.pack(f"<{len(levels)}H", *[int(v) for v in levels])
            + struct.pack(f"<{len(pieces)}H", *[int(v) for v in pieces]) + tail)


def parse_configure(body: bytes) -> dict:
    """Inverse of :func:`configure_body`; :class:`BodyError` on any malformed body."""
    f = _unpack(_CONFIGURE_FIXED, body, "CONFIGURE")
    keys = ("loop", "waveform", "sample_rate_hz", "n_samples", "lead_in_samples",
            "segment_samples", "dac_zero", "dac_min", "dac_max", "watchdog_ms",
            "position_gain", "velocity_gain", "n_levels")
    d = dict(zip(keys, f))
    loops = {v: k for k, v in LOOPS.items()}
    waves = {v: k for k, v in WAVEFORMS.items()}
    if d["loop"] not in loops or d["waveform"] not in waves:
        raise BodyError(f"CONFIGURE with unknown loop {d['loop']} or waveform {d['waveform']}")
    d["loop"], d["waveform"] = loops[d["loop"]], waves[d["waveform"]]
    d["position_gain"] /= 100.0
    d["velocity_gain"] /= 100.0
    n = d.pop("n_levels")
    k = n - 1 if d["waveform"] == "pwl" and n else 0
    tail = 4 if d["loop"] == "board" else 0
    if not 1 <= n <= MAX_LEVELS or len(body) != _CONFIGURE_FIXED.size + 2 * n + 2 * k + tail:
        raise BodyError(f"CONFIGURE of {len(body)} bytes does not match its level count {n}")
    d["levels"] = list(struct.unpack_from(f"<{n}H", body, _CONFIGURE_FIXED.size))
    if d["waveform"] == "pwl":
        d["pieces"] = list(struct.unpack_from(f"<{k}H", body, _CONFIGURE_FIXED.size + 2 * n))
    if tail:
        d["ref_lead"], d["tacho_zero"] = struct.unpack_from("<2H", body, len(body) - 4)
    return d


def parse_hello(body: bytes) -> dict:
    """HELLO: protocol version, board, capabilities, limits, the build's rig (protocol 2),
    firmware id. A protocol 1 board is an MS150 bridge with Timer1's 2 MHz clock."""
    (ver, board, caps, max_rate, batch, dac_bits, adc_bits, n_adc, max_levels, dac_zero,
     fw_min, fw_max, wd_ms) = _unpack(_HELLO_FIXED, body, "HELLO")
    d = {"protocol": ver, "board": BOARDS.get(board, str(board)), "capabilities": caps,
         "max_rate_hz": max_rate, "batch": batch, "dac_bits": dac_bits,
         "adc_bits": adc_bits, "n_adc": n_adc, "max_levels": max_levels,
         "dac_zero": dac_zero, "fw_dac_min": fw_min, "fw_dac_max": fw_max,
         "watchdog_ms_default": wd_ms, "rig": "ms150", "timer_hz": 2_000_000,
         "rig_flags": 0, "decoding": 0, "pwm_bits": 0, "min_rate_hz": 50}
    start = _HELLO_FIXED.size
    if ver >= 2:
        rig, timer_hz, flags, decoding, pwm_bits, min_rate = _unpack(
            _HELLO_V2, body[start:], "HELLO (protocol 2)")
        d.update(rig=RIG_KINDS.get(rig, str(rig)), timer_hz=timer_hz, rig_flags=flags,
                 decoding=decoding, pwm_bits=pwm_bits, min_rate_hz=min_rate)
        start += _HELLO_V2.size
    d["firmware"] = body[start:].decode("ascii", "replace")
    return d


def samples_body(first_index: int, rows) -> bytes:
    """SAMPLES body from rows of (dac, tacho, pos, ref) words."""
    rows = np.asarray(rows, dtype="<u2").reshape(-1, 4)
    return struct.pack("<IB", first_index, len(rows)) + rows.tobytes()


def encoder_counts(words: np.ndarray) -> np.ndarray:
    """The signed 32-bit encoder counts of an H-bridge board's SAMPLES words (n, 4): the
    count's low half in column 1, its high half in column 2."""
    w = np.asarray(words, dtype=np.int64)
    return ((w[:, 1] & 0xFFFF) | ((w[:, 2] & 0xFFFF) << 16)).astype(np.uint32).view(np.int32)


def parse_samples(body: bytes) -> tuple[int, np.ndarray]:
    """Return ``(first_index, words)`` with ``words`` of shape (n, 4): dac, tacho, pos, ref."""
    first, n = _unpack(_SAMPLES_HEAD, body, "SAMPLES")
    if len(body) != _SAMPLES_HEAD.size + 8 * n or n == 0:
        raise BodyError(f"SAMPLES of {len(body)} bytes does not match its count {n}")
    return first, np.frombuffer(body, dtype="<u2", offset=5).reshape(n, 4).astype(np.int64)


def parse_status(body: bytes) -> dict:
    """STATUS: the board's counters (cumulative except ``sample_overruns``), state, DAC word,
    and an H-bridge board's undecodable encoder jumps since reset (``encoder_faults``,
    saturating at 65535; 0 on the MS150 bridge, whose word was reserved)."""
    vals = _unpack(_STATUS, body, "STATUS", exact=True)
    keys = ("samples_sent", "rx_frames_ok", "rx_crc_errors", "rx_overruns",
            "watchdog_trips", "sample_overruns", "state", "dac_word", "encoder_faults")
    d = dict(zip(keys, vals))
    d["state"] = STATES.get(d["state"], str(d["state"]))
    return d


def parse_index(body: bytes) -> dict:
    """INDEX: an encoder index pulse of this run -- the sample it came before, the count
    latched at its rising edge, and its number since START (a gap: pulses that came too close
    together to be reported one by one)."""
    sample, count, pulse = _unpack(_INDEX, body, "INDEX", exact=True)
    return {"sample": sample, "count": count, "pulse": pulse}


def parse_id(body: bytes) -> dict:
    """ID: the id a host gave the board (0: none yet)."""
    (board_id,) = _unpack(_ID, body, "ID", exact=True)
    return {"board_id": board_id}


def format_board_id(board_id: int | None) -> str:
    """A board id as labrig shows it (8 hex digits), or ``"-"`` for none."""
    return f"{board_id:08X}" if board_id else "-"


def parse_done(body: bytes) -> dict:
    """DONE: planned samples and the samples the board itself lost in this run."""
    n, lost = _unpack(_DONE, body, "DONE", exact=True)
    return {"n_samples": n, "samples_lost": lost}


def parse_error(body: bytes) -> dict:
    """ERROR: code, its name and the board's text."""
    if not body:
        raise BodyError("ERROR without a code")
    return {"code": body[0], "name": ERROR_CODES.get(body[0], str(body[0])),
            "text": body[1:].decode("ascii", "replace")}


def parse_ack(body: bytes) -> dict:
    """ACK: the acknowledged command's type and seq."""
    t, seq = _unpack(_ACK, body, "ACK", exact=True)
    return {"type": t, "seq": seq}


# ---- board -> host body builders ------------------------------------------------------
# The inverses of the parsers above. The host never sends these; they exist so a scripted
# board (labrig.bridge.transport.ScriptedTransport) answers with exactly the firmware's bytes.

def _code_of(names: dict, value) -> int:
    """The wire code of ``value``, given as a code or as its name in ``names``."""
    if isinstance(value, int):
        return value
    return {v: k for k, v in names.items()}[value]


def ack_body(type_: int, seq: int) -> bytes:
    """ACK body acknowledging the command (``type_``, ``seq``)."""
    return _ACK.pack(type_, seq)


def hello_body(*, protocol: int, board, capabilities: int, max_rate_hz: int, batch: int,
               dac_bits: int, adc_bits: int, n_adc: int, max_levels: int, dac_zero: int,
               fw_dac_min: int, fw_dac_max: int, watchdog_ms_default: int,
               firmware: str, rig="ms150", timer_hz: int = 2_000_000, rig_flags: int = 0,
               decoding: int = 0, pwm_bits: int = 0, min_rate_hz: int = 50) -> bytes:
    """HELLO body from the fields :func:`parse_hello` returns (``board`` and ``rig`` by
    name or code); the rig's fields are sent from protocol 2 on."""
    head = _HELLO_FIXED.pack(protocol, _code_of(BOARDS, board), capabilities, max_rate_hz,
                             batch, dac_bits, adc_bits, n_adc, max_levels, dac_zero,
                             fw_dac_min, fw_dac_max, watchdog_ms_default)
    if protocol >= 2:
        head += _HELLO_V2.pack(_code_of(RIG_KINDS, rig), timer_hz, rig_flags, decoding,
                               pwm_bits, min_rate_hz)
    return head + firmware.encode("ascii")


def status_body(*, samples_sent: int, rx_frames_ok: int, rx_crc_errors: int, rx_overruns: int,
                watchdog_trips: int, sample_overruns: int, state, dac_word: int,
                encoder_faults: int = 0) -> bytes:
    """STATUS body from the fields :func:`parse_status` returns (``state`` by name or code)."""
    return _STATUS.pack(samples_sent, rx_frames_ok, rx_crc_errors, rx_overruns, watchdog_trips,
                        sample_overruns, _code_of(STATES, state), dac_word, encoder_faults)


def index_body(sample: int, count: int, pulse: int) -> bytes:
    """INDEX body from the fields :func:`parse_index` returns."""
    return _INDEX.pack(sample, count, pulse)


def id_body(board_id: int) -> bytes:
    """ID body (and BOARD_ID's when giving an id)."""
    return _ID.pack(board_id)


def done_body(n_samples: int, samples_lost: int = 0) -> bytes:
    """DONE body: the run's planned samples and those the board lost."""
    return _DONE.pack(n_samples, samples_lost)


def error_body(code, text: str = "") -> bytes:
    """ERROR body: ``code`` as a number or a name of :data:`ERROR_CODES`, then the text."""
    return bytes([_code_of(ERROR_CODES, code)]) + text.encode("ascii")


#: the body parser of every board->host message type
BOARD_PARSERS = {ACK: parse_ack, HELLO: parse_hello, SAMPLES: parse_samples, STATUS: parse_status,
                 DONE: parse_done, ERROR: parse_error, INDEX: parse_index, ID: parse_id}


class Message(NamedTuple):
    """A board->host frame whose body parsed: its type and its fields."""

    type: int
    fields: Any


def parse_message(frame: Frame) -> Message:
    """The fields of a board->host ``frame``; :class:`BodyError` when its body does not parse."""
    parser = BOARD_PARSERS.get(frame.type)
    if parser is None:
        raise BodyError(f"unknown message type 0x{frame.type:02X}")
    return Message(frame.type, parser(frame.body))
