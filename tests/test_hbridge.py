"""The bench a lab owns: an Arduino, an H-bridge and an encoder gear motor, played live.

The real H-bridge firmware (``make -C firmware RIG=hbridge``) runs under simavr against the
harness's motor plant (``firmware/emulator/motor.c``: it reads Timer1's registers and PORTB
as the chip drives them and moves the encoder's pins at the step the shaft crosses an
edge; it shares no code with labrig's simulator). A sweep goes through ``labrig sweep
--port`` over the emulator's pty; every sample is accounted for, the board's counts are
the plant's angle within one count, the bridge's duty is what the plan commanded, and
``diagnose --auto`` finds the plant's hidden dead zone and friction.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from labrig.bridge import hbridge
from labrig.bridge.emulate import APT_PACKAGES, FIRMWARE_DIR, Emulator, firmware_make, missing_tools
from labrig.io.config import load_rig
from test_hbridge_rig import board_loop_plan, position_window_trip

_missing = missing_tools()
pytestmark = [
    pytest.mark.firmware,
    pytest.mark.skipif(bool(_missing), reason=f"firmware toolchain missing ({', '.join(_missing)}): "
                                              f"apt-get install {APT_PACKAGES}"),
]

ROOT = Path(__file__).resolve().parents[1]
RIG_FILE = ROOT / "configs" / "rig_arduino_hbridge.toml"
PLAN = ROOT / "configs" / "plan_arduino.toml"
#: the hidden plant of the loop's test: a bridge dead zone wider in reverse and Coulomb
#: friction at the motor (what the harness models physically; the rig file's own
#: hidden effects are replaced)
HIDDEN = {"asymmetric_deadband": {"dpos_v": 1.0, "dneg_v": 1.6}, "coulomb_friction": {"tc_v": 0.8}}


def _labrig(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "labrig", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


def _swept(r) -> None:
    """A sweep on the emulated board finished: exit 0, or exit 1 for samples lost on the
    link beyond the rig's tolerance (a machine too busy for the real-time board: the runs
    are written with the losses as gaps, which no fit takes as measured); said, not
    silent."""
    if r.returncode == 1 and "max_lost_fraction" in r.stderr:
        print(f"\nlost on a busy machine (runs kept, gaps flagged): {r.stderr.splitlines()[-1]}")
        return
    assert r.returncode == 0, r.stderr


def _sweep_on_board(rig_file, plan, out, *, board="uno", plant=None, **emulator_kw):
    """``labrig sweep --port`` of ``plan`` on the emulated ``board`` whose plant is the rig
    file's (or ``plant``); ``emulator_kw`` goes to :class:`Emulator`."""
    with Emulator(board, plant if plant is not None else load_rig(rig_file), **emulator_kw) as emu:
        return _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan", plan, "-o", out)


def _rig_with(tmp_path: Path, effects: dict, **bridge) -> Path:
    """The shipped H-bridge rig file with other hidden effects (and [bridge] keys)."""
    text = RIG_FILE.read_text().split("[effects.")[0]
    for key, value in bridge.items():
        toml = ("{" + ", ".join(f"{k} = {json.dumps(v)}" for k, v in value.items()) + "}"
                if isinstance(value, dict) else json.dumps(value))
        if re.search(rf"^{key} = ", text, flags=re.M):
            text = re.sub(rf"^{key} = .*$", f"{key} = {toml}", text, flags=re.M)
        else:
            text = text.replace("[bridge]\n", f"[bridge]\n{key} = {toml}\n", 1)
    for name, params in effects.items():
        text += f"[effects.{name}]\n" + "".join(f"{k} = {v}\n" for k, v in params.items()) + "\n"
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("board", ["uno", "nano", "mega"])
def test_the_hbridge_firmware_builds_for_each_board(board):
    r = firmware_make(board, *hbridge.make_options(load_rig(RIG_FILE)), timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert re.search(rf"{board}: flash \d+ of", r.stdout)
    assert "warning" not in (r.stdout + r.stderr).lower()
    assert (FIRMWARE_DIR / "build" / hbridge.build_folder(load_rig(RIG_FILE)) / board
            / "labrig_bridge.hex").exists()


def _edges(log: Path):
    """The harness's log: sample-clock starts, encoder edges (cycle, edge), duty changes."""
    starts, edge_c, edge_v, duty = [], [0], [0], []
    for line in log.read_text().splitlines():
        kind, *v = line.split()
        if kind == "T":
            starts.append(int(v[0]))
        elif kind == "E":
            edge_c.append(int(v[0]))
            edge_v.append(int(v[1]))
        elif kind == "D":
            duty.append((int(v[0]), int(v[1])))
    return starts, np.array(edge_c), np.array(edge_v), duty


@pytest.fixture(scope="module")
def played(tmp_path_factory):
    """The design card's command on the emulated board: ``labrig sweep --port PORT --rig
    RIG -o DIR`` with no plan plays the H-bridge family's default, the shipped PLAN."""
    tmp = tmp_path_factory.mktemp("hbridge")
    rig_file = _rig_with(tmp, HIDDEN)
    log = tmp / "emu.log"
    with Emulator("uno", load_rig(rig_file), dac_log=log) as emu:
        r = _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "-o", tmp / "runs")
        lag = emu.behind_s()
    assert r.returncode == 0, r.stderr
    return {"runs": tmp / "runs", "rig": rig_file, "log": log, "lag": lag}


