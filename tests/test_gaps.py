"""Gaps are not data: samples the link lost (``gap = 1``, interpolated by the bridge) are
never fitted, scored or taken for noise, are counted where results are reported, and a
run that is mostly gaps is refused."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import labrig as lr
from labrig.cli import main
from test_malformed_inputs import _expect_user_error

ROOT = Path(__file__).resolve().parent.parent
GOOD = ROOT / "data" / "sweep_default"
OPEN = ("sq_1.20V", "sq_1.50V", "sq_2.00V", "sq_2.50V")


def _copy(dst: Path, names=OPEN) -> Path:
    dst.mkdir(parents=True, exist_ok=True)
    for n in names:
        for ext in (".csv", ".json"):
            shutil.copy(GOOD / f"{n}{ext}", dst / f"{n}{ext}")
    return dst


def _lose(folder: Path, share: float, seed: int = 3, junk: float = 0.5) -> int:
    """Mark bursts of samples lost (about ``share`` of each run) the way the bridge
    writes them (gap = 1), and put junk in the lost rows' sensor columns: if anything
    read them as measurements, it would show. Returns the rows marked."""
    rng = np.random.default_rng(seed)
    total = 0
    for csv in sorted(folder.glob("*.csv")):
        df = pd.read_csv(csv)
        n = len(df)
        gap = np.zeros(n, np.int8)
        while gap.mean() < share:
            a = int(rng.integers(0, n - 12))
            gap[a:a + int(rng.integers(3, 12))] = 1
        lost = gap == 1
        # biased junk: read as data, it would pull the gain and the levels
        df.loc[lost, "tacho"] += junk * (1 + np.abs(rng.standard_normal(lost.sum())))
        df.loc[lost, "pos"] += junk * (1 + np.abs(rng.standard_normal(lost.sum())))
        df["gap"] = gap
        df.to_csv(csv, index=False, float_format="%.7g")
        total += int(lost.sum())
    return total


@pytest.fixture(scope="module")
def clean_and_lossy(tmp_path_factory):
    root = tmp_path_factory.mktemp("gaps")
    clean = _copy(root / "clean")
    lossy = _copy(root / "lossy")
    lost = _lose(lossy, 0.2)
    assert _lose(_copy(root / "junk"), 0.2, junk=5.0) == lost  # the same rows, other junk
    return clean, lossy, lost


def test_analysis_leaves_lost_samples_out(clean_and_lossy):
    clean, lossy, lost = clean_and_lossy
    a, b = lr.analyse(clean).to_json(), lr.analyse(lossy).to_json()
    # junk of 0.5 V (20 rad/s on the tacho) in a fifth of the samples moves nothing
    assert b["km"] == pytest.approx(a["km"], rel=0.01)
    assert b["tau_s"] == pytest.approx(a["tau_s"], rel=0.05)
    assert b["deadband_v"] == pytest.approx(a["deadband_v"], abs=0.02)
    notes = [n for r in b["runs"] for n in r.get("notes") or []]
    assert sum(int(n.split(" of ")[0]) for n in notes if "lost on the link" in n) == lost


def test_identification_leaves_lost_samples_out(clean_and_lossy):
    clean, lossy, lost = clean_and_lossy
    from labrig.identification.table import identification_dict

    a, b = lr.identify(clean), lr.identify(lossy)
    ia, ib = (identification_dict(x)["identifiable"] for x in (a, b))
    for k in ("km", "tau_m_s"):  # the same plant, in what the data resolve
        assert ib[k]["value"] == pytest.approx(ia[k]["value"], rel=0.01), k
    # the noise floor is the sensor's, not the junk's (nor the smoothness of interpolation)
    na, nb = a.metrics["noise"], b.metrics["noise"]
    assert nb["speed_rad_s"] == pytest.approx(na["speed_rad_s"], rel=0.15)
    assert b.metrics["rmse_over_noise"]["overall"] == pytest.approx(
        a.metrics["rmse_over_noise"]["overall"], rel=0.1)
    from labrig.identification.result import identification_warnings

    # what the lost rows hold makes no difference at all
    c = lr.identify(lossy.parent / "junk")
    assert c.params == pytest.approx(b.params, rel=1e-9)
    said = [w for w in identification_warnings(b) if "lost on the link" in w]
    assert said and said[0].startswith(f"{lost} samples")
    assert not [w for w in identification_warnings(a) if "lost on the link" in w]


def test_residuals_and_floor_ignore_lost_samples(clean_and_lossy):
    """The objective counts only measured samples, and the adequacy of the clean fit on the
    lossy runs equals its adequacy on the same samples of the clean runs."""
    from labrig.identification.objective import Objective, build_space
    from labrig.io.runs import read_dataset

    clean, lossy, lost = clean_and_lossy
    rc, rl = read_dataset([clean]), read_dataset([lossy])
    oc, ol = (Objective(r, [], build_space([])) for r in (rc, rl))
    assert oc.m - ol.m == 2 * lost  # speed and position: one residual each per sample
    assert ol.n_gaps == lost and oc.n_gaps == 0


@pytest.mark.parametrize("stride", [2, 3, 7])
def test_a_subsample_of_the_residuals_is_the_same_samples(clean_and_lossy, stride):
    """The loop's re-fits see every k-th residual: computed alone, they are exactly those
    of all residuals, also with samples lost on the link and a fold's mask."""
    from labrig.identification.objective import Objective, build_space
    from labrig.io.runs import read_dataset

    runs = read_dataset([clean_and_lossy[1]])
    masks = [np.arange(len(r.u)) % 5 != 2 for r in runs]
    for m in (None, masks):
        obj = Objective(runs, [], build_space([]), p=0.6, q=1.4, masks=m)
        lo, hi = obj.space.search_bounds()
        X = lo + np.random.default_rng(1).random((3, lo.size)) * (hi - lo)
        every = obj.solver_residuals_batch(X)
        assert np.array_equal(obj.solver_residuals_batch(X, stride), every[:, ::stride])


