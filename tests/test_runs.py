"""Run files (docs/design.md, 'Run files'): every bad case gives one clear line and exit code 2."""
import json

import numpy as np
import pandas as pd
import pytest

from labrig.core.errors import RunFileError
from labrig.io.runs import Run, make_meta, read_dataset, read_run, write_run
from conftest import labrig

META = {"format": "labrig-run/1", "sample_rate_hz": 1000,
        "experiment": {"loop": "open"},
        "sensors": {"tacho_v_per_rad_s": 0.026, "pos_v_per_rad": 0.5, "pos_offset_v": -4.0},
        "rig": {"gear_ratio": 30}}


def good_run(tmp_path, name="r", n=50, meta=None):
    t = np.arange(n) / 1000.0
    u = np.where(t > 0.01, 1.5, 0.0)
    df = pd.DataFrame({"t": t, "u": u, "tacho": 0.026 * 100 * u, "pos": -4 + 0.5 * t})
    write_run(Run(name, df, meta or dict(META)), tmp_path)
    return tmp_path / f"{name}.csv"


def test_round_trip_units(tmp_path):
    path = good_run(tmp_path)
    run = read_run(path)
    assert run.fs == 1000 and len(run) == 50
    np.testing.assert_allclose(run.speed[-1], 150.0, rtol=1e-6)          # rad/s
    np.testing.assert_allclose(run.position, np.arange(50) / 1000.0, atol=1e-6)  # rad
    assert run.gear_ratio == 30


def test_minimal_sidecar_accepted_and_notes_kept(tmp_path):
    path = good_run(tmp_path, meta=dict(META, notes={"a": 1}))
    run = read_run(path)
    assert run.meta["notes"] == {"a": 1}  # the user's own notes ride along


def test_an_unknown_sidecar_key_is_refused(tmp_path):
    """A misspelt key would otherwise be a silently missing value."""
    path = good_run(tmp_path, meta=dict(META, extra_key={"a": 1}))
    with pytest.raises(RunFileError, match="unknown key 'extra_key'"):
        read_run(path)


def test_never_overwrites_silently(tmp_path):
    good_run(tmp_path)
    with pytest.raises(RunFileError, match="already exists"):
        good_run(tmp_path)


