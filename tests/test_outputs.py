"""Output files and machine output: nothing is overwritten without --force (refused
before any fitting), --json survives inf/NaN, and fits at a bound or below 0 % say so."""
import json
import math
import os
import re

import numpy as np
import labrig.diagnosis.loop.search  # noqa: F401  (imported before any patching: it binds diagnose)
import pytest

from labrig.cli import main
from labrig.commands.registry import emit_json
from labrig.identification.objective import build_space
from conftest import make_rig, sim_dataset, square_plan

P = make_rig().plant
# R, L, K known (locked-rotor and back-EMF tests): a fit of J and B takes a fraction of a second
FIX = f"R={P.R},L={P.L},K={P.K}"


def strict_loads(text):
    def bad(name):
        raise AssertionError(f"non-strict JSON constant {name}")
    return json.loads(text, parse_constant=bad)


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    plan = square_plan(amps=(1.2, 2.0), rate=200.0, periods=1)
    return sim_dataset(tmp_path_factory.mktemp("out"), make_rig(effects={}), plan, seed=1)


@pytest.fixture(scope="module")
def model(ds, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "m.json"
    assert main(["identify", str(ds), "--fix", FIX, "--starts", "1", "--seed", "1",
                 "-o", str(path)]) == 0
    return path


def run(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def no_call(*a, **k):
    raise AssertionError("the long computation ran before the output check")


def assert_refused(rc, err, path):
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("labrig: error: "), err
    assert str(path) in lines[0] and "already exists" in lines[0]
    assert lines[0].endswith("add --force to replace it"), err


# -- A. nothing is overwritten silently ----------------------------------------------

def test_identify_refuses_existing_model_before_fitting_and_force_replaces(ds, tmp_path,
                                                                          capsys, monkeypatch):
    out = tmp_path / "model.json"
    out.write_text("keep")
    with monkeypatch.context() as m:
        m.setattr("labrig.identification.engine.identify", no_call)
        rc, _, err = run(capsys, "identify", ds, "--fix", FIX, "--starts", "1", "-o", out)
    assert_refused(rc, err, out)
    assert out.read_text() == "keep"
    rc, _, err = run(capsys, "identify", ds, "--fix", FIX, "--starts", "1", "--seed", "1",
                     "-o", out, "--force")
    assert rc == 0, err
    assert json.loads(out.read_text())["format"] == "labrig-model/1"


def test_identify_refuses_existing_convergence_figure(ds, tmp_path, capsys, monkeypatch):
    (tmp_path / "figs").mkdir()
    fig = tmp_path / "figs" / "convergence.png"
    fig.write_text("keep")
    monkeypatch.setattr("labrig.identification.engine.identify", no_call)
    rc, _, err = run(capsys, "identify", ds, "--figures", tmp_path / "figs")
    assert_refused(rc, err, fig)


def test_identify_output_that_is_a_folder_is_a_user_error(ds, tmp_path, capsys):
    rc, _, err = run(capsys, "identify", ds, "-o", tmp_path, "--force")
    assert rc == 2 and "is a folder; give a file name" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("cmd", ["compare", "diagnose", "ladder", "report", "mystery"])
def test_every_output_file_is_refused_before_the_work(cmd, ds, model, tmp_path, capsys,
                                                      monkeypatch):
    for target in ("labrig.diagnosis.evidence.evaluation.evaluate", "labrig.diagnosis.loop.diagnose.diagnose",
                   "labrig.diagnosis.loop.search.auto_ladder", "labrig.diagnosis.results.ladder.evaluate_ladder",
                   "labrig.report.html.build_report", "labrig.io.mystery.new_mystery"):
        monkeypatch.setattr(target, no_call)
    folder = tmp_path / "o"
    folder.mkdir()
    existing, argv = {
        "compare": (folder / "regimes.png", ["compare", ds, "--model", model, "-o", folder]),
        "diagnose": (tmp_path / "m1.json", ["diagnose", ds, "--model", model, "-o", tmp_path / "m1.json"]),
        "ladder": (folder / "ladder.png", ["ladder", ds, "--models", model, "-o", folder]),
        "report": (tmp_path / "r.html", ["report", ds, "-o", tmp_path / "r.html"]),
        "mystery": (tmp_path / "x.mystery", ["mystery", "new", "--seed", "3", "-o", tmp_path / "x.mystery"]),
    }[cmd]
    existing.write_text("keep")
    rc, _, err = run(capsys, *argv)
    assert_refused(rc, err, existing)
    assert existing.read_text() == "keep"


def test_ladder_automatic_mode_refuses_its_step_files(ds, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("labrig.diagnosis.loop.search.auto_ladder", no_call)
    (tmp_path / "step0.json").write_text("keep")
    rc, _, err = run(capsys, "ladder", ds, "-o", tmp_path)
    assert_refused(rc, err, tmp_path / "step0.json")


def test_compare_and_report_force_and_an_existing_empty_folder(ds, model, tmp_path, capsys,
                                                               monkeypatch):
    folder = tmp_path / "cmp"
    folder.mkdir()  # an existing folder is fine: only the files it would write count
    (folder / "notes.txt").write_text("mine")
    rc, out, err = run(capsys, "compare", ds, "--model", model, "-o", folder)
    assert rc == 0, err
    assert "figures in" in out
    rc, _, err = run(capsys, "compare", ds, "--model", model, "-o", folder)
    assert_refused(rc, err, folder / "compare_sq_1.20V.png")
    rc, _, err = run(capsys, "compare", ds, "--model", model, "-o", folder, "--force")
    assert rc == 0, err
    assert (folder / "notes.txt").read_text() == "mine"
    # a -o folder that is a file: one line, not an internal error
    rc, _, err = run(capsys, "compare", ds, "--model", model, "-o", folder / "notes.txt")
    assert rc == 2 and "is not a folder" in err
    # report --force reaches the writer
    calls = []
    monkeypatch.setattr("labrig.report.html.build_report",
                        lambda data, out, **kw: calls.append(out) or out)
    (tmp_path / "r.html").write_text("old")
    rc, _, err = run(capsys, "report", ds, "-o", tmp_path / "r.html", "--no-work", "--force")
    assert rc == 0 and calls, err


def test_mystery_new_force_replaces(tmp_path, capsys):
    f = tmp_path / "lab.mystery"
    assert run(capsys, "mystery", "new", "--seed", "2", "-o", f)[0] == 0
    rc, _, err = run(capsys, "mystery", "new", "--seed", "3", "-o", f)
    assert_refused(rc, err, f)
    assert run(capsys, "mystery", "new", "--seed", "3", "-o", f, "--force")[0] == 0


def test_model_file_follows_the_umask(ds, tmp_path, capsys):
    old = os.umask(0o022)
    try:
        rc, _, err = run(capsys, "identify", ds, "--fix", FIX, "--starts", "1", "--seed", "1",
                         "-o", tmp_path / "m.json")
    finally:
        os.umask(old)
    assert rc == 0, err
    assert (tmp_path / "m.json").stat().st_mode & 0o777 == 0o644


# -- B. --json never fails on inf or NaN ---------------------------------------------

def test_emit_json_turns_every_non_finite_number_into_null(capsys):
    obj = {"a": float("inf"), "b": [1.0, float("nan"), (2, -math.inf)],
           "c": np.float64("inf"), "d": np.array([1.0, np.inf, np.nan]), "e": np.float32("nan"),
           "f": {"g": {"h": np.array([[np.nan]])}}, "i": np.int64(3), "j": True, "k": None,
           "interval95": [0.0, np.inf]}
    emit_json(obj)
    d = strict_loads(capsys.readouterr().out)
    assert d == {"a": None, "b": [1.0, None, [2, None]], "c": None, "d": [1.0, None, None],
                 "e": None, "f": {"g": {"h": [[None]]}}, "i": 3, "j": True, "k": None,
                 "interval95": [0.0, None]}


def test_identify_json_with_an_unbounded_interval(ds, capsys):
    # a friction of 1e-9..1e-8 V changes nothing the sensors see: its 95 % interval is
    # [0, inf], which used to end in "internal error"; the bound warning comes too
    rc, out, err = run(capsys, "identify", ds, "--fix", f"{FIX},J={P.J},B={P.B}",
                       "--effects", "coulomb_friction", "--bounds", "coulomb_friction.tc_v=1e-9:1e-8",
                       "--starts", "1", "--seed", "1", "--json")
    assert rc == 0, err
    d = strict_loads(out)
    assert d["identifiable"]["parameters"]["coulomb_friction.tc_v"]["interval95"] is None
    # which end it sticks to depends on the noise; either is a bound
    assert any(re.match(r"coulomb_friction\.tc_v = \S+ V is at the (lower bound 1e-09 V: the "
                        r"data may want a value below|upper bound 1e-08 V: the data may want a "
                        r"value above) it; ", w) for w in d["warnings"]), d["warnings"]


# -- C. a fit at a bound or below 0 % says so ------------------------------------------

@pytest.mark.parametrize("bound,side,want", [
    (f"J={P.J / 10}:{P.J / 2}", "upper", "above"),   # the true J lies above the box
    (f"J={P.J * 2}:{P.J * 10}", "lower", "below"),   # ... and below it
])
def test_identify_warns_when_a_parameter_ends_at_a_bound(ds, capsys, bound, side, want):
    argv = ["identify", ds, "--fix", FIX, "--bounds", bound, "--starts", "1", "--seed", "1"]
    rc, text, err = run(capsys, *argv)
    assert rc == 0, err
    lo, hi = (float(x) for x in bound[2:].split(":"))
    b = f"{hi if side == 'upper' else lo:.4g} kg m^2"
    line = next(x for x in text.splitlines() if x.startswith("warning: J = "))
    assert f"is at the {side} bound {b}: the data may want a value {want} it" in line
    rc, out, err = run(capsys, *argv, "--json")
    assert rc == 0, err
    d = strict_loads(out)
    assert [w for w in d["warnings"] if w.startswith("J = ")] == [line[len("warning: "):]]
    assert not any(w.startswith("B = ") for w in d["warnings"])  # B is free, inside its box
    for key in ("method", "effects", "params", "effect_params", "fixed", "fitness",
                "rmse_over_noise", "fit_percent", "identifiable", "nfev", "nit", "seconds",
                "seed", "message", "history", "step_info", "noise", "per_run"):
        assert key in d  # the existing keys are unchanged


def test_bound_tolerance_is_in_the_searched_coordinates():
    from labrig.identification.result import bound_warnings, fit_warnings

    space = build_space([], bounds={"R": (0.1, 100.0), "J": (1e-6, 1e-4)}, fixed={"K": 0.05})
    params = {"R": 0.2, "L": 1e-5, "J": 0.999e-4, "B": 1e-4, "K": 0.05}
    w = bound_warnings(space, params, {"R": "ohm", "L": "H", "J": "kg m^2"})
    # R = 0.2 is twice its lower bound (0.1 % of the span in ohms would call it "at" 0.1);
    # L sits on its default lower bound; J within 0.1 % of 2 decades of its upper; K is fixed
    assert w == ["L = 1e-05 H is at the lower bound 1e-05 H: the data may want a value "
                 "below it; widen the bound (--bounds L=LOW:HIGH) or check the units",
                 "J = 9.99e-05 kg m^2 is at the upper bound 0.0001 kg m^2: the data may want "
                 "a value above it; widen the bound (--bounds J=LOW:HIGH) or check the units"]
    assert fit_warnings({"speed": 12.0, "position": 0.0}, "all runs") == []
    assert fit_warnings({"speed": -12.0}, "run 'a'")[0].startswith(
        "run 'a': speed fit -12.0 % is below zero: the model is worse than a constant")
    assert len(fit_warnings({"position": float("nan")}, "all runs")) == 1


def test_identify_explains_the_fitness_it_prints(ds, capsys):
    # the note under Table 2 says what the "fitness (eq. 26)" row is; check it says the
    # truth: with every run holding both channels (N/2 samples each) and p = 1, q = 4,
    # fitness^2 = (rmse_pos^2 + 4 rmse_speed^2) / 2, not rmse/noise overall
    from labrig.identification.table import FITNESS_NOTE

    argv = ["identify", ds, "--fix", FIX, "--starts", "1", "--seed", "1", "--weights", "p=1,q=4"]
    rc, text, err = run(capsys, *argv)
    assert rc == 0, err
    assert FITNESS_NOTE in text
    assert "weighted RMSE of position and speed" in FITNESS_NOTE
    rc, out, err = run(capsys, *argv, "--json")
    d = strict_loads(out)
    r = d["rmse_over_noise"]
    assert d["fitness"] == pytest.approx(math.sqrt((r["position"] ** 2 + 4 * r["speed"] ** 2) / 2),
                                         rel=1e-9)
    assert abs(d["fitness"] - r["overall"]) > 0.01 * r["overall"]


def test_diagnosis_words_name_the_side_of_the_bound():
    # a rail at its upper bound is absent, a dead zone at its lower one is: the words
    # say only which side and which way the data push, true for every effect
    from types import SimpleNamespace

    from labrig.diagnosis.loop.diagnose import at_bounds

    space = build_space(["deadband", "saturation"], bounds={"deadband.d_v": (0.001, 2.0),
                                                             "saturation.vmax_v": (0.5, 30.0)})
    params = {"R": 3.0, "L": 1e-3, "J": 1e-4, "B": 1e-5, "K": 0.05,
              "deadband.d_v": 0.001, "saturation.vmax_v": 30.0}
    assert at_bounds(SimpleNamespace(space=space, params=params)) == [
        "deadband.d_v = 0.001 at the lower bound 0.001 of its search range (the data may want "
        "a value below it)",
        "saturation.vmax_v = 30 at the upper bound 30 of its search range (the data may want "
        "a value above it)"]


def test_compare_warns_when_the_model_is_worse_than_a_constant(ds, model, tmp_path, capsys):
    bad = json.loads(model.read_text())
    bad["params"]["K"] = P.K / 3  # 2.4 times the gain, a slower pole: position fit -80 %
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    rc, text, err = run(capsys, "compare", ds, "--model", path, "-o", tmp_path / "c1")
    assert rc == 0, err
    assert "warning: run 'sq_1.20V': position fit -" in text and "worse than a constant" in text
    rc, out, err = run(capsys, "compare", ds, "--model", path, "-o", tmp_path / "c2", "--json")
    assert rc == 0, err
    d = strict_loads(out)
    assert [r["run"] for r in d["runs"]] == ["sq_1.20V", "sq_2.00V"]
    assert d["runs"][0]["fit_percent"]["position"] < 0
    assert any(w.startswith("run 'sq_1.20V': position fit -") for w in d["warnings"])
    # a good model: no warnings
    rc, out, err = run(capsys, "compare", ds, "--model", model, "-o", tmp_path / "c3", "--json")
    assert rc == 0 and strict_loads(out)["warnings"] == []


def test_analyse_figures_refused_unless_force(ds, tmp_path, capsys):
    figs = tmp_path / "figs"
    assert main(["analyse", str(ds), "-o", str(figs)]) == 0
    before = {p.name: p.stat().st_mtime_ns for p in figs.iterdir()}
    capsys.readouterr()
    assert main(["analyse", str(ds), "-o", str(figs)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "add --force" in err
    assert {p.name: p.stat().st_mtime_ns for p in figs.iterdir()} == before
    assert main(["analyse", str(ds), "-o", str(figs), "--force"]) == 0
