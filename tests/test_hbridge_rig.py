"""An H-bridge rig file against what the board can do: one line, exit 2, nothing played."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from labrig.bridge import hbridge, protocol as P
from labrig.bridge.settings import bridge_settings, dac_word_to_volts, volts_to_dac_word
from labrig.io.config import load_rig

ROOT = Path(__file__).resolve().parents[1]
RIG_FILE = ROOT / "configs" / "rig_arduino_hbridge.toml"


def _rig(tmp_path, **changes) -> Path:
    text = RIG_FILE.read_text()
    for key, value in changes.items():
        if re.search(rf"^{key} = ", text, flags=re.M):
            text = re.sub(rf"^{key} = .*$", f"{key} = {value}", text, flags=re.M)
        else:
            text = text.replace("[bridge]\n", f"[bridge]\n{key} = {value}\n")
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("changes, words", [
    ({"pwm_bits": 12}, ["bridge.pwm_bits", "8 to 10 bits", "in hearing"]),
    ({"encoder_counts_per_unit": 0}, ["sensors.encoder_counts_per_unit", "counts per rad"]),
    ({"dac_range_v": "[-9.0, 9.0]"}, ["bridge.output_limit_v", "above the supply"]),
    ({"dac_bits": 12}, ["bridge.dac_bits", "PWM bits and a sign (9)"]),
    ({"sample_rate_hz": 300.0}, ["bridge.sample_rate_hz", "divisors of 10000"]),
    ({"pins": "{pwm_in1 = 10}"}, ["bridge.pins.pwm_in1", "an Uno uses D9", "OC1A"]),
    ({"board": '"mega"'}, ["bridge.pins.pwm_in1", "a Mega 2560 uses D11", "OC1A"]),
    ({"pins": "{enc_z = 4}"}, ["bridge.pins.enc_z", "no such signal", "enc_a"]),
    ({"board": "false"}, ["bridge.board"]),
    ({"index_counts": 100}, ["bridge.index_counts", "1320 (the output shaft) or 44 (the motor shaft)"]),
    ({"index_counts": -1}, ["bridge.index_counts"]),
    ({"firmware": '"ms150"', "pins": "{}", "index_counts": 44},
     ["bridge.index_counts", "reads no encoder"]),
])
def test_a_rig_file_the_board_cannot_play_is_refused_in_one_line(tmp_path, changes, words):
    rig = _rig(tmp_path, **changes)
    r = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--sim", "--rig", str(rig),
                        "-o", str(tmp_path / "runs")], capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and "Traceback" not in line
    assert str(rig) in line and all(w in line for w in words), line
    assert not (tmp_path / "runs").exists()


def test_a_plan_beyond_the_supply_is_refused_before_anything_moves(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text('[[experiment]]\nloop = "open"\nwaveform = "step"\namplitude_v = 15.0\n'
                    'duration_s = 1.0\nsample_rate_hz = 200.0\n')
    r = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--sim", "--rig", str(RIG_FILE),
                        "--plan", str(plan), "-o", str(tmp_path / "runs")],
                       capture_output=True, text=True)
    assert r.returncode == 2
    assert "15 V" in r.stderr and "12 V" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_the_output_word_is_the_pwm_and_a_sign_the_same_most_either_way():
    s = bridge_settings(load_rig(RIG_FILE))
    assert s.dac_bits == 9 and s.firmware == "hbridge"
    assert volts_to_dac_word(0.0, s) == 256
    assert volts_to_dac_word(12.0, s) == 511 and volts_to_dac_word(-12.0, s) == 1
    # a count is supply / 256 either way: 8-bit PWM of 12 V
    assert dac_word_to_volts([257, 255], s).tolist() == pytest.approx([12 / 256, -12 / 256])
    assert dac_word_to_volts([511, 1], s).tolist() == pytest.approx([12 * 255 / 256, -12 * 255 / 256])


def test_the_board_is_checked_against_the_rig_file():
    rig = load_rig(RIG_FILE)
    hello = P.parse_hello(P.hello_body(
        protocol=2, board="nano", capabilities=31, max_rate_hz=2000, batch=10, dac_bits=9,
        adc_bits=10, n_adc=0, max_levels=32, dac_zero=256, fw_dac_min=1, fw_dac_max=511,
        watchdog_ms_default=500, firmware="labrig-fw 2.0.0 nano hbridge", rig="hbridge",
        timer_hz=10000, rig_flags=hbridge.rig_flags(rig), decoding=4, pwm_bits=8))
    hbridge.check_board(rig, {**hello, "board": "uno"}, "/dev/ttyUSB0")   # the right build
    from labrig.core.errors import RigError
    with pytest.raises(RigError, match="other H-bridge options: decoding 2 .rig file: 4."):
        hbridge.check_board(rig, {**hello, "board": "uno", "decoding": 2}, "/dev/ttyUSB0")
    # the rig file's bench is an Uno: a Nano (the same chip, other pins on a shield) is not
    with pytest.raises(RigError, match="is a Nano, but the rig file's bench is built on an Uno"):
        hbridge.check_board(rig, {**hello, "board": "nano"}, "/dev/ttyUSB0")
    v1 = {**hello, "rig": "ms150"}
    with pytest.raises(RigError, match="runs the ms150 firmware.*labrig flash --board nano --rig .*rig_arduino_hbridge.toml"):
        hbridge.check_board(rig, v1, "/dev/ttyUSB0")
    # a 2.0 build reads no index: a rig file that wires one is told to reflash; 2.1 reads it
    # (and a rig file without one takes either)
    indexed = load_rig(RIG_FILE)
    indexed.bridge.index_counts = 44
    with pytest.raises(RigError, match="reads no index pulse.*index_counts = 0"):
        hbridge.check_board(indexed, {**hello, "board": "uno"}, "/dev/ttyUSB0")
    v21 = {**hello, "board": "uno", "rig_flags": hello["rig_flags"] | P.FLAG_INDEX}
    hbridge.check_board(indexed, v21, "/dev/ttyUSB0")
    hbridge.check_board(rig, v21, "/dev/ttyUSB0")


def test_the_rig_files_board_and_pins_are_the_wirings_and_the_emulators(tmp_path):
    """A rig file that names its board: the wiring and the emulator are for that board
    unless asked, and asked for another, the library says which argument and why."""
    import labrig.verbs as lr
    from labrig.core.errors import UserError
    from labrig.io.board_pins import check_pins

    rig = load_rig(RIG_FILE)
    assert rig.bridge.board == "uno"
    assert rig.bridge.pins == {"pwm_in1": "D9", "dir_in2": "D10", "enc_a": "D2", "enc_b": "D3"}
    assert lr.wiring(rig).board == "uno"
    with pytest.raises(UserError, match="board: 'mega', but the rig file .* on an Uno"):
        lr.wiring(rig, board="mega")
    assert lr.emulator(rig).board == "uno"
    mega = load_rig(_rig(tmp_path, board='"mega"', pins='{pwm_in1 = 11, enc_a = "d2"}'))
    assert mega.bridge.pins == {"pwm_in1": "D11", "enc_a": "D2"}
    assert lr.wiring(mega).to_pandas().loc[0, "pin"] == "D11"
    # the MS150 build's pins too
    assert check_pins("ms150", "mega", {"dac_cs": 53, "tacho": "A0"}, "f") == {
        "dac_cs": "D53", "tacho": "A0"}


def _arduino_pins(variant: str) -> dict:
    """Arduino pin name -> (port letter, bit), from the Arduino core's own variant tables."""
    text = Path(f"/usr/share/arduino/hardware/arduino/avr/variants/{variant}/pins_arduino.h").read_text()

    def table(name):
        body = text.split(f"{name}[] = {{")[1].split("};")[0]
        body = re.sub(r"/\*.*?\*/|//[^\n]*", "", body, flags=re.S)
        return [t.strip() for t in body.split(",") if t.strip()]

    ports = table("digital_pin_to_port_PGM")
    bits = [int(re.fullmatch(r"_BV\(\s*(\d+)\s*\)", b).group(1)) for b in table("digital_pin_to_bit_mask_PGM")]
    return {f"D{i}": (p[1], b) for i, (p, b) in enumerate(zip(ports, bits))}


