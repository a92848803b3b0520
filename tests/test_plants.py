"""Beyond the MS150 (issue 15): torque- and force-driven plants, linear axes, encoders,
the armature current as an output, closed-loop runs with their controller, physical
results in the axis's units."""
import json
from pathlib import Path

import numpy as np
import pytest

from labrig.io.config import rig_from_dict
from labrig.core.errors import ConfigError
from labrig.identification.engine import identify
from labrig.model.effects import get_effect
from labrig.model.plants import ForcePlant, TorquePlant, VoltagePlant
from labrig.model.simulate import Simulator
from labrig.model.truth import simulate_truth
from labrig.io.runs import read_dataset
from conftest import labrig, sim_dataset, square_plan

SENSORS = {
    # a tacho and a pot: the MS150's sensors
    "tacho+pot": {"rotary": {"tacho_v_per_rad_s": 0.026, "pos_v_per_rad": 0.5,
                             "pos_offset_v": -4.0},
                  "linear": {"tacho_v_per_rad_s": 2.0, "pos_v_per_rad": 2.0,
                             "pos_offset_v": -4.0}},
    # a pot and no tacho
    "pot": {"rotary": {"tacho_v_per_rad_s": 0.0, "pos_v_per_rad": 0.5, "pos_offset_v": -4.0},
            "linear": {"tacho_v_per_rad_s": 0.0, "pos_v_per_rad": 2.0, "pos_offset_v": -4.0}},
    # an encoder and nothing else: the Arduino + H-bridge + gear motor of a student lab
    "encoder": {"rotary": {"tacho_v_per_rad_s": 0.0, "encoder_counts_per_unit": 1000 / (2 * np.pi)},
                "linear": {"tacho_v_per_rad_s": 0.0, "encoder_counts_per_unit": 2e5}},
    # the MS150 plus a current-sense resistor (voltage plant only)
    "tacho+pot+current": {"rotary": {"tacho_v_per_rad_s": 0.026, "pos_v_per_rad": 0.5,
                                     "pos_offset_v": -4.0, "current_v_per_a": 2.0}},
}
PLANTS = {"voltage": {"R_ohm": 8.0, "L_h": 0.0085, "J_kgm2": 5.2245e-5,
                      "B_nms_per_rad": 1e-5, "K_nm_per_a": 0.05},
          "torque": {"J_kgm2": 2e-4, "B_nms_per_rad": 2e-3},
          "force": {"M_kg": 2.5, "Fv_ns_per_m": 40.0}}
GAINS = {"voltage": 5.0, "torque": 0.1, "force": 20.0}


def plant_rig(drive="voltage", sensors="tacho+pot", effects=None, seed=3):
    axis = "linear" if drive == "force" else "rotary"
    rig = {"name": f"{drive} {sensors}", "drive": drive}
    if drive != "force":
        rig["gear_ratio"] = 30.0
    return rig_from_dict({"rig": rig, "plant": PLANTS[drive],
                          "amplifier": {"gain": GAINS[drive], "output_limit_v": 1e3},
                          "sensors": SENSORS[sensors][axis], "noise": {"seed": seed},
                          "effects": effects or {}}, f"<{drive} rig>")


# -- the plants on the kernels ------------------------------------------------------------

@pytest.mark.parametrize("plant, values", [(TorquePlant, {"J": 2e-4, "B": 2e-3}),
                                           (ForcePlant, {"M": 2.5, "Fv": 40.0})])
def test_fast_simulator_matches_the_truth_on_a_current_mode_drive(tmp_path, plant, values):
    """J w' = kd u - B w - Tc sign(w): the population kernel against the accurate
    integrator, with Coulomb friction (stick-slip at the reversals), open loop."""
    runs = read_dataset(sim_dataset(tmp_path, plant_rig(plant.kind, effects={}),
                                    square_plan(amps=(1.5,), periods=1)))
    coulomb = get_effect("coulomb_friction")
    sp = plant.servo(values, runs[0].constants)
    truth = simulate_truth(sp, runs[0].u, runs[0].dt, effects=[coulomb],
                           effect_params={"coulomb_friction": {"tc_v": 0.3}})
    sim = Simulator(runs, [coulomb], plant=plant).simulate(
        np.array([[values[n] for n in plant.names]]), {"coulomb_friction": {"tc_v": 0.3}})[0]
    scale = np.max(np.abs(truth["w"]))
    assert np.max(np.abs(sim["w"][0] - truth["w"])) < 2e-3 * scale
    # the steady speed is (kd u - Tc) / B: the physics, not just agreement
    kd, B = runs[0].constants["Ka"], values[plant.names[1]]
    steady = truth["w"][np.searchsorted(runs[0].t, 2.4)]
    assert steady == pytest.approx(kd * (1.5 - 0.3) / B, rel=0.01)


