"""The accurate "truth" integrator of the simulated rig (docs/physics.md, 'The simulators').

Fixed step with sub-steps inside each sample: semi-implicit armature update (no L/R
stability limit), explicit mechanical update with the Karnopp stick-slip rule (no
chatter), backlash as a play operator on the output shaft, transport delay by
shifting the held input. One parameter set at a time; accuracy, not speed, is its
job (the identifiers use ``labrig.model.simulate``).

Sampling convention (the board's): sample k is read at t_k before the output for
sample k is applied; the output is held until t_{k+1} (zero-order hold).
"""
from __future__ import annotations

import math

import numpy as np

from labrig.model.effects import Effect, ordered
from labrig.simulation.sampled_kernel import adc_word, pd_counts
from labrig.model.servo import ServoParams


def simulate_truth(p: ServoParams, u: np.ndarray, dt: float, *, effects=(),
                   effect_params: dict | None = None, loop: str = "open",
                   kp: float | None = None, kv: float | None = None, substeps: int = 20,
                   x0=(0.0, 0.0, 0.0), rail_v: float = np.inf,
                   sampled: dict | None = None, sensor_noise=None) -> dict:
    """Simulate one run.

    Parameters
    ----------
    p : ServoParams
    u : array
        Bridge output per sample (V): amplifier input in open loop, reference in
        closed loop.
    dt : float
        Sample period (s).
    effects : sequence of Effect
    effect_params : dict
        ``{effect name: {param: value}}``.
    loop : {"open", "closed"}
    substeps : int
        Integration steps per sample.
    rail_v : float
        The amplifier's supply rail (V): physics, not an optional effect.
    sampled : dict, optional
        A closed loop run by a board on its encoder count (an H-bridge board's law:
        ``kp_q``, ``kd_q``, ``counts_per_unit``, ``volts_per_count``, ``limits``, as
        :func:`labrig.bridge.settings.sampled_pd` gives it): at each sample the count of
        the output shaft (rounded, as the simulated rig records it) from the run's start
        against ``u`` in counts, its change over one sample, the output held to the next.
        With ``feedback = "sensors"`` the MS150 board's own loop
        (:func:`labrig.bridge.settings.sensor_pd`): the pot's and the tacho's ADC words,
        ``u`` the reference in output rad.
    sensor_noise : (array, array), optional
        The tacho's and the pot's noise in ADC words, sample by sample: what the board's loop
        on its sensors reads with them (the run records the same words).

    Returns
    -------
    dict with ``w`` (motor rad/s), ``theta`` (output rad, after backlash),
    ``theta_m`` (motor rad), ``i`` (A), all sampled at t_k; with ``sampled``, ``drive``
    (the board's output, V), and on sensors the words it read (``tacho_word``,
    ``pos_word``).
    """
    effect_params = effect_params or {}
    if loop == "closed" and (kp is None or kv is None):
        raise ValueError("a closed loop needs its gains kp and kv")
    u = np.asarray(u, dtype=float)
    n = len(u)
    h = dt / substeps
    by_stage: dict[str, list[tuple[Effect, dict]]] = {}
    for e in ordered(effects):
        by_stage.setdefault(e.stage, []).append((e, effect_params.get(e.name, {})))
    td = sum(e.delay_s(**ep) for e, ep in by_stage.get("delay", []))
    fric = by_stage.get("friction", [])
    outp = by_stage.get("output", [])
    # friction larger one way: the mean level as friction, half the difference as a
    # constant drive entering where an input offset does (labrig.model.friction.FrictionCurve)
    bias = sum(float(e.input_bias(**ep)) for e, ep in fric if hasattr(e, "input_bias"))

    R, L, J, B, K, Ka, Ke = p.R, p.L, p.J, p.B, p.K, p.Ka, p.ke
    # inductance invisible at this step (docs/physics.md, 'The simulators')
    quasi_static = L / R < h / 10
    i, w, th = map(float, x0)
    play = th / p.N
    out_w, out_th, out_thm, out_i = (np.empty(n) for _ in range(4))
    drive = np.zeros(n) if sampled else None
    if sampled:
        kq, dq = float(sampled["kp_q"]), float(sampled["kd_q"])
        cpu, vpc = float(sampled["counts_per_unit"]), float(sampled["volts_per_count"])
        lo, hi = (float(v) for v in sampled["limits"])
        sensors = sampled.get("feedback") == "sensors"
        if sensors:   # pot and tacho words, as the board's ADC codes them
            pz, tpu = float(sampled["pos_zero"]), float(sampled["tacho_counts_per_unit_s"])
            tz, tzw = float(sampled["tacho_zero"]), int(sampled["tacho_zero_word"])
            wmax = float(sampled["word_max"])
            n_tw, n_pw = (np.zeros(n), np.zeros(n)) if sensor_noise is None else sensor_noise
            words = {"tacho_word": np.zeros(n), "pos_word": np.zeros(n)}
            ref = np.round(u * cpu + pz)
        else:
            ref = np.round(u * cpu)   # the board's reference words: counts from the run's start
        c0, x_prev = None, 0
    held = drive if sampled else u   # what the amplifier input follows, sample by sample
    for k in range(n):
        # sample first (the ADC reads at t_k)
        out_w[k], out_thm[k], out_i[k] = w, th, i
        out_th[k] = play if outp else th / p.N
        if sampled and sensors:   # the board's law on this sample's pot and tacho words
            x = adc_word(out_th[k] * cpu + pz + n_pw[k], wmax)
            t = adc_word(w * tpu + tz + n_tw[k], wmax)
            words["pos_word"][k], words["tacho_word"][k] = x, t
            drive[k] = vpc * pd_counts(kq, dq, ref[k] - x, t - tzw, lo, hi)
        elif sampled:   # the board's law at this tick, on this sample's count
            count = math.floor(out_th[k] * cpu + 0.5)
            c0 = count if c0 is None else c0
            x = count - c0
            drive[k] = vpc * pd_counts(kq, dq, ref[k] - x, x - x_prev, lo, hi)
            x_prev = x
        for s in range(substeps):
            tau = k * dt + s * h - td
            kk = int(np.floor(tau / dt + 1e-9))
            r = held[kk] if kk >= 0 else 0.0
            if loop == "closed" and not sampled:
                # the pot on the output shaft closes the loop: it sees the backlash
                v = kp * (r - p.Kpot * (play if outp else th / p.N)) - kv * p.Kt * w
            else:
                v = r
            v += bias
            for e, ep in by_stage.get("input", []):
                v = float(e.apply(np.float64(v), **ep))
            v = min(max(Ka * v, -rail_v), rail_v)
            for e, ep in by_stage.get("drive", []):
                v = float(e.apply(np.float64(v), **ep))
            if quasi_static:  # (a current-mode drive: Ke = 0, the drive sets K i)
                i = (v - Ke * w) / R
            else:
                i = (i + h / L * (v - Ke * w)) / (1.0 + h * R / L)
            tnf = K * i - B * w
            if fric:
                tc, ts = 0.0, 0.0
                for e, ep in fric:
                    a, b = e.friction(p, **ep)
                    tc, ts = tc + float(a), ts + float(b)
                w = _karnopp_step(w, tnf, tc, ts, h / J)
            else:
                w = w + h / J * tnf
            th = th + h * w
            for e, ep in outp:  # the play operator is rate-independent: track every sub-step
                play, _ = e.output(play, th / p.N, **ep)
    out = {"w": out_w, "theta": out_th, "theta_m": out_thm, "i": out_i}
    if sampled:
        out["drive"] = drive
        if sensors:
            out.update(words)
    return out


def _karnopp_step(w: float, tnf: float, tc: float, ts: float, h_over_j: float) -> float:
    """One explicit step of J dw/dt = Tnf - Tf with stick-slip and no chatter."""
    if w == 0.0:
        if abs(tnf) <= ts:
            return 0.0  # stuck: static friction balances the drive
        return h_over_j * (tnf - ts * np.sign(tnf))
    w_new = w + h_over_j * (tnf - tc * np.sign(w))
    if w_new * w <= 0.0 and abs(tnf) <= ts:
        return 0.0  # crossed zero and friction can hold it: stick, don't chatter
    return w_new