def test_a_sweep_plays_with_every_sample_counted_and_the_counts_of_the_shaft(played):
    rig = load_rig(played["rig"])
    starts, edge_c, edge_v, duty = _edges(played["log"])
    names = sorted(played["runs"].glob("*.csv"), key=lambda p: float(p.stem[3:-1]))
    assert len(names) == 5 and len(starts) == 5
    for csv, start in zip(names, starts):
        meta = json.loads(csv.with_suffix(".json").read_text())
        d = pd.read_csv(csv)
        assert "gap" not in d and meta["bridge"]["dropped_samples"] == 0
        assert meta["bridge"]["board_sample_overruns"] == 0
        assert meta["bridge"]["firmware"].endswith("uno hbridge")
        assert meta["sensors"]["pos_kind"] == "encoder"
        # sample k is read at the (k+1)-th division of the 10 kHz clock after START
        # (1600 cycles of 16 MHz each); the plant's edge index then, against the board's count
        div = hbridge.TIMER_HZ // int(rig.bridge.sample_rate_hz)
        at = start + (np.arange(len(d)) + 1) * div * 1600
        truth = edge_v[np.searchsorted(edge_c, at, side="right") - 1]
        assert np.abs(d["pos"].to_numpy() - truth).max() <= 1, csv.name
        assert np.ptp(d["pos"]) > 500   # the shaft really turned
    # the bridge's duty, as the chip's registers set it, is the plan's: every duty held
    # longer than one PWM period (256 cycles) is a level of some run, in timer counts
    held = {v for (c0, v), (c1, _) in zip(duty, duty[1:]) if c1 - c0 > 256}
    levels = set()
    for csv in names:
        levels |= {int(round(u / 12.0 * 256)) for u in pd.read_csv(csv)["u"].unique()}
    assert held <= levels and len(held) >= 8, (held, levels)


@pytest.fixture(scope="module")
def diagnosed(played):
    out = played["runs"].parent / "diagnosis"
    r = _labrig("diagnose", "--auto", played["runs"], "--json", "-o", out)
    assert r.returncode == 0, r.stderr
    return {"json": json.loads(r.stdout), "model": out / "model.json"}


def test_diagnose_auto_finds_the_hidden_dead_zone_and_friction(diagnosed):
    final = diagnosed["json"]["final_model"]
    assert set(final["effects"]) == {"asymmetric_deadband", "coulomb_friction"}
    dz, fr = final["effect_params"]["asymmetric_deadband"], final["effect_params"]["coulomb_friction"]
    # within 10 % of the hidden values (one PWM count is 47 mV; the data resolve a few of them)
    assert dz["dpos_v"] == pytest.approx(1.0, rel=0.1)
    assert dz["dneg_v"] == pytest.approx(1.6, rel=0.1)
    assert fr["tc_v"] == pytest.approx(0.8, rel=0.1)
    # near the floor, not at it: 1.31 in a run by hand, 2.52 in a CI firmware stage on the
    # same plant (complete runs, no lost sample; the runs start where the previous one left
    # the shaft, and the fit's end moved with them: not understood yet)
    assert final["rmse_over_noise"]["overall"] < 3.0


def test_a_proposed_experiment_plays_on_the_board(played, diagnosed, tmp_path):
    plan = tmp_path / "proposed.toml"
    r = _labrig("propose", played["runs"], "--model", diagnosed["model"], "--rig", played["rig"],
                "-o", plan)
    assert r.returncode == 0, r.stderr
    with Emulator("uno", load_rig(played["rig"])) as emu:
        r = _labrig("sweep", "--port", emu.pty, "--rig", played["rig"], "--plan", plan,
                    "-o", tmp_path / "next")
    assert r.returncode == 0, r.stderr
    runs = sorted((tmp_path / "next").glob("*.json"))
    assert runs
    for run in runs:
        meta = json.loads(run.read_text())
        assert meta["bridge"]["dropped_samples"] == 0
        assert meta["bridge"]["firmware"].endswith("hbridge")
        assert meta["experiment"]["waveform"] == "pwl"
        d = pd.read_csv(run.with_suffix(".csv"))
        assert np.ptp(d["pos"]) > 100   # the ramp turned the shaft


def test_a_board_flashed_for_the_other_rig_is_named_and_nothing_plays(tmp_path):
    """The MS150 bridge's firmware on the port, an H-bridge rig file: exit 1, one line
    that says which firmware the board runs and how to flash the right one."""
    with Emulator("uno") as emu:
        r = _labrig("sweep", "--port", emu.pty, "--rig", RIG_FILE, "--plan", PLAN, "-o", tmp_path / "r")
    assert r.returncode == 1
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1, line
    assert "runs the ms150 firmware" in line and f"labrig flash --board uno --rig {RIG_FILE}" in line
    assert not list((tmp_path / "r").glob("*.csv")) if (tmp_path / "r").exists() else True


def test_a_board_other_than_the_rig_files_is_named_and_nothing_plays(tmp_path):
    """The H-bridge firmware on an emulated Mega, the shipped rig file's bench an Uno
    (bridge.board): exit 1, one line naming both boards, no run written."""
    r = _sweep_on_board(RIG_FILE, PLAN, tmp_path / "r", board="mega")
    assert r.returncode == 1, r.stderr
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1, line
    assert "is a Mega 2560" in line and "built on an Uno" in line, line
    assert not (tmp_path / "r").exists() or not list((tmp_path / "r").glob("*.csv"))


