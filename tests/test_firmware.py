"""Firmware tests: host unit tests of the C core, AVR builds, and the real compiled
firmware under simavr driven through SerialBridge over a pty (end to end, link faults,
watchdog, a vanishing board). Needs gcc-avr, avr-libc, arduino-core-avr, simavr,
libsimavr-dev, libsimavrparts1."""
from __future__ import annotations

import copy
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from labrig.io.experiment import Experiment
from labrig.bridge.emulate import (APT_PACKAGES, FIRMWARE_DIR, Emulator, firmware_make,
                                   missing_tools)
from labrig.bridge.serial import SerialBridge, bridge_settings, volts_to_dac_word
from labrig.io.config import RigConfig
from labrig.core.errors import RigError, UserError
from linkproxy import B2H, LinkProxy

_missing = missing_tools()
pytestmark = [
    pytest.mark.firmware,
    pytest.mark.skipif(bool(_missing), reason=f"firmware toolchain missing ({', '.join(_missing)}): "
                                              f"apt-get install {APT_PACKAGES}"),
]

RIG = RigConfig()   # the default rig's bridge (1 kHz, +-2.5 V, 12-bit DAC), no hidden friction
LSB = 10.0 / 4096


def _make(*targets):
    return firmware_make(*targets, timeout=300)   # (the lock the emulator's builds take)


def test_core_unit_tests_pass():
    r = _make("test")
    assert r.returncode == 0, r.stdout + r.stderr
    assert " passed, 0 failed" in r.stdout


def test_both_boards_build_and_report_size():
    """Both rigs' builds fit, and PROTOCOL.md quotes the Uno's static RAM use as they report it."""
    import re

    from labrig.bridge.hbridge import make_options
    from labrig.io.config import load_rig

    r = _make("uno", "mega")
    assert r.returncode == 0, r.stdout + r.stderr
    for board in ("uno", "mega"):
        assert (FIRMWARE_DIR / "build" / board / "labrig_bridge.hex").exists()
        assert f"{board}: flash " in r.stdout and "RAM" in r.stdout
    shipped = load_rig(Path(__file__).resolve().parents[1] / "configs" / "rig_arduino_hbridge.toml")
    h = _make("uno", *make_options(shipped))
    assert h.returncode == 0, h.stdout + h.stderr
    ram = [float(re.search(r"uno: .*RAM \d+ of \d+ bytes \(([\d.]+)%\)", out).group(1))
           for out in (r.stdout, h.stdout)]
    doc = (FIRMWARE_DIR / "PROTOCOL.md").read_text()
    assert (f"the build reports {ram[0]:.0f} % of RAM used statically, {ram[1]:.0f} % for the "
            "H-bridge build") in doc, ram
    # docs/hardware.md quotes every build's bytes as the compiler it names made them
    version = subprocess.run(["avr-gcc", "--version"], capture_output=True, text=True).stdout
    if " 5.4" not in version.splitlines()[0]:
        return   # another avr-gcc lays the code out otherwise: the percentages above still hold
    sizes = {}
    for rig, out in (("ms150", r.stdout), ("hbridge", h.stdout + _make("mega", *make_options(shipped)).stdout)):
        for board, flash, fpc, ram_b, rpc in re.findall(
                r"(uno|mega): flash (\d+) of \d+ bytes \(([\d.]+)%\), RAM (\d+) of \d+ bytes "
                r"\(([\d.]+)%\)", out):
            sizes[rig, board] = (flash, fpc, ram_b, rpc)
    hw = " ".join((Path(__file__).resolve().parents[1] / "docs" / "hardware.md").read_text().split())
    for (rig, board), (flash, fpc, ram_b, rpc) in sizes.items():
        assert f"{flash} bytes" in hw and f"({fpc} %)" in hw, (rig, board, flash, fpc)
        assert f"{ram_b} bytes" in hw and f"{rpc} %" in hw, (rig, board, ram_b, rpc)
    assert len(sizes) == 4, sizes


def _plan(exp, idx):
    """The planned output at sample ``idx`` (waveform_at works on integer sample counts,
    like the firmware, so edges fall on the same sample)."""
    return exp.waveform_at(idx / exp.sample_rate_hz)


