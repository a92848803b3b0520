"""Ask the rig (issue 16): the pwl waveform, the proposed experiment, and the decision it
brings, on the project's own accurate integrator."""
import json

import numpy as np
import pytest

from labrig.bridge.sweep import sweep
from labrig.io.experiment import Experiment
from labrig.bridge.sim import SimRig
from labrig.io.config import load_plan
from labrig.loop.diagnose import linear_model
from labrig.core.errors import ConfigError
from labrig.model.effects import get_effect
from labrig.loop.decide import Decision, decide
from labrig.loop.propose import propose
from labrig.loop.refit import refit_with
from labrig.io.runs import read_dataset
from conftest import labrig, make_rig, sim_dataset

HIDDEN = {"deadband": {"d_v": 0.3}, "coulomb_friction": {"tc_v": 0.3},
          "stiction": {"tc_v": 0.2, "excess": 1.0}, "backlash": {"a_rad": 0.02},
          "delay": {"td_s": 0.012}}
STEP = [Experiment(name="step", waveform="step", amplitude_v=1.5, duration_s=3.0)]


# -- the pwl waveform -------------------------------------------------------------------

def test_pwl_is_linear_between_breakpoints_and_held_after(tmp_path):
    plan = tmp_path / "p.toml"
    plan.write_text('[[experiment]]\nname = "r"\nwaveform = "pwl"\nlead_in_s = 0.5\n'
                    'points = [[0, 0], [2, 2.0], [3, -1.0]]\nduration_s = 4.5\n')
    exp = load_plan(plan)[0]
    t = np.arange(exp.n_samples) / exp.sample_rate_hz
    u = exp.waveform_at(t)
    assert exp.n_samples == 4500 and exp.peak_v() == 2.0
    assert u[499] == 0.0 and u[1500] == pytest.approx(1.0) and u[2500] == pytest.approx(2.0)
    assert u[3000] == pytest.approx(0.5) and u[3500] == pytest.approx(-1.0)
    assert u[-1] == pytest.approx(-1.0)   # held after the last breakpoint
    side = exp.to_sidecar()
    assert side["waveform"] == "pwl" and side["points"][1] == [2.0, 2.0]


@pytest.mark.parametrize("points, message", [
    ("[[0.5, 0], [2, 1]]", "first breakpoint must be at t = 0"),
    ("[[0, 0], [1, 1], [1, 2]]", "times must rise"),
    ("[[0, 0]]", "at least two"),
    ("[" + ", ".join(f"[{k}, 0]" for k in range(65)) + "]", "at most 64"),
])
def test_pwl_plan_refuses_bad_breakpoints(tmp_path, points, message):
    plan = tmp_path / "p.toml"
    plan.write_text(f'[[experiment]]\nname = "r"\nwaveform = "pwl"\npoints = {points}\n')
    with pytest.raises(ConfigError, match=message):
        load_plan(plan)


def test_pwl_points_on_another_waveform_and_unknown_pairs_are_refused(tmp_path):
    plan = tmp_path / "p.toml"
    plan.write_text('[[experiment]]\nname = "r"\nwaveform = "square"\npoints = [[0, 0], [1, 1]]\n')
    with pytest.raises(ConfigError, match="belong to waveform"):
        load_plan(plan)
    plan.write_text('[[experiment]]\nname = "r"\nwaveform = "pwl"\npoints = [[0, 0], [1, 1]]\n'
                    'between = ["deadband", "gremlins"]\n')
    with pytest.raises(ConfigError, match="not a catalogue effect"):
        load_plan(plan)


# -- propose, run, decide ---------------------------------------------------------------

def _confusable(tmp_path, truth, pair):
    """One step on a rig hiding ``truth``: both explanations fit it equally well."""
    rig = make_rig({truth: HIDDEN[truth]})
    runs = read_dataset(sim_dataset(tmp_path, rig, STEP))
    model = refit_with(runs, linear_model(runs, seed=0), get_effect(pair[0]), seed=0).model()
    return rig, runs, model


CASES = [(t, p) for p in (("deadband", "coulomb_friction"), ("deadband", "stiction"),
                          ("delay", "backlash")) for t in p]


@pytest.mark.slow
@pytest.mark.parametrize("truth, pair", CASES, ids=[f"{t}-of-{'|'.join(p)}" for t, p in CASES])
def test_the_proposed_experiment_decides_for_the_true_effect(tmp_path, truth, pair):
    """From one run where the pair is confusable, the proposed input (at most 20 s), played
    on the simulated rig with the true effect, puts the true effect first and at least
    triples the separation, whichever of the two is true."""
    rig, runs, model = _confusable(tmp_path, truth, pair)
    prop = propose(runs, model, ",".join(pair), budget_s=20.0, seed=0)
    assert prop.chosen.candidate.duration <= 20.0
    assert len(prop.chosen.candidate.points) <= 64
    assert max(abs(u) for _, u in prop.chosen.candidate.points) <= 1.5 + 1e-9
    plan = tmp_path / "plan.toml"
    plan.write_text(prop.to_toml())
    sweep(SimRig(rig), load_plan(plan), rig, tmp_path / "ds" / "new")
    d = decide(read_dataset([tmp_path / "ds", tmp_path / "ds" / "new"]), model, seed=0)
    assert d.pair == tuple(pair) and d.leader == truth, d.to_text()
    before, after = Decision.separation(d.before), Decision.separation(d.after)
    assert before < 0.1, d.to_text()                 # the start was confusable
    assert after >= 3 * before and after >= 0.1, d.to_text()