def test_the_lab_station_plays_and_fits_on_the_emulated_hbridge_board(tmp_path):
    """``labrig lab --emulate --rig configs/rig_arduino_hbridge.toml``: the station builds the
    H-bridge firmware, plays a run on it and fits the linear model to it."""
    import time

    from labrig.io.config import load_plan
    from labrig.lab.serve import make_station

    st = make_station(tmp_path, rig_path=RIG_FILE, emulate=True)
    try:
        st.start_sweep(load_plan(PLAN, st.rig)[2:3])   # the 6 V square wave
        t0 = time.monotonic()
        while not st.runs_on_disk() or st.busy():
            assert time.monotonic() - t0 < 120, "the sweep did not finish"
            st.poll()
            time.sleep(0.05)
        assert st.runs_on_disk() == ["sq_6.00V"]
        meta = json.loads(next(tmp_path.rglob("sq_6.00V.json")).read_text())
        assert meta["bridge"]["firmware"].endswith("hbridge")
        # every sample accounted for: received or counted lost and flagged (one frame of 10
        # was lost once in a CI firmware stage, beside the station's own jobs; the run keeps
        # its length and its gap rows say where)
        b = meta["bridge"]
        d = pd.read_csv(next(tmp_path.rglob("sq_6.00V.csv")))
        assert b["samples"] + b["dropped_samples"] == len(d) == 900
        assert int(d["gap"].sum()) == b["dropped_samples"] if "gap" in d else b["dropped_samples"] == 0
        st.fit_linear()
        while not st.rungs or st.busy():
            assert time.monotonic() - t0 < 300, "the fit did not finish"
            st.poll()
            time.sleep(0.05)
        assert st.rungs[0]["runs"] == ["sq_6.00V"]
    finally:
        st.close()


def test_diagnose_auto_finds_the_gears_play_seen_by_an_output_shaft_encoder(tmp_path):
    """With the gear's play hidden, the emulated encoder sits on the output shaft (the
    play is invisible to a motor-shaft encoder): the loop finds the dead zone and the play."""
    rig_file = _rig_with(tmp_path, {"asymmetric_deadband": {"dpos_v": 1.0, "dneg_v": 1.6},
                                    "backlash": {"a_rad": 0.03}})
    _swept(_labrig("sweep", "--emulate", "--rig", rig_file, "--plan", PLAN, "-o",
                   tmp_path / "runs"))
    r = _labrig("diagnose", "--auto", tmp_path / "runs", "--json")
    assert r.returncode == 0, r.stderr
    final = json.loads(r.stdout)["final_model"]
    assert set(final["effects"]) == {"asymmetric_deadband", "backlash"}
    assert final["effect_params"]["backlash"]["a_rad"] == pytest.approx(0.03, rel=0.1)
    dz = final["effect_params"]["asymmetric_deadband"]
    assert (dz["dpos_v"], dz["dneg_v"]) == (pytest.approx(1.0, rel=0.1), pytest.approx(1.6, rel=0.1))
    assert final["rmse_over_noise"]["overall"] < 2.0


def test_a_closed_loop_plan_runs_the_boards_own_pd_and_the_plant_is_fitted_through_it(tmp_path):
    """A position plan in closed loop: the board computes a PD on its count at every sample
    with the plan's gains (kp V/rad, kd V per rad/s, in its Q8.8 units), and the output it
    records is exactly that law applied to the recorded counts and references; the shaft
    follows the reference; the plant is then fitted from the logged output."""
    from labrig.bridge.settings import bridge_settings, pd_gain_words, pd_output
    from labrig.io.config import load_plan

    plan = tmp_path / "plan.toml"
    plan.write_text('[[experiment]]\nname = "pd_3rad"\nloop = "closed"\nwaveform = "square"\n'
                    'amplitude_v = 3.0\nfrequency_hz = 0.5\nperiods = 2\nsample_rate_hz = 200.0\n'
                    'lead_in_s = 0.5\nposition_gain = 10.0\nvelocity_gain = 0.3\n')
    r = _labrig("sweep", "--emulate", "--rig", RIG_FILE, "--plan", plan, "-o", tmp_path / "runs")
    assert r.returncode == 0, r.stderr
    rig = load_rig(RIG_FILE)
    s = bridge_settings(rig)
    d = pd.read_csv(tmp_path / "runs" / "pd_3rad.csv")
    meta = json.loads((tmp_path / "runs" / "pd_3rad.json").read_text())
    kp_q, kd_q = pd_gain_words(load_plan(plan, rig)[0], s)
    # the board's own law is on record, for the model to run the same (one output count is
    # 12 V / 256; the word's limits +-255 counts)
    assert meta["experiment"]["controller"] == {
        "kind": "pd", "kp": 10.0, "kd": 0.3, "ki": 0.0, "feedback": "position",
        "sampled": {"kp_q": kp_q, "kd_q": kd_q, "counts_per_unit": s.counts_per_unit,
                    "volts_per_count": 12.0 / 256, "limits": [-255, 255]}}
    ref = np.round(d["u"].to_numpy() * s.counts_per_unit).astype(int)   # counts from the start
    x = d["pos"].to_numpy().astype(int) - int(d["pos"][0])
    law = np.clip(pd_output(kp_q, kd_q, ref, x), -255, 255) * 12.0 / 256
    # to the file's digits: one output count is 47 mV
    assert np.abs(d["drive"].to_numpy() - law).max() < 1e-4
    # the shaft follows: within 15 counts (0.07 rad) of +-3 rad at the end of each half period
    ends = np.nonzero(np.diff(ref) != 0)[0]
    assert len(ends) >= 3
    assert np.abs(x[ends[1:]] - ref[ends[1:]]).max() <= 15
    r = _labrig("identify", tmp_path / "runs", "--effects", "asymmetric_deadband", "--json")
    assert r.returncode == 0, r.stderr
    fit = json.loads(r.stdout)
    assert fit["effect_params"]["asymmetric_deadband"]["dpos_v"] == pytest.approx(1.5, rel=0.05)
    assert fit["effect_params"]["asymmetric_deadband"]["dneg_v"] == pytest.approx(2.1, rel=0.05)


