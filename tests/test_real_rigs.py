"""The loop on real rigs (issue 14): an honest noise floor, folds, data-derived bounds,
and the hidden-effect matrix: several effects at once, a quantised encoder, one long
staircase, a short delay and nothing hidden, each run through ``diagnose --auto``."""
import shutil

import numpy as np
import pandas as pd
import pytest

from labrig.diagnosis.loop.auto import auto_diagnose
from labrig.io.experiment import Experiment
from labrig.diagnosis.evidence.crossval import make_folds
from labrig.model.effects import get_effect
from labrig.model.reach import Reach
from labrig.analysis.noise import noise_floor
from labrig.io.runs import read_dataset
from conftest import make_rig, sim_dataset, square_plan

FIVE = (0.6, 0.9, 1.2, 1.8, 2.5)


# -- the noise floor -------------------------------------------------------------------

def test_floor_of_an_analogue_tacho_is_its_noise(tmp_path):
    """Gaussian tacho noise of 10 mV behind a 10-bit ADC (19.5 mV steps): the floor is the
    rms of both, sqrt(0.010^2 + 0.0195^2/12) / Kt, measured moving and at rest."""
    runs = read_dataset(sim_dataset(tmp_path, make_rig(), square_plan(amps=(1.2, 2.5))))
    from labrig.model.simulate import prepare
    from labrig.analysis.noise import channel_floors

    f = channel_floors(prepare(runs))["speed"]
    truth = np.hypot(0.010, 20.0 / 1024 / np.sqrt(12)) / 0.026
    assert f.sigma == pytest.approx(truth, rel=0.08)
    assert f.moving == pytest.approx(truth, rel=0.1) and f.rest == pytest.approx(truth, rel=0.2)
    assert "moving" in f.describe() and "q/sqrt(12)" in f.describe()


