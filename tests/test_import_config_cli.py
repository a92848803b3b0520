"""labrig import, configuration files and CLI exit codes."""
import json
import math

import numpy as np
import pytest

from labrig.io.config import load_plan, load_rig, rig_from_dict
from labrig.core.errors import ConfigError
from labrig.io.runs import Run, read_dataset, read_run
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


@pytest.mark.parametrize("cli,unit,value", [
    ((), "rad/s", 3000 * 2 * math.pi / 60),                       # 314.159... rad/s
    (("--drive", "force", "--input-gain", "20"), "m/s", 0.25),     # 250 mm/s on a carriage
])
def test_imported_speed_is_stored_as_speed_with_its_unit(tmp_path, cli, unit, value):
    # physical speed is speed: no 'tacho' column, no tacho gain, the unit in the sidecar
    src = tmp_path / "drive_log.csv"
    given = 3000 if unit == "rad/s" else 250
    src.write_text("Time,CH1,V\n" + "".join(f"{i * 0.01:.2f},1,{given}\n" for i in range(20)))
    labrig("import", src, "-o", tmp_path / "ds", "--map", "t=Time,u=CH1,speed=V",
           "--speed-unit", "rpm" if unit == "rad/s" else "mm/s", *cli, check=0)
    csv = (tmp_path / "ds" / "drive_log.csv").read_text().splitlines()
    assert csv[0] == "t,u,speed"
    stored = float(csv[1].split(",")[2])
    assert stored == pytest.approx(float(f"{value:.7g}"), rel=1e-9)   # the conversion, rounded
    assert stored == pytest.approx(value, rel=5e-7)                   # as every column is
    sensors = json.loads((tmp_path / "ds" / "drive_log.json").read_text())["sensors"]
    assert sensors == {"speed_unit": unit}
    run = read_run(tmp_path / "ds" / "drive_log.csv")
    assert run.has_speed and not run.has_tacho and run.units[1] == unit
    np.testing.assert_array_equal(run.speed, np.full(20, stored))
    assert run.constants["Kt"] == 1.0


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
    # raw tacho volts stay volts, with their gain
    assert run.has_tacho and "speed" not in run.data and run.kt == 0.026
    assert "speed_unit" not in run.sensors


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
    from labrig.io.steady_table import read_table1

    tab = read_table1(ROOT / "data" / "paper_table1.csv")
    assert len(tab) == 8
    assert tab["speed_rpm"].abs().max() == 3150


# -- an imported speed through analyse and identify ------------------------------------

@pytest.fixture(scope="module")
def imported_speed(tmp_path_factory):
    """Simulated square waves exported as another lab would (rpm and degrees, no tacho)
    and imported: runs with a 'speed' column and a pot. Returns (folder, rig)."""
    from labrig.io.importer import import_csv
    from conftest import make_rig, sim_dataset, square_plan

    tmp = tmp_path_factory.mktemp("imported_speed")
    rig = make_rig(effects={})
    plan = square_plan(amps=(1.2, 2.0), rate=200.0, periods=1, freq=0.5, lead=0.3)
    for r in read_dataset(sim_dataset(tmp, rig, plan)):
        src = tmp / f"{r.name}_export.csv"
        rows = zip(r.t, r.u, r.speed * 30 / math.pi, np.degrees(r.position))
        src.write_text("Time,CH1,RPM,deg\n" + "".join(f"{a:.4f},{b:.6g},{c:.9g},{d:.9g}\n"
                                                      for a, b, c, d in rows))
        import_csv(src, tmp / "imported", {"t": "Time", "u": "CH1", "speed": "RPM", "pos": "deg"},
                   speed_unit="rpm", pos_unit="deg", gear_ratio=rig.gear_ratio,
                   amplifier_gain=rig.amplifier.gain, waveform="square", name=r.name)
    return tmp / "imported", rig


def test_analyse_of_imported_speed_shows_no_tacho_volts_and_no_kt(imported_speed, capsys):
    from labrig.analysis import analyse
    from labrig.analysis.text import NO_TACHO
    from labrig.cli import main
    from labrig.model.servo import ServoParams

    ds, rig = imported_speed
    res = analyse(ds)
    assert res.km == pytest.approx(ServoParams.from_rig(rig).km, rel=0.02)
    levels, summary = res.table_rows()
    vt = levels.columns.index("Vt (V)")
    assert all(row[vt] == "-" for row in levels.rows)
    assert dict((r[0], r[1]) for r in summary.rows)["kt"] == NO_TACHO
    assert main(["analyse", str(ds)]) == 0
    text = capsys.readouterr().out
    assert NO_TACHO in text and "V per rad/s" not in text and "configured" not in text
    assert main(["analyse", str(ds), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["kt"] is None and doc["kt_configured"] is None and doc["kt_mismatch"] is None
    assert all(r["sensor"] == "speed" and r["kt_est"] is None for r in doc["runs"])


def test_identify_on_imported_speed_is_the_fit_of_the_old_virtual_tacho(imported_speed):
    """The data did not change, only their storage: a CO fit on the 'speed' runs is
    bit-identical to one on the same samples stored the old way (tacho volts at 1 V per
    rad/s)."""
    from labrig.identification.engine import identify
    from labrig.model.servo import ServoParams

    ds, rig = imported_speed
    runs = read_dataset(ds)
    old = []
    for r in runs:
        meta = json.loads(json.dumps(r.meta))
        meta["sensors"] = {k: v for k, v in meta["sensors"].items() if k != "speed_unit"}
        meta["sensors"]["tacho_v_per_rad_s"] = 1.0
        old.append(Run(r.name, r.data.rename(columns={"speed": "tacho"}), meta))
    assert all(np.array_equal(a.speed, b.speed) for a, b in zip(runs, old))
    assert [a.constants for a in runs] == [b.constants for b in old]
    new_fit = identify(runs, "co", seed=1, starts=2)
    old_fit = identify(old, "co", seed=1, starts=2)
    assert new_fit.params == old_fit.params
    assert new_fit.metrics == old_fit.metrics
    assert new_fit.identifiable["km"]["value"] == pytest.approx(ServoParams.from_rig(rig).km,
                                                                rel=0.02)
