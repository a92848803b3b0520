"""The MS150 board's own loop (``closed_by = "board"``), host side: the words it is sent,
the plan's rules, the simulated rig playing the board's law on the words its sensors give,
and the model running the same law (the emulated board's own run is in test_ms150_loop)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from labrig.bridge import protocol as P
from labrig.bridge.settings import (bridge_settings, experiment_body, sensor_gain_words,
                                    sensor_words)
from labrig.core.errors import ConfigError, UserError
from labrig.io.config import RigConfig, load_plan, load_rig, packaged_config
from labrig.io.experiment import Experiment

#: the board's HELLO fields the host reads (firmware 2.4 on the MS150: the board loop bit)
HELLO = {"capabilities": 0x1F | P.CAP_BOARD_LOOP, "max_rate_hz": 1000, "fw_dac_min": 984,
         "fw_dac_max": 3112}


def _exp(by="board", kp=2.0, kv=0.15, amp=0.5, name="cl") -> Experiment:
    return Experiment(name=name, loop="closed", waveform="square", amplitude_v=amp,
                      frequency_hz=0.25, periods=1, position_gain=kp, velocity_gain=kv,
                      closed_by=by)


def test_the_board_is_sent_its_gains_references_and_sensor_zeros_in_its_own_words():
    """Default rig: 10-bit ADC over +-10 V (19.5 mV a word), 12-bit DAC over +-5 V (409.6
    counts a volt). Kp 2 V/V is 2 x 0.01953 x 409.6 x 256 = 4096 in Q8.8; Kv 0.15 is 307.
    The pot (0.5 V/rad, -4 V at 0) reads word 307.2 at 0 rad; a 0.5 V reference is
    1 rad either side, 25.6 words: words 333 and 282; the tacho's zero is mid-scale, 512."""
    s = bridge_settings(load_rig(None))
    assert sensor_gain_words(_exp(), s) == (4096, 307)
    w = sensor_words(s)
    assert w["counts_per_unit"] == pytest.approx(25.6) and w["pos_zero"] == pytest.approx(307.2)
    assert w["tacho_zero_word"] == 512 and w["word_max"] == 1023
    cfg = P.parse_configure(experiment_body(_exp(), s, HELLO))
    assert cfg["loop"] == "board" and cfg["levels"] == [333, 282]
    assert (cfg["ref_lead"], cfg["tacho_zero"]) == (307, 512)
    # the analog loop's run is sent as before: the reference as DAC words, gains x 100
    old = P.parse_configure(experiment_body(_exp(by=None), s, HELLO))
    assert old["loop"] == "closed" and old["position_gain"] == 2.0 and "ref_lead" not in old


def test_a_board_loop_is_refused_by_firmware_that_cannot_close_it():
    s = bridge_settings(load_rig(None))
    with pytest.raises(UserError, match="does not close the loop itself.*labrig flash"):
        experiment_body(_exp(), s, dict(HELLO, capabilities=0x1F))
    # docs/hardware.md: at the default rig's scales Kp and Kv below 32 V/V each
    experiment_body(_exp(kp=31.99, kv=31.99), s, HELLO)
    for kp, kv in ((32.01, 0.1), (2.0, 32.01)):
        with pytest.raises(UserError, match="do not fit the board's loop"):
            experiment_body(_exp(kp=kp, kv=kv), s, HELLO)


@pytest.mark.parametrize("rig_file, experiment, words", [
    ("rig_default.toml", 'loop = "open"\nclosed_by = "board"',
     "belongs to a closed-loop experiment"),
    ("rig_arduino_hbridge.toml", 'loop = "closed"\nclosed_by = "analog"',
     "board closes its loop itself"),
    ("rig_default.toml", 'loop = "closed"\nclosed_by = "patch"', "closed_by"),
])
def test_a_closed_by_the_rig_cannot_have_is_refused(tmp_path, rig_file, experiment, words):
    plan = tmp_path / "plan.toml"
    plan.write_text(f'[[experiment]]\n{experiment}\nwaveform = "step"\namplitude_v = 0.3\n'
                    "duration_s = 1.0\n")
    with pytest.raises(ConfigError, match=words):
        load_plan(plan, load_rig(packaged_config(rig_file)))


