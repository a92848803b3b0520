"""A board's own position loop, sample by sample: the controller a microcontroller runs.

An H-bridge board closes its loop on the encoder's count at each sample (the firmware's
``lr_core_tick``): it reads the count, computes ``out = floor((kp_q e - kd_q v) / 256)``
output counts (Q8.8 gains, ``e`` the reference less the count, ``v`` the count's change
since the sample before, both from the run's start and clipped to 16 bits), clamps it to
the output word and holds it to the next sample. Nothing of that is continuous: the
position is seen a whole count at a time, the derivative is a one-sample difference, the
drive is held and clamped. A continuous PD stands for it only while a count is small
against the motion and the loop slow against the sample rate; here the model runs the
same law on its own simulated count.

Between samples the plant is driven open loop by the held output through the candidate's
input map (dead zone, offset, rail...), so the update is the open-loop one of
:func:`labrig.simulation.candidate_kernel._candidate`: the same lines, without its closed
loop and with the controller in front. (That kernel is the population kernel's bit-for-bit
reference and the identifiers' hot path: it is kept free of this branch.)
"""
from __future__ import annotations

import math

import numba
import numpy as np

from labrig.simulation.candidate_kernel import friction_step, input_map, substeps
from labrig.simulation.layout import (C_A, C_GAP0, C_I0, C_TC, C_TH0, C_TS, C_W0, M_D, M_DN,
                                      M_DP, M_K, M_U0, M_VMAX)
from labrig.simulation.loop_kernel import play_operator

#: the controller's constants (``pd``): Q8.8 gains, counts per position unit, input volts
#: per output count, the output's limits in counts (below and above zero); then what the
#: MS150 board's loop on its sensors needs (``D_SENSORS`` 1): the pot's word at 0, the
#: tacho's words per unit/s of the motor, its word at rest and the whole word the board
#: takes for it, the largest word
D_KP, D_KD, D_CPU, D_VPC, D_LO, D_HI, D_SENSORS, D_PZ, D_TPU, D_TZ, D_TZW, D_WMAX = range(12)


def pd_constants(sampled: dict) -> np.ndarray:
    """A run's ``experiment.controller.sampled`` as the kernel's constants."""
    sensors = sampled.get("feedback") == "sensors"
    return np.array([sampled["kp_q"], sampled["kd_q"], sampled["counts_per_unit"],
                     sampled["volts_per_count"], *sampled["limits"], float(sensors),
                     sampled.get("pos_zero", 0.0), sampled.get("tacho_counts_per_unit_s", 0.0),
                     sampled.get("tacho_zero", 0.0), sampled.get("tacho_zero_word", 0),
                     sampled.get("word_max", 0xFFFF)], float)


def first_output(pd: np.ndarray, u0: float, theta: np.ndarray, w0: np.ndarray) -> np.ndarray:
    """The board's first output (input volts) per candidate: on its count, 0 at the start
    and unchanged; on its sensors, the pot's word at ``theta`` (output units) against the
    reference ``u0`` and the tacho's at ``w0`` (motor)."""
    theta, w0 = np.broadcast_arrays(np.asarray(theta, float), np.asarray(w0, float))
    ref = float(np.round(u0 * pd[D_CPU] + pd[D_PZ]))
    if pd[D_SENSORS]:
        e = [ref - adc_word(th * pd[D_CPU] + pd[D_PZ], pd[D_WMAX]) for th in theta]
        v = [adc_word(w * pd[D_TPU] + pd[D_TZ], pd[D_WMAX]) - pd[D_TZW] for w in w0]
    else:
        e, v = [ref] * len(theta), [0.0] * len(theta)
    return np.array([pd_counts(pd[D_KP], pd[D_KD], a, b, pd[D_LO], pd[D_HI]) * pd[D_VPC]
                     for a, b in zip(e, v)])


@numba.njit(cache=True, inline="always")
def adc_word(v, wmax):
    """The word an ADC codes for ``v`` (in words): the nearest code, within its range."""
    return min(max(math.floor(v + 0.5), 0.0), wmax)


@numba.njit(cache=True, inline="always")
def pd_counts(kq, dq, e, v, lo, hi):
    """The board's PD output in counts: 16-bit clipped error and change, Q8.8 gains, the
    floor of the shift, clamped to the output word's limits."""
    e = min(max(e, -32767.0), 32767.0)
    v = min(max(v, -32767.0), 32767.0)
    o = math.floor((kq * e - dq * v) / 256.0)
    return min(max(o, lo), hi)


