"""The servo model, the truth integrator and each effect's signature (issue 3)."""
import numpy as np
import control
import pytest

from labrig.io.config import load_rig
from labrig.model.effects import get_effect
from labrig.model.servo import ServoParams
from labrig.model.truth import simulate_truth

DT = 1e-3


@pytest.fixture(scope="module")
def p():
    return ServoParams.from_rig(load_rig())


def step(n=3000, amp=1.5, lead=100):
    u = np.zeros(n)
    u[lead:] = amp
    return u


def test_open_loop_gain_and_time_constant(p):
    u = step()
    w = simulate_truth(p, u, DT)["w"]
    km = p.Ka * p.K / (p.B * p.R + p.K ** 2)
    assert w[-1] / 1.5 == pytest.approx(km, rel=0.01)
    # 63.2 % point of the step, interpolated between samples
    y = w[100:] / w[-1]
    k = np.argmax(y >= 1 - np.exp(-1))
    t63 = (k - 1 + (1 - np.exp(-1) - y[k - 1]) / (y[k] - y[k - 1])) * DT
    assert t63 == pytest.approx(p.J * p.R / (p.B * p.R + p.K ** 2), rel=0.01)


def test_closed_loop_matches_python_control(p):
    kp, kv = 2.0, 0.15
    u = step(3000, amp=0.5)
    sim = simulate_truth(p, u, DT, loop="closed", kp=kp, kv=kv)
    t = np.arange(3000) * DT
    resp = control.forced_response(p.closed_loop(kp, kv), T=t, U=u)
    theta_ref = resp.outputs[1]
    assert np.max(np.abs(sim["theta"] - theta_ref)) < 2e-3 * np.max(np.abs(theta_ref))
    info = p.position_step_info(kp, kv)
    assert 0 < info["rise_time_s"] < info["settling_time_s"] < 3


def run_with(p, name, params, u, **kw):
    e = get_effect(name)
    return simulate_truth(p, u, DT, effects=[e], effect_params={name: params}, **kw)


def test_deadband_signature(p):
    d = 0.5
    assert np.all(run_with(p, "deadband", {"d_v": d}, step(1000, amp=0.8 * d))["w"] == 0)
    amps = np.array([1.0, 1.5, 2.0])
    ws = [run_with(p, "deadband", {"d_v": d}, step(2000, amp=a))["w"][-1] for a in amps]
    slope, icpt = np.polyfit(amps, ws, 1)
    assert -icpt / slope == pytest.approx(d, abs=0.01)
    assert slope == pytest.approx(p.km, rel=0.01)


def test_saturation_signature(p):
    vmax = 6.0
    ws = [run_with(p, "saturation", {"vmax_v": vmax}, step(2000, amp=a))["w"][-1]
          for a in (1.5, 2.0, 2.5)]
    assert np.ptp(ws) < 1e-6 * ws[0]
    assert ws[0] == pytest.approx(p.km / p.Ka * vmax, rel=0.01)


def test_coulomb_friction_stops_in_finite_time(p):
    u = np.r_[np.full(1500, 2.0), np.zeros(1500)]
    w_f = run_with(p, "coulomb_friction", {"tc_v": 0.13}, u)["w"]
    w_0 = simulate_truth(p, u, DT)["w"]
    stop = np.argmax(w_f[1500:] == 0)
    assert 0 < stop < 1000 and np.all(w_f[1500 + stop:] == 0)   # stuck for good, no chatter
    assert np.all(w_0[1500:] > 0)                                # viscous alone never stops


def test_backlash_signature(p):
    a = np.radians(2.0)
    u = np.r_[np.full(1000, 1.5), np.full(1000, -1.5)]
    with_b = run_with(p, "backlash", {"a_rad": a}, u)
    plain = simulate_truth(p, u, DT)
    np.testing.assert_array_equal(with_b["w"], plain["w"])       # tacho unaffected
    th = with_b["theta"]
    rev = 1001 + np.argmax(np.diff(plain["theta"][1000:]) < 0)    # first sample after the peak
    flat = np.flatnonzero(np.diff(th[rev:]) != 0)[0]              # output stands still ...
    motor_travel = plain["theta"].max() - plain["theta"][rev + flat]
    assert motor_travel == pytest.approx(2 * a, rel=0.05)         # ... while the motor takes up 2a


def test_delay_signature(p):
    u = step(1500)
    w = simulate_truth(p, u, DT)["w"]
    wd = run_with(p, "delay", {"td_s": 0.005}, u)["w"]
    np.testing.assert_allclose(wd[5:], w[:-5], atol=1e-9)


def test_convergence_halving_the_step_changes_less_than_adc_quantum(p):
    rig = load_rig()
    q_tacho = rig.bridge.adc_quantum_v / rig.sensors.tacho_v_per_rad_s
    q_pos = rig.bridge.adc_quantum_v / rig.sensors.pos_v_per_rad
    effs = [get_effect("coulomb_friction"), get_effect("backlash"), get_effect("deadband")]
    prm = {"coulomb_friction": {"tc_v": 0.13}, "backlash": {"a_rad": 0.02}, "deadband": {"d_v": 0.2}}
    u = np.r_[np.zeros(200), np.full(2000, 1.5), np.full(2000, -1.5), np.zeros(1000)]
    a = simulate_truth(p, u, DT, effects=effs, effect_params=prm, substeps=20)
    b = simulate_truth(p, u, DT, effects=effs, effect_params=prm, substeps=40)
    assert np.max(np.abs(a["w"] - b["w"])) < q_tacho
    assert np.max(np.abs(a["theta"] - b["theta"])) < q_pos
