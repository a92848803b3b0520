"""Finding the board: the serial ports pyserial lists, the Arduino-class ones among them
greeted, the labrig bridges marked.

Opening an Arduino's port resets it (the DTR line), so only ports whose USB VID:PID is an
Arduino or one of the USB-serial chips Arduino-class boards and their clones carry are
greeted; any other device is listed and left alone unless asked by name (``probe``: also
how an emulator's pseudo-terminal, which no USB listing shows, is found).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

from labrig.bridge import protocol as P
from labrig.core.errors import LabrigError, UserError

#: USB vendors whose every product is an Arduino board
ARDUINO_VIDS = {0x2341: "Arduino", 0x2A03: "Arduino (arduino.org)"}
#: USB-serial chips of Arduino-class boards and their clones: (VID, PID) -> what it is
USB_SERIAL = {(0x1A86, 0x7523): "CH340 (Uno/Nano clone)",
              (0x0403, 0x6001): "FTDI FT232R (Nano, older boards)",
              (0x10C4, 0xEA60): "CP2102 (clone)"}


@dataclass
class Port:
    """A serial port: what the system says of it and, when greeted, what the board says.

    Attributes
    ----------
    device : str
    vid, pid : int or None
        USB vendor and product ids (None: not a USB device, or a pseudo-terminal).
    description, serial_number : str
    kind : str
        ``"Arduino"``, the USB-serial chip of a clone, or ``""`` (not a board labrig greets).
    hello : dict
        The board's greeting (firmware, board, rig, protocol) when it is a labrig bridge.
    note : str
        Why it was not greeted, or what the greeting found instead.
    """

    device: str
    vid: int | None = None
    pid: int | None = None
    description: str = ""
    serial_number: str = ""
    kind: str = ""
    hello: dict = field(default_factory=dict)
    note: str = ""

    @property
    def usb_id(self) -> str:
        return f"{self.vid:04X}:{self.pid:04X}" if self.vid is not None else "-"

    @property
    def is_labrig(self) -> bool:
        return bool(self.hello)


def board_kind(vid: int | None, pid: int | None) -> str:
    """What a USB VID:PID is, for labrig: an Arduino, a clone's USB-serial chip, or ''."""
    if vid in ARDUINO_VIDS:
        return ARDUINO_VIDS[vid]
    return USB_SERIAL.get((vid, pid), "")


def greet(device: str, *, timeout: float = 2.5, assign: bool = False,
          baud: int = 500000) -> dict:
    """The HELLO of the labrig firmware at ``device`` ({} when nothing labrig answers),
    with the board's id (``board_id``; None from a firmware before 2.3).

    Asks every 0.5 s for ``timeout`` seconds: an Uno resets when its port opens and
    answers after its bootloader (~1-2 s). ``assign`` gives a board without an id one;
    ``baud``: the speed its firmware was built for.

    Raises
    ------
    RigError
        The port cannot be opened (held by another process, no permission, not there).
    """
    from labrig.bridge.transport import SerialTransport

    link = SerialTransport(device, baud)
    link.open()
    try:
        dec = P.StreamDecoder()
        end, ask = time.monotonic() + timeout, 0.0
        while time.monotonic() < end:
            if time.monotonic() >= ask:
                link.write(b"\x00" + P.encode_frame(P.HELLO_REQ, 1))
                ask = time.monotonic() + 0.5
            for f in dec.feed(link.read(256, 0.05)):
                if f.type == P.HELLO:
                    try:
                        hello = P.parse_message(f).fields
                    except P.BodyError:
                        continue
                    hello["board_id"] = _read_id(link, dec, hello, assign)
                    return hello
        return {}
    finally:
        link.close()


def _read_id(link, dec, hello: dict, assign: bool = False) -> int | None:
    """The board's id (given one first when it has none and ``assign``); None from a
    firmware that keeps none, or no answer. A listing only reads: a sweep gives ids."""
    from labrig.bridge.hbridge import firmware_version
    from labrig.bridge.identity import settle

    def ask(body: bytes, timeout: float = 0.6):
        link.write(b"\x00" + P.encode_frame(P.BOARD_ID, 2, body))
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for f in dec.feed(link.read(256, 0.05)):
                if f.type == P.ID:
                    try:
                        return P.parse_message(f).fields["board_id"]
                    except P.BodyError:
                        return None
        return None

    return settle(ask, firmware_version(hello), assign=assign)


def list_ports(probe=(), *, greet_boards: bool = True, lister=None) -> list[Port]:
    """The serial ports, the Arduino-class ones greeted.

    Parameters
    ----------
    probe : sequence of str
        Devices to greet whatever they are (an emulator's pty, a board behind an adapter
        labrig does not know).
    greet_boards : bool
        Greet the Arduino-class ports (opening one resets the board).
    lister : callable, optional
        What lists the system's ports (default ``serial.tools.list_ports.comports``).

    Returns
    -------
    list of Port
        Every port listed, then the probed ones.
    """
    if lister is None:
        from serial.tools.list_ports import comports as lister
    ports = [Port(p.device, p.vid, p.pid, p.description or "", p.serial_number or "",
                  board_kind(p.vid, p.pid)) for p in lister()]
    known = {p.device for p in ports}
    ports += [Port(str(d), description="probed") for d in probe if str(d) not in known]
    asked = {str(d) for d in probe}
    for port in ports:
        if not (port.device in asked or (greet_boards and port.kind)):
            port.note = "not greeted (not an Arduino-class USB id; --probe to ask it)"
            continue
        try:
            port.hello = greet(port.device)
        except LabrigError as e:
            port.note = str(e)
            continue
        if not port.hello:
            port.note = "no labrig greeting (other firmware, or the wrong baud rate)"
    return ports


def the_board(ports: list[Port], board_id: int | None = None) -> str:
    """The one labrig board's device among ``ports`` (the one whose id is ``board_id``).

    Raises
    ------
    UserError
        None is connected, or several are (listing them and how to choose).
    """
    boards = [p for p in ports if p.is_labrig]
    if board_id is not None:
        mine = [p for p in boards if p.hello.get("board_id") == board_id]
        if len(mine) == 1:
            return mine[0].device
        seen = ", ".join(f"{p.device} {P.format_board_id(p.hello.get('board_id'))}"
                         for p in boards) or "none"
        raise UserError(f"board_id: no labrig board {P.format_board_id(board_id)} is connected "
                        f"(labrig boards: {seen}); plug it in, or check the id with labrig ports")
    if len(boards) == 1:
        return boards[0].device
    if not boards:
        raise UserError("port: no labrig board found (labrig ports lists what is connected); "
                        "plug it in and flash it, or give `port`")
    listed = "; ".join(f"{p.device} ({p.hello.get('firmware')}, id "
                       f"{P.format_board_id(p.hello.get('board_id'))}, serial {p.serial_number or '-'})"
                       for p in boards)
    raise UserError(f"port: {len(boards)} labrig boards are connected ({listed}); choose one "
                    "with `port` or `board_id`")