def _run(bridge, exp, timeout=2.0):
    bridge.configure(exp)
    bridge.start()
    blocks = []
    while (b := bridge.read(timeout)) is not None:
        blocks.append(b)
    bridge.stop()
    idx = np.concatenate([b.index for b in blocks])
    u = np.concatenate([b.u for b in blocks])
    return idx, u, blocks


def test_end_to_end_square_wave():
    exp = Experiment(name="sq_1.50V", amplitude_v=1.5, frequency_hz=1.0, lead_in_s=0.25, periods=1.75)
    with Emulator("uno", RIG) as emu, SerialBridge(emu.pty, RIG) as bridge:
        assert bridge.hello["firmware"].startswith("labrig-fw")
        idx, u, blocks = _run(bridge, exp)
        c = bridge.counters()
    assert c["dropped_samples"] == 0 and c["crc_errors"] == 0
    assert np.array_equal(idx, np.arange(exp.n_samples))
    plan = _plan(exp, idx)
    assert np.max(np.abs(u - plan)) <= LSB          # the plan, to one DAC step
    tacho = np.concatenate([b.tacho for b in blocks])
    # the motor answers: fast positive during the first high half, negative in the low one
    assert tacho[600:740].mean() > 2.0 and tacho[1100:1240].mean() < -2.0


@pytest.mark.parametrize("board", ["uno", "mega"])
def test_end_to_end_pwl(board):
    """A proposed pwl (ramps through zero, a dwell, a coast-down) on the compiled firmware:
    the board plays the plan to one DAC step, and the motor follows."""
    exp = Experiment(name="proposed", waveform="pwl", lead_in_s=0.2,
                     points=[[0, 0.0], [0.5, 2.0], [0.9, 2.0], [1.0, 0.0], [1.4, 0.0],
                             [2.2, -1.5], [2.4, 0.0]])
    with Emulator(board, RIG) as emu, SerialBridge(emu.pty, RIG) as bridge:
        assert "pwl" in bridge.open()["capabilities"]
        idx, u, blocks = _run(bridge, exp)
        c = bridge.counters()
    assert c["dropped_samples"] == 0 and np.array_equal(idx, np.arange(exp.n_samples))
    assert np.max(np.abs(u - _plan(exp, idx))) <= 1.5 * LSB   # the plan, to a DAC step
    tacho = np.concatenate([b.tacho for b in blocks])
    assert tacho[1000:1100].mean() > 2.0 and tacho[2300:2400].mean() < -1.0


def test_a_closed_loop_pwl_plays_through_the_boards_loop():
    """A proposed closed-loop plan (``propose --loop closed``: position steps as the
    reference of the analog loop, kp 2, kv 0.15) on the compiled firmware: the board plays
    the reference to one DAC step and the loop takes the pot to it and back (the default
    rig hides no friction: no error band)."""
    exp = Experiment(name="proposed", loop="closed", waveform="pwl", lead_in_s=0.2,
                     points=[[0, 0.0], [0.01, 0.5], [1.5, 0.5], [1.51, 0.0], [3.0, 0.0]])
    rig = copy.deepcopy(RIG)   # the patch panel's knobs at the gains the run is made for
    rig.bridge.loop_kp, rig.bridge.loop_kv = exp.position_gain, exp.velocity_gain
    with Emulator("uno", rig) as emu, SerialBridge(emu.pty, rig) as bridge:
        idx, u, blocks = _run(bridge, exp)
        c = bridge.counters()
    assert c["dropped_samples"] == 0 and np.array_equal(idx, np.arange(exp.n_samples))
    assert np.max(np.abs(u - _plan(exp, idx))) <= 1.5 * LSB
    pos = np.concatenate([b.pos for b in blocks])
    start = pos[:150].mean()
    assert abs(pos[1500:1700].mean() - start - 0.5) < 0.05     # at the reference
    assert abs(pos[3000:3200].mean() - start) < 0.05           # and back


def test_board_refuses_a_pwl_beyond_its_table():
    points = [[0.01 * k, 0.5 * (-1) ** k] for k in range(40)]   # 40 > the board's 32
    with Emulator("uno", RIG) as emu, SerialBridge(emu.pty, RIG) as bridge:
        with pytest.raises(UserError, match="at most 32 pwl breakpoints"):
            bridge.configure(Experiment(name="long", waveform="pwl", points=points))


