"""A pty between the host and the emulated board that damages the link on purpose.

It injects seeded byte faults (bit flips and drops) in both directions, and a ``policy``
can drop, corrupt or precede chosen frames. It records what the board really sent and
decodes what it passes on with the host's own decoder, so a test can tell per run how
many samples the host can have received and how many damaged frames it must have seen.

Runs are counted on the host->board side: a CONFIGURE with a new ``seq`` starts run
``k + 1`` (a retransmission keeps its seq); run 0 is the handshake before the first one.
"""
from __future__ import annotations

import os
import random
import select
import threading
import termios
import tty
from collections import defaultdict

from labrig.bridge import protocol as P

B2H, H2B = "b2h", "h2b"


def corrupt(wire: bytes) -> bytes:
    """The same frame with one body bit flipped and the old CRC: a certain CRC error."""
    raw = bytearray(P.cobs_decode(wire[:-1]))
    raw[min(4, len(raw) - 3)] ^= 0x10
    return P.cobs_encode(bytes(raw)) + b"\x00"


class LinkProxy:
    """Forward bytes between ``board_pty`` and ``self.path``, damaging them.

    Parameters
    ----------
    board_pty : str
        The emulator's pty.
    b2h, h2b : tuple of float
        ``(p_flip, p_drop)`` per byte, board->host and host->board.
    seed : int
        Seeds one random stream per direction.
    policy : callable, optional
        ``policy(direction, frame, run, nth)`` for every intact original frame (``nth``
        counts frames of that type in that direction and run, from 0). It returns None
        (pass), ``"drop"``, ``"corrupt"`` or ``("before", wire)`` to send ``wire`` first.

    Attributes
    ----------
    sent : dict
        ``run -> {sample index: (dac, tacho, pos, ref)}`` as the board sent them.
    delivered : dict
        ``run -> set of sample indices`` in SAMPLES frames that reached the host intact.
    errors : dict
        ``(direction, run) -> crc + framing errors`` the receiver's decoder must count.
    faults : dict
        ``(direction, run) -> bytes flipped or dropped`` by the random faults.
    frames : dict
        ``(direction, run) -> [(type, seq), ...]`` original frames in order.
    """

    def __init__(self, board_pty: str, *, b2h=(0.0, 0.0), h2b=(0.0, 0.0), seed: int = 7,
                 policy=None):
        self.board = os.open(board_pty, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.board)
        # the board's line speed (the emulator garbles bytes at any other, as a UART would)
        mode = termios.tcgetattr(self.board)
        mode[4] = mode[5] = termios.B500000
        termios.tcsetattr(self.board, termios.TCSANOW, mode)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)   # keep a slave fd open so the master never sees EIO
        self.path = os.ttyname(self.slave)
        self.p = {B2H: b2h, H2B: h2b}
        self.rng = {B2H: random.Random(f"{seed}-b2h"), H2B: random.Random(f"{seed}-h2b")}
        self.policy = policy
        self.run = 0
        self._cfg_seq = None
        self._buf = {B2H: bytearray(), H2B: bytearray()}
        self._out = {B2H: P.StreamDecoder(), H2B: P.StreamDecoder()}
        self._nth = defaultdict(int)
        self.sent = defaultdict(dict)
        self.delivered = defaultdict(set)
        self.errors = defaultdict(int)
        self.faults = defaultdict(int)
        self.frames = defaultdict(list)
        self.upstream_bad_frames: list = []
        #: frames already damaged when the port opened (before the first whole one)
        self.opening_noise: list = []
        self._intact = {B2H: False, H2B: False}
        self._lock = threading.Lock()
        self._stop = False
        self.thread = threading.Thread(target=self._pump, daemon=True)
        self.thread.start()

    @property
    def upstream_bad(self) -> int:
        """Frames damaged before the proxy (each kept in ``upstream_bad_frames``)."""
        return len(self.upstream_bad_frames)

    # ---- one direction -------------------------------------------------------------
    def _original(self, d: str, wire: bytes) -> bytes:
        """Record one whole original frame (delimiter included); return what to forward."""
        if wire == b"\x00":
            return wire
        try:
            f = P.decode_frame(wire)
        except P.FrameError as exc:
            if not self._intact[d]:
                # before the first whole frame: the board's unsolicited greeting caught by
                # the port's opening (its head gone, or sent before the proxy set the line
                # speed, which the emulator garbles as a UART would), as any host meets it
                self.opening_noise.append((d, wire[:40], str(exc)))
            else:   # damaged before the proxy (should not happen)
                self.upstream_bad_frames.append((d, self.run, wire[:40], str(exc)))
            return wire
        self._intact[d] = True
        if d == H2B and f.type == P.CONFIGURE and f.seq != self._cfg_seq:
            self._cfg_seq = f.seq
            self.run += 1
        self.frames[d, self.run].append((f.type, f.seq))
        if d == B2H and f.type == P.SAMPLES:
            first, words = P.parse_samples(f.body)
            for k, row in enumerate(words.tolist()):
                self.sent[self.run][first + k] = tuple(row)
        action = None
        if self.policy is not None:
            key = (d, self.run, f.type)
            action = self.policy(d, f, self.run, self._nth[key])
            self._nth[key] += 1
        if action == "drop":
            return b""
        if action == "corrupt":
            return corrupt(wire)
        if isinstance(action, tuple) and action[0] == "before":
            return bytes(action[1]) + wire
        return wire

    def _damage(self, d: str, data: bytes) -> bytes:
        p_flip, p_drop = self.p[d]
        if not p_flip and not p_drop:
            return data
        rng, out = self.rng[d], bytearray()
        for b in data:
            x = rng.random()
            if x < p_drop:
                self.faults[d, self.run] += 1
                continue
            if x < p_drop + p_flip:
                b ^= 1 << rng.randrange(8)
                self.faults[d, self.run] += 1
            out.append(b)
        return bytes(out)

    def _through(self, d: str, data: bytes) -> bytes:
        buf = self._buf[d]
        buf += data
        out = bytearray()
        while (end := buf.find(b"\x00")) >= 0:
            wire = bytes(buf[:end + 1])
            del buf[:end + 1]
            out += self._damage(d, self._original(d, wire))
        dec = self._out[d]
        before = dec.crc_errors + dec.framing_errors
        for f in dec.feed(bytes(out)):
            if d == B2H and f.type == P.SAMPLES:
                try:
                    first, words = P.parse_samples(f.body)
                except P.FrameError:
                    continue
                self.delivered[self.run].update(range(first, first + len(words)))
        self.errors[d, self.run] += dec.crc_errors + dec.framing_errors - before
        return bytes(out)

    @staticmethod
    def _write_all(fd, data):
        while data:   # blocking fds: a short write is retried, nothing is lost
            n = os.write(fd, data)
            data = data[n:]

    def _pump(self):
        while not self._stop:
            r, _, _ = select.select([self.board, self.master], [], [], 0.05)
            with self._lock:
                if self.board in r:
                    self._write_all(self.master, self._through(B2H, os.read(self.board, 4096)))
                if self.master in r:
                    self._write_all(self.board, self._through(H2B, os.read(self.master, 4096)))

    def total(self, table: dict, direction: str) -> int:
        return sum(v for (d, _), v in table.items() if d == direction)

    def close(self):
        self._stop = True
        self.thread.join(2)
        for fd in (self.board, self.master, self.slave):
            os.close(fd)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