def test_rig_file_refuses_a_drive_and_axis_that_do_not_go_together():
    with pytest.raises(ConfigError, match="force-driven plant moves a linear axis"):
        rig_from_dict({"rig": {"drive": "force", "axis": "rotary"}}, "r.toml")
    with pytest.raises(ConfigError, match="linear axis has none"):
        rig_from_dict({"rig": {"drive": "force", "gear_ratio": 5.0}}, "r.toml")
    with pytest.raises(ConfigError, match="current is its command"):
        rig_from_dict({"rig": {"drive": "torque"}, "sensors": {"current_v_per_a": 1.0}}, "r.toml")


def test_linear_axis_example_config_identifies_in_physical_units(tmp_path):
    """configs/rig_linear_axis.toml: a force-driven carriage, a 5 um encoder, closed-loop
    runs under a PD; identify gives M, Fv, Fc and F0 in kg, N s/m, N and N."""
    out = tmp_path / "lin"
    labrig("sweep", "--sim", "--rig", "configs/rig_linear_axis.toml", "-o", out, check=0)
    meta = json.loads((out / "cl_sq_0.50V.json").read_text())
    assert meta["experiment"]["controller"]["kind"] == "pd"
    assert meta["rig"]["axis"] == "linear" and meta["sensors"]["pos_kind"] == "encoder"
    proc = labrig("identify", out, "--effects", "coulomb_friction,offset", "--seed", "1",
                  "--json", check=0)
    d = json.loads(proc.stdout)
    assert d["plant"] == "force" and d["units"] == {"position": "m", "speed": "m/s"}
    ph = d["physical"]
    assert ph["M"]["unit"] == "kg" and ph["M"]["value"] == pytest.approx(2.5, rel=0.05)
    assert ph["Fv"]["unit"] == "N s/m" and ph["Fv"]["value"] == pytest.approx(40.0, rel=0.05)
    assert ph["Fc"]["unit"] == "N" and ph["Fc"]["value"] == pytest.approx(8.0, rel=0.05)
    assert ph["F0"]["value"] == pytest.approx(1.0, rel=0.05)
    assert ph["M"]["interval95"][0] <= ph["M"]["value"] <= ph["M"]["interval95"][1]
    # the guide quotes these numbers ("Your rig is not an MS150")
    readme = (Path(__file__).resolve().parent.parent / "docs" / "guide" / "your-rig.md").read_text(
        encoding="utf-8")
    quoted = ", ".join(f"{k} = {ph[k]['value']:.4g} {u}" for k, u in
                       (("M", "kg"), ("Fv", "N s/m"), ("Fc", "N")))
    assert f"finds {quoted} and F0 = {ph['F0']['value']:.4g} N" in readme
    text = labrig("identify", out, "--effects", "coulomb_friction,offset", check=0).stdout
    assert "M (kg)" in text and "Fc (N)" in text and "Km (m/s per V)" in text


# -- the armature current ----------------------------------------------------------------