@pytest.fixture(scope="module")
def board_loop(tmp_path_factory):
    """Two open-loop squares and a closed-loop run of the board's own PD (kp 10 V/rad, kd
    0.3 V per rad/s at 200 Hz) on the emulated board, dead zone and friction hidden."""
    tmp_path = tmp_path_factory.mktemp("board_loop")
    rig_file = _rig_with(tmp_path, HIDDEN)
    plan = board_loop_plan(tmp_path)
    runs = tmp_path / "runs"
    _swept(_labrig("sweep", "--emulate", "--rig", rig_file, "--plan", plan, "-o", runs))
    return {"runs": runs, "rig": rig_file, "tmp": tmp_path}


def test_the_model_runs_the_boards_own_loop_on_its_own_count(board_loop, tmp_path):
    """Two open-loop squares and a closed-loop run of the board's PD (kp 10 V/rad, kd 0.3
    V per rad/s at 200 Hz), dead zone and Coulomb friction hidden. The run's sidecar holds
    the board's law; the model runs it sample by sample on its own count (held output,
    one-count position, one-sample difference, the word's clamp):
    - fitted through the loop, the drive at which the shaft moves each way (dead zone plus
      friction, what a threshold in a loop shows) within 3 % (their split wanders by 10 %
      between sweeps: both stop the loop short);
    - the model fitted from the logged output, run through the loop, follows the run to
      within twice the error band the dead zone leaves the loop (d / kp: the board and
      the model may each stop anywhere in the band, at its two edges at worst; where they
      stop is as sensitive as a real loop's: 4-12 counts rms against a band of 21 in most
      recordings, once 22.6 in a full suite's run), where a continuous PD with the same
      gains (the sidecar without its law) is off by 8 bands (179 counts rms, measured)."""
    runs, rig_file = board_loop["runs"], board_loop["rig"]
    effects = ("--effects", "asymmetric_deadband,coulomb_friction")
    r = _labrig("identify", runs, *effects, "--through", "loop", "--json")
    assert r.returncode == 0, r.stderr
    fit = json.loads(r.stdout)["effect_params"]
    dz = HIDDEN["asymmetric_deadband"]
    print("through the loop:", fit)
    tc = fit["coulomb_friction"]["tc_v"]
    assert fit["asymmetric_deadband"]["dpos_v"] + tc == pytest.approx(dz["dpos_v"] + 0.8, rel=0.03)
    assert fit["asymmetric_deadband"]["dneg_v"] + tc == pytest.approx(dz["dneg_v"] + 0.8, rel=0.03)

    r = _labrig("identify", runs, *effects, "-o", tmp_path / "m.json")   # from the output
    assert r.returncode == 0, r.stderr
    cont = tmp_path / "continuous"
    cont.mkdir()
    for f in runs.iterdir():
        (cont / f.name).write_bytes(f.read_bytes())
    side = json.loads((cont / "pd_3rad.json").read_text())
    side["experiment"]["controller"].pop("sampled")
    (cont / "pd_3rad.json").write_text(json.dumps(side))
    cpu = load_rig(rig_file).sensors.encoder_counts_per_unit
    d = pd.read_csv(cont / "pd_3rad.csv")   # (its reference from where the count stood)
    d["u"] += d["pos"][0] / cpu
    d.to_csv(cont / "pd_3rad.csv", index=False)
    from labrig.io.runs import read_dataset
    from labrig.model.model import Model
    model = Model.load(tmp_path / "m.json")
    band = dz["dpos_v"] / 10.0 * cpu   # counts: where the loop may stop short
    for folder, most in ((runs, 2 * band), (cont, None)):
        run = next(r for r in read_dataset(folder) if r.name == "pd_3rad")
        sim = model.simulate([run])[0]
        err = np.sqrt(np.mean((sim["theta"] - run.position) ** 2)) * cpu   # counts rms
        print(folder.name, f"rms {err:.1f} counts; band {band:.1f}")
        if most:
            assert err < most, (err, most)
        else:
            assert err > 4 * band, err


def test_a_proposal_through_the_boards_own_loop_plays_on_the_board(board_loop, tmp_path):
    """With a closed-loop run of the board in the data, `propose --loop closed` plans
    position steps through the board's loop (references in rad from the start, the run's
    gains), simulated as the board runs them, to tell the hidden Coulomb friction from a
    delay (through the loop friction brakes each step short, a delay shifts it); the plan
    plays on the emulated board, its run records the same law, and the diagnosis that reads
    it puts the friction ahead of the delay. (Against stiction the order depends on the
    sweep: with no excess hidden, stiction at zero excess is the friction.)"""
    runs, rig_file = board_loop["runs"], board_loop["rig"]
    model = tmp_path / "m.json"
    assert _labrig("identify", runs, "--effects", "asymmetric_deadband", "-o", model).returncode == 0
    plan = tmp_path / "p.toml"
    r = _labrig("propose", runs, "--model", model, "--between", "coulomb_friction,delay",
                "--loop", "closed", "--budget-s", "20", "-o", plan)
    assert r.returncode == 0, r.stderr
    assert "through the board's loop (kp 10)" in r.stdout and " rad " in r.stdout
    exp = tomllib.loads(plan.read_text())["experiment"][0]
    assert (exp["loop"], exp["position_gain"], exp["velocity_gain"]) == ("closed", 10.0, 0.3)
    _swept(_labrig("sweep", "--emulate", "--rig", rig_file, "--plan", plan, "-o", tmp_path / "new"))
    played = json.loads((tmp_path / "new" / "proposed.json").read_text())["experiment"]
    board = json.loads((runs / "pd_3rad.json").read_text())["experiment"]["controller"]
    assert played["controller"]["sampled"] == board["sampled"]
    r = _labrig("diagnose", runs, tmp_path / "new", "--model", model, "--json")
    assert r.returncode == 0, r.stderr
    ranked = json.loads(r.stdout)["ranking"]
    # the pair the run was proposed for is told apart: the friction, not the delay; between
    # Coulomb friction and stiction at no excess (the same physics here) the order is a near
    # tie that moves between sweeps (0.96 against 1.00 rmse/noise on one, the other way on
    # another): the Coulomb level stays within 10 % of the first
    rank = {c["effect"]: c for c in ranked}
    assert ranked[0]["effect"] in ("coulomb_friction", "stiction") and ranked[0]["supported"], \
        ranked[:2]
    coulomb = rank["coulomb_friction"]
    assert coulomb["rmse_over_noise"] <= 1.10 * ranked[0]["rmse_over_noise"], ranked[:3]
    if "delay" in rank:
        assert coulomb["rmse_over_noise"] < rank["delay"]["rmse_over_noise"], ranked


