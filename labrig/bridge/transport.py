"""Byte links under :class:`labrig.bridge.serial.SerialBridge`.

The bridge speaks frames; a transport only moves bytes. Injecting it (the model is
pymeasure's ``ProtocolAdapter``) lets the same driver run on a real port
(:class:`SerialTransport`: a USB board or an emulator's pty) and on a scripted board
(:class:`ScriptedTransport`) that tests the handshake, retries and error paths without
hardware or simavr.
"""
from __future__ import annotations

import abc
from contextlib import contextmanager
import os
import time
from collections.abc import Callable, Sequence

from labrig.bridge import protocol as P
from labrig.core.errors import LabrigError, RigError, UserError


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


@contextmanager
def link_faults(port: str, doing: str = ""):
    """A link that fails inside the block (pyserial raises SerialException and OSError
    subclasses) is a :class:`RigError` naming ``port``; labrig's own errors pass as they
    are (e.g. Terminated from a signal handler: not a link fault)."""
    try:
        yield
    except LabrigError:
        raise
    except Exception as e:
        raise RigError(f"lost {port}{doing}: {e}") from e


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


def port_holders(port: str) -> list[tuple[int, str]]:
    """The processes holding ``port``'s lock: (pid, command line), from Linux's
    ``/proc/locks`` (the flock pyserial's ``exclusive`` takes); empty elsewhere."""
    try:
        st = os.stat(port)
        with open("/proc/locks") as fh:
            locks = fh.read().splitlines()
    except OSError:
        return []
    inode = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    found = []
    for line in locks:
        f = line.split()
        if len(f) > 5 and f[1] == "FLOCK" and f[5] == inode and f[4].isdigit():
            pid = int(f[4])
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as cl:
                    argv = [a.decode(errors="replace") for a in cl.read().split(b"\0") if a]
            except OSError:
                argv = []
            found.append((pid, " ".join(argv)[:120] or "?"))
    return found


#: ports this process holds: realpath -> (lock file's fd, holders in this process)
_LEASES: dict = {}


def _lock_file(port: str) -> str:
    import tempfile

    name = os.path.realpath(port).strip("/").replace("/", "_")
    return os.path.join(tempfile.gettempdir(), f"labrig-{name}.lock")


def lease(port: str) -> None:
    """Hold ``port`` for this process until :func:`release`: a lab station holds its board
    between runs, each sweep while it plays; another process asking for the port is
    refused at once, naming the holder. Nested leases in one process share the hold.

    Raises
    ------
    RigError
        Another process holds the port.
    """
    import fcntl

    key = os.path.realpath(port)
    if key in _LEASES:
        fd, n = _LEASES[key]
        _LEASES[key] = (fd, n + 1)
        return
    path = _lock_file(port)
    fd = os.open(path, os.O_RDONLY | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        held = ", ".join(f"PID {pid} ({cmd})" for pid, cmd in port_holders(path))
        raise RigError(f"{port} is in use by {held or 'another labrig'}: one user per port; "
                       "wait for it to finish, or stop it") from None
    _LEASES[key] = (fd, 1)


def release(port: str) -> None:
    """End one :func:`lease` of ``port``; the last one lets the port go."""
    key = os.path.realpath(port)
    if key not in _LEASES:
        return
    fd, n = _LEASES[key]
    if n > 1:
        _LEASES[key] = (fd, n - 1)
        return
    del _LEASES[key]
    os.close(fd)   # closing the descriptor drops the lock


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
        """Open the port for this process alone (pyserial's ``exclusive``: an OS lock, so a
        second sweep, lab page or ask-the-rig on the same board is refused at once).

        Raises
        ------
        RigError
            The port is held (naming the holder), not ours to open (the dialout group), or
            not there.
        """
        import errno
        import serial  # pyserial; imported here so the module loads without it

        if self.is_open:   # opened again (a second handshake): let go of the first hold
            self.close()
        if os.path.isfile(self.port) or os.path.isdir(self.port):
            raise UserError(f"port: {self.port} is a {'folder' if os.path.isdir(self.port) else 'file'}, "
                            "not a serial device; give the board's (labrig ports lists them)")
        ser = serial.Serial()
        ser.port, ser.baudrate = self.port, self.baudrate
        ser.timeout, ser.write_timeout = 0.05, self.write_timeout
        ser.exclusive = True
        lease(self.port)
        try:
            ser.open()   # pyserial ignores ENOTTY from DTR/RTS on a pty itself
        except Exception as e:
            release(self.port)
            if "exclusively lock" in str(e):
                held = ", ".join(f"PID {pid} ({cmd})" for pid, cmd in port_holders(self.port))
                raise RigError(f"{self.port} is in use by {held or 'another process'}: one user "
                               "per port; wait for it to finish, or stop it") from None
            if getattr(e, "errno", None) == errno.EACCES:
                raise RigError(f"no permission to open {self.port}: add yourself to its group "
                               "(sudo usermod -aG dialout $USER), then log out and in") from None
            raise RigError(f"cannot open {self.port} ({getattr(e, 'strerror', None) or e}): is the "
                           "board plugged in and is this its port? (ls /dev/ttyACM* /dev/ttyUSB*)") from e
        self._ser = ser

    def close(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            ser.close()
            release(self.port)

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
