"""The MS150's loop, closed by the board or by the rig's patch panel: a closed-loop run means
on the emulated board what it means on the rig. The board closes it itself at each sample
from the pot and tacho its ADC reads (`closed_by = "board"`, the plan's gains); the analog
loop's gains are the rig file's patched knobs (`[bridge] loop_kp, loop_kv`), which the
emulator's patch panel takes as a real one has them; a plan's gains nothing applies are
refused, never recorded as applied; exercise 4's gain change changes the run as the sheet
says, either way. And the MS150 board stops itself as the H-bridge board does: at its
position window in a closed loop and at its E-stop, the DAC at 0 V within a sample."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from labrig.bridge.emulate import APT_PACKAGES, missing_tools

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.firmware,
              pytest.mark.skipif(bool(missing_tools()), reason=f"apt-get install {APT_PACKAGES}")]

#: exercise 4's gain step (its cl_gain.toml), without gains: the rig's patch gives them
CL_PLAN = """[defaults]
sample_rate_hz = 200.0
lead_in_s = 0.5

[[experiment]]
loop = "closed"
waveform = "square"
amplitudes_v = [0.3]
frequency_hz = 0.25
periods = 1
"""


def _labrig(*args):
    return subprocess.run([sys.executable, "-m", "labrig", *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def _rig(tmp_path, name, **bridge) -> Path:
    text = (ROOT / "configs" / "rig_default.toml").read_text()
    keys = "".join(f"{k} = {v}\n" for k, v in bridge.items())
    path = tmp_path / name
    path.write_text(text.replace("[bridge]\n", "[bridge]\n" + keys, 1))
    return path


def _error(csv: Path, rig_file: Path) -> tuple[float, float]:
    """The first step's steady-state error (pot volts short of the reference, last 0.5 s of
    the half period) and its 10-90 % rise time, from the recorded run (a loop the board
    closed records its reference in rad: times the pot's volts per rad)."""
    from labrig.io.config import load_rig

    d = pd.read_csv(csv)
    s = load_rig(rig_file).sensors
    pos = (d["pos"] - s.pos_offset_v).to_numpy()
    board = "drive" in d
    t, ref = d["t"].to_numpy(), d["u"].to_numpy() * (s.pos_v_per_rad if board else 1.0)
    first = (t > 0.5) & (t < 2.5)
    start = pos[(t > 0.3) & (t < 0.5)].mean()
    final = pos[first & (t > 2.0)].mean()
    step = ref[first][-1] - ref[t < 0.5][-1]
    move = (pos[first] - start) / (final - start)
    rise = t[first][np.argmax(move >= 0.9)] - t[first][np.argmax(move >= 0.1)]
    return abs(step - (final - start)) / abs(step), rise


def test_a_gain_change_on_the_patch_panel_changes_the_run_on_the_board(tmp_path):
    """Exercise 4, section 4, on the emulated board: the Kp knob at 2, then at 4 (the rig
    file says so each time); the plan is the same. At Kp 4 the loop is faster and the
    friction's error band narrower, as the sheet says; each run records the gains it was
    played at."""
    from labrig.bridge.emulate import Emulator
    from labrig.io.config import load_rig

    plan = tmp_path / "cl.toml"
    plan.write_text(CL_PLAN)
    out = {}
    for kp in (2.0, 4.0):
        rig_file = _rig(tmp_path, f"rig_kp{kp:g}.toml", loop_kp=kp, loop_kv=0.15)
        with Emulator("uno", load_rig(rig_file)) as emu:
            r = _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan", plan,
                        "-o", tmp_path / f"kp{kp:g}")
        assert r.returncode == 0, r.stderr
        side = json.loads((tmp_path / f"kp{kp:g}" / "cl_sq_0.30V.json").read_text())
        assert (side["experiment"]["position_gain"], side["experiment"]["velocity_gain"]) == (kp, 0.15)
        out[kp] = _error(tmp_path / f"kp{kp:g}" / "cl_sq_0.30V.csv", rig_file)
    (e2, rise2), (e4, rise4) = out[2.0], out[4.0]
    print(f"\nKp 2: error {100 * e2:.1f} %, rise {rise2:.3f} s; Kp 4: error {100 * e4:.1f} %, "
          f"rise {rise4:.3f} s")
    assert e4 < 0.6 * e2            # the band is tc_v / Kp: at least halved, as the sheet says
    assert rise4 < 0.8 * rise2      # and the loop is faster