def test_the_current_sense_channel_reads_the_armature_current_at_each_sample(tmp_path):
    """A board built with current sense samples A0 at each sample instant: the recorded
    current, after the rig file's zero and V per A, is the emulated motor's armature current
    at the instant the conversion started, within the ADC's step (5 V / 1024 / V-per-A and
    simavr's 1 mV),
    in both directions."""
    text = RIG_FILE.read_text().split("[effects.")[0]
    text = text.replace("pos_offset_v = 0.0\n", "pos_offset_v = 0.0\ncurrent_v_per_a = 0.4\n"
                        "current_zero_v = 2.5\n", 1)
    text = text.replace('firmware = "hbridge"', 'firmware = "hbridge"\ncurrent_sense = true', 1)
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(text)
    plan = tmp_path / "plan.toml"
    plan.write_text('[defaults]\nsample_rate_hz = 200.0\nlead_in_s = 0.2\n\n[[experiment]]\n'
                    'loop = "open"\nwaveform = "square"\namplitudes_v = [6.0]\n'
                    'frequency_hz = 1.0\nperiods = 2\n')
    rig = load_rig(rig_file)
    log = tmp_path / "emu.log"
    r = _sweep_on_board(rig_file, plan, tmp_path / "runs", plant=rig, dac_log=log)
    assert r.returncode == 0, r.stderr
    (csv,) = sorted((tmp_path / "runs").glob("*.csv"))
    d = pd.read_csv(csv)
    meta = json.loads(csv.with_suffix(".json").read_text())
    assert "gap" not in d and meta["bridge"]["dropped_samples"] == 0
    amps = d["current"].to_numpy() * meta["sensors"]["current_a_per_v"]
    truth = np.array([float(line.split()[2]) for line in log.read_text().splitlines()
                      if line.startswith("I ")])
    assert len(truth) >= len(d)
    truth = truth[:len(d)]   # conversions of this run, in order (a STOP may start one more)
    # the ADC truncates (one step, 5 V / 1024) and simavr takes its input in whole mV
    step = (5.0 / 1024 + 0.001) / 0.4
    assert np.abs(amps - truth).max() <= step, np.abs(amps - truth).max()
    assert amps.max() > 0.3 and amps.min() < -0.3   # the current was read both ways


def test_a_sweep_through_a_damaging_link_on_the_hbridge_board(tmp_path):
    """Protocol 2's frames (the 32-bit count) through a link that flips or drops 1 byte in
    1000 each way: `labrig sweep --port` exits 0, every row that is not a gap is what the
    board sent -- its output word and its count, word for word -- and every lost sample
    is a gap row, the ones the proxy kept from the host."""
    from linkproxy import B2H, LinkProxy

    from labrig.bridge import protocol as P
    from labrig.bridge.settings import bridge_settings, volts_to_dac_word
    from labrig.io.runs import read_dataset

    rig_file = _rig_with(tmp_path, HIDDEN)
    rig_file.write_text(rig_file.read_text().replace(   # losses are the point here
        "[bridge]\n", "[bridge]\nmax_lost_fraction = 1.0\n", 1))
    plan = tmp_path / "plan.toml"
    plan.write_text('[defaults]\nsample_rate_hz = 500.0\nlead_in_s = 0.2\n\n[[experiment]]\n'
                    'loop = "open"\nwaveform = "square"\namplitudes_v = [6.0, 9.0]\n'
                    'frequency_hz = 1.0\nperiods = 2\n')
    rig = load_rig(rig_file)
    with Emulator("uno", rig) as emu:
        with LinkProxy(emu.pty, b2h=(5e-4, 5e-4), h2b=(5e-4, 5e-4), seed=5) as proxy:
            r = _labrig("sweep", "--port", proxy.path, "--rig", rig_file, "--plan", plan,
                        "-o", tmp_path / "runs", timeout=120)
    assert r.returncode == 0, r.stderr
    assert proxy.total(proxy.faults, B2H) > 5
    s = bridge_settings(rig)
    runs = sorted(read_dataset(tmp_path / "runs"), key=lambda run: run.name)
    assert len(runs) == 2
    for k, run in enumerate(runs, start=1):
        gap = run.data["gap"].to_numpy() if "gap" in run.data else np.zeros(len(run), int)
        ok = np.flatnonzero(gap == 0)
        sent = np.array([proxy.sent[k][i] for i in ok])
        counts = run.data["pos"].to_numpy()[ok].astype(int)
        assert np.array_equal(counts, P.encoder_counts(sent).astype(int)), run.name
        assert np.array_equal([volts_to_dac_word(v, s) for v in run.u[ok]], sent[:, 0])
        delivered = {i for i in proxy.delivered[k] if i < len(run)}
        assert run.meta["bridge"]["dropped_samples"] == gap.sum() == len(run) - len(delivered)
        assert np.ptp(counts) > 100