def test_refuses_beyond_output_limit():
    with Emulator("uno", RIG) as emu, SerialBridge(emu.pty, RIG) as bridge:
        with pytest.raises(UserError, match="2.5 V"):
            bridge.configure(Experiment(name="too_big", amplitude_v=3.0))


def test_link_faults_detected_counted_never_a_wrong_sample():
    exp = Experiment(name="sq_2.00V", amplitude_v=2.0, frequency_hz=1.0, lead_in_s=0.2, periods=2.5)
    with Emulator("uno", RIG) as emu:
        # both directions: lost commands are retried, lost samples counted
        with LinkProxy(emu.pty, b2h=(1 / 1500, 1 / 1500), h2b=(1 / 1500, 1 / 1500)) as proxy:
            with SerialBridge(proxy.path, RIG) as bridge:
                idx, u, _ = _run(bridge, exp)
                c = bridge.counters()
    assert proxy.total(proxy.faults, B2H) > 10
    assert c["crc_errors"] + c["framing_errors"] > 0
    assert c["dropped_samples"] == exp.n_samples - len(idx) > 0
    assert np.all(np.diff(idx) > 0)
    # every sample that got through is the one the board took: its DAC word is the plan's
    s = bridge_settings(RIG)
    want = np.array([volts_to_dac_word(v, s) for v in _plan(exp, idx)])
    got = np.rint((u + 5.0) / LSB)
    assert np.array_equal(got, want)


def test_silent_host_trips_watchdog_to_zero(tmp_path):
    log = tmp_path / "dac.log"
    exp = Experiment(name="hold", waveform="constant", amplitude_v=1.0, lead_in_s=0.0, duration_s=10.0)
    with Emulator("uno", RIG, dac_log=log) as emu, SerialBridge(emu.pty, RIG) as bridge:
        bridge.configure(exp)
        bridge.start()
        assert bridge.read() is not None
        time.sleep(1.5)                       # the host goes silent: no heartbeats
        with pytest.raises(RigError, match="WATCHDOG"):
            while bridge.read() is not None:
                pass
        bridge.stop()
        assert bridge.counters()["board_watchdog_trips"] == 1
    words = [int(line.split()[1]) for line in log.read_text().split("\n") if line.strip()]
    s = bridge_settings(RIG)
    assert volts_to_dac_word(1.0, s) in words
    assert words[-1] == volts_to_dac_word(0.0, s) == 2048


def test_board_vanishing_mid_stream_raises_rig_error():
    exp = Experiment(name="long", waveform="square", amplitude_v=1.0, frequency_hz=1.0, duration_s=20.0)
    emu = Emulator("uno", RIG)
    emu.start()
    try:
        bridge = SerialBridge(emu.pty, RIG)
        bridge.open()
        bridge.configure(exp)
        bridge.start()
        for _ in range(5):
            assert bridge.read() is not None
        emu.stop()                            # the board is unplugged
        t0 = time.monotonic()
        with pytest.raises(RigError) as err:
            while bridge.read(timeout=1.0) is not None:
                pass
        assert time.monotonic() - t0 < 5
        msg = str(err.value)
        assert ("no data from" in msg or "lost" in msg) and "\n" not in msg
        bridge.zero()                         # must not raise on a dead link
        bridge.close()
    finally:
        emu.stop()


def _sweep_past(port: str, plan: Path, folder: Path, run: str) -> subprocess.Popen:
    """`labrig sweep --port PORT --plan PLAN -o FOLDER` started in a subprocess (its
    output piped), returned once ``run`` is finished (its sidecar written; at most 30 s):
    the next run is then on its way."""
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "labrig", "sweep", "--port", port,
                             "--plan", str(plan), "-o", str(folder)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 30
    while time.time() < deadline and not (folder / f"{run}.json").exists():
        time.sleep(0.05)
    return proc


