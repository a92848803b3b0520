"""labrig analyse on simulated runs with known truth, the paper's Table 1 and bad inputs."""
import json
import math

import numpy as np
import pandas as pd
import pytest

from labrig.analysis import analyse, find_segments
from labrig.io.experiment import Experiment
from labrig.core.errors import AnalysisError
from labrig.model.servo import ServoParams
from labrig.io.runs import Run, make_meta, read_dataset, write_run
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


def test_paper_table1_gain_trend_is_the_plain_fall_of_w_over_v():
    # Table 1: w/V is 2600 rpm/V (272.7 rad/s per V, both directions) at 1.2 V and
    # 1260 rpm/V (131.9) at 2.5 V: a fall of 51.6 %, which the summary and the verdict
    # print and explain (a regression slope times span over mean said -70.1 %)
    from labrig.analysis.text import summary_table

    res = analyse(ROOT / "data" / "paper_table1.csv")
    assert res.trend["relative_change"] == pytest.approx(131.95 / 272.7 - 1, abs=5e-4)
    assert res.trend["amplitude_range_v"] == pytest.approx([1.2, 2.5])
    detail = next(r[2] for r in summary_table(res).rows if r[0] == "gain trend")
    assert detail.startswith("w/V changes by -51.6 % from 1.2 V to 2.5 V (mean w/V at the "
                             "largest amplitude over that at the smallest, minus 1)")
    assert "w/V goes from 272.7 to 131.9 rad/s per V between 1.2 and 2.5 V, -51.6 %" in res.verdict


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


# -- the redesigned package: typed edges, tables, figure objects ----------------------

TOP_KEYS = ["deadband_v", "km", "tau_s", "kt", "gain_trend", "runs", "verdict", "km_paper",
            "trend", "tolerance", "breakaway_v", "forward", "reverse", "asymmetry",
            "line_region", "kt_configured", "kt_mismatch", "source", "figures"]
RUN_KEYS = ["name", "loop", "sample_rate_hz", "skipped", "sensor", "tau_s", "kt_est", "levels",
            "edges", "notes", "figure"]
EDGE_KEYS = ["t_s", "v_from", "v_to", "kind", "speed_from", "speed_to", "tau_s", "tau63_s",
             "delay_s", "fit_nrmse", "note"]
LEVEL_KEYS = ["v", "speed_rad_s", "spread_rad_s", "km_paper", "moving", "segments", "settled",
              "tau_s"]


def test_json_keys_pinned_and_to_dict_alias(linear_ds):
    res = analyse(linear_ds[0])
    d = res.to_json()
    # (the keys, not their order: a JSON object has none; the declaration's derived keys
    # come after its fields)
    assert sorted(d) == sorted(TOP_KEYS) and res.to_dict() == d
    r = d["runs"][0]
    assert sorted(r) == sorted(RUN_KEYS)
    assert sorted(r["edges"][0]) == sorted(EDGE_KEYS)
    assert sorted(r["levels"][0]) == sorted(LEVEL_KEYS)
    json.dumps(d, allow_nan=False)


def test_edge_conditions_are_booleans_and_the_note_is_derived():
    from labrig.analysis import EdgeFit, StepFit

    def edge(**flags):
        return EdgeFit(index=0, t_s=0.0, v_from=0.0, v_to=1.0, kind="from_rest",
                       fit=StepFit(nrmse=0.234, error="boom"), **flags)
    assert edge().note == "" and edge().to_json()["note"] is None
    assert edge(too_short=True).note == "segment too short to fit"
    assert edge(no_response=True).note == "no speed change (the motor did not respond)"
    assert edge(fit_failed=True).note == "fit failed (boom)"
    assert edge(not_settled=True, tau_at_bound=True).note == (
        "time constant longer than half the segment: not settled; time constant at a bound "
        "of the search")
    low = EdgeFit(index=0, t_s=0.0, v_from=0.0, v_to=1.0, kind="speed", tau_at_bound=True,
                  fit=StepFit(tau=1e-4, tau_bound="lower"))
    assert low.note == ("time constant at its lower bound, a quarter of a sample: faster "
                        "than this sampling can show")
    assert edge(poor_fit=True, t63_disagrees=True).to_json()["note"] == (
        "poor first-order fit (residual 23 % of the step); 63 % point disagrees with the fit")


