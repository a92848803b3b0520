"""Putting the bridge firmware on a board: the image for the board and the rig, uploaded by
avrdude through the board's bootloader (or an ISP programmer), then the board greeted.

The image is built from ``firmware/`` when the AVR toolchain is there (any rig file's
options), else taken from the prebuilt images shipped in the package
(``labrig/bridge/images``: the MS150 bridge and the shipped H-bridge rig's build, each
board; ``make -C firmware images`` rebuilds them and a test checks they equal a fresh
build).
"""
from __future__ import annotations

import os
import re
import shutil
import stat
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from labrig.bridge import hbridge
from labrig.core.errors import RigError, UserError

#: the firmware this package's host code speaks to (the sketch's FW_VERSION; a test checks)
FIRMWARE_VERSION = "2.4.1"
#: the prebuilt images shipped in the package, one folder per rig build
IMAGES = Path(__file__).with_name("images")
AVRDUDE_APT = "apt-get install -y avrdude"


@dataclass(frozen=True)
class Board:
    """An Arduino-class board as avrdude reaches it through its bootloader.

    Attributes
    ----------
    name : str
        labrig's name (``--board``).
    build : str
        The firmware's build of it (``make -C firmware <build>``).
    mcu, programmer : str
        avrdude's part (``-p``) and programmer (``-c``: the bootloader's protocol).
    baud : int
        The bootloader's baud rate (``-b``).
    watchdog : bool
        Built with the AVR's own watchdog (the old Nano bootloader loops after a watchdog
        reset: it gets a build without).
    what : str
        How a user recognises it.
    """

    name: str
    build: str
    mcu: str
    programmer: str
    baud: int
    watchdog: bool
    what: str


BOARDS = {b.name: b for b in (
    Board("uno", "uno", "atmega328p", "arduino", 115200, True,
          "Arduino Uno or a clone (optiboot bootloader)"),
    Board("nano", "nano", "atmega328p", "arduino", 115200, True,
          "Arduino Nano with the new bootloader (optiboot, every Nano since 2018)"),
    Board("nano-old", "nano", "atmega328p", "arduino", 57600, False,
          "Arduino Nano with the old bootloader (ATmegaBOOT, 57600 baud; many clones): built "
          "without the AVR's watchdog, after whose reset that bootloader loops"),
    Board("mega", "mega", "atmega2560", "wiring", 115200, True,
          "Arduino Mega 2560 (stk500v2 bootloader)"),
)}


@dataclass
class FlashResult:
    """What ``flash`` did.

    Attributes
    ----------
    board : Board
    image : Path
        The Intel-hex image uploaded.
    source : str
        ``"built"`` (from ``firmware/``) or ``"packaged"`` (the package's prebuilt image).
    command : list of str
        The avrdude command run.
    hello : dict
        The board's greeting after the upload ({} when not greeted).
    """

    board: Board
    image: Path
    source: str
    command: list[str]
    hello: dict = field(default_factory=dict)


def board_spec(board: str) -> Board:
    """The :class:`Board` named ``board``.

    Raises
    ------
    UserError
        An unknown name (the message lists the known ones).
    """
    if board not in BOARDS:
        raise UserError(f"board: unknown board {board!r}; one of {', '.join(BOARDS)}")
    return BOARDS[board]


def rig_build(rig) -> str:
    """The folder of ``rig``'s firmware build among the images (``ms150`` or the H-bridge
    build's name)."""
    return (hbridge.build_folder(rig) if rig is not None else "") or "ms150"


def can_build() -> bool:
    """Whether the AVR toolchain and the firmware's sources are here to build an image."""
    from labrig.bridge.emulate import FIRMWARE_DIR, missing_build_tools

    return not missing_build_tools() and (FIRMWARE_DIR / "Makefile").exists()