def test_current_makes_all_five_voltage_parameters_identifiable(tmp_path):
    """Speed and position fix three of R, L, J, B, K; the measured current fixes all five:
    rank 5, every parameter with an interval, no advice to measure what was measured."""
    plan = square_plan(amps=(1.2, 2.5), periods=1)
    with_i = read_dataset(sim_dataset(tmp_path, plant_rig("voltage", "tacho+pot+current"), plan, "i"))
    without = read_dataset(sim_dataset(tmp_path, plant_rig("voltage", "tacho+pot"), plan, "n"))
    a = identify(with_i, "co", seed=1, starts=4)
    b = identify(without, "co", seed=1, starts=4)
    assert a.identifiable["structural_rank"] == 5 and b.identifiable["structural_rank"] == 3
    assert "current" in a.metrics["rmse_over_noise"]
    for n, truth in (("R", 8.0), ("L", 0.0085), ("J", 5.2245e-5), ("B", 1e-5), ("K", 0.05)):
        assert a.params[n] == pytest.approx(truth, rel=0.10), n
        assert a.identifiable["parameters"][n]["interval95"] is not None, n
    assert not any("measure the armature current" in w for w in a.identifiable["warnings"])
    assert any("measure the armature current" in w for w in b.identifiable["warnings"])
    # the interval of tau_m tightens with the current
    wa, wb = (np.diff(np.log(r.identifiable["tau_m_s"]["interval95"]))[0] for r in (a, b))
    assert wa < wb


# -- import -------------------------------------------------------------------------------

def _axis_recording(tmp_path):
    """A closed-loop force-driven linear axis under a PD, as a lab would record it,
    saved as a MATLAB file: time, reference, controller output, encoder position."""
    import scipy.io

    rig = plant_rig("force", "encoder", effects={"coulomb_friction": {"tc_v": 0.3},
                                                 "offset": {"u0_v": 0.04}})
    sp = ForcePlant.servo({"M": 2.5, "Fv": 40.0}, {"Ka": 20.0, "N": 1.0, "Kt": 1.0, "Kpot": 1.0})
    dt, n = 1e-3, 6000
    t = np.arange(n) * dt
    ref = 0.05 * np.sign(np.sin(2 * np.pi * 0.5 * t + 1e-9)) * (t > 0.2)
    kp, kd = 60.0, 4.0
    effects = [get_effect("offset"), get_effect("coulomb_friction")]
    sim = simulate_truth(sp, ref, dt, effects=effects,
                         effect_params={e: rig.effects[e] for e in rig.effects},
                         loop="closed", kp=kp, kv=kd)
    x = np.floor(sim["theta"] * 2e5 + 0.5) / 2e5          # the encoder's 5 um counts
    drive = kp * (ref - sim["theta"]) - kd * sim["w"]     # the controller output, logged
    path = tmp_path / "axis.mat"
    scipy.io.savemat(path, {"time": t, "ref_m": ref, "drive_v": drive, "x_m": x})
    return path, kp, kd


def test_import_a_closed_loop_linear_axis_from_matlab(tmp_path):
    path, kp, kd = _axis_recording(tmp_path)
    out = tmp_path / "runs"
    labrig("import", path, "--map", "t=time,u=drive_v,ref=ref_m,pos=x_m", "--axis", "linear",
           "--drive", "force", "--input-gain", "20", "--pos-unit", "m", "--loop", "closed",
           "--controller", f"pd:kp={kp},kd={kd}", "-o", out, check=0)
    meta = json.loads((out / "axis.json").read_text())
    assert meta["rig"] == {**meta["rig"], "drive": "force", "axis": "linear", "input_gain": 20.0}
    assert meta["experiment"]["controller"] == {"kind": "pd", "kp": kp, "kd": kd, "ki": 0.0,
                                                "feedback": "position"}
    run = read_dataset(out)[0]
    assert run.units == ("m", "m/s") and "drive" in run.data
    for through in ("loop", "input"):
        proc = labrig("identify", out, "--effects", "coulomb_friction,offset", "--through",
                      through, "--json", check=0)
        d = json.loads(proc.stdout)
        assert d["closed_loop"]["way"] == through
        ph = d["physical"]
        assert ph["M"]["value"] == pytest.approx(2.5, rel=0.05), through
        assert ph["Fv"]["value"] == pytest.approx(40.0, rel=0.05), through
        assert ph["Fc"]["value"] == pytest.approx(6.0, rel=0.05), through