def test_a_silent_host_trips_the_hbridge_boards_watchdog_and_the_bridge_lets_go(tmp_path):
    """The host starts a 4 s run and then says nothing: the board stops driving (duty 0,
    the bridge released) one watchdog period after the last byte it heard, says WATCHDOG,
    and counts the trip."""
    from labrig.bridge.serial import SerialBridge
    from labrig.core.errors import RigError
    from labrig.io.experiment import Experiment

    rig = load_rig(_rig_with(tmp_path, {}))
    log = tmp_path / "emu.log"
    with Emulator("uno", rig, dac_log=log) as emu:
        bridge = SerialBridge(emu.pty, rig)
        bridge.open()
        bridge.configure(Experiment(name="a", amplitude_v=6.0, frequency_hz=0.25, periods=1.0,
                                    lead_in_s=0.0, sample_rate_hz=200.0))
        bridge.start()                      # ... and nothing more: no heartbeat, no read
        time.sleep(1.5)
        with pytest.raises(RigError, match="WATCHDOG"):
            while bridge.read(timeout=1.0) is not None:
                pass
        bridge.stop()
        counters = bridge.counters()
        bridge.close()
    starts, _, _, duty = _edges(log)
    start = starts[-1]
    driven = [c for c, d in duty if c > start and d != 0]
    released = [c for c, d in duty if c > start and d == 0]
    assert driven and released, duty
    held_s = (released[0] - start) / 16e6
    watchdog_s = rig.bridge.watchdog_ms / 1e3
    print(f"driven {held_s:.3f} s after START (watchdog {watchdog_s:.3f} s)")
    assert watchdog_s - 0.02 < held_s < watchdog_s + 0.15, held_s
    assert counters["board_watchdog_trips"] == 1, counters


def test_diagnose_auto_finds_stiction_hidden_beside_the_dead_zone(tmp_path):
    """Stiction (Coulomb 0.8 V, breakaway twice that) behind the bridge's dead zone
    (1.0 V forward, 1.6 V reverse): the linear model bends its plant to mimic the friction
    and the dead zone added first takes the friction's volts too; the loop still ends with
    both effects, the steady-state thresholds each way (dead zone + friction) and the
    breakaway where the plant has them, near the noise floor. How the square waves split
    a threshold between the dead zone and the friction is what they pin least: the split
    is not asserted."""
    hidden = {"asymmetric_deadband": {"dpos_v": 1.0, "dneg_v": 1.6},
              "stiction": {"tc_v": 0.8, "excess": 1.0}}
    rig_file = _rig_with(tmp_path, hidden)
    _swept(_sweep_on_board(rig_file, PLAN, tmp_path / "runs"))
    r = _labrig("diagnose", "--auto", tmp_path / "runs", "--json", "-o", tmp_path / "auto")
    assert r.returncode == 0, r.stderr
    final = json.loads(r.stdout)["final_model"]
    assert set(final["effects"]) == {"asymmetric_deadband", "stiction"}, final["effects"]
    dz, st = final["effect_params"]["asymmetric_deadband"], final["effect_params"]["stiction"]
    assert dz["dpos_v"] + st["tc_v"] == pytest.approx(1.0 + 0.8, abs=0.15)
    assert dz["dneg_v"] + st["tc_v"] == pytest.approx(1.6 + 0.8, abs=0.15)
    assert st["tc_v"] * (1 + st["excess"]) == pytest.approx(1.6, rel=0.25)
    # at the floor: each run of the sweep starts in the coast of the one before (the host's
    # pause between runs is real time), and a run's start fitted by the dead-zone-only model
    # ran to the bound of its speed; re-fitted from the start the data show (four sweeps:
    # 0.50, 0.50, 0.51, 0.64; 1.19-2.55 before)
    assert final["rmse_over_noise"]["overall"] < 1.0


def _square_plan(tmp_path: Path, volts: float = 6.0) -> Path:
    plan = tmp_path / "plan.toml"
    plan.write_text('[defaults]\nsample_rate_hz = 200.0\nlead_in_s = 0.2\n\n[[experiment]]\n'
                    f'loop = "open"\nwaveform = "square"\namplitudes_v = [{volts}]\n'
                    'frequency_hz = 1.0\nperiods = 2\n')
    return plan


def _index_events(log: Path) -> list[int]:
    """The plant's encoder edge at each rise of its index pin (the harness's ``X`` lines)."""
    return [int(line.split()[2]) for line in log.read_text().splitlines() if line.startswith("X ")]