def firmware_image(board: str, rig=None, *, build: bool | None = None) -> tuple[Path, str]:
    """The firmware image for ``board`` and ``rig``.

    Parameters
    ----------
    board : str
        One of :data:`BOARDS`.
    rig : RigConfig, optional
        The rig whose firmware (its ``[bridge]`` build options); default the MS150 bridge.
    build : bool, optional
        Build from ``firmware/`` (True), take the packaged image (False), or build when the
        toolchain is there (None).

    Returns
    -------
    (image, source) : (Path, str)
        The Intel-hex file and ``"built"`` or ``"packaged"``.

    Raises
    ------
    UserError
        No packaged image for this rig's options and no toolchain to build one.
    RigError
        The build failed.
    """
    spec = board_spec(board)
    if build is None:
        build = can_build()
    if build:
        from labrig.bridge.emulate import build_firmware

        folder = build_firmware(spec.build, rig, watchdog=spec.watchdog)
        return folder / "labrig_bridge.hex", "built"
    image = IMAGES / rig_build(rig) / f"{spec.name}.hex"
    if not image.is_file():
        shipped = ", ".join(sorted(p.name for p in IMAGES.iterdir() if p.is_dir()))
        raise UserError(f"rig: no prebuilt image for this rig's build ({rig_build(rig)}; the "
                        f"package ships {shipped}); install the AVR toolchain to build it: "
                        "apt-get install -y gcc-avr avr-libc arduino-core-avr")
    return image, "packaged"


#: how often avrdude tries to reach an stk500v1 bootloader (the Uno's and the Nanos'); its
#: own default, 10, keeps a board at the wrong speed (a Nano clone with the old
#: bootloader) silent for about a minute before the hint to try ``nano-old``; an auto-reset
#: board answers the first or the second try
BOOTLOADER_ATTEMPTS = 3


def avrdude_command(board: str, port: str | None, image, *, programmer: str | None = None,
                    avrdude: str = "avrdude", attempts: int | None = None) -> list[str]:
    """The avrdude command that writes ``image`` to ``board``.

    Through the board's bootloader (the default): its protocol and baud rate, no chip erase
    (``-D``: the bootloader erases the pages it writes), and ``attempts`` tries to reach an
    stk500v1 bootloader when given (avrdude 7.1 and later). Through another ``programmer``
    (an ISP such as ``usbasp``, or avrdude's ``dryrun``): no baud rate, the chip erased.

    Examples
    --------
    >>> avrdude_command("uno", "/dev/ttyACM0", "fw.hex")
    ['avrdude', '-p', 'atmega328p', '-c', 'arduino', '-P', '/dev/ttyACM0', '-b', '115200', '-D', '-U', 'flash:w:fw.hex:i']
    """
    spec = board_spec(board)
    cmd = [avrdude, "-p", spec.mcu, "-c", programmer or spec.programmer]
    if port:
        cmd += ["-P", str(port)]
    if programmer in (None, spec.programmer):
        cmd += ["-b", str(spec.baud), "-D"]
        if attempts is not None and spec.programmer == "arduino":
            cmd += ["-x", f"attempts={int(attempts)}"]
    return cmd + ["-U", f"flash:w:{image}:i"]


