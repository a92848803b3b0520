"""The population kernel (candidates in SIMD lanes, the identifiers' fitness path) against
the per-candidate kernel (trajectories): the same model, sample by sample."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import make_rig, sim_dataset, square_plan
from labrig.model.effects import CATALOGUE
from labrig.model.simulate import Simulator
from labrig.io.runs import read_dataset

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
          ["saturation", "coulomb_friction", "delay"]]


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