@pytest.mark.parametrize("share,ok", [(0.45, True), (0.55, False), (1.0, False)])
def test_a_run_that_is_mostly_gaps_is_refused(tmp_path, capsys, share, ok):
    d = _copy(tmp_path / "runs", names=("sq_2.00V",))
    csv = d / "sq_2.00V.csv"
    df = pd.read_csv(csv)
    gap = np.zeros(len(df), np.int8)
    gap[: int(share * len(df))] = 1
    df["gap"] = gap
    df.to_csv(csv, index=False)
    if ok:
        from labrig.io.runs import read_run

        assert read_run(csv).n_gaps == int(share * len(df))
        return
    line = _expect_user_error(capsys, ["identify", d], "sq_2.00V.csv", "lost on the link",
                              "record the run again")
    assert f"{int(share * len(df))} of {len(df)}" in line


@pytest.mark.parametrize("value", ["2", "0.5", "-1"])
def test_an_invalid_gap_flag_is_a_user_error(tmp_path, capsys, value):
    d = _copy(tmp_path / "runs", names=("sq_2.00V",))
    csv = d / "sq_2.00V.csv"
    df = pd.read_csv(csv).astype({"u": float})
    df["gap"] = 0
    df.to_csv(csv, index=False)
    lines = csv.read_text().splitlines()
    lines[11] = lines[11][: lines[11].rindex(",")] + "," + value
    csv.write_text("\n".join(lines) + "\n")
    _expect_user_error(capsys, ["analyse", d], "row 12", "column 'gap'")


@pytest.mark.parametrize("col,value", [("u", "1e300"), ("u", "9.2e18"), ("tacho", "-3e5"),
                                       ("pos", "1e13")])
def test_a_value_outside_any_physical_range_is_refused(tmp_path, capsys, col, value):
    d = _copy(tmp_path / "runs", names=("sq_2.00V",))
    csv = d / "sq_2.00V.csv"
    df = pd.read_csv(csv).astype(str)
    df.loc[40, col] = value
    df.to_csv(csv, index=False)
    _expect_user_error(capsys, ["identify", d], "row 42", f"column '{col}'",
                       "outside any physical range")


def test_an_import_outside_any_physical_range_writes_nothing(tmp_path, capsys):
    src = tmp_path / "scope.csv"
    rows = [f"{i * 0.001:.3f},{1e300 if i == 20 else (i // 10) % 2},{i % 5}"
            for i in range(60)]
    src.write_text("Time,CH1,CH2\n" + "\n".join(rows) + "\n")
    _expect_user_error(capsys, ["import", src, "--map", "t=Time,u=CH1,speed=CH2", "-o",
                                tmp_path / "out"], "column 'CH1'", "outside any physical range")
    assert not list((tmp_path / "out").glob("*.json")) if (tmp_path / "out").exists() else True


def test_compare_counts_and_draws_lost_samples_as_gaps(clean_and_lossy, tmp_path):
    """The model-vs-measurement view: a lost stretch is a break in the lines, shaded and
    labelled, never a residual of zero that looks like a perfect fit; the counts and the
    regime table leave it out."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    _, lossy, lost = clean_and_lossy
    ev = lr.compare(lossy, lr.identify(lossy))
    total = sum(len(r.u) for r in lr.read_runs(lossy))
    assert ev.metrics["counts"] == {"speed": total - lost, "position": total - lost}
    assert ev.n == 2 * (total - lost)
    fig = ev.plot(run="sq_1.20V")
    fig.savefig(tmp_path / "lossy_compare.png", dpi=60)
    resid = fig.axes[1]
    line = resid.get_lines()[0].get_ydata()
    rr = next(r for r in ev.per_run if r["name"] == "sq_1.20V")
    assert np.isnan(line[rr["lost"]]).all() and np.isfinite(line[~rr["lost"]]).all()
    labels = [h.get_label() for h in resid.patches]
    assert "lost on the link (not fitted)" in labels