def test_cli_sweep_on_emulated_board_then_board_vanishes(tmp_path):
    """`labrig sweep --port` against the real firmware: runs that `labrig analyse` reads;
    the board vanishing mid-sweep gives exit 1, one clear line, and intact finished runs."""
    from labrig.io.runs import read_dataset

    plan = tmp_path / "plan.toml"
    plan.write_text("[defaults]\nlead_in_s = 0.3\n[[experiment]]\namplitudes_v = [1.2, 2.0, 2.5]\n"
                    "frequency_hz = 0.5\nperiods = 1\n")
    with Emulator("uno", speed=1.0) as emu:
        proc = _sweep_past(emu.pty, plan, tmp_path / "ds", "sq_2.00V")
        time.sleep(0.5)       # the third run is now streaming
        emu.stop()            # ... and the board disappears
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 1, err
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("labrig: error:")
    runs = read_dataset(tmp_path / "ds")
    assert [r.name for r in runs] == ["sq_1.20V", "sq_2.00V"]
    for r in runs:
        assert len(r) == 2300 and r.meta["bridge"]["dropped_samples"] == 0
        assert r.meta["source"] == "serial"
    # the finished runs are real data: the analyser reads them
    from labrig.analysis import analyse

    res = analyse([tmp_path / "ds"]).to_dict()
    assert res["km"] is not None and 80 < res["km"] < 115


def _first_run_kept_and_the_host_zeroed_the_board(folder: Path, log: Path, emu) -> dict:
    """A sweep of two runs (1.2 V, then 2.0 V) ended in its second: the first run whole in
    ``folder``, nothing half-written, the DAC's last word (``log``) mid-scale after the
    2 V run played; returns the board's status asked past its watchdog time (had the host
    not zeroed it, the board would have tripped)."""
    from labrig.io.runs import read_dataset

    runs = read_dataset(folder)
    assert [r.name for r in runs] == ["sq_1.20V"] and len(runs[0]) == 1600
    assert not [p for p in folder.iterdir() if p.suffix == ".tmp"]
    s = bridge_settings(RIG)
    words = [int(line.split()[1]) for line in log.read_text().split("\n") if line.strip()]
    assert volts_to_dac_word(2.0, s) in words and words[-1] == 2048
    time.sleep(0.5)
    with SerialBridge(emu.pty, RIG) as bridge:
        return bridge.board_status


def test_sigterm_mid_run_stops_the_board_at_zero(tmp_path, emulators):
    """Point 9 on the emulated board: SIGTERM by PID while a run streams -> exit 143, the
    finished run intact, and the host itself (not the watchdog) put the output at 0 V."""
    import signal

    log = tmp_path / "dac.log"
    plan = tmp_path / "plan.toml"
    plan.write_text("[defaults]\nlead_in_s = 0.1\n[[experiment]]\namplitudes_v = [1.2, 2.0]\n"
                    "frequency_hz = 1.0\nperiods = 1.5\n")
    emu = emulators("uno", dac_log=log, speed=1.0)   # real time: the bench's watchdog margin
    proc = _sweep_past(emu.pty, plan, tmp_path / "ds", "sq_1.20V")
    time.sleep(0.4)                       # the second run is streaming, output at +-2 V
    os.kill(proc.pid, signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == ("labrig: terminated by SIGTERM; finished runs "
                                            "are kept, the output is at 0 V")
    st = _first_run_kept_and_the_host_zeroed_the_board(tmp_path / "ds", log, emu)
    assert st["watchdog_trips"] == 0 and st["state"] in ("idle", "configured")
    assert st["dac_word"] == 2048


def test_a_full_disk_mid_sweep_on_the_board_leaves_it_at_zero(tmp_path, emulators):
    """The disk fills while the board's second run is written (files capped between the
    first run's size and the second's): exit 1 with one line naming the file, the first
    run whole, nothing half-written, and the host put the board's output at 0 V itself
    (its DAC's last word mid-scale, no watchdog trip)."""
    from test_sweep import GROWING_PLAN, _files_no_larger_than

    log = tmp_path / "dac.log"
    plan = tmp_path / "plan.toml"
    plan.write_text(GROWING_PLAN)
    emu = emulators("uno", dac_log=log, speed=1.0)
    r = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--port", emu.pty, "--plan",
                        str(plan), "-o", str(tmp_path / "ds")], capture_output=True, text=True,
                       timeout=120, preexec_fn=_files_no_larger_than(150_000))
    assert r.returncode == 1, r.stderr
    said = [x for x in r.stderr.strip().splitlines() if not x.startswith("wrote ")]
    assert len(said) == 1 and "sq_2.00V.csv: cannot be written" in said[0], r.stderr
    assert "the output is at 0 V" in said[0], said[0]
    st = _first_run_kept_and_the_host_zeroed_the_board(tmp_path / "ds", log, emu)
    assert st["watchdog_trips"] == 0 and st["dac_word"] == 2048