@pytest.mark.skipif(not Path("/usr/share/arduino/hardware/arduino/avr/variants").exists(),
                    reason="arduino-core-avr not installed")
@pytest.mark.parametrize("board, variant, mcu", [("uno", "standard", "328"), ("mega", "mega", "2560")])
def test_the_pin_map_is_the_one_the_firmware_drives(board, variant, mcu):
    """labrig.bridge.hbridge.PINS (what docs/hardware.md shows) against hal_hbridge.inc's
    port bits, through the Arduino core's own table of which port bit each pin is."""
    hal = (ROOT / "firmware" / "labrig_bridge" / "src" / "hal_hbridge.inc").read_text()
    block = re.search(r"#if defined\(__AVR_ATmega2560__\)\n(#define PIN_A_BIT.*?)#endif", hal, re.S).group(1)
    mega, other = block.split("#else")
    defs = dict(re.findall(r"#define (\w+_BIT) P([A-Z]\d)", mega if board == "mega" else other))
    pins = _arduino_pins(variant)
    want = hbridge.PINS[board]
    for key, define in (("pwm_in1", "PIN_A_BIT"), ("dir_in2", "PIN_B_BIT"), ("enc_a", "ENC_A_BIT"),
                        ("enc_b", "ENC_B_BIT"), ("index", "IDX_BIT")):
        port, bit = defs[define][0], int(defs[define][1])
        assert pins[want[key]] == (port, bit), (board, key, want[key], defs[define])
    doc = (ROOT / "docs" / "hardware.md").read_text()
    rows = doc.split("## The H-bridge + encoder bench")[1]
    col = 1 if board == "uno" else 2
    for key, label in (("pwm_in1", "PWM / IN1"), ("dir_in2", "DIR / IN2"), ("enc_a", "encoder A"),
                       ("enc_b", "encoder B"), ("index", "encoder index")):
        row = next(r for r in rows.splitlines() if r.startswith(f"| {label} |"))
        assert row.split("|")[1 + col].strip().startswith(want[key] + " "), row


