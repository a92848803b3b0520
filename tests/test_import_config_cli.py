"""labrig import, configuration files and CLI exit codes."""
import math

import numpy as np
import pytest

from labrig.config import load_plan, load_rig, rig_from_dict
from labrig.errors import ConfigError
from labrig.runs import read_run
from conftest import ROOT, labrig


def test_import_staircase_speed_only_100hz_rpm(tmp_path):
    # another lab's open-loop staircase: speed in rpm, time in ms, 100 Hz
    t = np.arange(0, 4000, 10.0)
    u = np.repeat([0.0, 0.5, 1.0, 1.5], 100)
    rpm = 900 * u
    src = tmp_path / "stair.csv"
    src.write_text("time_ms,volts,RPM\n" + "\n".join(f"{a:g},{b:g},{c:g}" for a, b, c in zip(t, u, rpm)))
    labrig("import", src, "-o", tmp_path / "ds", "--map", "t=time_ms,u=volts,speed=RPM",
           "--speed-unit", "rpm", "--time-unit", "ms", "--waveform", "staircase", check=0)
    run = read_run(tmp_path / "ds" / "stair.csv")
    assert run.fs == 100 and run.meta["source"] == "import"
    assert run.experiment["waveform"] == "staircase" and not run.has_pos
    np.testing.assert_allclose(run.speed[-1], 1350 * 2 * math.pi / 60, rtol=1e-6)


def test_import_square_wave_raw_volts(tmp_path):
    t = np.arange(2000) / 1000
    u = np.where((t // 0.5) % 2 == 0, 1.5, -1.5)
    src = tmp_path / "scope.csv"
    src.write_text("Time,CH1,CH2,CH3\n" + "\n".join(
        f"{a:.4f},{b:g},{0.026 * 140 * b / 1.5:.5f},{0.1 * a:.5f}" for a, b in zip(t, u)))
    labrig("import", src, "-o", tmp_path / "ds", "--map", "t=Time,u=CH1,tacho=CH2,pos=CH3",
           "--tacho-gain", "0.026", "--pos-gain", "0.5", "--gear-ratio", "30",
           "--waveform", "square", check=0)
    run = read_run(tmp_path / "ds" / "scope.csv")
    np.testing.assert_allclose(run.speed[10], 140, rtol=1e-3)
    np.testing.assert_allclose(run.position[1000], 0.2, atol=1e-3)
    assert run.gear_ratio == 30


@pytest.mark.parametrize("args,msg", [
    (["--map", "t=Time,u=CH1"], "at least one of speed"),
    (["--map", "t=Time,u=CH1,velocity=CH2"], "unknown target 'velocity'"),
    (["--map", "t=Time,u=CH9,speed=CH2"], "column 'CH9' not found"),
    (["--map", "t=Time,u=CH1,speed=CH2", "--speed-unit", "furlongs"], "unknown unit"),
    (["--map", "t=Time,u=CH1,tacho=CH2"], "--tacho-gain"),
])
def test_import_bad_options(tmp_path, args, msg):
    src = tmp_path / "s.csv"
    src.write_text("Time,CH1,CH2\n0,0,0\n0.001,1,2\n0.002,1,2\n")
    proc = labrig("import", src, "-o", tmp_path / "o", *args)
    assert proc.returncode == 2 and msg in proc.stderr and "Traceback" not in proc.stderr


def test_default_rig_physically_consistent():
    from labrig.model.servo import ServoParams

    rig = load_rig()
    p = ServoParams.from_rig(rig)
    assert abs(p.tau_m_approx - 0.162) < 1e-3          # the paper's measured tau_m
    assert rig.sensors.tacho_v_per_rad_s == 0.026      # the paper's Kt
    # the default plan stays inside the amplifier's rail in open loop
    assert rig.amplifier.gain * 2.5 < rig.amplifier.output_limit_v


@pytest.mark.parametrize("doc,msg", [
    ({"plant": {"R_ohm": -1.0}}, "plant.R_ohm"),
    ({"plant": {"R": 1.0}}, "unknown key 'plant.R'"),
    ({"planet": {}}, "unknown section"),
    ({"bridge": {"adc_range_v": [5, -5]}}, "bridge.adc_range_v"),
    ({"effects": {"gremlins": {}}}, "unknown effect 'gremlins'"),
    ({"effects": {"deadband": {"width": 1}}}, "effects.deadband.width"),
    ({"noise": {"tacho_v": "loud"}}, "noise.tacho_v"),
])
def test_config_errors_name_the_key(doc, msg):
    with pytest.raises(ConfigError, match=msg):
        rig_from_dict(doc, "x.toml")


def test_plan_expands_and_validates(tmp_path):
    plan = load_plan()
    names = [e.name for e in plan]
    assert names[:4] == ["sq_1.20V", "sq_1.50V", "sq_2.00V", "sq_2.50V"]
    assert all(e.loop == "closed" for e in plan[4:]) and len(plan) > 4
    bad = tmp_path / "p.toml"
    bad.write_text("[[experiment]]\nwaveform='sine'\n")
    with pytest.raises(ConfigError, match="waveform"):
        load_plan(bad)
    bad.write_text("[[experiment]]\namplitude=1\n")
    with pytest.raises(ConfigError, match="unknown key 'amplitude'"):
        load_plan(bad)


def test_cli_exit_codes(tmp_path):
    assert labrig("--version").returncode == 0
    p = labrig("frobnicate")
    assert p.returncode == 2 and "Traceback" not in p.stderr
    p = labrig("sweep", "--sim", "--rig", tmp_path / "nope.toml", "-o", tmp_path / "o")
    assert p.returncode == 2 and "nope.toml: rig file not found" in p.stderr
    (tmp_path / "bad.toml").write_text("[plant\n")
    p = labrig("sweep", "--sim", "--rig", tmp_path / "bad.toml", "-o", tmp_path / "o")
    assert p.returncode == 2 and "not valid TOML" in p.stderr


def test_seed_paper_table1_present():
    from labrig.table1 import read_table1

    tab = read_table1(ROOT / "data" / "paper_table1.csv")
    assert len(tab) == 8
    assert tab["speed_rpm"].abs().max() == 3150