def test_the_board_closes_the_loop_itself_and_a_gain_change_shows(tmp_path):
    """Exercise 4, section 4, closed by the board: the plan's Kp 2, then 4, on the default
    rig (no patch: the emulator's patch panel stays open, so the only loop is the board's,
    on the words its ADC reads from the plant's pins). At Kp 4 the loop is faster and the
    friction's band narrower, as on the patch panel; each run records the law the board
    ran; and the simulated rig plays the same plan to within a pot word."""
    from labrig.bridge.emulate import Emulator
    from labrig.io.config import load_rig

    rig_file = ROOT / "configs" / "rig_default.toml"
    out = {}
    for kp in (2.0, 4.0):
        plan = tmp_path / f"board_kp{kp:g}.toml"
        plan.write_text(CL_PLAN + f'closed_by = "board"\nposition_gain = {kp}\n'
                        "velocity_gain = 0.15\n")
        with Emulator("uno", load_rig(rig_file)) as emu:
            r = _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan", plan,
                        "-o", tmp_path / f"kp{kp:g}")
        assert r.returncode == 0, r.stderr
        side = json.loads((tmp_path / f"kp{kp:g}" / "cl_sq_0.30V.json").read_text())
        law = side["experiment"]["controller"]["sampled"]
        assert law["feedback"] == "sensors" and law["kp_q"] == int(2048 * kp)
        out[kp] = _error(tmp_path / f"kp{kp:g}" / "cl_sq_0.30V.csv", rig_file)
        if kp == 2.0:
            r = _labrig("sweep", "--sim", "--rig", rig_file, "--plan", plan, "-o", tmp_path / "sim")
            assert r.returncode == 0, r.stderr
            board, sim = (pd.read_csv(d / "cl_sq_0.30V.csv") for d in (tmp_path / "kp2", tmp_path / "sim"))
            gap = np.sqrt(np.mean((board["pos"] - sim["pos"]) ** 2))
            print(f"\nboard against simulated rig: pot rms {1000 * gap:.1f} mV (a word is 19.5 mV)")
            assert gap < 0.0195
    (e2, rise2), (e4, rise4) = out[2.0], out[4.0]
    print(f"board's loop: Kp 2: error {100 * e2:.1f} %, rise {rise2:.3f} s; Kp 4: error "
          f"{100 * e4:.1f} %, rise {rise4:.3f} s")
    assert e4 < 0.6 * e2
    assert rise4 < 0.8 * rise2


def test_gains_nothing_applies_are_refused_before_anything_plays(tmp_path):
    """On the board: a closed-loop plan with a rig file that says nothing of its patch, a
    plan whose gains differ from the patched ones, a plan mixing open and closed runs (the
    patch differs): each one line, exit 2, no run written."""
    from labrig.bridge.emulate import Emulator
    from labrig.io.config import load_rig

    plan = tmp_path / "cl.toml"
    plan.write_text(CL_PLAN)
    asks4 = tmp_path / "kp4.toml"
    asks4.write_text(CL_PLAN + "position_gain = 4.0\nvelocity_gain = 0.15\n")
    mixed = tmp_path / "mixed.toml"
    mixed.write_text(CL_PLAN + '\n[[experiment]]\nloop = "open"\nwaveform = "step"\n'
                     'amplitudes_v = [1.0]\nduration_s = 1.0\n')
    patched = _rig(tmp_path, "rig_kp2.toml", loop_kp=2.0, loop_kv=0.15)
    default = ROOT / "configs" / "rig_default.toml"
    # (a closed loop that names no closer on a rig that names no patch is the board's on
    # this firmware: test_the_design_cards_sweep_plays_the_default_plan_on_a_fresh_board;
    # on a board that cannot close it, refused: test_sweep's the_rigs_way tests)
    cases = [(patched, asks4, "position_gain = 4, but the rig's loop is patched at 2"),
             (patched, mixed, "mixes runs through the rig's analog loop")]
    with Emulator("uno", load_rig(patched)) as emu:
        for k, (rig_file, plan_file, words) in enumerate(cases):
            r = _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan", plan_file,
                        "-o", tmp_path / f"out{k}")
            assert r.returncode == 2 and words in r.stderr, r.stderr
            assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
            assert not list((tmp_path / f"out{k}").glob("*.csv"))