@pytest.mark.parametrize("args, message", [
    (["--loop", "closed"], "needs its controller"),
    (["--pos-unit", "m"], "unit of a linear axis"),
    (["--drive", "force"], "--input-gain: a force-driven axis needs"),
    (["--drive", "torque", "--axis", "linear", "--input-gain", "1"], "linear axis is force-driven"),
    (["--loop", "closed", "--controller", "pd:kp=1,ki=2"], "a pd controller has no ki"),
    (["--loop", "closed", "--controller", "lqr:kp=1"], "kind 'lqr' unknown"),
    (["--pos-unit", "counts:0"], "not counts:N"),
])
def test_import_refuses_what_does_not_describe_a_rig(tmp_path, args, message):
    src = tmp_path / "x.csv"
    src.write_text("time,u,x\n" + "".join(f"{k * 0.01},{k % 7},{k}\n" for k in range(50)))
    proc = labrig("import", src, "--map", "t=time,u=u,pos=x", "-o", tmp_path / "o", *args)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_encoder_counts_import_with_their_quantum(tmp_path):
    src = tmp_path / "enc.csv"
    src.write_text("t,u,counts\n" + "".join(f"{k * 0.01},{1.0},{3 * k}\n" for k in range(50)))
    labrig("import", src, "--map", "t=t,u=u,pos=counts", "--pos-unit", "counts:2000",
           "-o", tmp_path / "o", check=0)
    run = read_dataset(tmp_path / "o")[0]
    assert run.pos_quantum == pytest.approx(2 * np.pi / 2000)
    assert run.position[10] == pytest.approx(30 * 2 * np.pi / 2000)


# -- every plant x axis x sensor, a hidden effect found by diagnose --auto -----------------

MATRIX = [
    ("voltage", "tacho+pot", {"deadband": {"d_v": 0.3}}, "deadband", "d_v", 0.3),
    ("voltage", "encoder", {"coulomb_friction": {"tc_v": 0.2}}, "coulomb_friction", "tc_v", 0.2),
    ("voltage", "tacho+pot+current", {"deadband": {"d_v": 0.3}}, "deadband", "d_v", 0.3),
    ("torque", "tacho+pot", {"coulomb_friction": {"tc_v": 0.2}}, "coulomb_friction", "Tc", 0.02),
    ("torque", "encoder", {"deadband": {"d_v": 0.3}}, "deadband", "d_v", 0.3),
    ("force", "tacho+pot", {"deadband": {"d_v": 0.3}}, "deadband", "d_v", 0.3),
    ("force", "encoder", {"coulomb_friction": {"tc_v": 0.3}}, "coulomb_friction", "Fc", 6.0),
    ("voltage", "pot", {"coulomb_friction": {"tc_v": 0.2}}, "coulomb_friction", "tc_v", 0.2),
    ("torque", "pot", {"deadband": {"d_v": 0.3}}, "deadband", "d_v", 0.3),
    ("force", "pot", {"deadband": {"d_v": 0.3}}, "deadband", "d_v", 0.3),
]


@pytest.mark.slow
@pytest.mark.parametrize("drive, sensors, hidden, effect, key, truth", MATRIX,
                         ids=[f"{m[0]}-{m[1]}" for m in MATRIX])
def test_diagnose_auto_finds_the_hidden_effect_on_every_plant(tmp_path, drive, sensors, hidden,
                                                              effect, key, truth):
    from labrig.diagnosis.loop.auto import auto_diagnose

    rig = plant_rig(drive, sensors, effects=hidden)
    runs = read_dataset(sim_dataset(tmp_path, rig, square_plan(amps=(1.0, 1.7, 2.5), periods=1)))
    res = auto_diagnose(runs, None, max_rounds=2, seed=0)
    assert res.model.names == [effect], res.to_text()
    got = res.model.effect_params[effect].get(key)
    if got is None:  # a physical quantity: the plant's friction in N m or N
        phys = res.model.plant_class.physical(res.model.params, res.model.effect_params,
                                              res.model.constants)
        got = phys[key][0]
    assert got == pytest.approx(truth, rel=0.10)
    plant = {"voltage": VoltagePlant, "torque": TorquePlant, "force": ForcePlant}[drive]
    sp = res.model.servo()
    true_sp = plant.servo(dict(zip(plant.names, [PLANTS[drive][k] for k in PLANTS[drive]]))
                          if drive != "voltage" else
                          {n: v for n, v in zip(plant.names, PLANTS[drive].values())},
                          res.model.constants)
    assert sp.km == pytest.approx(true_sp.km, rel=0.10)
    assert sp.tau_m == pytest.approx(true_sp.tau_m, rel=0.10)