@pytest.mark.parametrize("board", ["uno", "mega"])
def test_the_index_pulse_latches_the_count_of_its_mark_every_turn(board, tmp_path):
    """An encoder with an index (11 lines on the motor shaft, x4: 44 counts a turn): every
    pulse of a run is reported and lies a whole number of turns from the first (slip 0), the
    first's count is the plant's edge where its index pin rose, and no edge went undecoded
    -- on the Uno's pin-change interrupt (D4) and the Mega's INT2 (D19)."""
    rig_file = _rig_with(tmp_path, HIDDEN, board=board, index_counts=44,
                         pins={"pwm_in1": hbridge.PINS[board]["pwm_in1"],
                               "dir_in2": hbridge.PINS[board]["dir_in2"],
                               "enc_a": "D2", "enc_b": "D3", "index": hbridge.PINS[board]["index"]})
    log = tmp_path / "emu.log"
    r = _sweep_on_board(rig_file, _square_plan(tmp_path), tmp_path / "runs", board=board,
                        dac_log=log)
    _swept(r)
    (side,) = sorted((tmp_path / "runs").glob("*.json"))
    enc = json.loads(side.read_text())["bridge"]["encoder"]
    d = pd.read_csv(side.with_suffix(".csv"))
    turns = np.ptp(d["pos"]) / 44
    rises = _index_events(log)
    assert turns > 20 and enc["index_pulses"] >= int(turns) - 1, (turns, enc)
    assert len(rises) >= enc["index_pulses"]
    assert enc["faults"] == 0 and enc["slip_counts"] == 0 and "problems" not in enc, enc
    assert enc["index_count"] in rises and (enc["index_count"] - rises[0]) % 44 == 0


def test_edges_the_board_could_not_decode_are_counted_and_the_sweep_says_so(tmp_path):
    """A shaft that outruns the chip (the harness withholds every 400th edge's pin change,
    so the next moves both channels at once): the board counts each undecodable jump, the
    run is written with them in its sidecar and the sweep exits 1 naming the run."""
    rig_file = _rig_with(tmp_path, HIDDEN, index_counts=44)
    r = _sweep_on_board(rig_file, _square_plan(tmp_path), tmp_path / "runs",
                        extra_args=("--miss-edges", "400"))
    assert r.returncode == 1, r.stderr
    assert "could not decode" in r.stderr and "bridge.encoder" in r.stderr
    assert r.stderr.count("labrig: error:") == 1 and "Traceback" not in r.stderr
    (side,) = sorted((tmp_path / "runs").glob("*.json"))
    enc = json.loads(side.read_text())["bridge"]["encoder"]
    d = pd.read_csv(side.with_suffix(".csv"))
    # every 400th of the run's edges (4 a count): the jumps the board counted, to one
    assert abs(enc["faults"] - np.abs(np.diff(d["pos"])).sum() / 400) <= 2 + 0.1 * enc["faults"]
    assert enc["slip_counts"] > 0
    # and no analysis takes its positions as the shaft's
    a = _labrig("analyse", tmp_path / "runs", "-o", tmp_path / "an")
    assert a.returncode == 2 and "its encoder lost counts" in a.stderr, a.stderr


def test_an_index_the_rig_file_wires_but_that_never_pulses_is_named(tmp_path):
    """The rig file says an index is wired; the bench's never pulses (the emulator drives no
    index pin): the shaft turned many turns without one, and the sweep says to check it."""
    rig_file = _rig_with(tmp_path, HIDDEN, index_counts=44)
    plant = load_rig(rig_file)
    plant.bridge.index_counts = 0
    r = _sweep_on_board(rig_file, _square_plan(tmp_path), tmp_path / "runs", plant=plant)
    assert r.returncode == 1, r.stderr
    assert "no index pulse while the shaft turned" in r.stderr and "is the index wired" in r.stderr


def test_asking_the_board_itself_and_the_runs_together_find_the_dead_zone(tmp_path):
    """One 4 V square of a motor whose bridge hides a 1.0/1.6 V dead zone: the square alone
    cannot tell a dead zone from a gain asymmetry (the loop took the asymmetry, at 0.88 of
    the noise, on two sweeps of this plant). `diagnose --auto --ask-rig --port` greets the
    board, plays the proposed ramp on it (the real firmware, its run beside the others in
    asked/), and the decision says that neither explains it; all the runs together then
    name the asymmetric dead zone, each way within 5 %. (Should a sweep's square alone
    already name the dead zone, nothing is asked and that is checked instead.)"""
    rig_file = _rig_with(tmp_path, {"asymmetric_deadband": {"dpos_v": 1.0, "dneg_v": 1.6}})
    runs = tmp_path / "runs"
    with Emulator("uno", load_rig(rig_file)) as emu:
        _swept(_labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan",
                       _square_plan(tmp_path, 4.0), "-o", runs))
        r = _labrig("diagnose", runs, "--auto", "--ask-rig", "--port", emu.pty, "--rig", rig_file,
                    "--json", timeout=900)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    asked = d.get("asked") or {}
    if not asked.get("decision"):
        final = d["final_model"]
        print(f"\nthe square alone named {final['effects']}: {asked.get('text')}")
        assert final["effects"] == ["asymmetric_deadband"], (final, asked.get("text"))
        return
    (played,) = sorted((runs / "asked").glob("*.json"))
    meta = json.loads(played.read_text())
    assert meta["bridge"]["firmware"].endswith("uno hbridge") and meta["bridge"]["dropped_samples"] == 0
    assert set(meta["experiment"]["between"]) == set(asked["pair"])
    assert asked["decision"]["neither"], asked["text"]
    assert "Neither explains them" in asked["text"]
    r = _labrig("diagnose", runs, runs / "asked", "--auto", "--json", timeout=900)
    assert r.returncode == 0, r.stderr
    final = json.loads(r.stdout)["final_model"]
    assert final["effects"] == ["asymmetric_deadband"], final
    dz = final["effect_params"]["asymmetric_deadband"]
    assert dz["dpos_v"] == pytest.approx(1.0, rel=0.05) and dz["dneg_v"] == pytest.approx(1.6, rel=0.05)
    assert final["rmse_over_noise"]["overall"] < 1.5