def test_floor_of_an_encoder_speed_is_taken_while_moving():
    """An encoder-derived speed (counts per 10 ms sample, no window declared) does not
    scatter at rest and jumps by whole steps while moving: it is found to be a count, its
    floor the counting noise while moving (q/sqrt(6)) and exactly zero at rest, overall
    the error a perfect model leaves, with the quantum said in rad/s."""
    rng = np.random.default_rng(4)
    dt, cpr = 0.01, 48 * 30.0
    t = np.arange(0, 40, dt)
    cmd = np.repeat(rng.choice([0.0, 0.0, 6.0, 12.0, -9.0], 40), len(t) // 40)
    w = np.convolve(cmd, np.ones(30) / 30, mode="same")         # smooth speed, with rests
    theta = np.cumsum(w) * dt + rng.uniform(0, 1)
    counts = np.floor(theta * cpr / (2 * np.pi))
    w_enc = np.diff(counts, prepend=counts[0]) * 2 * np.pi / cpr / dt
    q = 2 * np.pi / cpr / dt
    f = noise_floor([w_enc], [w_enc], "speed", "rad/s")
    actual = np.sqrt(np.mean((w_enc - w)[50:] ** 2))              # what a perfect model leaves
    assert f.counted and f.found and f.q == pytest.approx(q, rel=1e-6)
    assert f.sigma == pytest.approx(actual, rel=0.15)
    assert f.moving == pytest.approx(q / np.sqrt(6), rel=1e-9) and f.rest == 0.0
    assert f"one count reads {q:.4g} rad/s" in f.describe()
    assert "found in the readings" in f.describe()


# -- folds and bounds ----------------------------------------------------------------------

class _R:
    def __init__(self, n, amp, dt=0.01):
        self.u, self.loop, self.amplitude, self.dt = np.zeros(n), "open", amp, dt


def test_a_run_without_steps_is_cut_in_contiguous_blocks():
    """Interleaved segments are tested in tests/test_same_answer.py; an input without
    steps to interleave falls back to blocks that tile each run."""
    single = make_folds([_R(1000, 2.0)])
    assert "blocks" in single.kind and len(single.folds) == 4
    cover = sum(fold.test[0].astype(int) for fold in single.folds)
    assert (cover == 1).all()                      # contiguous blocks tile the run
    assert all(np.flatnonzero(np.diff(fold.test[0].astype(int))).size <= 2 for fold in single.folds)


def test_threshold_bounds_come_from_the_data():
    """A hobby H-bridge's dead zone of 3-4 V fits when the data reach 6 V; a rail is
    bounded by the drive the inputs reach (through the dead zone in front)."""
    reach = Reach(amin=1.0, amax=6.0, Ka=1.0, drive_max=5.0, speed_max=50.0, theta_span=3.0,
                  dt=0.01, duration=20.0)
    assert get_effect("deadband").data_bounds(reach)["d_v"][1] == 6.0
    assert get_effect("coulomb_friction").data_bounds(reach)["tc_v"][1] == 6.0
    assert get_effect("saturation").data_bounds(reach)["vmax_v"][1] == pytest.approx(7.5)
    grid = get_effect("deadband").scan_grid(reach)["d_v"]
    assert grid.min() < 0.2 and grid.max() > 5.0   # the scan covers what the data see


# -- the hidden-effect matrix --------------------------------------------------------------

def _encoder(tmp_path, effects):
    """A position-only rig with a 1000-count encoder on the output shaft (no noise, no
    ADC: the counts are the only error)."""
    rig = make_rig(effects=effects, noise=False)
    rig.bridge.adc_bits = 24
    ds = sim_dataset(tmp_path, rig, square_plan(amps=FIVE))
    for csv in ds.glob("*.csv"):
        d = pd.read_csv(csv)
        th = (d["pos"] - rig.sensors.pos_offset_v) / rig.sensors.pos_v_per_rad
        q = 2 * np.pi / 1000
        d["pos"] = np.round(th / q) * q * rig.sensors.pos_v_per_rad + rig.sensors.pos_offset_v
        d.drop(columns=["tacho"]).to_csv(csv, index=False)
    return ds


def _staircase(tmp_path, effects):
    """One long run: a staircase up, down through zero, and back (18 levels of 0.8 s)."""
    from labrig.bridge.sweep import sweep
    from labrig.bridge.sim import SimRig

    levels = [0.5, 1.0, 1.5, 2.0, 2.5, 0.0, -0.5, -1.0, -1.5, -2.0, -2.5, 0.0,
              1.2, -1.2, 2.2, -2.2, 0.8, 0.0]
    rig = make_rig(effects=effects)
    out = tmp_path / "stair"
    sweep(SimRig(rig, seed=3), [Experiment(name="stair", waveform="staircase", levels=levels,
                                           step_s=0.8, duration_s=0.8 * len(levels))], rig, out)
    return out


def _paper(tmp_path, effects):
    """The lab's sweep where every open-loop amplitude (1.2-2.5 V) is on the rail; the
    closed-loop position steps pass through the dead zone as they settle."""
    plan = square_plan(amps=(1.2, 1.5, 2.0, 2.5)) + [
        Experiment(name=f"cl_{a:.2f}V", loop="closed", amplitude_v=a, periods=1)
        for a in (0.5, 0.6)]
    return sim_dataset(tmp_path, make_rig(effects=effects), plan)


def _sweep(tmp_path, effects):
    return sim_dataset(tmp_path, make_rig(effects=effects), square_plan(amps=FIVE))


#: case -> (data maker, hidden effects); tau_m of the default rig is 0.162 s
MATRIX = {
    "paper's rig: dead zone + rail every amplitude reaches": (
        _paper, {"deadband": {"d_v": 0.3}, "saturation": {"vmax_v": 4.0}}),
    "dead zone + rail, five amplitudes": (
        _sweep, {"deadband": {"d_v": 0.3}, "saturation": {"vmax_v": 4.0}}),
    "Coulomb friction + delay": (
        _sweep, {"coulomb_friction": {"tc_v": 0.2}, "delay": {"td_s": 0.012}}),
    "asymmetric dead zone": (
        _sweep, {"asymmetric_deadband": {"dpos_v": 0.25, "dneg_v": 0.65}}),
    "position-only quantised encoder": (_encoder, {"deadband": {"d_v": 0.3}}),
    "one long staircase, two effects": (
        _staircase, {"coulomb_friction": {"tc_v": 0.2}, "saturation": {"vmax_v": 9.0}}),
    "delay of 0.12 tau_m": (_sweep, {"delay": {"td_s": 0.0194}}),
    "nothing hidden": (_sweep, {}),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(MATRIX))
def test_hidden_effects_found_nothing_invented(tmp_path, case):
    make, hidden = MATRIX[case]
    runs = read_dataset(make(tmp_path, hidden))
    res = auto_diagnose(runs, seed=0)
    assert sorted(res.model.names) == sorted(hidden), [m.label for m in res.moves]
    final = res.ladder.steps[-1]
    for ch, v in final.rmse_over_noise.items():
        assert v <= 1.5, (ch, v)                  # within 1.5x of the honest floor
    for name, params in hidden.items():
        for k, v in params.items():
            assert res.model.effect_params[name][k] == pytest.approx(v, rel=0.15), (name, k)
    if hidden:  # the ladder falls and the cross-validated error with it
        assert final.cross_validated < 0.9 * res.ladder.steps[0].cross_validated
    shutil.rmtree(tmp_path, ignore_errors=True)


# -- real-rig classes (issue 30): records built like real ones, imported as a user would ----

def _torque_record(tmp_path, **kw):
    """The torque-drive class: a current-mode servo stepped from rest both ways, offset +
    Coulomb friction + viscous friction, exported by a scope (tests/twin.py, no labrig
    code), imported with ``labrig import --drive torque --input-gain 1``."""
    from labrig.io.importer import import_csv
    from twin import torque_drive_from_rest

    out = tmp_path / "runs"
    position = kw.get("position", True)
    for src in torque_drive_from_rest(tmp_path / "scope", **kw):
        cols = {"t": "t", "u": "torque", "speed": "speed"}
        if position:
            cols["pos"] = "pos"
        import_csv(src, out, cols, drive="torque", input_gain=1.0, waveform="step")
    return read_dataset(out)


def _assert_torque_physics(res, offset, coulomb):
    assert sorted(res.model.names) == ["coulomb_friction", "offset"], [m.label for m in res.moves]
    phys = res.model.params
    assert phys["J"] == pytest.approx(2e-4, rel=0.02)
    assert phys["B"] == pytest.approx(2e-3, rel=0.02)
    assert res.model.effect_params["offset"]["u0_v"] == pytest.approx(offset, rel=0.05)
    assert res.model.effect_params["coulomb_friction"]["tc_v"] == pytest.approx(coulomb, rel=0.03)
    assert res.ladder.steps[-1].rmse_over_noise["speed"] <= 1.2


@pytest.mark.slow
def test_torque_drive_offset_and_friction_found_as_a_pair(tmp_path):
    """Speed only, an offset of 3/4 of the friction: one effect at a time, the search
    took a lopsided dead zone and stopped there (J 15 % off, nothing else earned its
    parameters); the pairs of the threshold family, fitted in its place, reach the
    physics."""
    runs = _torque_record(tmp_path, offset=0.015, coulomb=0.02, position=False)
    res = auto_diagnose(runs, seed=0)
    _assert_torque_physics(res, 0.015, 0.02)
    assert any(m.kind == "pair" and sorted(m.effects) == ["coulomb_friction", "offset"]
               for m in res.moves), [m.label for m in res.moves]


@pytest.mark.slow
def test_torque_drive_position_that_drifts_does_not_pull_the_inertia(tmp_path):
    """Speed and a position logged over hundreds of radians that wanders by ~37 of its
    noise floors against the integral of the speed: weighted at its noise floor it
    outweighed the speed (stiction and a lopsided dead zone, J 7 % off); weighted by its
    drift, the speed decides, and the output says so."""
    runs = _torque_record(tmp_path, offset=0.006, coulomb=0.02, position=True)
    res = auto_diagnose(runs, seed=0)
    _assert_torque_physics(res, 0.006, 0.02)
    why = res.rounds[0].weights.get("why", "")
    assert why.startswith("the speed decides") and "integral of the speed" in why
    assert "drift against the speed" in res.verdict


def _stair_runs(tmp_path, name="runs", *, window=None, position=True, **kw):
    """The Arduino + H-bridge class: a 100 Hz staircase up then down through zero, the
    speed a 50 ms moving window of encoder counts (tests/twin.py), imported as a user
    would; ``window`` declares the speed's window, the PWM's step is declared."""
    from labrig.io.importer import import_csv
    from twin import hbridge_staircase

    src = hbridge_staircase(tmp_path / f"{name}_log", **kw)
    cols = {"t": "ms", "u": "u_V", "speed": "speed_rpm"}
    opts = {}
    if position:
        cols["pos"] = "count"
        opts["pos_unit"] = "counts:1440"
    out = tmp_path / name
    import_csv(src, out, cols, time_unit="ms", speed_unit="rpm", gear_ratio=30.0,
               waveform="staircase", speed_window=window, input_step=12.0 / 255, **opts)
    return read_dataset(out)


def _tau_e(model):
    from labrig.identification.identifiability import time_constants

    return time_constants(model.plant_class, model.params, model.constants)["tau_e_s"]


@pytest.mark.slow
def test_staircase_with_a_declared_speed_window_is_modelled(tmp_path):
    """Declared (import --speed-window 0.05), the window is simulated on the model's
    speed: the direction-dependent threshold is found to 3 %, both channels reach their
    floors, and no electrical pole or delay carries the window's 25 ms."""
    runs = _stair_runs(tmp_path, window=0.05)
    assert runs[0].speed_window_s == 0.05
    res = auto_diagnose(runs, seed=0)
    assert res.model.names == ["asymmetric_deadband"], [m.label for m in res.moves]
    p = res.model.effect_params["asymmetric_deadband"]
    assert p["dpos_v"] == pytest.approx(1.2, rel=0.03)
    assert p["dneg_v"] == pytest.approx(1.8, rel=0.03)
    for ch, v in res.ladder.steps[-1].rmse_over_noise.items():
        assert v <= 1.2, (ch, v)
    assert _tau_e(res.model) < 0.005      # L/R of the truth: 0.2 ms; the window: 25 ms


@pytest.mark.slow
def test_staircase_with_an_undeclared_speed_window_is_named_not_fitted(tmp_path):
    """Undeclared, the speed reads 25 ms late against the counts: before, the electrical
    pole took it (tau_e 23 ms, the verdict silent); now the lag is measured, named as a
    filtered speed of about a 50 ms window, the position decides, and the threshold is
    found without a delay or a slow pole."""
    from labrig.analysis.agreement import channel_agreement
    from labrig.model.simulate import prepare

    runs = _stair_runs(tmp_path)
    rd = prepare(runs)
    agree = channel_agreement(rd, 1.0, 1e-3)
    assert agree.lag_s == pytest.approx(0.025, abs=0.003)
    res = auto_diagnose(runs, seed=0)
    assert res.model.names == ["asymmetric_deadband"], [m.label for m in res.moves]
    p = res.model.effect_params["asymmetric_deadband"]
    assert p["dpos_v"] == pytest.approx(1.2, rel=0.03)
    assert p["dneg_v"] == pytest.approx(1.8, rel=0.03)
    assert _tau_e(res.model) < 0.005
    why = res.rounds[0].weights["why"]
    assert why.startswith("the position decides") and "moving window of about" in why


@pytest.mark.slow
def test_a_windowed_speed_with_nothing_hidden_adds_no_physics(tmp_path):
    """Nothing physical hidden, the speed a 50 ms window, the counts logged: no effect is
    added (before: a dead zone of a millivolt, below the PWM's 47 mV step) and the
    verdict names the filtered speed."""
    runs = _stair_runs(tmp_path, dpos=0.0, dneg=0.0)
    res = auto_diagnose(runs, seed=0)
    assert res.model.names == [], [m.label for m in res.moves]
    assert "filtered speed" in res.verdict and "position, which decides" in res.verdict


@pytest.mark.slow
def test_a_windowed_speed_alone_is_pointed_at(tmp_path):
    """Speed only, nothing hidden: the window's lag cannot be told from a plant's by
    these data (a delay or a slow pole takes it); the verdict says what it looks like
    and how to decide (declare the window, or log the position)."""
    runs = _stair_runs(tmp_path, position=False, dpos=0.0, dneg=0.0)
    res = auto_diagnose(runs, seed=0)
    assert "A filtered speed reads like this" in res.verdict
    assert "log the position too" in res.verdict


@pytest.mark.slow
def test_a_rippled_tacho_is_named_and_nothing_invented(tmp_path):
    """The MS150 twin with a tacho whose gain ripples 3 % twice per motor turn and
    nothing hidden: no effect is added, and the verdict names a line locked to the
    shaft at 2 cycles per turn (before: 'outside the catalogue')."""
    from twin import Twin

    twin = Twin(tacho_ripple=0.03, ripple_cycles=2)
    for a in (0.6, 1.2, 1.8, 2.5):
        twin.square(tmp_path / "runs", amplitude=a, periods=1)
    res = auto_diagnose(read_dataset(tmp_path / "runs"), seed=0)
    assert res.model.names == [], [m.label for m in res.moves]
    assert "locked to the shaft's angle: 2.0" in res.verdict
    assert "ripple of the speed sensor" in res.verdict


@pytest.mark.slow
def test_force_axis_in_a_loop_offset_and_coulomb_friction(tmp_path):
    """A force-driven carriage in a digital PD loop, position only, logged with its
    drive: a 16 N offset and 22 N of Coulomb friction (38 N one way, 6 N the other).
    Before: the offset was held at +-0.5 V of a bench amplifier's input (10 N here) and
    a dead zone took the friction's place (M 40 % off); now the offset's range follows the
    drive's inputs and the physics is reached."""
    from labrig.api import read_runs
    from labrig.io.importer import import_csv
    from twin import force_axis_closed_loop

    for src in force_axis_closed_loop(tmp_path / "log", offset=16.0, coulomb=22.0):
        import_csv(src, tmp_path / "runs", {"t": "t", "ref": "ref", "u": "drive", "pos": "pos"},
                   drive="force", input_gain=20.0, loop="closed", waveform="step",
                   controller={"kind": "pd", "kp": 400.0, "kd": 8.0})
    # as every command reads them: from the logged drive (--through auto)
    res = auto_diagnose(read_runs(tmp_path / "runs"), seed=0)
    assert sorted(res.model.names) == ["coulomb_friction", "offset"], [m.label for m in res.moves]
    assert res.model.params["M"] == pytest.approx(2.5, rel=0.02)
    assert res.model.params["Fv"] == pytest.approx(40.0, rel=0.03)
    assert 20.0 * res.model.effect_params["offset"]["u0_v"] == pytest.approx(16.0, rel=0.03)
    assert 20.0 * res.model.effect_params["coulomb_friction"]["tc_v"] == pytest.approx(22.0, rel=0.03)


def test_effect_parameters_are_in_the_drive_units(tmp_path):
    """On a force drive (kd = 20 N/V) an offset and a friction are forces: named u0_n and
    tc_n and valued in N in the identification's JSON and table, the model file (read
    back to the same model) and the effects' words; a voltage drive keeps its volts."""
    from labrig.api import read_runs
    from labrig.identification.engine import identify
    from labrig.identification.table import format_identification
    from labrig.io.importer import import_csv
    from labrig.diagnosis.words.explain import context, thresholds
    from labrig.model.model import Model
    from twin import force_axis_closed_loop

    for src in force_axis_closed_loop(tmp_path / "log", offset=16.0, coulomb=22.0,
                                      steps=((0.03, -0.03, 0.06, 0.0),)):
        import_csv(src, tmp_path / "runs", {"t": "t", "ref": "ref", "u": "drive", "pos": "pos"},
                   drive="force", input_gain=20.0, loop="closed", waveform="step",
                   controller={"kind": "pd", "kp": 400.0, "kd": 8.0})
    runs = read_runs(tmp_path / "runs")
    fit = identify(runs, "co", [get_effect("offset"), get_effect("coulomb_friction")])
    doc = fit.to_dict()
    assert set(doc["effect_params"]) == {"offset", "coulomb_friction"}
    assert doc["effect_params"]["offset"]["u0_n"] == pytest.approx(16.0, rel=0.02)
    assert doc["effect_params"]["coulomb_friction"]["tc_n"] == pytest.approx(22.0, rel=0.02)
    lo, hi = doc["identifiable"]["parameters"]["coulomb_friction.tc_n"]["interval95"]
    assert lo <= doc["effect_params"]["coulomb_friction"]["tc_n"] <= hi
    text = format_identification([fit])
    assert "coulomb_friction.tc_n" in text and "tc_v" not in text.split("rows:")[0]
    model = fit.model()
    path = model.save(tmp_path / "m.json")
    import json
    assert json.loads(path.read_text())["effect_params"]["offset"] == {"u0_n": pytest.approx(
        20.0 * model.effect_params["offset"]["u0_v"])}
    back = Model.load(path)
    assert back.effect_params["offset"]["u0_v"] == pytest.approx(model.effect_params["offset"]["u0_v"])
    assert "tc_n = 22" in back.describe()
    words = back.effects.by_name("coulomb_friction").explain_params(
        back.effect_params["coulomb_friction"], context(back, runs))
    assert words.startswith("Tc = 22 N") and " V" not in words
    assert thresholds(back, runs).startswith("At the drive: an offset of 16 N")
    # a voltage drive is as it was
    volt = Model.load(path).__class__.from_flat(
        {"R": 8.0, "L": 0.0085, "J": 5e-5, "B": 1e-5, "K": 0.05, "offset.u0_v": 0.01},
        [get_effect("offset")], {"Ka": 5.0}, plant="voltage")
    assert volt.to_json()["effect_params"] == {"offset": {"u0_v": 0.01}}


@pytest.mark.slow
def test_a_fitted_pole_that_is_the_speed_filter_is_said_so(tmp_path):
    """identify on the undeclared staircase with the speed weighted up (the weights a
    user gave): the electrical pole takes the window's lag, and the warning says it is
    the speed's own lag against the position (25 ms), not the armature's L/R."""
    from labrig.identification.engine import identify
    from labrig.identification.result import identification_warnings

    runs = _stair_runs(tmp_path)
    fit = identify(runs, "co", [get_effect("asymmetric_deadband")], p=0.001, q=1.0)
    tau_e = _tau_e(fit.model())
    assert 0.0125 < tau_e < 0.05                   # the pole carries the window, as before
    said = [w for w in identification_warnings(fit) if "own lag against the position" in w]
    assert said and "not the armature's L/R" in said[0] and "25 ms" in said[0], said


def test_a_force_drive_names_its_levels_in_newtons_when_refusing_one(tmp_path):
    """A wrong name in --fix, or a level missing from a model file, is told with the
    names a force drive's output uses (u0_n), not the volts inside."""
    import json

    from labrig.core.errors import UserError
    from labrig.identification.objective import build_space
    from labrig.model.model import Model
    from labrig.model.plants import ForcePlant
    from labrig.model.reach import Reach

    reach = Reach(amin=1.0, amax=10.0, Ka=20.0, drive_max=200.0, speed_max=1.0,
                  theta_span=0.1, dt=0.002, duration=4.0)
    with pytest.raises(UserError, match=r"'offset.u0_nm'; the model has M, Fv, offset.u0_n$"):
        build_space([get_effect("offset")], fixed={"offset.u0_nm": 1.0}, reach=reach,
                    plant=ForcePlant)
    space = build_space([get_effect("offset")], fixed={"offset.u0_n": 16.0}, reach=reach,
                        plant=ForcePlant)
    assert space.fixed == {"offset.u0_v": pytest.approx(0.8)}
    doc = {"format": "labrig-model/1", "structure": "force", "params": {"M": 2.5, "Fv": 40.0},
           "effects": ["offset"], "effect_params": {"offset": {}}, "constants": {"Ka": 20.0}}
    (tmp_path / "m.json").write_text(json.dumps(doc))
    with pytest.raises(UserError, match=r"key 'effect_params.offset.u0_n' missing"):
        Model.load(tmp_path / "m.json")