def test_no_temp_files_left(tmp_path):
    good_run(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv", "r.json"]


def corrupt(tmp_path, csv_text=None, meta=None, drop_json=False):
    path = good_run(tmp_path)
    if csv_text is not None:
        path.write_text(csv_text)
    if meta is not None:
        path.with_suffix(".json").write_text(meta if isinstance(meta, str) else json.dumps(meta))
    if drop_json:
        path.with_suffix(".json").unlink()
    return path


GOOD_ROWS = "0,0,0,0\n0.001,1,0,0\n0.002,1,0.1,0\n"


def speed_meta(unit):
    """A sidecar for a run with a physical 'speed' column in ``unit``."""
    return dict(META, sensors={"speed_unit": unit, "pos_v_per_rad": 0.5})


CASES = {
    "empty file": ("", None, "empty"),
    "no header": ("0,0,0,0\n0.001,1,0,0\n", None, "no header"),
    "missing t": ("u,tacho,pos\n0,0,0\n1,0,0\n", None, "column 't' missing"),
    "missing u": ("t,tacho,pos\n0,0,0\n0.001,0,0\n", None, "column 'u' missing"),
    "no sensors": ("t,u\n0,0\n0.001,1\n", None, "no sensor column"),
    "non-numeric": ("t,u,tacho,pos\n0,0,0,0\n0.001,abc,0,0\n", None, "row 3, column 'u'.*non-numeric"),
    "nan": ("t,u,tacho,pos\n0,0,0,0\n0.001,1,nan,0\n", None, "row 3, column 'tacho': NaN"),
    "inf": ("t,u,tacho,pos\n0,0,0,0\n0.001,1,0,inf\n", None, "row 3, column 'pos': NaN or inf"),
    "t decreasing": ("t,u,tacho,pos\n0,0,0,0\n0.002,1,0,0\n0.001,1,0,0\n", None,
                     "row 4, column 't'.*strictly increasing"),
    "t not uniform": ("t,u,tacho,pos\n0,0,0,0\n0.001,1,0,0\n0.003,1,0,0\n0.004,1,0,0\n", None,
                      "row 4, column 't'.*uniform"),
    "sidecar malformed": ("t,u,tacho,pos\n" + GOOD_ROWS, "{not json", "not valid JSON"),
    "unknown format": ("t,u,tacho,pos\n" + GOOD_ROWS, dict(META, format="other/9"),
                       "key 'format'"),
    "rate mismatch": ("t,u,tacho,pos\n" + GOOD_ROWS, dict(META, sample_rate_hz=500),
                      "sample_rate_hz.*1000 Hz"),
    "bad loop": ("t,u,tacho,pos\n" + GOOD_ROWS, dict(META, experiment={"loop": "sideways"}),
                 "experiment.loop"),
    # a 'speed' column is physical speed: its unit stated, the axis's, and never a tacho too
    "speed without unit": ("t,u,speed,pos\n" + GOOD_ROWS, META,
                           r"r.json: key 'sensors.speed_unit' missing.*add \"speed_unit\": "
                           r"\"rad/s\""),
    "speed unit unknown": ("t,u,speed,pos\n" + GOOD_ROWS, speed_meta("rpm"),
                           "key 'sensors.speed_unit' = 'rpm': input should be 'rad/s' or 'm/s'"),
    "speed unit of the other axis": ("t,u,speed,pos\n" + GOOD_ROWS, speed_meta("m/s"),
                                     "'sensors.speed_unit' = 'm/s' but the axis is rotary"),
    "speed and tacho": ("t,u,tacho,speed,pos\n0,0,0,0,0\n0.001,1,0,0,0\n0.002,1,0.1,4,0\n",
                        speed_meta("rad/s"), "r.csv: both a 'speed' and a 'tacho' column"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_run_files(tmp_path, case):
    text, meta, msg = CASES[case]
    path = corrupt(tmp_path, text, meta)
    with pytest.raises(RunFileError, match=msg) as exc:
        read_run(path)
    assert str(path.name) in str(exc.value) or path.with_suffix(".json").name in str(exc.value)
    assert "\n" not in str(exc.value)


def test_speed_column_round_trip(tmp_path):
    """Physical speed (an import without a tacho) is written after u and read as it is."""
    t = np.arange(50) / 1000.0
    df = pd.DataFrame({"pos": -4 + 0.5 * t, "t": t, "u": np.ones(50), "speed": 150.0 + t})
    path = write_run(Run("s", df, speed_meta("rad/s")), tmp_path)
    assert path.read_text().splitlines()[0] == "t,u,speed,pos"
    run = read_run(path)
    assert run.has_speed and not run.has_tacho
    np.testing.assert_allclose(run.speed, 150.0 + t, rtol=1e-7)
    assert run.constants["Kt"] == 1.0 and run.sensors["speed_unit"] == "rad/s"


def test_speed_column_without_unit_cli_exit_2(tmp_path):
    path = corrupt(tmp_path, "t,u,speed,pos\n" + GOOD_ROWS)
    proc = labrig("analyse", path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().count("\n") == 0
    assert "r.json: key 'sensors.speed_unit' missing" in proc.stderr


def test_missing_file_and_sidecar(tmp_path):
    with pytest.raises(RunFileError, match="not found"):
        read_run(tmp_path / "nope.csv")
    path = corrupt(tmp_path, drop_json=True)
    with pytest.raises(RunFileError, match="sidecar missing"):
        read_run(path)
    with pytest.raises(RunFileError, match="no runs"):
        read_dataset(tmp_path / "empty") if (tmp_path / "empty").mkdir() is None else None


def test_cli_exit_code_2_no_traceback(tmp_path):
    path = corrupt(tmp_path, "t,u,tacho,pos\n0,0,0,0\n0.001,1,nan,0\n")
    proc = labrig("analyse", path, check=None)
    # analyse may not exist in an early build; the run check is what matters here
    if "invalid choice" not in proc.stderr:
        assert proc.returncode == 2
        assert "Traceback" not in proc.stderr
        assert proc.stderr.strip().count("\n") == 0
        assert "row 3, column 'tacho'" in proc.stderr
