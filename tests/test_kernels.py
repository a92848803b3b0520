"""The population kernel (candidates in SIMD lanes, the identifiers' fitness path) against
the per-candidate kernel (trajectories): the same model, sample by sample."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import make_rig, sim_dataset, square_plan
from labrig.model.effects import CATALOGUE
from labrig.model.simulate import Simulator
from labrig.io.runs import read_dataset
from labrig.simulation.layout import C_TC, C_TS

VALUES = {"coulomb_friction": {"tc_v": (0.05, 0.3)},
          "stiction": {"tc_v": (0.05, 0.3), "excess": (0.1, 1.0)},
          "deadband": {"d_v": (0.05, 0.4)}, "saturation": {"vmax_v": (5.0, 12.0)},
          "backlash": {"a_rad": (0.005, 0.05)}, "delay": {"td_s": (0.0005, 0.01)},
          "offset": {"u0_v": (-0.1, 0.1)}, "asymmetry": {"k": (-0.2, 0.2)},
          "asymmetric_deadband": {"dpos_v": (0.05, 0.3), "dneg_v": (0.05, 0.3)}}
COMBOS = [[], ["coulomb_friction"], ["stiction"], ["deadband"], ["delay"], ["backlash"],
          ["offset", "asymmetry", "saturation"], ["asymmetric_deadband"],
          ["coulomb_friction", "backlash"], ["coulomb_friction", "delay"],
          ["stiction", "backlash", "delay"], ["deadband", "coulomb_friction", "backlash"],
          ["saturation", "coulomb_friction", "delay"], ["backlash", "deadband"],
          ["backlash", "offset", "saturation"]]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two open-loop square waves and the rig's two closed-loop runs (200 Hz: quick)."""
    from labrig.io.experiment import Experiment

    plan = square_plan(amps=(0.6, 2.0), rate=200.0, periods=1) + [
        Experiment(name="cl", amplitude_v=0.5, frequency_hz=0.25, periods=1, lead_in_s=0.5,
                   sample_rate_hz=200.0, loop="closed", position_gain=1.0, velocity_gain=0.3)]
    folder = sim_dataset(tmp_path_factory.mktemp("k"), make_rig(), plan, seed=2)
    runs = read_dataset(folder)
    assert {r.loop for r in runs} == {"open", "closed"}
    return runs


@pytest.mark.parametrize("names", COMBOS, ids=lambda n: "+".join(n) or "linear")
def test_population_kernel_is_the_per_candidate_kernel(runs, names):
    """Fitness from the vector lanes = the sum of squares of the per-candidate kernel's
    trajectories, candidate by candidate (only the summation order differs)."""
    rng = np.random.default_rng(len(names))
    P = 40
    plant = np.array([8.0, 0.0085, 5.2245e-5, 1.0e-5, 0.05]) * 10.0 ** rng.uniform(-0.3, 0.3,
                                                                                  (P, 5))
    ep = {n: {k: rng.uniform(lo, hi, P) for k, (lo, hi) in VALUES[n].items()} for n in names}
    sim = Simulator(runs, [CATALOGUE[n]() for n in names])
    weights = [(r.speed, 1.3, r.position, 20.0, None, 0.0) for r in runs]
    fast = sim.sse(plant, ep, weights)
    ref = np.zeros(P)
    for r, tr, (wm, iw, tm, it, _, _) in zip(runs, sim.simulate(plant, ep), weights):
        ref += iw ** 2 * np.sum((wm - tr["w"]) ** 2, axis=1)
        ref += it ** 2 * np.sum((tm - tr["theta"]) ** 2, axis=1)
    assert np.all(np.isfinite(fast))
    np.testing.assert_allclose(fast, ref, rtol=1e-9)


@pytest.mark.parametrize("names", [[], ["coulomb_friction"], ["deadband"], ["backlash"],
                                   ["stiction", "backlash", "delay"]],
                         ids=lambda n: "+".join(n) or "linear")
