"""Byte links under :class:`labrig.bridge.serial.SerialBridge`.

The bridge speaks frames; a transport only moves bytes. Injecting it (the model is
pymeasure's ``ProtocolAdapter``) lets the same driver run on a real port
(:class:`SerialTransport`: a USB board or an emulator's pty) and on a scripted board
(:class:`ScriptedTransport`) that tests the handshake, retries and error paths without
hardware or simavr.
"""
from __future__ import annotations

import abc
import time
from collections.abc import Callable, Sequence

from labrig.bridge import protocol as P
from labrig.core.errors import RigError


class Transport(abc.ABC):
    """A byte link to the board.

    Attributes
    ----------
    name : str
        What messages call the link (the port path for a serial port).
    """

    name: str = "link"

    @property
    @abc.abstractmethod
    def is_open(self) -> bool:
        """Whether :meth:`open` succeeded and :meth:`close` has not been called since."""

    @property
    @abc.abstractmethod
    def in_waiting(self) -> int:
        """Bytes received and not yet read."""

    @abc.abstractmethod
    def open(self) -> None:
        """Open the link; raise :class:`~labrig.core.errors.RigError` with the cure on failure."""

    @abc.abstractmethod
    def close(self) -> None:
        """Close the link."""

    @abc.abstractmethod
    def write(self, data: bytes) -> None:
        """Send ``data``."""

    @abc.abstractmethod
    def read(self, max_bytes: int, timeout: float) -> bytes:
        """Up to ``max_bytes`` bytes, waiting up to ``timeout`` s for them; ``b""`` if none came."""

    def flush(self) -> None:
        """Wait until written bytes are on their way (default: nothing is buffered)."""


def link_hint(since: tuple[int, int], now: tuple[int, int]) -> str:
    """Why no answer came, from the link's (damaged, intact) frame counts, and the cure.

    Parameters
    ----------
    since, now : tuple of int
        Damaged and intact frames received before the wait began, and by now: damage
        means a board behind a bad link, intact frames alone a lossy host->board
        direction, nothing at all a missing board.
    """
    cure = "use a shorter or shielded USB cable, away from the motor leads, or a lower baud rate"
    total_damaged, total_intact = now
    damaged, intact = total_damaged - since[0], total_intact - since[1]
    if damaged:
        return f"the link answers but garbles ({damaged} damaged frame(s), {intact} intact): {cure}"
    if intact:
        return f"the board sends but does not answer: the host->board direction loses data; {cure}"
    if total_damaged:
        return (f"nothing came back, and the link has damaged {total_damaged} of "
                f"{total_damaged + total_intact} frames so far: {cure}")
    return "is the board plugged in?"