def test_the_board_trips_on_over_speed_at_once_and_the_sweep_keeps_the_run(tmp_path):
    """A rig file's speed limit below what the 9 V square reaches: the board itself ends
    that run at the first sample past it (its output off before the next sample), reports
    the trip; the sweep writes the run up to there (the rest are gaps, never fitted),
    plays nothing more and exits 1 naming it; the runs before are whole."""
    rig_file = _rig_with(tmp_path, HIDDEN, trip_speed=450.0)
    rig = load_rig(rig_file)
    log = tmp_path / "emu.log"
    r = _sweep_on_board(rig_file, PLAN, tmp_path / "runs", plant=rig, dac_log=log)
    assert r.returncode == 1, r.stderr
    assert "run 'sq_9.00V': the board tripped" in r.stderr and "over-speed" in r.stderr, r.stderr
    assert [line for line in r.stderr.splitlines() if not line.startswith("wrote ")] == [
        r.stderr.strip().splitlines()[-1]], r.stderr   # the runs written, then one line
    runs = tmp_path / "runs"
    assert sorted(p.stem for p in runs.glob("*.csv")) == ["sq_3.00V", "sq_4.50V", "sq_6.00V",
                                                           "sq_9.00V"]
    for name in ("sq_3.00V", "sq_4.50V", "sq_6.00V"):
        assert "trip" not in json.loads((runs / f"{name}.json").read_text())["bridge"]
    meta = json.loads((runs / "sq_9.00V.json").read_text())
    trip = meta["bridge"]["trip"]
    assert trip["fault"] == "TRIP" and "over-speed" in trip["text"]
    d = pd.read_csv(runs / "sq_9.00V.csv")
    k = trip["after_sample"]
    # the count's change per sample passed the limit at the last sample, and not before
    per_sample = 450.0 / rig.gear_ratio * rig.sensors.encoder_counts_per_unit / 200.0
    step = np.abs(np.diff(d["pos"].to_numpy()[:k + 1]))
    assert step[-1] > np.floor(per_sample) >= step[:-1].max(), (step[-1], per_sample)
    assert (d["gap"].to_numpy()[k + 1:] == 1).all() and (d["gap"].to_numpy()[:k + 1] == 0).all()
    # the chip's own pins: the bridge off within one sample period of that sample
    starts, _, _, duty = _edges(log)
    start, period = starts[3], 16e6 / 200.0
    sampled = start + (k + 1) * period
    assert [v for c, v in duty if c <= sampled - period][-1] != 0   # driven before it
    off = [c for c, v in duty if c > sampled - period and v == 0]
    assert off and sampled - 1 <= off[0] <= sampled + period, (off[:1], sampled)
    assert all(v == 0 for c, v in duty if c > off[0]), "driven again after the trip"
    # the tripped run is read with its tail as gaps; the fit never sees them
    a = _labrig("analyse", runs, "--json")
    assert a.returncode == 0, a.stderr


def test_the_estop_stops_the_run_at_once_and_latches(tmp_path):
    """An E-stop wired to D7 (normally closed to GND), opened 0.5 s after the emulated
    sweep first drives the motor: the board drives nothing from the next sample on, the run is kept up to there
    and recorded as an E-stop, the sweep exits 1 saying so; another sweep while the switch
    stays open is refused by the board before anything plays."""
    rig_file = _rig_with(tmp_path, HIDDEN, estop=True)
    rig = load_rig(rig_file)
    log = tmp_path / "emu.log"
    with Emulator("uno", rig, dac_log=log, extra_args=("--estop-at", "0.5")) as emu:
        r = _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan", PLAN, "-o",
                    tmp_path / "runs")
        again = _labrig("sweep", "--port", emu.pty, "--rig", rig_file, "--plan", PLAN, "-o",
                        tmp_path / "again")
    assert r.returncode == 1 and "(E-stop)" in r.stderr and "pressed the E-stop" in r.stderr, r.stderr
    tripped = [p for p in (tmp_path / "runs").glob("*.json")
               if "trip" in json.loads(p.read_text())["bridge"]]
    assert len(tripped) == 1, tripped
    trip = json.loads(tripped[0].read_text())["bridge"]["trip"]
    assert trip["fault"] == "TRIP" and trip["text"] == "E-stop"
    starts, _, _, duty = _edges(log)
    pressed = next(c for c, v in duty if v != 0) + 0.5 * 16e6   # 0.5 s into the driving
    period = 16e6 / 200.0
    assert all(v == 0 for c, v in duty if c > pressed + period), "driven after the E-stop"
    assert [v for c, v in duty if c <= pressed][-1] != 0     # it was driving when pressed
    assert again.returncode == 1 and "E-stop latched" in again.stderr, again.stderr
    assert not (tmp_path / "again").exists() or not list((tmp_path / "again").glob("*.csv"))


def test_the_board_trips_at_its_position_window_in_a_closed_loop(tmp_path):
    """A closed-loop square of +-3 rad against a window of +-2 rad from the run's start:
    the emulated board's own PD drives the shaft out of it and the board trips there; the
    open-loop runs, where the window does not apply, play whole. The simulated rig trips
    at the same place on the same law (test_hbridge_rig)."""
    rig_file = _rig_with(tmp_path, HIDDEN, trip_position=[-2.0, 2.0])
    rig = load_rig(rig_file)
    r = _sweep_on_board(rig_file, board_loop_plan(tmp_path), tmp_path / "runs", plant=rig)
    assert r.returncode == 1, r.stderr
    position_window_trip(tmp_path / "runs", rig, r.stderr, 2.0)