def test_the_design_cards_sweep_plays_the_default_plan_on_a_fresh_board(tmp_path):
    """`labrig sweep --port PORT -o DIR` as the design card writes it (the default rig and
    plan) on a freshly flashed Uno: every run plays, the closed-loop steps closed by the
    board at the plan's gains (its firmware closes loops; the rig file names no patch) and
    recorded so, the position following each step (within a quarter of it: the friction's
    band at Kp 2 is what test_the_board_closes_the_loop_itself_and_a_gain_change_shows
    measures); then `labrig identify DIR` fits the runs."""
    from labrig.bridge.emulate import Emulator
    from labrig.io.config import load_plan, load_rig

    rig = load_rig(ROOT / "configs" / "rig_default.toml")
    with Emulator("uno", rig) as emu:
        r = _labrig("sweep", "--port", emu.pty, "-o", tmp_path / "runs")
    assert r.returncode == 0, r.stderr
    plan = load_plan(None, rig)
    assert sorted(p.stem for p in (tmp_path / "runs").glob("*.csv")) == sorted(e.name for e in plan)
    closed = [e for e in plan if e.loop == "closed"]
    assert len(closed) == 2
    for e in closed:
        meta = json.loads((tmp_path / "runs" / f"{e.name}.json").read_text())
        assert meta["experiment"]["closed_by"] == "board", meta["experiment"]
        assert meta["experiment"]["position_gain"] == e.position_gain
        d = pd.read_csv(tmp_path / "runs" / f"{e.name}.csv")
        pos = (d["pos"] - rig.sensors.pos_offset_v) / rig.sensors.pos_v_per_rad
        t = d["t"].to_numpy()
        held = (t > e.lead_in_s + 1.5) & (t < e.lead_in_s + 2.0)   # late in the first half period
        ref = d["u"].to_numpy()[held].mean()
        assert abs(ref) > 0.1 and pos[held].mean() == pytest.approx(ref, rel=0.25), e.name
    fit = _labrig("identify", tmp_path / "runs", "-o", tmp_path / "m.json")
    assert fit.returncode == 0, fit.stderr
    assert json.loads((tmp_path / "m.json").read_text())["params"]["R"] > 0


def test_the_simulated_rig_takes_the_patched_gains_too(tmp_path):
    """The same rig file on the simulated rig: a plan without gains plays at the patch's,
    one asking for others is refused as on the board."""
    patched = _rig(tmp_path, "rig_kp4.toml", loop_kp=4.0, loop_kv=0.15)
    plan = tmp_path / "cl.toml"
    plan.write_text(CL_PLAN)
    r = _labrig("sweep", "--sim", "--rig", patched, "--plan", plan, "-o", tmp_path / "sim")
    assert r.returncode == 0, r.stderr
    side = json.loads((tmp_path / "sim" / "cl_sq_0.30V.json").read_text())
    assert side["experiment"]["position_gain"] == 4.0
    asks2 = tmp_path / "kp2.toml"
    asks2.write_text(CL_PLAN + "position_gain = 2.0\n")
    r = _labrig("sweep", "--sim", "--rig", patched, "--plan", asks2, "-o", tmp_path / "sim2")
    assert r.returncode == 2 and "patched at 4" in r.stderr, r.stderr


@pytest.mark.parametrize("base, keys, words", [
    ("rig_arduino_hbridge.toml", {"loop_kp": 2.0, "loop_kv": 0.1},
     "key 'bridge.loop_kp': the hbridge board closes its loop itself"),
    ("rig_default.toml", {"loop_kp": 2.0}, "key 'bridge.loop_kp' without 'bridge.loop_kv'"),
    ("rig_default.toml", {"loop_kp": -1.0, "loop_kv": 0.1}, "loop_kp"),
])
def test_a_patched_loop_the_rig_cannot_have_is_refused(tmp_path, base, keys, words):
    text = (ROOT / "configs" / base).read_text()
    rig = tmp_path / "rig.toml"
    rig.write_text(text.replace("[bridge]\n", "[bridge]\n" + "".join(
        f"{k} = {v}\n" for k, v in keys.items()), 1))
    r = _labrig("sweep", "--sim", "--rig", rig, "-o", tmp_path / "x")
    assert r.returncode == 2 and words in r.stderr and "Traceback" not in r.stderr, r.stderr


def _dac_events(log: Path) -> list[tuple[float, int]]:
    """The emulator's DAC log: (seconds, word) at each change of the MCP4822's latched word."""
    return [(float(a), int(b)) for a, b in (line.split() for line in log.read_text().splitlines())]