class SerialTransport(Transport):
    """A serial port through pyserial: the default transport of ``SerialBridge``.

    Parameters
    ----------
    port : str
        Serial device (``/dev/ttyACM0``, an emulator's pty).
    baudrate : int
        Link speed; the firmware runs at 500000.
    write_timeout : float
        Seconds a write may block before pyserial gives up (a wedged USB link).
    """

    def __init__(self, port: str, baudrate: int = 500000, *, write_timeout: float = 2.0):
        self.name = self.port = str(port)
        self.baudrate, self.write_timeout = baudrate, write_timeout
        self._ser = None

    @property
    def is_open(self) -> bool:
        return self._ser is not None and self._ser.is_open

    @property
    def in_waiting(self) -> int:
        return self._port().in_waiting

    def _port(self):
        if self._ser is None:
            raise RigError(f"{self.port} is not open")
        return self._ser

    def open(self) -> None:
        import serial  # pyserial; imported here so the module loads without it

        ser = serial.Serial()
        ser.port, ser.baudrate = self.port, self.baudrate
        ser.timeout, ser.write_timeout = 0.05, self.write_timeout
        try:
            ser.open()   # pyserial ignores ENOTTY from DTR/RTS on a pty itself
        except Exception as e:
            raise RigError(f"cannot open {self.port} ({getattr(e, 'strerror', None) or e}): is the "
                           "board plugged in and is this its port? (ls /dev/ttyACM* /dev/ttyUSB*)") from e
        self._ser = ser

    def close(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            ser.close()

    def write(self, data: bytes) -> None:
        self._port().write(data)

    def read(self, max_bytes: int, timeout: float) -> bytes:
        ser = self._port()
        ser.timeout = timeout
        return ser.read(max_bytes)

    def flush(self) -> None:
        self._port().flush()


#: what a scripted board sends: raw wire bytes (as they are: garbage, a damaged frame), a
#: ``(type, body)`` pair framed with the board's own sequence number, or a callable of the
#: host frame that returns one of these (e.g. :func:`ack`)
Reply = bytes | tuple[int, bytes] | Callable[[P.Frame], bytes | tuple[int, bytes]]


def ack(frame: P.Frame) -> tuple[int, bytes]:
    """The ACK of ``frame`` (its type and seq), as a scripted :data:`Reply`."""
    return P.ACK, P.ack_body(frame.type, frame.seq)


class ScriptError(AssertionError):
    """The host sent a frame the script did not expect at that point."""


class ScriptedTransport(Transport):
    """A board made of a script: every host frame is answered with scripted board frames.

    Replies are queued the moment the host's frame is written, so a test runs as fast as
    the bridge's own timeouts allow; a read with nothing queued waits its whole timeout,
    as a silent port does.

    Parameters
    ----------
    script : sequence of (int, sequence of Reply), or callable
        Either steps ``(expected host frame type, replies)``, consumed one per host frame,
        or a callable ``board(frame) -> replies`` answering every frame. An empty reply
        list is a lost answer (the host should retransmit).
    name : str
        What the bridge's messages call this link.
    ignore : tuple of int
        Host frame types recorded but neither answered nor matched against the steps:
        heartbeats by default, whose number depends on timing.

    Attributes
    ----------
    received : list of labrig.bridge.protocol.Frame
        Every host frame, in order.
    unscripted : list of labrig.bridge.protocol.Frame
        Host frames that came after the steps ran out; they go unanswered, as on a
        board that has gone silent.

    Raises
    ------
    ScriptError
        From :meth:`write`, when a host frame is not the type its step expects.
    """

    def __init__(self, script: Sequence[tuple[int, Sequence[Reply]]] | Callable[[P.Frame], Sequence[Reply]],
                 *, name: str = "scripted", ignore: tuple[int, ...] = (P.HEARTBEAT,)):
        self.name = name
        self._board = script if callable(script) else None
        self._steps = [] if callable(script) else list(script)
        self.ignore = tuple(ignore)
        self.received: list[P.Frame] = []
        self.unscripted: list[P.Frame] = []
        self._decoder = P.StreamDecoder()
        self._out = bytearray()
        self._seq = 0
        self._open = False

    @property
    def remaining(self) -> int:
        """Steps of the script not yet consumed."""
        return len(self._steps)

    @property
    def is_open(self) -> bool:
        return self._open

    @property
    def in_waiting(self) -> int:
        return len(self._out)

    def open(self) -> None:
        self._open = True

    def close(self) -> None:
        self._open = False

    def write(self, data: bytes) -> None:
        if not self._open:
            raise OSError("write to a closed scripted port")
        for frame in self._decoder.feed(bytes(data)):
            self.received.append(frame)
            if frame.type in self.ignore:
                continue
            for reply in self._replies(frame):
                self._out += self._wire(reply, frame)

    def _replies(self, frame: P.Frame) -> Sequence[Reply]:
        if self._board is not None:
            return self._board(frame) or ()
        if not self._steps:
            self.unscripted.append(frame)
            return ()
        expected, replies = self._steps[0]
        if frame.type != expected:
            raise ScriptError(f"the script's next step expects {P.TYPE_NAMES.get(expected, expected)}, "
                              f"the host sent {frame.name} (seq {frame.seq})")
        self._steps.pop(0)
        return replies

    def _wire(self, reply: Reply, frame: P.Frame) -> bytes:
        if callable(reply):
            reply = reply(frame)
        if isinstance(reply, (bytes, bytearray)):
            return bytes(reply)
        type_, body = reply
        seq, self._seq = self._seq, (self._seq + 1) & 0xFF
        return P.encode_frame(type_, seq, body)

    def read(self, max_bytes: int, timeout: float) -> bytes:
        if not self._out:
            time.sleep(timeout)   # nothing arrives later: a scripted board only answers
            return b""
        data = bytes(self._out[:max_bytes])
        del self._out[:max_bytes]
        return data