def test_the_ms150_output_stage_rises_with_channel_a_as_the_emulator_assumes():
    """The output stage's netlist solved with an ideal op-amp: u = (R2/R1)(VA - VB), the
    sign and (to the calibration's 0.5 %) the gain the emulator's bridge_out and the host's
    word-to-volts conversion use; the old drawing's wiring (VOUTA to the inverting input)
    gives the opposite sign."""
    from labrig.bridge import circuits
    from labrig.io.config import RigConfig

    harness = (ROOT / "firmware" / "emulator" / "harness.c").read_text()
    assert "return (va - vb) * (5.0 / 2.048);" in harness   # the emulator's stage
    host = bridge_settings(RigConfig())
    for word in (0, 1024, 3000, 4095):
        u = circuits.output_for_word(word)
        va, vb = word * 4.096 / 4096, 2048 * 4.096 / 4096
        emulated = (va - vb) * (5.0 / 2.048)
        nominal = float(dac_word_to_volts([word], host)[0])
        if word != 2048:
            assert np.sign(u) == np.sign(emulated) == np.sign(nominal)
            assert u / emulated == pytest.approx(1.0, abs=0.006)
            assert u / nominal == pytest.approx(1.0, abs=0.006)
    assert circuits.output_for_word(4095) == pytest.approx(4.974, abs=0.001)
    swapped = tuple((n, {"VOUTB": "VOUTA", "VOUTA": "VOUTB"}.get(a, a), b, r)
                    for n, a, b, r in circuits.OUTPUT_STAGE)
    assert circuits.output_for_word(4095, netlist=swapped) == pytest.approx(-4.974, abs=0.001)
    # the page says what the netlist is
    doc = (ROOT / "docs" / "hardware.md").read_text()
    assert "R1 = 10.0 k (0.1 %) from VOUTB to the\ninverting input" in doc