def test_the_ms150_board_trips_at_its_position_window_in_its_own_loop(tmp_path):
    """The position window on the MS150 (firmware's pot words, closed-loop runs only): the
    board's own loop asked for a 1.6 rad step against a window of +-1 rad; the board ends the
    run at the first sample whose pot word leaves the window, the DAC back at 0 V within one
    sample period, the run kept up to there and recorded as tripped; the sweep exits 1."""
    from labrig.bridge import trips
    from labrig.bridge.emulate import Emulator
    from labrig.bridge.serial import bridge_settings
    from labrig.io.config import load_rig
    from labrig.io.experiment import Experiment

    rig_file = _rig(tmp_path, "rig_window.toml", trip_position="[-1.0, 1.0]")
    rig = load_rig(rig_file)
    plan = tmp_path / "board.toml"
    plan.write_text(CL_PLAN.replace("[0.3]", "[0.8]") + 'closed_by = "board"\n'
                    "position_gain = 2.0\nvelocity_gain = 0.15\n")
    log = tmp_path / "dac.log"
    with Emulator("uno", rig, dac_log=log) as emu:
        r = _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan", plan,
                    "-o", tmp_path / "runs")
    assert r.returncode == 1 and "(position limit)" in r.stderr, r.stderr
    side = json.loads((tmp_path / "runs" / "cl_sq_0.80V.json").read_text())
    trip = side["bridge"]["trip"]
    assert trip["fault"] == "TRIP" and trip["text"] == "position limit", trip
    k = trip["after_sample"]
    d = pd.read_csv(tmp_path / "runs" / "cl_sq_0.80V.csv")
    s = bridge_settings(rig)
    _, _, _, lo, hi = trips.limits(Experiment(name="w", loop="closed"), rig, s)
    words = trips.adc_words(d["pos"].to_numpy()[:k + 1], "pos", s)
    assert not lo <= words[-1] <= hi and ((words[:-1] >= lo) & (words[:-1] <= hi)).all(), \
        (words[-3:], lo, hi)
    assert (d["gap"].iloc[k + 1:] == 1).all() and (d["gap"].iloc[:k + 1] == 0).all()  # never taken
    events = _dac_events(log)
    driven = [t for t, w in events if w != 2048]
    back = [t for t, w in events if driven and t > driven[0] and w == 2048]
    rate = 200.0    # the plan's
    # the tripping sample's tick, counted from the board's first drive (the lead-in's
    # reference holds the shaft, so the first word off 2048 is at most a tick after START)
    tick_k = driven[0] + (k + 1) / rate
    assert back and back[0] <= tick_k + 1.0 / rate + 1e-3, (back[:1], tick_k)
    assert events[-1][1] == 2048


def test_the_ms150_board_stops_at_its_estop_and_latches(tmp_path):
    """The E-stop on the MS150 (D7, normally closed to GND), opened 0.5 s after the board
    first drives: the DAC at 0 V from the next sample on, the run kept and recorded as an
    E-stop, the sweep exits 1; another sweep while it stays open is refused by the board."""
    from labrig.bridge.emulate import Emulator
    from labrig.io.config import load_rig

    rig_file = _rig(tmp_path, "rig_estop.toml", estop="true")
    plan = tmp_path / "step.toml"
    plan.write_text('[defaults]\nsample_rate_hz = 200.0\nlead_in_s = 0.2\n\n[[experiment]]\n'
                    'loop = "open"\nwaveform = "step"\namplitudes_v = [1.0]\nduration_s = 2.0\n')
    log = tmp_path / "dac.log"
    with Emulator("uno", load_rig(rig_file), dac_log=log, extra_args=("--estop-at", "0.5")) as emu:
        r = _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan", plan,
                    "-o", tmp_path / "runs")
        again = _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan", plan,
                        "-o", tmp_path / "again")
    assert r.returncode == 1 and "(E-stop)" in r.stderr, r.stderr
    (side,) = [json.loads(p.read_text()) for p in (tmp_path / "runs").glob("*.json")]
    assert side["bridge"]["trip"]["text"] == "E-stop"
    events = _dac_events(log)
    first = next(t for t, w in events if w != 2048)
    off = [t for t, w in events if t > first and w == 2048]
    assert off and first + 0.5 - 1e-3 <= off[0] <= first + 0.5 + 1.0 / 200.0 + 1e-3, (first, off[:1])
    assert all(w == 2048 for t, w in events if t >= off[0])
    assert again.returncode == 1 and "E-stop latched" in again.stderr, again.stderr
    assert not list((tmp_path / "again").glob("*.csv"))
