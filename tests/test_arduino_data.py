"""Exercise 5's example logs (data/arduino_hbridge/) are what their script makes from the
simulated rig, and they import as position-only encoder runs with the sheet's options."""
import importlib.util

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, labrig

DATA = ROOT / "data" / "arduino_hbridge"


def _make():
    spec = importlib.util.spec_from_file_location("make_arduino", DATA / "make.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.make


def test_the_logs_are_what_the_script_makes(tmp_path):
    made = _make()(tmp_path)
    assert sorted(p.name for p in made) == sorted(p.name for p in DATA.glob("step_*.csv"))
    for p in made:
        new, old = pd.read_csv(p), pd.read_csv(DATA / p.name)
        assert list(old.columns) == ["ms", "u_V", "count"]
        assert (new["ms"] == old["ms"]).all() and np.allclose(new["u_V"], old["u_V"], atol=1e-3)
        # a count may flip where the angle sits within rounding of an edge
        assert (new["count"] - old["count"]).abs().max() <= 1
        assert ((new["count"] != old["count"]).mean()) < 1e-3


def test_a_log_imports_as_an_encoder_run(tmp_path):
    src = DATA / "step_6.00V.csv"
    labrig("import", src, "--map", "t=ms,u=u_V,pos=count", "--time-unit", "ms",
           "--pos-unit", "counts:1320", "--gear-ratio", "30", "-o", tmp_path, check=0)
    from labrig.io.runs import read_run

    run = read_run(tmp_path / "step_6.00V.csv")
    assert run.fs == 200.0
    assert run.sensors["pos_kind"] == "encoder"
    assert run.sensors["pos_quantum"] == 2 * np.pi / 1320            # one count, in rad
    # 6 V for 1 s: the output shaft turns several times, one count is 1/1320 of a turn
    th = run.position
    assert np.max(np.abs(th)) > 2 * np.pi
    k = th / run.sensors["pos_quantum"]          # whole counts, nothing in between
    assert np.allclose(k, np.round(k), atol=1e-6)


def test_a_dead_zone_may_be_volts_wide_on_a_12_v_bridge():
    """Input thresholds are bounded by what the rig's bridge can output: 2.1 V is a real
    H-bridge dead zone at 12 V, while on the MS150's 2.5 V bridge 3 V is refused."""
    from labrig.io.config import load_rig, rig_from_dict
    from labrig.core.errors import ConfigError

    rig = load_rig(ROOT / "configs" / "rig_arduino_hbridge.toml")
    assert rig.effects["asymmetric_deadband"] == {"dpos_v": 1.5, "dneg_v": 2.1}
    with pytest.raises(ConfigError, match=r"d_v' = 3 is out of range \[0.001, 2.5\] V"):
        rig_from_dict({"effects": {"deadband": {"d_v": 3.0}}}, "r.toml")