def test_the_encoders_record_judges_a_runs_counts():
    """Pulses a whole number of turns apart (either way, below zero too) are clean; one
    within an encoder cycle of it is an ungated index met from the other side, not a slip;
    beyond it, and undecodable edges, and a wired index that never pulsed, are named."""
    ev = lambda *counts: [{"sample": 10 * k, "count": c, "pulse": k + 1} for k, c in enumerate(counts)]
    clean = hbridge.encoder_record(ev(-70, -26, 18, -114), 0, 44, 4, 300)
    assert clean == {"faults": 0, "index_pulses": 4, "index_sample": 0, "index_count": -70,
                     "slip_counts": 0}
    assert hbridge.encoder_record(ev(20, 67), 0, 44, 4, 100)["slip_counts"] == 3
    assert "problems" not in hbridge.encoder_record(ev(20, 67), 0, 44, 4, 100)
    slipped = hbridge.encoder_record(ev(20, 70), None, 44, 4, 100)
    assert slipped["slip_counts"] == 6 and slipped["faults"] is None
    assert "6 counts off a whole number of turns" in slipped["problems"][0]
    assert "could not decode" in hbridge.encoder_record([], 3, 0, 4, 1000)["problems"][0]
    assert "problems" not in hbridge.encoder_record([], 0, 44, 4, 60)   # not a turn and a half
    assert "is the index wired" in hbridge.encoder_record([], 0, 44, 4, 70)["problems"][0]


def board_loop_plan(folder: Path) -> Path:
    """Two open-loop squares and a closed-loop run of the board's own PD (kp 10 V/rad, kd
    0.3 V per rad/s at 200 Hz): ``folder/plan.toml``."""
    plan = folder / "plan.toml"
    plan.write_text('[defaults]\nsample_rate_hz = 200.0\nlead_in_s = 0.5\n\n'
                    '[[experiment]]\nloop = "open"\nwaveform = "square"\namplitudes_v = [4.5, 9.0]\n'
                    'frequency_hz = 0.5\nperiods = 2\n\n'
                    '[[experiment]]\nname = "pd_3rad"\nloop = "closed"\nwaveform = "square"\n'
                    'amplitude_v = 3.0\nfrequency_hz = 0.5\nperiods = 2\nposition_gain = 10.0\n'
                    'velocity_gain = 0.3\n')
    return plan


def test_the_simulated_rig_runs_an_hbridge_boards_own_loop(tmp_path):
    """`sweep --sim` on an H-bridge rig closes a position loop as its board does: the run
    carries the board's law (experiment.controller.sampled), and every logged drive is that
    law -- Q8.8 gains, floor, clamp -- on the run's own recorded count against the
    reference in whole counts; the model fitted through the law follows the run."""
    import json
    import math

    import pandas as pd

    rig_file = _rig(tmp_path)
    plan = board_loop_plan(tmp_path)
    runs = tmp_path / "runs"
    r = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--sim", "--rig", str(rig_file),
                        "--plan", str(plan), "-o", str(runs)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    meta = json.loads((runs / "pd_3rad.json").read_text())
    law = meta["experiment"]["controller"]["sampled"]
    d = pd.read_csv(runs / "pd_3rad.csv")
    cpu = law["counts_per_unit"]
    x = d["pos"].to_numpy() - d["pos"].iloc[0]
    ref = np.round(d["u"].to_numpy() * cpu)
    prev = np.concatenate([[0.0], x[:-1]])
    out = [min(max(math.floor((law["kp_q"] * e - law["kd_q"] * v) / 256.0), law["limits"][0]),
               law["limits"][1]) for e, v in zip(ref - x, x - prev)]
    # (the CSV keeps seven digits: equal to 1e-5 V, a five-thousandth of an output count)
    assert np.allclose(d["drive"].to_numpy(), np.array(out) * law["volts_per_count"], rtol=0,
                       atol=1e-5)
    assert np.ptp(x) > 0.8 * 6.0 * cpu   # the loop followed the 3 rad square either way
    fit = subprocess.run([sys.executable, "-m", "labrig", "identify", str(runs), "--effects",
                          "asymmetric_deadband,delay", "--json"], capture_output=True, text=True)
    assert fit.returncode == 0, fit.stderr
    res = json.loads(fit.stdout)
    res = res["results"][0] if "results" in res else res
    # the rig file hides a 1.5/2.1 V dead zone and a 10 ms delay (fitted 1.4998/2.0999 V and
    # 9.0 ms, the closed-loop run at 0.79 of its noise, when this was written)
    assert res["per_run"]["pd_3rad"]["position"] < 1.5, res["per_run"]
    dz = res["effect_params"]["asymmetric_deadband"]
    assert dz["dpos_v"] == pytest.approx(1.5, rel=0.03) and dz["dneg_v"] == pytest.approx(2.1, rel=0.03)


