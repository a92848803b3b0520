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


def greet(device: str, *, timeout: float = 2.5) -> dict:
    """The HELLO of the labrig firmware at ``device`` ({} when nothing labrig answers).

    Asks every 0.5 s for ``timeout`` seconds: an Uno resets when its port opens and
    answers after its bootloader (~1-2 s).

    Raises
    ------
    RigError
        The port cannot be opened (held by another process, no permission, not there).
    """
    from labrig.bridge.transport import SerialTransport

    link = SerialTransport(device)
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
                        return P.parse_message(f).fields
                    except P.BodyError:
                        continue
        return {}
    finally:
        link.close()


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


def the_board(ports: list[Port]) -> str:
    """The one labrig board's device among ``ports``.

    Raises
    ------
    UserError
        None is connected, or several are (listing them and how to choose).
    """
    boards = [p for p in ports if p.is_labrig]
    if len(boards) == 1:
        return boards[0].device
    if not boards:
        raise UserError("port: no labrig board found (labrig ports lists what is connected); "
                        "plug it in and flash it, or give --port")
    listed = "; ".join(f"{p.device} ({p.hello.get('firmware')}, serial {p.serial_number or '-'})"
                       for p in boards)
    raise UserError(f"port: {len(boards)} labrig boards are connected ({listed}); choose one "
                    "with --port")
