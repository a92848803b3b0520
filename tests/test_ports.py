"""Finding the board: `labrig ports` lists the serial ports, greets the Arduino-class ones
and the probed ones, and marks the labrig bridges; a sweep without --port takes the one
labrig board connected."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from serial.tools.list_ports_common import ListPortInfo

from labrig.bridge.emulate import APT_PACKAGES, missing_tools
from labrig.bridge.ports import Port, board_kind, list_ports, the_board
from labrig.core.errors import UserError


def _labrig(*args):
    return subprocess.run([sys.executable, "-m", "labrig", *map(str, args)], capture_output=True,
                          text=True, timeout=120)


def _usb(device, vid, pid, serial="", description="") -> ListPortInfo:
    info = ListPortInfo(device, skip_link_detection=True)
    info.vid, info.pid, info.serial_number, info.description = vid, pid, serial, description
    return info


def test_arduino_class_usb_ids_are_told_from_other_devices():
    assert board_kind(0x2341, 0x0043) == "Arduino"               # Uno R3
    assert board_kind(0x2341, 0x0042) == "Arduino"               # Mega 2560
    assert board_kind(0x1A86, 0x7523).startswith("CH340")        # a clone
    assert board_kind(0x0403, 0x6001).startswith("FTDI")         # an older Nano
    assert board_kind(0x046D, 0xC52B) == "" and board_kind(None, None) == ""


def test_only_arduino_class_ports_are_opened(tmp_path):
    """A port that is no Arduino-class device is listed and never opened (opening resets a
    board; an unknown device is not ours to write to); an Arduino's port that is not there
    says why in its note."""
    ports = list_ports(lister=lambda: [_usb(str(tmp_path / "ttyACM9"), 0x2341, 0x0043, "8573"),
                                       _usb("/dev/ttyS0", None, None)])
    uno, other = ports
    assert uno.kind == "Arduino" and not uno.is_labrig and "cannot open" in uno.note
    assert other.kind == "" and other.note.startswith("not greeted")


def test_the_one_board_is_taken_and_two_are_named():
    one = Port("/dev/ttyACM0", 0x2341, 0x0043, serial_number="A1", hello={"firmware": "labrig-fw 2.0.0 uno ms150"})
    two = Port("/dev/ttyACM1", 0x1A86, 0x7523, serial_number="B2", hello={"firmware": "labrig-fw 2.0.0 nano hbridge"})
    plain = Port("/dev/ttyS0")
    assert the_board([plain, one]) == "/dev/ttyACM0"
    with pytest.raises(UserError, match=r"2 labrig boards .*/dev/ttyACM0 .*serial A1.*/dev/ttyACM1.*`port`"):
        the_board([one, two])
    with pytest.raises(UserError, match="no labrig board found"):
        the_board([plain])


def test_a_sweep_on_a_plain_file_is_refused_in_one_line(tmp_path):
    plain = tmp_path / "notaport"
    plain.write_text("hello\n")
    r = _labrig("sweep", "--port", plain, "-o", tmp_path / "out")
    assert r.returncode == 2 and "not a serial device" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "out").exists()


def test_a_plain_file_or_a_silent_device_is_no_board(tmp_path):
    """--probe of a plain file says it cannot be opened as a port; of a terminal nothing
    answers on, that no labrig greeting came."""
    plain = tmp_path / "notaport"
    plain.write_text("hello\n")
    master, slave = os.openpty()
    silent = os.ttyname(slave)
    try:
        r = _labrig("ports", "--probe", plain, "--probe", silent, "--json")
    finally:
        os.close(master)
        os.close(slave)
    assert r.returncode == 0, r.stderr
    found = {p["device"]: p for p in json.loads(r.stdout)["ports"]}
    assert "not a serial device" in found[str(plain)]["note"] and not found[str(plain)]["labrig"]
    assert "no labrig greeting" in found[silent]["note"] and not found[silent]["labrig"]


@pytest.mark.firmware
@pytest.mark.skipif(bool(missing_tools()), reason=f"apt-get install {APT_PACKAGES}")
def test_ports_greets_the_emulated_board(emulators):
    """The emulator's pty, which no USB listing shows, is greeted with --probe: the board
    names its firmware, board, rig and protocol."""
    from labrig.io.config import load_rig

    emu = emulators("uno", load_rig())
    r = _labrig("ports", "--probe", emu.pty, "--json")
    assert r.returncode == 0, r.stderr
    (port,) = [p for p in json.loads(r.stdout)["ports"] if p["device"] == emu.pty]
    hello = port["labrig"]
    assert hello["firmware"].startswith("labrig-fw ") and hello["firmware"].endswith("uno ms150")
    assert hello["protocol"] == 2 and hello["rig"] == "ms150"
    text = _labrig("ports", "--probe", emu.pty)
    assert f"{emu.pty}" in text.stdout and "labrig labrig-fw" in text.stdout


@pytest.mark.firmware
@pytest.mark.skipif(bool(missing_tools()), reason=f"apt-get install {APT_PACKAGES}")
def test_a_board_keeps_the_id_a_sweep_gave_it_and_a_station_bound_to_another_refuses_it(
        emulators, tmp_path):
    """A board new to labrig has no id; the first sweep gives it one, which the board
    keeps in its EEPROM (the emulator keeps the EEPROM in a file, as the chip does, across a
    power cycle) and every run records; a station bound to another id refuses the board
    before anything plays; the id finds the board among the probed ports."""
    from labrig.io.config import load_rig

    rig, plan = load_rig(), "configs/plan_two_steps.toml"
    eeprom = tmp_path / "board.eeprom"
    emu = emulators("uno", rig, eeprom=eeprom)
    (first,) = [p for p in json.loads(_labrig("ports", "--probe", emu.pty, "--json").stdout)["ports"]
                if p["device"] == emu.pty]
    assert first["labrig"]["board_id"] == "-"          # a listing only reads
    r = _labrig("sweep", "--port", emu.pty, "--plan", plan, "-o", tmp_path / "a")
    assert r.returncode == 0, r.stderr
    ids = {json.loads(p.read_text())["bridge"]["board_id"] for p in (tmp_path / "a").glob("*.json")}
    (given,) = ids
    assert len(given) == 8 and int(given, 16) != 0
    emu.stop()                                           # a power cycle
    emu = emulators("uno", rig, eeprom=eeprom)
    assert the_board(list_ports([emu.pty], greet_boards=False), int(given, 16)) == emu.pty
    other = f"{int(given, 16) ^ 0xFFFFFFFF:08X}"
    r = _labrig("sweep", "--port", emu.pty, "--plan", plan, "--board-id", other, "-o", tmp_path / "b")
    assert r.returncode == 1 and f"is {given}, not {other} (--board-id)" in r.stderr, r.stderr
    assert not (tmp_path / "b").exists() or not list((tmp_path / "b").glob("*.csv"))
    r = _labrig("sweep", "--port", emu.pty, "--plan", plan, "--board-id", given, "-o", tmp_path / "c")
    assert r.returncode == 0, r.stderr
    r = _labrig("sweep", "--port", emu.pty, "--plan", plan, "--board-id", "nothex", "-o", tmp_path / "d")
    assert r.returncode == 2 and "is not a board id" in r.stderr, r.stderr
