"""labrig analyse on simulated runs with known truth, the paper's Table 1 and bad inputs."""
import json
import math

import numpy as np
import pandas as pd
import pytest

from labrig.analyse import analyse, find_segments
from labrig.bridge.base import Experiment
from labrig.errors import AnalysisError
from labrig.model.servo import ServoParams
from labrig.runs import Run, make_meta, read_dataset, write_run
from conftest import ROOT, labrig, make_rig, sim_dataset, square_plan

# short plans keep the suite fast: half-periods of 1 s are > 6 time constants
AMPS = (1.0, 1.5, 2.0, 2.5)


def plan(amps=AMPS, rate=1000.0):
    return square_plan(amps=amps, rate=rate, periods=1, freq=0.5, lead=0.3)


def truth(rig):
    p = ServoParams.from_rig(rig)
    return p.km, p.tau_m_approx


@pytest.fixture(scope="module")
def linear_ds(tmp_path_factory):
    rig = make_rig(effects={})
    return sim_dataset(tmp_path_factory.mktemp("lin"), rig, plan()), rig


def test_linear_plant_km_tau_within_2_percent(linear_ds):
    ds, rig = linear_ds
    km, tau = truth(rig)
    res = analyse(ds)
    assert res.km == pytest.approx(km, rel=0.02)
    assert res.tau_s == pytest.approx(tau, rel=0.02)
    assert res.gain_trend == "constant"
    assert abs(res.deadband_v) < 0.05
    # per level: the paper's Km = w/V equals the incremental gain for a linear plant
    df = res.to_pandas()
    moving = df[df["moving"] & (df["input_v"].abs() > 0)]
    assert len(moving) == 8
    assert np.allclose(moving["km_paper"], km, rtol=0.02)
    # every edge fitted, 63 % point agrees with the fit
    edges = [e for r in res.runs for e in r.edges]
    assert len(edges) == 8 and all(e.ok for e in edges)
    assert all(abs(e.tau63_s - e.tau_s) < 0.1 * e.tau_s for e in edges)
    # both sensors: Kt from the pot agrees with the configured value
    assert res.kt == pytest.approx(0.026, rel=0.03) and res.kt_mismatch is False


def test_deadband_found_and_trend_rising(tmp_path):
    rig = make_rig(effects={"deadband": {"d_v": 0.5}})
    km, tau = truth(rig)
    res = analyse(sim_dataset(tmp_path, rig, plan()))
    assert res.deadband_v == pytest.approx(0.5, abs=0.05)
    assert res.gain_trend == "rising"
    assert res.km == pytest.approx(km, rel=0.02)       # slope above the deadband
    assert res.tau_s == pytest.approx(tau, rel=0.03)   # a deadband leaves tau alone
    assert "deadband" in res.verdict


def test_saturation_trend_falling(tmp_path):
    rig = make_rig(effects={"saturation": {"vmax_v": 8.0}})
    res = analyse(sim_dataset(tmp_path, rig, plan()))
    assert res.gain_trend == "falling"
    assert "saturation" in res.verdict
    # the slope is taken on the unsaturated levels (1.0 and 1.5 V)
    assert res.km == pytest.approx(truth(rig)[0], rel=0.03)


def test_coulomb_friction_trend_rising_verdict(tmp_path):
    rig = make_rig(effects={"coulomb_friction": {"tc_v": 0.13}})
    res = analyse(sim_dataset(tmp_path, rig, plan()))
    assert res.gain_trend == "rising"
    assert "friction" in res.verdict and "deadband" in res.verdict
    assert "ramp" in res.verdict       # names the experiment that separates them
    # the equivalent threshold Tc R / (K Ka) = 0.128 V
    assert res.deadband_v == pytest.approx(0.128, abs=0.03)


def test_staircase_at_100_hz(tmp_path):
    rig = make_rig(effects={"deadband": {"d_v": 0.5}})
    exp = Experiment(name="stair", waveform="staircase", levels=[0.25, 1.0, 1.5, 2.0, 2.5, -1.0, -2.0],
                     step_s=1.0, lead_in_s=0.3, sample_rate_hz=100)
    res = analyse(sim_dataset(tmp_path, rig, [exp]))
    km, tau = truth(rig)
    assert res.km == pytest.approx(km, rel=0.02)
    assert res.tau_s == pytest.approx(tau, rel=0.05)
    assert res.deadband_v == pytest.approx(0.5, abs=0.05)
    assert res.gain_trend == "rising"
    # 0.25 V lies inside the deadband: a level at rest, not a point of the line
    lv = {round(L.v, 2): L for L in res.levels}
    assert lv[0.25].moving is False


