"""labrig doctor on the emulated board: every check passes on a sound chain, and each
injected fault is named with what to do -- a wrong baud rate, no permission on the port (as
an unprivileged user), a sensor stuck at its rail, a port another program holds."""
from __future__ import annotations

import grp
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from labrig.bridge.emulate import APT_PACKAGES, missing_tools

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.firmware,
              pytest.mark.skipif(bool(missing_tools()), reason=f"apt-get install {APT_PACKAGES}")]


def _doctor(*args):
    r = subprocess.run([sys.executable, "-m", "labrig", "doctor", *map(str, args), "--json"],
                       capture_output=True, text=True, timeout=120)
    return r, (json.loads(r.stdout) if r.stdout.strip() else None)


def _checks(report) -> dict:
    return {c["name"]: (c["ok"], c["text"]) for c in report["checks"]}


@pytest.mark.parametrize("rig_file", [None, "configs/rig_arduino_hbridge.toml"])
def test_every_check_passes_on_a_sound_chain(emulators, rig_file):
    from labrig.io.config import load_rig

    rig = load_rig(ROOT / rig_file) if rig_file else load_rig()
    emu = emulators("uno", rig)
    r, rep = _doctor("--port", emu.pty, *(["--rig", ROOT / rig_file] if rig_file else []))
    assert r.returncode == 0 and rep["ok"], r.stdout + r.stderr
    c = _checks(rep)
    assert list(c) == ["port", "permissions", "in use", "greeting", "firmware", "rig", "board id",
                       "0 V out", "sensors", "sample rate"]
    assert c["greeting"][1].endswith("at 500000 baud") and len(c["board id"][1]) == 8
    n = int(rig.bridge.sample_rate_hz * 2)
    assert c["sample rate"][1].startswith(f"{n} of {n} samples")


def test_a_wrong_baud_rate_is_named_as_such(emulators):
    """The emulated line garbles bytes at another speed than the chip's UART, as a real one
    does: at 115200 nothing greets, and the doctor finds the board's own speed."""
    emu = emulators("uno")
    r, rep = _doctor("--port", emu.pty, "--baud", "115200")
    assert r.returncode == 1
    ok, text = _checks(rep)["greeting"]
    assert not ok and "greets at 500000 baud, not 115200: give --baud 500000" in text
    assert _checks(rep)["firmware"][0] is None   # not run


def test_a_sensor_stuck_at_its_rail_is_named(emulators):
    emu = emulators("uno", extra_args=("--stuck-adc", "1"))
    r, rep = _doctor("--port", emu.pty)
    assert r.returncode == 1
    ok, text = _checks(rep)["sensors"]
    assert not ok and "the output pot (A1) reads the top of its range" in text, text
    assert _checks(rep)["0 V out"][0] and _checks(rep)["sample rate"][0]


def test_a_port_another_program_holds_is_named(emulators):
    from labrig.bridge.transport import lease, release

    emu = emulators("uno")
    lease(emu.pty)
    try:
        r, rep = _doctor("--port", emu.pty)
    finally:
        release(emu.pty)
    ok, text = _checks(rep)["in use"]
    assert r.returncode == 1 and not ok and f"PID {os.getpid()}" in text, text


@pytest.mark.skipif(os.geteuid() != 0, reason="taking a user's rights away needs root")
@pytest.mark.skipif(shutil.which("setpriv") is None, reason="needs util-linux's setpriv")
def test_no_permission_on_the_port_names_the_group_to_join(emulators, tmp_path):
    """A user who may not open a port of the dialout group: the doctor names the group and
    the command. The user is this one with every capability and supplementary group taken
    away (util-linux's setpriv), on a port owned by nobody: the kernel's own permission
    checks then refuse it as they refuse any user outside the group, and the code it runs
    stays readable wherever the clone is (a private 0700 home folder, which nobody itself
    could not read)."""
    emu = emulators("uno")
    dialout = grp.getgrnam("dialout").gr_gid
    os.chown(emu.pty, 65534, dialout)
    os.chmod(emu.pty, 0o660)
    r = subprocess.run(["setpriv", "--clear-groups", "--inh-caps=-all", "--ambient-caps=-all",
                        "--bounding-set=-all", sys.executable, "-m", "labrig", "doctor",
                        "--port", emu.pty, "--json"],
                       capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    ok, text = _checks(json.loads(r.stdout))["permissions"]
    assert not ok and "sudo usermod -aG dialout $USER" in text, text


@pytest.mark.parametrize("port, words", [("/etc/hostname", "is not a serial device"),
                                         ("/dev/no-such-port", "does not exist")])
def test_a_port_that_is_no_serial_device_is_bad_input(port, words):
    r = subprocess.run([sys.executable, "-m", "labrig", "doctor", "--port", port],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and words in r.stderr and "Traceback" not in r.stderr, r.stderr