def test_edge_flags_from_real_fits():
    """A 4-sample visit to a level is too short to fit; an edge inside the deadband
    gives no response; a time constant longer than half its segment is rejected."""
    fs, tau, k = 1000.0, 0.1, 100.0
    u = np.concatenate([np.repeat([0.0, 1.0], 800), [2.0] * 4, np.repeat([1.0, -1.0, 0.0], 800),
                        np.repeat([0.05, 0.0, 2.0], 800)])
    drive = np.where(np.abs(u) > 0.2, u, 0.0)        # a deadband of 0.2 V
    y = np.zeros_like(u)
    for i in range(1, len(u)):
        y[i] = y[i - 1] + (k * drive[i - 1] - y[i - 1]) / (tau * fs)
    y += np.random.default_rng(1).normal(0, 0.3, len(u))
    run = _run(u)
    run.data["tacho"] = y * 0.026
    ra = analyse([run]).runs[0]
    by_v = {(round(e.v_from, 2), round(e.v_to, 2)): e for e in ra.edges}
    assert by_v[(1.0, 2.0)].too_short and not by_v[(1.0, 2.0)].ok
    assert by_v[(0.0, 0.05)].no_response and by_v[(0.0, 0.05)].speed_to is not None
    good = by_v[(0.0, 1.0)]
    assert good.ok and not any([good.too_short, good.no_response, good.not_settled,
                                good.tau_at_bound, good.fit_failed])
    assert good.tau_s == pytest.approx(tau, rel=0.05) and good.fit.accepted
    # tau = 0.2 s on 0.3 s segments: fitted but rejected as not settled
    u2 = np.concatenate([np.repeat([0.0, 1.0, -1.0, 2.0], 300), np.repeat([1.0, -1.0], 3000)])
    y2 = np.zeros_like(u2)
    for i in range(1, len(u2)):
        y2[i] = y2[i - 1] + (k * u2[i - 1] - y2[i - 1]) / (0.2 * fs)
    run2 = _run(u2)
    run2.data["tacho"] = y2 * 0.026
    edges = analyse([run2]).runs[0].edges
    rejected = [e for e in edges if e.not_settled]
    assert rejected and all(not e.ok and e.fit.ran and "not settled" in e.note
                            for e in rejected)


def test_table_rows_are_tables_and_the_summary_prints_them(linear_ds):
    from labrig.core.tables import Table

    res = analyse(linear_ds[0])
    levels, summary = res.table_rows()
    assert isinstance(levels, Table) and isinstance(summary, Table)
    assert len(levels.rows) == len(res.levels)
    assert all(len(r) == len(t.columns) for t in (levels, summary) for r in t.rows)
    assert len(set(levels.columns)) == len(levels.columns)
    assert [r[0] for r in summary.rows] == ["km (incremental)", "deadband", "tau_m", "kt",
                                            "gain trend"]
    assert summary.rows[-1][1] == "constant"
    text = res.summary()
    assert "Km=w/V" in text and res.verdict in text
    # the closed-loop runs of the example sweep are listed under the level table
    ex = analyse(ROOT / "data" / "sweep_default")
    assert any(n.startswith("cl_sq_0.50V: skipped (closed-loop") for n in ex.table_rows()[0].notes)


def test_figures_are_objects_drawn_on_demand(linear_ds, tmp_path, monkeypatch):
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    from labrig.analysis.plots import plot_edges, plot_km_vs_amplitude

    monkeypatch.chdir(tmp_path)
    res = analyse(linear_ds[0])
    plt.close("all")
    figs = res.figures()
    # names without drawing: nothing is open until a figure is looked up
    assert list(figs) == ["edges_sq_1.00V.png", "edges_sq_1.50V.png", "edges_sq_2.00V.png",
                          "edges_sq_2.50V.png", "speed_vs_voltage.png", "km_vs_amplitude.png"]
    assert plt.get_fignums() == []
    for name, fig in figs.items():
        assert isinstance(fig, Figure) and fig.axes
        plt.close(fig)
    fig = res.plot()
    assert isinstance(fig, Figure) and "Speed against voltage" in fig.axes[0].get_title()
    # drawn on the caller's Axes: same figure back, nothing saved anywhere
    own, axes = plt.subplots(1, 3)
    assert res.plot(ax=axes[0]) is own
    assert plot_km_vs_amplitude(res, ax=axes[1]) is own
    assert plot_edges(res.runs[0], ax=axes[2]) is own and axes[2].get_lines()
    assert list(tmp_path.iterdir()) == [] and res.to_json()["figures"] == []
    plt.close("all")


def test_saving_closes_figures_and_records_paths(linear_ds, tmp_path):
    import matplotlib.pyplot as plt

    from labrig.cli import main

    plt.close("all")
    assert main(["analyse", str(linear_ds[0]), "-o", str(tmp_path / "f"), "--json"]) == 0
    assert plt.get_fignums() == []
    res = analyse(linear_ds[0])
    with pytest.warns(DeprecationWarning):
        paths = res.plot(tmp_path / "old")       # the old plot(figdir), kept for callers
    assert [p.split("/")[-1] for p in paths] == list(res.figures())
    assert res.to_json()["figures"] == paths and plt.get_fignums() == []
    assert res.to_json()["runs"][0]["figure"] == str(tmp_path / "old" / "edges_sq_1.00V.png")


def test_package_modules_are_small_and_share_no_private_names():
    import ast

    pkg = ROOT / "labrig" / "analysis"
    for f in pkg.glob("*.py"):
        src = f.read_text(encoding="utf-8")
        assert len(src.splitlines()) <= 400, f.name
        for node in ast.walk(ast.parse(src)):
            if isinstance(node, ast.ImportFrom):
                assert not [a.name for a in node.names if a.name.startswith("_")], \
                    f"{f.name} imports a private name from {node.module}"