def test_emulator_ends_with_the_process_that_started_it():
    """Point 10: the emulator's parent is SIGKILLed (no cleanup runs) -> the emulator
    exits by itself (PR_SET_PDEATHSIG), found gone by its PID."""
    import signal
    import sys

    code = ("import sys, time\nfrom labrig.bridge.emulate import Emulator\n"
            "e = Emulator('uno')\ne.start()\nprint(e.proc.pid, flush=True)\ntime.sleep(60)\n")
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    emu_pid = None
    try:
        emu_pid = int(child.stdout.readline())
        assert _running(emu_pid)
        os.kill(child.pid, signal.SIGKILL)
        child.wait(5)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and _running(emu_pid):
            time.sleep(0.05)
        assert not _running(emu_pid)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        if emu_pid is not None and _running(emu_pid):
            os.kill(emu_pid, signal.SIGKILL)   # by the PID we recorded, never by name


def _running(pid: int) -> bool:
    """The process exists and is not a zombie waiting for a reaper."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_crc_residual_tool_measures_the_framing():
    """Point 8: the offline residual-rate tool (firmware/tools/crc_residual.c, documented
    in PROTOCOL.md) runs, is seeded, and measures what theory predicts on a short run."""
    import re

    r = _make("build/host/crc_residual")
    assert r.returncode == 0, r.stdout + r.stderr
    tool = str(FIRMWARE_DIR / "build" / "host" / "crc_residual")
    clean = subprocess.run([tool, "-p", "0", "-n", "20000"], capture_output=True, text=True)
    assert clean.returncode == 0 and "corrupted 0 " in clean.stdout
    runs = [subprocess.run([tool, "-p", "1e-2", "-n", "300000", "-s", "3"], capture_output=True,
                           text=True, timeout=60).stdout for _ in range(2)]
    assert runs[0] == runs[1]                       # seeded: the same numbers every time
    out = runs[0]
    corrupted = int(re.search(r"corrupted (\d+)", out).group(1))
    assert abs(corrupted / 300000 - (1 - 0.99 ** 91)) < 0.005   # 91-byte frames, p = 1e-2
    crc = int(re.search(r"passing crc\s*: (\d+)", out).group(1))
    body = int(re.search(r"passing body: (\d+)", out).group(1))
    assert crc <= 4 * corrupted / 65536 + 5 and body == 0
    assert "## Residual risk of CRC-16" in (FIRMWARE_DIR / "PROTOCOL.md").read_text()


def test_a_proposed_plan_plays_through_sweep_port(tmp_path):
    """`labrig propose` -> `labrig sweep --port` on the compiled firmware: the proposed pwl
    is played (to a DAC step) and its run carries the pair it was proposed for."""
    import json
    import sys

    from labrig.io.config import load_plan
    from labrig.io.runs import read_dataset
    from conftest import make_rig, sim_dataset

    step = [Experiment(name="step", waveform="step", amplitude_v=1.5, duration_s=3.0)]
    runs = sim_dataset(tmp_path, make_rig({"coulomb_friction": {"tc_v": 0.3}}), step)
    model = tmp_path / "m.json"
    subprocess.run([sys.executable, "-m", "labrig", "identify", str(runs), "--effects",
                    "deadband", "--starts", "2", "-o", str(model)], check=True,
                   capture_output=True)
    plan = tmp_path / "plan.toml"
    subprocess.run([sys.executable, "-m", "labrig", "propose", str(runs), "--model", str(model),
                    "-o", str(plan)], check=True, capture_output=True)
    with Emulator("uno", speed=1.0) as emu:
        proc = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--port", emu.pty,
                               "--plan", str(plan), "-o", str(tmp_path / "new")],
                              capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    run = read_dataset(tmp_path / "new")[0]
    exp = load_plan(plan)[0]
    assert run.meta["source"] == "serial" and run.experiment["between"] == exp.between
    assert np.max(np.abs(run.u - exp.waveform_at(run.t))) <= 1.5 * LSB
    assert json.loads(run.path.with_suffix(".json").read_text())["experiment"]["points"]


def test_the_ms150_board_trips_on_its_tacho_within_one_sample(tmp_path):
    """A speed limit of 150 rad/s and a 2 V step the motor takes past it: the board ends
    the run at the first sample whose tacho word passes the limit's (the host reads it as
    a trip, the samples up to it kept), and the DAC -- the MCP4822's own latched word --
    is back at 0 V within one sample period of that sample's tick."""
    from dataclasses import replace

    from labrig.bridge import trips

    rig = RigConfig()
    rig.bridge = replace(rig.bridge, trip_speed=150.0)
    log = tmp_path / "dac.log"
    exp = Experiment(name="step", waveform="constant", amplitude_v=2.0, lead_in_s=0.1,
                     duration_s=3.0)
    with Emulator("uno", rig, dac_log=log) as emu, SerialBridge(emu.pty, rig) as bridge:
        idx, u, blocks = _run(bridge, exp)
        trip = bridge.trip
        counters = bridge.counters()
    assert trip is not None and trip["fault"] == "TRIP" and trip["text"] == "over-speed", trip
    k = trip["after_sample"]
    assert idx[-1] == k and counters["trip"] == trip
    s = bridge_settings(rig)
    _, lo, hi, _, _ = trips.limits(exp, rig, s)
    tacho = trips.adc_words(np.concatenate([b.tacho for b in blocks]), "tacho", s)
    assert not lo <= tacho[-1] <= hi and ((tacho[:-1] >= lo) & (tacho[:-1] <= hi)).all()
    # the DAC log: (seconds, word) at each change of the latched word
    events = [(float(a), int(b)) for a, b in (line.split() for line in log.read_text().splitlines())]
    step_on = next(t for t, w in events if w == volts_to_dac_word(2.0, s))
    lead = int(round(exp.lead_in_s * exp.sample_rate_hz))
    tick_k = step_on + (k - lead) / exp.sample_rate_hz
    back = [t for t, w in events if t > step_on and w == 2048]
    assert back and tick_k - 1e-4 <= back[0] <= tick_k + 1.0 / exp.sample_rate_hz, (back[:1], tick_k)
    assert events[-1][1] == 2048