def avrdude_version(avrdude: str = "avrdude") -> tuple[int, int] | None:
    """avrdude's version as (major, minor), None when it does not say.

    Examples
    --------
    >>> avrdude_version("/nonexistent/avrdude") is None
    True
    """
    try:
        r = subprocess.run([avrdude, "-?"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    m = re.search(r"version (\d+)\.(\d+)", r.stdout + r.stderr, re.I)
    return (int(m.group(1)), int(m.group(2))) if m else None


def _check_port(port: str) -> None:
    """A device that can be a board's serial port (not a plain file, not missing)."""
    try:
        mode = os.stat(port).st_mode
    except FileNotFoundError:
        raise UserError(f"port: {port} does not exist (labrig ports lists the serial ports)") \
            from None
    if not stat.S_ISCHR(mode):
        raise UserError(f"port: {port} is not a serial device (labrig ports lists them)")


def default_port() -> str:
    """The one Arduino-class USB port connected (its firmware may be anything yet).

    Raises
    ------
    UserError
        None, or several (listed, with how to choose).
    """
    from labrig.bridge.ports import list_ports

    boards = [p for p in list_ports(greet_boards=False) if p.kind]
    if len(boards) == 1:
        return boards[0].device
    if not boards:
        raise UserError("port: no Arduino-class board found (labrig ports lists every serial "
                        "port); plug it in, or give `port`")
    listed = "; ".join(f"{p.device} ({p.kind}, serial {p.serial_number or '-'})" for p in boards)
    raise UserError(f"port: {len(boards)} Arduino-class boards are connected ({listed}); "
                    "choose one with `port`")


def flash(board: str, rig=None, port: str | None = None, *, programmer: str | None = None,
          build: bool | None = None, avrdude: str = "avrdude", greet: bool = True,
          timeout: float = 180.0) -> FlashResult:
    """Upload the bridge firmware for ``board`` and ``rig``, then greet the board.

    Parameters
    ----------
    board : str
        ``"uno"``, ``"nano"``, ``"nano-old"`` or ``"mega"`` (:data:`BOARDS`).
    rig : RigConfig, optional
        The rig whose firmware (default the MS150 bridge).
    port : str, optional
        The board's serial device; default the one Arduino-class USB port connected.
    programmer : str, optional
        avrdude's programmer instead of the bootloader (e.g. ``usbasp``); the board is not
        greeted through it unless ``port`` is given too.
    build : bool, optional
        See :func:`firmware_image`.
    avrdude : str
        The avrdude executable.
    greet : bool
        Greet the board after the upload and check what it runs.

    Returns
    -------
    FlashResult

    Raises
    ------
    UserError
        An unknown board, a port that is not a serial device, no port found.
    RigError
        avrdude missing or failing (its last lines and what to try), or the board not
        greeting as the firmware just written.
    """
    spec = board_spec(board)
    isp = programmer not in (None, spec.programmer)
    if port is None and not isp:
        port = default_port()
    if port is not None and programmer != "dryrun":
        _check_port(port)
    exe = shutil.which(avrdude)
    if exe is None:
        raise RigError(f"avrdude not found; install it ({AVRDUDE_APT}), or upload the image "
                       "with arduino-cli (docs/hardware.md, 'Building and flashing')")
    image, source = firmware_image(board, rig, build=build)
    # fewer tries where avrdude can be told (7.1 added -x attempts for stk500v1)
    attempts = BOOTLOADER_ATTEMPTS if (avrdude_version(exe) or (0, 0)) >= (7, 1) else None
    cmd = avrdude_command(board, port, image, programmer=programmer, avrdude=exe,
                          attempts=attempts)
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise RigError(f"avrdude did not finish in {timeout:g} s ({' '.join(cmd)})") from None
    if r.returncode != 0:
        tail = " | ".join([ln.strip() for ln in (r.stdout + r.stderr).splitlines()
                           if ln.strip()][-3:])
        hint = (" -- the bootloader did not answer: a Nano clone often has the old one "
                "(`board=nano-old`); check the board and the port"
                if "sync" in tail or "not responding" in tail else "")
        raise RigError(f"avrdude failed (exit {r.returncode}): {tail}{hint}")
    result = FlashResult(spec, Path(image), source, cmd)
    if greet and port is not None and programmer != "dryrun":
        result.hello = confirm(port, spec, rig)
    return result


def confirm(port: str, spec: Board, rig=None, *, timeout: float = 6.0) -> dict:
    """Greet the board just flashed: it must run this package's firmware version, for this
    board and this rig.

    Raises
    ------
    RigError
        No greeting, or another version, board or rig than was written.
    """
    from labrig.bridge.ports import greet

    hello = greet(port, timeout=timeout, assign=True)   # a board new to labrig gets its id
    if not hello:
        raise RigError(f"the upload ended, but the board on {port} does not greet as labrig "
                       "firmware: press its reset button and try labrig ports; a Nano clone "
                       "may need `board=nano-old`")
    want = f"labrig-fw {FIRMWARE_VERSION} {spec.build} {rig.bridge.firmware if rig else 'ms150'}"
    if hello.get("firmware") != want:
        raise RigError(f"the board on {port} greets as {hello.get('firmware')!r} after the "
                       f"upload, not {want!r}: was it written (is the port this board's)?")
    return hello