def test_population_kernel_with_a_measured_current(runs, names):
    """A measured current's residual (added after the lanes' own) as the per-candidate
    kernel's trajectories give it."""
    rng = np.random.default_rng(7 + len(names))
    P = 24
    plant = np.array([8.0, 0.0085, 5.2245e-5, 1.0e-5, 0.05]) * 10.0 ** rng.uniform(-0.3, 0.3,
                                                                                  (P, 5))
    ep = {n: {k: rng.uniform(lo, hi, P) for k, (lo, hi) in VALUES[n].items()} for n in names}
    sim = Simulator(runs, [CATALOGUE[n]() for n in names])
    weights = [(r.speed, 1.3, r.position, 20.0, 0.02 * r.speed, 40.0) for r in runs]
    fast = sim.sse(plant, ep, weights)
    ref = np.zeros(P)
    for r, tr, (wm, iw, tm, it, im, ii) in zip(runs, sim.simulate(plant, ep), weights):
        ref += iw ** 2 * np.sum((wm - tr["w"]) ** 2, axis=1)
        ref += it ** 2 * np.sum((tm - tr["theta"]) ** 2, axis=1)
        ref += ii ** 2 * np.sum((im - tr["i"]) ** 2, axis=1)
    without = sim.sse(plant, ep, [w[:4] + (None, 0.0) for w in weights])
    assert np.all(fast > without)  # the current's residual is in the sum
    np.testing.assert_allclose(fast, ref, rtol=1e-9)


def _stepped(sim, effects, step):
    """The run of ``sim`` (one closed-loop run) stepped sample by sample from rest by
    ``step(i, w, th, pl, s_old, s_new, fr, c) -> (i, w, th, pl)``: its speed and the
    position the pot reads, as the kernels record them."""
    rd = sim.runs[0]
    c = np.array([rd.dt, rd.Ka, rd.N, rd.Kt, rd.Kpot, rd.kp, rd.kv, rd.theta0])
    td = effects.get("delay", {}).get("td_s", 0.0)
    m = int(np.floor(td / rd.dt + 1e-9))
    fr = td / rd.dt - m
    i, w, th, pl = 0.0, 0.0, c[7] * c[2], c[7]
    ws, ths = np.empty(len(rd.u)), np.empty(len(rd.u))
    for k in range(len(rd.u)):
        ws[k], ths[k] = w, (pl if "backlash" in effects else th / c[2])
        s_old = rd.u[k - m - 1] if k - m - 1 >= 0 else 0.0
        s_new = rd.u[k - m] if k - m >= 0 else 0.0
        i, w, th, pl = step(i, w, th, pl, s_old, s_new, fr, c)
    return ws, ths


@pytest.mark.parametrize("effects", [
    {"deadband": {"d_v": 0.3}}, {"saturation": {"vmax_v": 6.0}}, {"backlash": {"a_rad": 0.03}},
    {"asymmetry": {"k": 0.15}, "offset": {"u0_v": 0.05}},
    {"deadband": {"d_v": 0.2}, "delay": {"td_s": 0.0035}},
    {"coulomb_friction": {"tc_v": 0.2}, "backlash": {"a_rad": 0.02}},
], ids=lambda e: "+".join(e))
def test_closed_loop_pieces_are_as_accurate_as_the_substeps_they_replace(tmp_path, effects):
    """A closed loop with an effect inside, exact in each affine piece of its drive: against
    the truth at 400 sub-steps per sample (accurate to far below a count) it is within a
    fifth of an ADC count of the tacho and of the pot, and no farther from it than the 16
    semi-implicit sub-steps per sample it replaced."""
    from labrig.io.experiment import Experiment
    from labrig.simulation.candidate_kernel import substeps
    from labrig.model.servo import ServoParams
    from labrig.model.truth import simulate_truth

    rig = make_rig(effects=effects)
    plan = [Experiment(name="cl", loop="closed", amplitude_v=0.5, frequency_hz=0.25, periods=1,
                       lead_in_s=0.5, position_gain=2.0, velocity_gain=0.15)]
    run = read_dataset(sim_dataset(tmp_path, rig, plan))[0]
    p = ServoParams.from_rig(rig)
    sim = Simulator([run], [CATALOGUE[n]() for n in effects])
    x = np.array([[p.R, p.L, p.J, p.B, p.K]])
    pieces = sim.simulate(x, effects)[0]
    fine = simulate_truth(p, run.u, run.dt, effects=[CATALOGUE[n]() for n in effects],
                          effect_params=effects, loop="closed", kp=2.0, kv=0.15, substeps=400)
    # the sub-steps throughout (the kernel before the pieces), sample by sample
    prm, _, _ = sim._params(x, effects)
    old_w, old_th = _stepped(sim, effects, lambda i, w, th, pl, s_old, s_new, fr, c: substeps(
        i, w, th, pl, s_old, s_new, fr, prm[0], 2, 16, c))
    qw = rig.bridge.adc_quantum_v / rig.sensors.tacho_v_per_rad_s
    qt = rig.bridge.adc_quantum_v / rig.sensors.pos_v_per_rad
    ew, et = (np.sqrt(np.mean((pieces[k][0] - fine[k]) ** 2)) for k in ("w", "theta"))
    ow, ot = (np.sqrt(np.mean((o - fine[k]) ** 2)) for o, k in ((old_w, "w"), (old_th, "theta")))
    assert ew < 0.2 * qw and et < 0.2 * qt, (ew / qw, et / qt)
    assert ew <= 1.05 * ow and et <= 1.05 * ot, (ew, ow, et, ot)