def test_a_hung_main_loop_is_reset_by_the_avrs_watchdog_to_0_v(tmp_path):
    """The test build's hang (message 0x7E: the main loop stops, the interrupts run on, so
    the output holds and no host-silence check runs): the AVR's own watchdog resets the
    chip within its 250 ms, the reset starts at 0 V, and the host takes the board's unasked
    greeting as the end of the run (recorded as a reset, the samples before it kept)."""
    from labrig.bridge import protocol as P

    log = tmp_path / "dac.log"
    exp = Experiment(name="hold", waveform="constant", amplitude_v=1.0, lead_in_s=0.0,
                     duration_s=10.0)
    s = bridge_settings(RIG)
    with Emulator("uno", RIG, dac_log=log, test_hooks=True) as emu, \
            SerialBridge(emu.pty, RIG) as bridge:
        bridge.configure(exp)
        bridge.start()
        for _ in range(5):
            assert bridge.read() is not None
        bridge.link.write(b"\x00" + P.encode_frame(0x7E, 0x55))
        while bridge.read(timeout=3.0) is not None:
            pass
        trip = bridge.trip
    assert trip is not None and trip["fault"] == "RESET", trip
    events = [(float(a), int(b)) for a, b in (line.split() for line in log.read_text().splitlines())]
    on = [t for t, w in events if w == volts_to_dac_word(1.0, s)]
    off = [t for t, w in events if on and t > on[0] and w == 2048]
    assert on and off, events
    # the last sample the host got came before the hang; the output went to 0 V within the
    # watchdog's 250 ms (its oscillator runs 10 % either way on a real chip) of it
    last = on[0] + (trip["after_sample"] + 1) / exp.sample_rate_hz
    print(f"0 V {1e3 * (off[0] - last):.0f} ms after the last sample the host got")
    assert off[0] - last < 0.25 * 1.1 + 0.05, (off[0], last)