def test_position_only_run(tmp_path, linear_ds):
    ds, rig = linear_ds
    for r in read_dataset(ds):
        r.data = r.data.drop(columns="tacho")
        write_run(r, tmp_path / "pos")
    res = analyse(tmp_path / "pos")
    km, tau = truth(rig)
    assert all(r.sensor == "pos" for r in res.runs)
    assert res.km == pytest.approx(km, rel=0.02)
    assert res.tau_s == pytest.approx(tau, rel=0.03)
    assert res.kt is None            # no tacho: nothing to cross-check


def test_realistic_noise_and_no_lead_in_at_10_khz(tmp_path):
    rig = make_rig(effects={})
    rig.noise.tacho_v, rig.noise.pos_v = 0.08, 0.03     # 8x the default noise
    res = analyse(sim_dataset(tmp_path, rig, plan(amps=(1.0, 2.0))))
    km, tau = truth(rig)
    assert res.km == pytest.approx(km, rel=0.02)
    assert res.tau_s == pytest.approx(tau, rel=0.03)
    rig = make_rig(effects={})
    p = square_plan(amps=(1.0, 2.0), rate=10000, periods=1, freq=0.5, lead=0.0)
    res = analyse(sim_dataset(tmp_path, rig, p, name="fast"))
    assert res.km == pytest.approx(km, rel=0.02)
    assert res.tau_s == pytest.approx(tau, rel=0.02)


def test_kt_mismatch_flagged(tmp_path, linear_ds):
    ds, rig = linear_ds
    for r in read_dataset(ds)[:2]:
        r.meta["sensors"]["tacho_v_per_rad_s"] = 0.030
        write_run(r, tmp_path / "kt")
    res = analyse(tmp_path / "kt")
    assert res.kt == pytest.approx(0.026, rel=0.03)
    assert res.kt_mismatch is True and "tacho" in res.verdict


def test_paper_table1_says_saturation():
    res = analyse(ROOT / "data" / "paper_table1.csv")
    assert res.gain_trend == "falling"
    assert "saturation" in res.verdict
    assert res.tau_s is None
    d = res.to_dict()
    assert d["km_paper"]["1.2"] == pytest.approx(272.7, abs=1.0)
    json.dumps(d, allow_nan=False)


def test_find_segments_noisy_scope_trace():
    rng = np.random.default_rng(0)
    u = np.repeat([0.0, 1.5, -1.5, 1.5, 0.7], 400) + rng.normal(0, 0.01, 2000)
    starts, levels = find_segments(u)
    assert list(starts) == [0, 400, 800, 1200, 1600]
    assert np.allclose(levels, [0, 1.5, -1.5, 1.5, 0.7], atol=0.01)


def _run(u, fs=1000.0, name="bad"):
    t = np.arange(len(u)) / fs
    data = pd.DataFrame({"t": t, "u": u, "tacho": np.zeros_like(u), "pos": np.zeros_like(u)})
    meta = make_meta(sample_rate_hz=fs, experiment={"loop": "open"},
                     sensors={"tacho_v_per_rad_s": 0.026, "pos_v_per_rad": 0.5},
                     rig={"gear_ratio": 30.0}, source="import")
    return Run(name=name, data=data, meta=meta)


@pytest.mark.parametrize("u, msg", [
    (np.full(2000, 1.0), "constant"),
    (np.zeros(2000), "constant"),
    (np.linspace(0, 2, 2000), "not piecewise constant"),
])
def test_bad_inputs_give_clear_messages(u, msg):
    with pytest.raises(AnalysisError, match=msg):
        analyse([_run(u)])


def test_run_too_short_to_settle(tmp_path):
    rig = make_rig(effects={})
    ds = sim_dataset(tmp_path, rig, square_plan(amps=(1.5,), freq=5, periods=3, lead=0.1))
    with pytest.raises(AnalysisError, match="never settles"):
        analyse(ds)


def test_cli_json_figures_and_errors(tmp_path, linear_ds):
    ds, _ = linear_ds
    p = labrig("analyse", ds, "--json", "-o", tmp_path / "figs", check=0)
    d = json.loads(p.stdout)
    for k in ("deadband_v", "km", "tau_s", "kt", "gain_trend", "runs", "verdict"):
        assert k in d
    assert d["gain_trend"] in ("constant", "rising", "falling")
    assert sorted(x.name for x in (tmp_path / "figs").iterdir()) == [
        "edges_sq_1.00V.png", "edges_sq_1.50V.png", "edges_sq_2.00V.png", "edges_sq_2.50V.png",
        "km_vs_amplitude.png", "speed_vs_voltage.png"]
    p = labrig("analyse", ROOT / "data" / "sweep_default", check=0)
    assert "Km=w/V" in p.stdout and "cl_sq_0.50V: skipped (closed-loop" in p.stdout
    p = labrig("analyse", ROOT / "data" / "paper_table1.csv", "--json", check=0)
    assert json.loads(p.stdout)["gain_trend"] == "falling"
    write_run(_run(np.full(500, 1.0), name="flat"), tmp_path / "bad")
    p = labrig("analyse", tmp_path / "bad")
    assert p.returncode == 2 and "flat" in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