@pytest.mark.parametrize("effects", [
    {"deadband": {"d_v": 0.3}}, {"saturation": {"vmax_v": 3.0}}, {"backlash": {"a_rad": 0.03}},
    {"asymmetry": {"k": 0.15}, "offset": {"u0_v": 0.05}},
    {"deadband": {"d_v": 0.2}, "delay": {"td_s": 0.0035}},
    {"coulomb_friction": {"tc_v": 0.2}, "deadband": {"d_v": 0.1}},
    {"stiction": {"tc_v": 0.1, "excess": 0.5}, "backlash": {"a_rad": 0.02}},
], ids=lambda e: "+".join(e))
def test_loop_candidate_is_loop_step_sample_by_sample(runs, effects):
    """The per-candidate kernel of a closed loop with its input map keeps what a steady
    input leaves unchanged (the piece, its levels, the slot's coefficients) instead of
    finding it again each sample: the same numbers, bit for bit, as stepping
    :func:`loop_sample_alone` (its piece found afresh every sample) through the run."""
    from labrig.model.simulate import _loop_table
    from labrig.simulation.candidate_kernel import loop_sample_alone

    run = next(r for r in runs if r.loop == "closed")
    sim = Simulator([run], [CATALOGUE[n]() for n in effects])
    x = np.array([[8.0, 0.0085, 5.2245e-5, 1.0e-5, 0.05]])
    kept = sim.simulate(x, effects)[0]
    prm, _, _ = sim._params(x, effects)
    td = effects.get("delay", {}).get("td_s", 0.0)
    fr = td / sim.runs[0].dt - np.floor(td / sim.runs[0].dt + 1e-9)
    T = _loop_table(prm, sim.runs[0], np.array([fr]), sim.substeps)
    friction = prm[0, C_TC] > 0.0 or prm[0, C_TS] > 0.0
    w_ref, th_ref = _stepped(sim, effects, lambda i, w, th, pl, s_old, s_new, fr, c:
                             loop_sample_alone(i, w, th, pl, s_old, s_new, fr, prm[0], friction,
                                               sim.substeps, c, T, 0))
    assert np.array_equal(kept["w"][0], w_ref) and np.array_equal(kept["theta"][0], th_ref)


def test_zero_order_hold_is_the_matrix_exponential():
    """The simulator's exact ZOH (plain loops over the three non-zero rows) against
    scipy's expm of the augmented matrix, with and without a fractional delay."""
    from scipy.linalg import expm

    from labrig.simulation.expm import zoh_batch
    from labrig.simulation.discretise import plant_matrices

    rng = np.random.default_rng(3)
    P, h = 12, 1e-3
    prm = np.zeros((P, 14))
    prm[:, :5] = np.array([8.0, 0.0085, 5.2245e-5, 1.0e-5, 0.05]) * 10.0 ** rng.uniform(
        -0.5, 0.5, (P, 5))
    prm[:, 13] = prm[:, 4]
    A, bs, bf = plant_matrices(prm)
    A[:, 0, 2] -= 4.0 / 30.0 / prm[:, 1]  # a closed loop's position feedback
    frac = np.where(np.arange(P) % 2 == 0, 0.0, rng.uniform(0.05, 0.95, P))
    Ad, g_old, g_new, gf = zoh_batch(A, bs, bf, frac, h)
    for p in range(P):
        M = np.zeros((5, 5))
        M[:3, :3], M[:3, 3], M[:3, 4] = A[p], bs[p], bf[p]
        E1, E2 = expm(M * frac[p] * h), expm(M * (1.0 - frac[p]) * h)
        # x+ = E2 (E1 x + switch-part) : the old input over frac, the new over the rest
        np.testing.assert_allclose(Ad[p], E2[:3, :3] @ E1[:3, :3], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(g_old[p], E2[:3, :3] @ E1[:3, 3], rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(g_new[p], E2[:3, 3], rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(gf[p], E2[:3, :3] @ E1[:3, 4] + E2[:3, 4], rtol=1e-12,
                                   atol=1e-18)
        if frac[p] == 0.0:
            assert not g_old[p].any()