def test_propose_cli_writes_a_plan_the_sweep_plays(tmp_path):
    """The command end to end: a plan with one pwl experiment (at most 64 breakpoints,
    inside the data's inputs), its figure, the words that say why; the plan plays on the
    simulated rig and its run carries the pair it was proposed for."""
    rig, runs, model = _confusable(tmp_path, "coulomb_friction", ("deadband", "coulomb_friction"))
    model.save(tmp_path / "m.json")
    out = tmp_path / "plan.toml"
    proc = labrig("propose", tmp_path / "ds", "--model", tmp_path / "m.json", "-o", out,
                  "--json", check=0)
    d = json.loads(proc.stdout)
    assert d["between"] == ["deadband", "coulomb_friction"] and (tmp_path / "plan.png").exists()
    p = d["proposed"]
    assert p["duration_s"] <= 20 and len(p["points"]) <= 64 and p["why"]
    assert p["separation"]["naive"] > p["separation"]["worst_after_refit"] > 100
    plan = load_plan(out)
    assert plan[0].waveform == "pwl" and plan[0].between == ["deadband", "coulomb_friction"]
    labrig("sweep", "--sim", "--plan", out, "-o", tmp_path / "ds" / "new", check=0)
    meta = json.loads((tmp_path / "ds" / "new" / "proposed.json").read_text())
    assert meta["experiment"]["between"] == ["deadband", "coulomb_friction"]
    again = labrig("propose", tmp_path / "ds", "--model", tmp_path / "m.json", "-o", out)
    assert again.returncode == 2 and "--force" in again.stderr


@pytest.mark.parametrize("args, message", [
    (["--between", "deadband"], "give two effects"),
    (["--between", "deadband,gremlins"], "gremlins"),
    (["--budget-s", "0.1"], "--budget-s"),
])
def test_propose_refuses_bad_options(tmp_path, args, message):
    runs = sim_dataset(tmp_path, make_rig({}), STEP)
    labrig("identify", runs, "--effects", "deadband", "--starts", "1", "-o", tmp_path / "m.json",
           check=0)
    proc = labrig("propose", runs, "--model", tmp_path / "m.json", "-o", tmp_path / "p.toml",
                  *args)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_ask_the_rig_plays_the_proposal_and_decides(tmp_path):
    """`diagnose --auto --ask-rig --sim` on two steps of the default rig (README step 5,
    whose figures tests/test_exercises.py checks): it proposes, plays the proposal on the
    simulated rig into runs3/asked/ and decides for the friction the rig hides."""
    runs = tmp_path / "runs3"
    labrig("sweep", "--sim", "--plan", "configs/plan_two_steps.toml", "-o", runs, check=0)
    d = json.loads(labrig("diagnose", runs, "--auto", "--ask-rig", "--sim", "--json",
                          check=0).stdout)
    dec = d["asked"]["decision"]
    assert dec["leader"] == "coulomb_friction"      # the default rig hides Coulomb friction
    assert dec["separation_after"] > dec["separation_before"]
    assert (runs / "asked" / "plan.toml").exists() and (runs / "asked" / "proposed.csv").exists()


def test_default_pair_is_the_diagnosis_first_confusable_pair(tmp_path):
    """`diagnose --auto -o DIR` writes diagnosis.json beside model.json: propose takes its
    first confusable pair (an asymmetric dead zone asked about as a dead zone)."""
    from labrig.core.errors import UserError
    from labrig.loop.propose import pair_from_diagnosis

    model = tmp_path / "model.json"
    assert pair_from_diagnosis(model) is None
    (tmp_path / "diagnosis.json").write_text(json.dumps(
        {"confusable": [{"pair": ["asymmetric_deadband", "coulomb_friction"]}]}))
    assert pair_from_diagnosis(model) == "deadband,coulomb_friction"
    (tmp_path / "diagnosis.json").write_text(json.dumps({"confusable": [{"pair": [1, 2]}]}))
    with pytest.raises(UserError, match="confusable.0.pair"):
        pair_from_diagnosis(model)


@pytest.mark.slow
def test_the_decision_does_not_hang_on_the_last_digits_of_the_noise_floor(tmp_path, monkeypatch):
    """Stiction hidden, dead zone vs stiction: a noise floor 1e-13 larger turns the proposal
    from a ramp into dwells at several levels (the candidates are nearly tied). On the
    dwells the re-fit with the true structure must still reach the floor: it is also
    started from the earlier fit's plant with the effect scanned afresh (it stalled at
    rmse/noise 22 when it was not)."""
    import dataclasses

    import labrig.analysis.noise as noise

    floor = noise.noise_floor

    def nudged(*a, **k):
        f = floor(*a, **k)
        return dataclasses.replace(f, sigma=f.sigma * (1 + 1e-13))

    monkeypatch.setattr(noise, "noise_floor", nudged)
    pair = ("deadband", "stiction")
    rig, runs, model = _confusable(tmp_path, "stiction", pair)
    prop = propose(runs, model, ",".join(pair), budget_s=20.0, seed=0)
    plan = tmp_path / "plan.toml"
    plan.write_text(prop.to_toml())
    sweep(SimRig(rig), load_plan(plan), rig, tmp_path / "ds" / "new")
    d = decide(read_dataset([tmp_path / "ds", tmp_path / "ds" / "new"]), model, seed=0)
    assert d.leader == "stiction", d.to_text()
    assert d.after["stiction"] <= 1.1, d.to_text()            # at the floor, not stalled
    assert Decision.separation(d.after) >= 3.0, d.to_text()