def test_a_default_closed_by_leaves_the_open_loops_alone(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text('[defaults]\nclosed_by = "board"\n\n[[experiment]]\nloop = "open"\n'
                    'waveform = "step"\namplitude_v = 1.0\nduration_s = 1.0\n\n'
                    '[[experiment]]\nloop = "closed"\nwaveform = "step"\namplitude_v = 0.3\n'
                    "duration_s = 1.0\n")
    opened, closed = load_plan(plan, load_rig(None))
    assert opened.closed_by is None and closed.closed_by == "board"
    assert "closed_by" not in opened.to_sidecar() and closed.to_sidecar()["closed_by"] == "board"


def test_on_the_board_a_loop_it_closes_needs_no_patch_and_mixes_with_open_runs():
    from labrig.bridge.sweep import check_plan

    rig = load_rig(None)
    step = Experiment(name="o", loop="open", waveform="step", amplitude_v=1.0, duration_s=1.0)
    check_plan([step, _exp()], rig, board=True)          # the bridge drives the amplifier
    with pytest.raises(UserError, match="closed_by"):     # an analog loop needs its patch
        check_plan([_exp(by=None)], rig, board=True)
    patched = load_rig(None)
    patched.bridge.loop_kp, patched.bridge.loop_kv = 2.0, 0.15
    with pytest.raises(UserError, match="mixes runs through the rig's analog loop"):
        check_plan([_exp(by=None, name="a"), _exp(name="b")], patched, board=True)


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """The default plan on the simulated rig twice: its closed-loop runs through the
    analog loop, and closed by the board."""
    from labrig.bridge.sim import SimRig
    from labrig.bridge.sweep import acquire

    rig = RigConfig()
    out = {}
    for by in (None, "board"):
        out[by] = [acquire(SimRig(rig), _exp(by=by, amp=a, name=f"cl_{a}"), rig)
                   for a in (0.5, 0.6)]
    return out


def test_the_board_loop_on_the_simulated_rig_moves_as_the_analog_loop(sweeps):
    """The same gains in the same units: the board's sampled, quantised loop follows the
    analog loop's run within about half a pot word (0.039 rad); the board's run records
    its reference in rad, its drive, and the law it ran."""
    for analog, board in zip(sweeps[None], sweeps["board"]):
        assert np.sqrt(np.mean((analog.position - board.position) ** 2)) < 0.04
        assert np.allclose(board.u.max(), analog.u.max() / 0.5, atol=0.04)   # V -> rad
        law = board.meta["experiment"]["controller"]["sampled"]
        assert law["feedback"] == "sensors" and law["kp_q"] == 4096
        assert "drive" in board.data and "ref" not in board.data


def test_the_model_runs_the_boards_law_on_its_runs(sweeps, tmp_path):
    """Identified on the board's closed-loop runs alone, the model with the rig's hidden
    Coulomb friction fits them to the noise (rmse/noise near 1, the loop's own noise
    on top) and finds the rig's Km and tau_m within 5 %."""
    import labrig as lr
    from labrig.io.runs import write_run

    for run in sweeps["board"]:
        write_run(run, tmp_path)
    fit = lr.identify(tmp_path, "co", ["coulomb_friction"])
    ev = lr.compare(tmp_path, fit.model(), detail=False).to_pandas()
    print(ev.to_string())
    assert ev["rmse_over_noise"].max() < 1.3
    from labrig.model.servo import ServoParams

    got, truth = fit.model().servo(), ServoParams.from_rig(RigConfig())
    print(f"Km {got.km:.4g} against {truth.km:.4g}, tau_m {got.tau_m:.4g} against {truth.tau_m:.4g}")
    assert got.km == pytest.approx(truth.km, rel=0.05)
    assert got.tau_m == pytest.approx(truth.tau_m, rel=0.05)


def _sweep(*args):
    return subprocess.run([sys.executable, "-m", "labrig", "sweep", "--sim", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


BOARD_STEP = ('[[experiment]]\nloop = "closed"\nclosed_by = "board"\nwaveform = "square"\n'
              "amplitude_v = 0.4\nfrequency_hz = 0.5\nperiods = 1\n")


def test_a_board_loop_sweep_on_the_command_line(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(BOARD_STEP)
    r = _sweep("--plan", plan, "-o", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "out").glob("*.csv"))) == 1


@pytest.mark.parametrize("second, rig_keys, words", [
    ("position_gain = 40.0\n", "", "do not fit the board's loop"),
    ("", "tacho_v_per_rad_s = 0.0\n", "closes its loop on the pot and the tacho"),
])
def test_a_board_loop_it_cannot_play_is_refused_before_anything_plays(tmp_path, second, rig_keys,
                                                                     words):
    """Its gains beyond the board's words, or a rig without the tacho it reads: the plan's
    later experiment refused before the first plays (a sensor wired the other way round,
    a negative gain, is the rig file's error already)."""
    plan = tmp_path / "plan.toml"
    plan.write_text(BOARD_STEP + "\n" + BOARD_STEP.replace("0.4", "0.3") + second)
    text = packaged_config("rig_default.toml").read_text()
    rig = tmp_path / "rig.toml"
    rig.write_text(text.replace("tacho_v_per_rad_s = 0.026", rig_keys.strip() or
                                "tacho_v_per_rad_s = 0.026"))
    r = _sweep("--rig", rig, "--plan", plan, "-o", tmp_path / "out")
    assert r.returncode == 2 and words in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not list((tmp_path / "out").glob("*.csv"))