@numba.njit(cache=True)
def _sampled_candidate(p, ref, m, frac, Ad, g_old, g_new, gf, prm, S, c, pd, out_w, out_th,
                       out_i, out_u, store, wm, iw, tm, it, im, ii, sse, imap):
    """Candidate ``p`` through one run of a board's loop: ``ref`` the reference in counts
    from the run's start, ``pd`` the controller's constants; the plant's update as
    :func:`~labrig.simulation.candidate_kernel._candidate`'s open loop. ``out_u`` (with
    ``store``) receives the controller's output in input volts."""
    n = ref.shape[0]
    u0, mk, md, mdp, mdn, mvmax = (imap[p, M_U0], imap[p, M_K], imap[p, M_D],
                                   imap[p, M_DP], imap[p, M_DN], imap[p, M_VMAX])
    kq, dq, cpu, vpc, lo, hi = pd[D_KP], pd[D_KD], pd[D_CPU], pd[D_VPC], pd[D_LO], pd[D_HI]
    Ka = c[1]
    N = c[2]
    acc = 0.0
    pr = prm[p]
    i = pr[C_I0]
    w = pr[C_W0]
    th = (c[7] + pr[C_TH0] + pr[C_GAP0] * pr[C_A]) * N
    play = c[7] + pr[C_TH0]
    tc, ts, a = pr[C_TC], pr[C_TS], pr[C_A]
    friction = tc > 0.0 or ts > 0.0
    mp = m[p]
    A = Ad[p]
    a00, a01, a10, a11, a20, a21 = A[0, 0], A[0, 1], A[1, 0], A[1, 1], A[2, 0], A[2, 1]
    gn0, gn1, gn2 = g_new[p, 0], g_new[p, 1], g_new[p, 2]
    go0, go1, go2 = g_old[p, 0], g_old[p, 1], g_old[p, 2]
    gf0, gf1, gf2 = gf[p, 0], gf[p, 1], gf[p, 2]
    delayed = go0 != 0.0 or go1 != 0.0 or go2 != 0.0
    drive = np.zeros(n)   # the controller's output through the input map, per sample
    sensors = pd[D_SENSORS] != 0.0
    pz, tpu, tz, tzw, wmax = pd[D_PZ], pd[D_TPU], pd[D_TZ], pd[D_TZW], pd[D_WMAX]
    x0 = 0.0 if sensors else math.floor((play if a > 0.0 else th / N) * cpu + 0.5)   # origin
    xp = 0.0
    for k in range(n):
        yth = play if a > 0.0 else th / N
        if store:
            out_w[p, k] = w
            out_th[p, k] = yth
            out_i[p, k] = i
        else:
            acc += (iw * (wm[k] - w)) ** 2 + (it * (tm[k] - yth)) ** 2
            if ii != 0.0:
                acc += (ii * (im[k] - i)) ** 2
        # the board reads its count (or its pot and tacho) and sets its output now, held to
        # the next sample
        if sensors:
            x = adc_word(yth * cpu + pz, wmax)
            o = pd_counts(kq, dq, ref[k] - x, adc_word(w * tpu + tz, wmax) - tzw, lo, hi) * vpc
        else:
            x = math.floor(yth * cpu + 0.5) - x0
            o = pd_counts(kq, dq, ref[k] - x, x - xp, lo, hi) * vpc
        xp = x
        if store:
            out_u[p, k] = o
        drive[k] = input_map(o, u0, mk, md, mdp, mdn, Ka, mvmax)
        ko = k - mp - 1
        kn = k - mp
        s_old = drive[ko] if ko >= 0 else 0.0
        s_new = drive[kn] if kn >= 0 else 0.0
        if friction and w == 0.0:  # stuck rotor
            i, w, th, play = friction_step(i, w, th, play, s_old, s_new, frac[p], pr, 0, S, c)
            continue
        ni = a00 * i + a01 * w + gn0 * s_new
        nw = a10 * i + a11 * w + gn1 * s_new
        nt = a20 * i + a21 * w + th + gn2 * s_new
        if delayed:
            ni += go0 * s_old
            nw += go1 * s_old
            nt += go2 * s_old
        if friction and w != 0.0:
            tf = math.copysign(tc, w)
            ni += gf0 * tf
            nw += gf1 * tf
            nt += gf2 * tf
        if friction and nw * w <= 0.0:
            i, w, th, play = substeps(i, w, th, play, s_old, s_new, frac[p], pr, 0, S, c)
            continue
        i, w, th = ni, nw, nt
        if a > 0.0:
            play = play_operator(play, th / N, a)
    sse[p] = acc


@numba.njit(parallel=True, cache=True, nogil=True)
def each_sampled(ref, m, frac, Ad, g_old, g_new, gf, prm, S, c, pd, out_w, out_th, out_i,
                 out_u, store, wm, iw, tm, it, im, ii, sse, imap):
    """Every candidate through one run of a board's loop (threads across candidates)."""
    for p in numba.prange(prm.shape[0]):
        _sampled_candidate(p, ref, m, frac, Ad, g_old, g_new, gf, prm, S, c, pd, out_w,
                           out_th, out_i, out_u, store, wm, iw, tm, it, im, ii, sse, imap)


def run_sampled(u, pd, m, frac, Ad, g_old, g_new, gf, prm, S, c, imap, weights=None):
    """Every candidate through one run of a board's loop: ``u`` the reference in position
    units, ``pd`` the controller's constants (:data:`D_KP`...), the open loop's
    discretisation and input map per candidate. With ``weights`` (``(w, 1/sigma_w, theta,
    1/sigma_theta, i, 1/sigma_i)``) the weighted sum of squared residuals per candidate;
    else ``{"w", "theta", "i", "drive"}`` (P, n): the trajectories and the controller's
    output in input volts."""
    P, n = prm.shape[0], len(u)
    ref = np.round(np.asarray(u, float) * pd[D_CPU] + pd[D_PZ])   # the board's words
    if weights is not None:   # (as the kernels take them: contiguous, zeros if missing)
        wm, iw, tm, it, im, ii = weights
        out = np.zeros(P)
        dummy = np.empty((1, 1))
        each_sampled(ref, m, frac, Ad, g_old, g_new, gf, prm, S, c, pd, dummy, dummy, dummy,
                     dummy, False, wm, iw, tm, it, im, ii, out, imap)
        return out
    w, th, cur, drive = (np.empty((P, n)) for _ in range(4))
    each_sampled(ref, m, frac, Ad, g_old, g_new, gf, prm, S, c, pd, w, th, cur, drive, True,
                 np.zeros(1), 0.0, np.zeros(1), 0.0, np.zeros(1), 0.0, np.zeros(P), imap)
    return {"w": w, "theta": th, "i": cur, "drive": drive}