def test_a_mystery_rig_of_a_linear_axis_is_drawn_run_and_graded(tmp_path):
    """`mystery new --rig configs/rig_linear_axis.toml`: the plant's own parameters drawn
    around the base rig, hidden effects sized for a linear axis; reveal speaks of kg and
    m/s; check grades a model identified with the hidden effects."""
    from labrig.io.mystery import PLANT_SPREAD, new_mystery

    doc = new_mystery(4, "configs/rig_linear_axis.toml")
    assert doc["rig"]["drive"] == "force" and set(doc["plant"]) == {"M_kg", "Fv_ns_per_m"}
    assert abs(doc["plant"]["M_kg"] / 2.5 - 1) <= PLANT_SPREAD + 1e-3
    mfile = tmp_path / "axis.mystery"
    labrig("mystery", "new", "--seed", "4", "--rig", "configs/rig_linear_axis.toml",
           "-o", mfile, check=0)
    shown = labrig("mystery", "reveal", mfile, check=0).stdout
    assert "force-driven linear axis" in shown and " kg" in shown and "m/s per V" in shown
    runs = tmp_path / "runs"
    labrig("sweep", "--sim", "--rig", mfile, "-o", runs, check=0)
    hidden = ",".join(doc["effects"])
    labrig("identify", runs, "--effects", hidden, "--seed", "1", "-o", tmp_path / "m.json", check=0)
    graded = json.loads(labrig("mystery", "check", mfile, tmp_path / "m.json", "--json",
                               check=0).stdout)
    assert graded["found"] == sorted(doc["effects"]) and graded["pass"], graded["verdict"]
    assert abs(graded["plant"]["km"]["error_percent"]) < 5


@pytest.mark.parametrize("patch, message", [
    ({"rig": {"drive": "force", "axis": "rotary"}}, "key 'rig.axis'"),
    ({"rig": {"drive": "pneumatic"}}, "rig.drive"),
    ({"experiment": {"loop": "closed", "controller": {"kind": "lqr", "kp": 1.0}}},
     "experiment.controller.kind"),
    ({"experiment": {"loop": "closed"}}, "must state its controller"),
    ({"sensors": {"pos_quantum": -1.0}}, "sensors.pos_quantum"),
])
def test_a_sidecar_that_does_not_describe_a_plant_is_refused(tmp_path, patch, message):
    """Each bad key: one line naming the file and the key, exit 2, no traceback."""
    src = tmp_path / "x.csv"
    src.write_text("time,u,x\n" + "".join(f"{k * 0.01},{k % 7},{k}\n" for k in range(50)))
    labrig("import", src, "--map", "t=time,u=u,pos=x", "-o", tmp_path / "o", check=0)
    side = tmp_path / "o" / "x.json"
    meta = json.loads(side.read_text())
    for sec, body in patch.items():
        meta[sec].update(body)
    side.write_text(json.dumps(meta))
    proc = labrig("identify", tmp_path / "o")
    assert proc.returncode == 2 and message in proc.stderr and "x.json" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_friction_in_newton_metres_has_an_interval_only_when_the_data_fix_it(tmp_path):
    """On the voltage plant Tc = tc_v Ka K / R slides along the (R, L, J, B, K) family
    unless the current is measured: no interval without it, one with it."""
    plan = square_plan(amps=(1.2, 2.5), periods=1)
    hidden = {"coulomb_friction": {"tc_v": 0.2}}
    out = {}
    for sensors in ("tacho+pot", "tacho+pot+current"):
        runs = read_dataset(sim_dataset(tmp_path, plant_rig("voltage", sensors, hidden), plan,
                                        sensors))
        res = identify(runs, "co", [get_effect("coulomb_friction")], seed=1, starts=4)
        out[sensors] = res.physical()["Tc"]
    assert out["tacho+pot"]["interval95"] is None
    lo, hi = out["tacho+pot+current"]["interval95"]
    truth = 0.2 * 5.0 * 0.05 / 8.0   # tc_v Ka K / R, N m
    assert lo <= out["tacho+pot+current"]["value"] <= hi
    assert out["tacho+pot+current"]["value"] == pytest.approx(truth, rel=0.10)