@pytest.mark.parametrize("encoder", [{"problems": 5}, "junk", {"problems": [3]}])
def test_a_sidecars_malformed_encoder_record_is_one_line(tmp_path, encoder):
    """A sidecar whose ``bridge.encoder`` is not what a sweep writes: one line naming the
    file and the key, exit 2, no traceback."""
    import json
    import shutil

    runs = tmp_path / "runs"
    shutil.copytree(ROOT / "data" / "emulated_hbridge", runs)
    side = runs / "sq_3.00V.json"
    meta = json.loads(side.read_text())
    meta["bridge"]["encoder"] = encoder
    side.write_text(json.dumps(meta))
    r = subprocess.run([sys.executable, "-m", "labrig", "analyse", str(runs), "-o",
                        str(tmp_path / "an")], capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert str(side) in r.stderr and "bridge.encoder" in r.stderr


def position_window_trip(runs: Path, rig, stderr: str, window: float) -> None:
    """The sweep stopped at the closed-loop run, which tripped at the first sample whose
    count from the run's start left the window; the open-loop runs before it, which may
    turn far past it, played whole."""
    assert "run 'pd_3rad': the board tripped" in stderr and "(position limit)" in stderr, stderr
    for name in ("sq_4.50V", "sq_9.00V"):
        meta = json.loads((runs / f"{name}.json").read_text())
        assert "trip" not in meta["bridge"]
        assert np.ptp(pd.read_csv(runs / f"{name}.csv")["pos"]) > 2 * window * \
            rig.sensors.encoder_counts_per_unit
    meta = json.loads((runs / "pd_3rad.json").read_text())
    k = meta["bridge"]["trip"]["after_sample"]
    table = pd.read_csv(runs / "pd_3rad.csv")
    counts = table["pos"].to_numpy()[:k + 1]
    edge = np.floor(window * rig.sensors.encoder_counts_per_unit)
    travel = counts - counts[0]
    # the board counts from its START, a sample period before the first sample (its timer
    # starts there): a run that starts in the coast of the one before has moved since by that
    # period's step, which the coast's slowing makes up to twice the first step seen
    slack = 2 * abs(int(counts[1]) - int(counts[0])) + 1
    assert np.abs(travel[-1]) > edge - slack and (np.abs(travel[:-1]) <= edge + slack).all(), \
        (travel[:6], travel[-3:], edge, slack, meta["bridge"])



def test_the_simulated_rig_trips_at_the_position_window_as_the_board_does(tmp_path):
    """`sweep --sim` with a +-2 rad window and the board's own loop driving a +-3 rad square:
    the run ends at the first sample out of the window, recorded as the board records it;
    the open-loop runs, where the window does not apply, play whole."""
    rig_file = _rig(tmp_path, trip_position="[-2.0, 2.0]")
    r = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--sim", "--rig", rig_file,
                        "--plan", board_loop_plan(tmp_path), "-o", tmp_path / "runs"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr
    position_window_trip(tmp_path / "runs", load_rig(rig_file), r.stderr, 2.0)
