"""labrig flash: the image for the board and the rig, the exact avrdude command, a real
upload through a real bootloader under simavr, and the greeting after it."""
from __future__ import annotations

import filecmp
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from labrig.bridge import flash as F
from labrig.bridge.emulate import FIRMWARE_DIR, Emulator, missing_tools

ROOT = Path(__file__).resolve().parents[1]
#: the old Nano's (and Duemilanove's) bootloader, as Debian's arduino-core-avr ships it
ATMEGABOOT = Path("/usr/share/arduino/hardware/arduino/avr/bootloaders/atmega/"
                  "ATmegaBOOT_168_atmega328.hex")
_missing = missing_tools()


def _labrig(*args, env=None, timeout=300):
    return subprocess.run([sys.executable, "-m", "labrig", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=env)


@pytest.fixture
def stub(tmp_path):
    """An ``avrdude`` first on PATH that records its arguments and writes nothing."""
    bindir = tmp_path / "bin"
    bindir.mkdir()
    record = tmp_path / "avrdude.args"
    exe = bindir / "avrdude"
    exe.write_text(f'#!/bin/sh\nprintf "%s\\n" "$@" > {record}\necho "avrdude: stub"\n')
    exe.chmod(0o755)
    env = {**os.environ, "PATH": f"{bindir}{os.pathsep}{os.environ['PATH']}"}
    return env, record


def test_the_avrdude_command_of_each_board():
    """Each board's bootloader: its protocol, baud rate and part; no chip erase through a
    bootloader, an erase and no baud rate through an ISP programmer."""
    hexfile = "fw.hex"
    want = {"uno": ["-p", "atmega328p", "-c", "arduino", "-P", "/dev/ttyACM0", "-b", "115200", "-D"],
            "nano": ["-p", "atmega328p", "-c", "arduino", "-P", "/dev/ttyACM0", "-b", "115200", "-D"],
            "nano-old": ["-p", "atmega328p", "-c", "arduino", "-P", "/dev/ttyACM0", "-b", "57600",
                         "-D"],
            "mega": ["-p", "atmega2560", "-c", "wiring", "-P", "/dev/ttyACM0", "-b", "115200", "-D"]}
    for board, args in want.items():
        assert F.avrdude_command(board, "/dev/ttyACM0", hexfile) == \
            ["avrdude", *args, "-U", "flash:w:fw.hex:i"]
    assert F.avrdude_command("uno", None, hexfile, programmer="usbasp") == \
        ["avrdude", "-p", "atmega328p", "-c", "usbasp", "-U", "flash:w:fw.hex:i"]
    # fewer tries only where the stk500v1 bootloader is reached (the Mega's wiring has none)
    assert F.avrdude_command("nano", "/dev/ttyACM0", hexfile, attempts=3)[-4:-2] == \
        ["-x", "attempts=3"]
    assert "-x" not in F.avrdude_command("mega", "/dev/ttyACM0", hexfile, attempts=3)
    assert "-x" not in F.avrdude_command("uno", None, hexfile, programmer="usbasp", attempts=3)
    assert not F.BOARDS["nano-old"].watchdog and all(
        b.watchdog for n, b in F.BOARDS.items() if n != "nano-old")


def test_the_packaged_image_is_taken_without_a_build(stub):
    """--build no: the image shipped in the package, for the rig file's build."""
    env, record = stub
    r = _labrig("flash", "--board", "nano-old", "--rig", ROOT / "configs/rig_arduino_hbridge.toml",
                "--build", "no", "--programmer", "usbasp", env=env)
    assert r.returncode == 0, r.stderr
    args = record.read_text().split()
    image = F.IMAGES / "hbridge-in1_in2-brake-x4-pwm8" / "nano-old.hex"
    assert args[-1] == f"flash:w:{image}:i" and image.is_file()
    assert "packaged" in r.stdout


def test_the_host_speaks_the_version_the_sketch_declares():
    text = (FIRMWARE_DIR / "labrig_bridge" / "labrig_bridge.ino").read_text()
    assert re.search(r'#define FW_VERSION "([\d.]+)"', text).group(1) == F.FIRMWARE_VERSION


@pytest.mark.parametrize("args, code, words", [
    (("--board", "due"), 2, "invalid choice: 'due'"),
    (("--board", "uno", "--port", "/etc/hostname"), 2, "/etc/hostname is not a serial device"),
    (("--board", "uno", "--port", "/dev/no-such-port"), 2, "/dev/no-such-port does not exist"),
])
def test_bad_input_is_one_line_and_nothing_is_written(stub, args, code, words):
    env, record = stub
    r = _labrig("flash", *args, env=env)
    assert r.returncode == code and words in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and not record.exists()


def test_no_avrdude_names_the_package_to_install(tmp_path):
    env = {**os.environ, "PATH": str(tmp_path)}   # nothing on it
    r = subprocess.run([sys.executable, "-m", "labrig", "flash", "--board", "uno", "--port",
                        "/dev/null"], capture_output=True, text=True, env=env)
    assert r.returncode == 1 and "apt-get install -y avrdude" in r.stderr, r.stderr


@pytest.mark.firmware
@pytest.mark.parametrize("board, emulated", [("uno", "uno"), ("nano", "nano"),
                                             ("nano-old", "nano"), ("mega", "mega")])
def test_each_board_is_flashed_with_its_command_then_greeted(stub, board, emulated):
    """Through a stub avrdude (it records, writes nothing) onto an emulated board that
    already runs the firmware: the command is the board's and the greeting confirms it."""
    if _missing:
        pytest.skip(f"firmware toolchain missing: {_missing}")
    env, record = stub
    with Emulator(emulated) as emu:
        r = _labrig("flash", "--board", board, "--port", emu.pty, env=env)
    assert r.returncode == 0, r.stderr
    args = record.read_text().split()
    spec = F.BOARDS[board]
    assert args[:8] == ["-p", spec.mcu, "-c", spec.programmer, "-P", emu.pty, "-b", str(spec.baud)]
    assert args[-1].endswith(f"{'nowdt/' if board == 'nano-old' else ''}{emulated}/labrig_bridge.hex:i")
    assert f"labrig-fw {F.FIRMWARE_VERSION} {emulated} ms150" in r.stdout


@pytest.mark.firmware
@pytest.mark.skipif(not shutil.which("avrdude") or not ATMEGABOOT.exists() or bool(_missing),
                    reason="needs avrdude, arduino-core-avr's bootloaders and simavr")
def test_a_real_upload_through_the_old_nano_bootloader_then_the_board_greets():
    """A Nano as it comes from the box (its bootloader, the flash erased) under simavr: the
    real avrdude writes and verifies the image through the real bootloader over the pty, the
    bootloader starts it, and it greets. The line judges the speed as a UART does: the new
    bootloader's 115200 baud finds no bootloader, and the message names --board nano-old
    after avrdude's three tries (``F.BOOTLOADER_ATTEMPTS``; its own ten took a minute)."""
    with Emulator("nano", bootloader=ATMEGABOOT) as emu:
        wrong = _labrig("flash", "--board", "nano", "--port", emu.pty)
        right = _labrig("flash", "--board", "nano-old", "--port", emu.pty)
    assert wrong.returncode == 1 and "not in sync" in wrong.stderr, wrong.stderr
    if (F.avrdude_version() or (0, 0)) >= (7, 1):
        assert "attempt 3 of 3" in wrong.stderr, wrong.stderr
    assert "--board nano-old" in wrong.stderr
    assert right.returncode == 0, right.stderr
    assert f"the board greets: labrig-fw {F.FIRMWARE_VERSION} nano ms150" in right.stdout


@pytest.mark.firmware
@pytest.mark.skipif(bool(_missing), reason="firmware toolchain missing")
def test_the_packaged_images_equal_a_fresh_build(tmp_path):
    """Every image shipped in the package is what `make -C firmware images` builds now
    (a firmware change without `make -C firmware images` fails here)."""
    r = subprocess.run(["make", "-C", str(FIRMWARE_DIR), "--no-print-directory", "images",
                        f"B={tmp_path / 'build'}", f"IMAGES={tmp_path / 'images'}"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    fresh = sorted(p.relative_to(tmp_path / "images") for p in (tmp_path / "images").rglob("*.hex"))
    shipped = sorted(p.relative_to(F.IMAGES) for p in F.IMAGES.rglob("*.hex"))
    assert fresh == shipped and len(fresh) == 8
    for rel in fresh:
        assert filecmp.cmp(tmp_path / "images" / rel, F.IMAGES / rel, shallow=False), rel


def test_avrdudes_dry_run_programmer_takes_the_image(tmp_path):
    """avrdude 7.2 and later have a dry-run programmer: the packaged image is uploaded to
    it. Debian bookworm ships 7.1, which has none: skipped there, said so."""
    exe = shutil.which("avrdude")
    if exe is None:
        pytest.skip("avrdude not installed")
    version = F.avrdude_version(exe)
    if not version or version < (7, 2):
        said = ".".join(map(str, version)) if version else "?"
        pytest.skip(f"avrdude {said} has no dryrun programmer (7.2+)")
    r = _labrig("flash", "--board", "uno", "--programmer", "dryrun", "--build", "no")
    assert r.returncode == 0, r.stderr
