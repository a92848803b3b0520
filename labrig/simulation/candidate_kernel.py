"""The per-candidate kernels: one candidate through a run, sample after sample.

The reference the population kernel (:mod:`labrig.simulation.kernels`) reproduces bit for bit,
and the kernel of the cases it leaves: trajectories (each candidate writes its own
contiguous rows) and a Jacobian's few rows. A closed loop with an input nonlinearity or
backlash inside is exact in each affine piece of its drive (:func:`loop_step`, taken by
:func:`_loop_candidate` keeping what a steady input leaves unchanged); only the samples
where the drive crosses a threshold, a gap opens or closes, or the speed reaches zero under
friction are sub-stepped (semi-implicit, Karnopp friction, as the truth integrator).
"""
from __future__ import annotations

import math

import numba

from labrig.simulation.layout import (C_A, C_ASYM, C_D, C_GAP0, C_I0, C_TC, C_TH0, C_TS, C_U0, C_VMAX,
                                      C_W0, M_D, M_DN, M_DP, M_K, M_U0, M_VMAX, T_OK)
from labrig.simulation.loop_kernel import (drive_piece, gap_side, loop_drive, loop_step,
                                           piece_level, piece_slot, piece_update, play_operator,
                                           slot_row, stays)


@numba.njit(cache=True, error_model="numpy")
def input_map(v, u0, k, d, dp, dn, Ka, vmax):
    """The built-in input and drive effects of one candidate on one held input (V -> V at
    the armature); an absent effect's parameters (0, or inf for the rail) leave v as is."""
    v = v + u0
    v = v * (1.0 + k) if v >= 0 else v * (1.0 - k)
    sg = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)  # np.sign
    v = sg * max(abs(v) - d, 0.0)
    v = max(v - dp, 0.0) if v >= 0 else min(v + dn, 0.0)
    v = v * Ka
    return min(max(v, -vmax), vmax)  # np.clip


@numba.njit(cache=True)
def substeps(i, w, th, play, s_old, s_new, frac, prm, closed, S, c):
    """Semi-implicit sub-steps through one sample, Karnopp friction (as the truth)."""
    dt, N = c[0], c[2]
    R, L, J, B, K, Ke = prm[0], prm[1], prm[2], prm[3], prm[4], prm[13]
    tc, ts, a = prm[9], prm[10], prm[11]
    h = dt / S
    quasi = L / R < h / 10.0
    for j in range(S):
        s = s_old if j < frac * S - 1e-9 else s_new
        if closed:
            v = loop_drive(s, play if a > 0.0 else th / N, w, prm, c)
        else:
            v = s
        if quasi:
            i = (v - Ke * w) / R
        else:
            i = (i + h / L * (v - Ke * w)) / (1.0 + h * R / L)
        tnf = K * i - B * w
        if tc > 0.0 or ts > 0.0:
            if w == 0.0:
                if abs(tnf) <= ts:
                    w = 0.0
                else:
                    w = h / J * (tnf - math.copysign(ts, tnf))
            else:
                wn = w + h / J * (tnf - math.copysign(tc, w))
                if wn * w <= 0.0 and abs(tnf) <= ts:
                    wn = 0.0
                w = wn
        else:
            w = w + h / J * tnf
        th = th + h * w
        if a > 0.0:
            play = play_operator(play, th / N, a)
    return i, w, th, play


@numba.njit(cache=True)
def friction_step(i, w, th, play, s_old, s_new, fr, pr, closed, S, c):
    """One sample of a candidate under friction that the exact update cannot take: a stuck
    rotor (only the current moves, exactly, while friction holds), else sub-steps.
    ``closed``: 0 open loop, 1 a linear closed loop, 2 one with its input map."""
    N = c[2]
    if w == 0.0:
        R, L, K, ts = pr[0], pr[1], pr[4], pr[C_TS]
        if closed == 2:
            seen = play if pr[C_A] > 0.0 else th / N
            v1 = loop_drive(s_old, seen, 0.0, pr, c)
            v2 = loop_drive(s_new, seen, 0.0, pr, c)
        elif closed:
            v1 = c[1] * c[5] * (s_old - c[4] * th / N)
            v2 = c[1] * c[5] * (s_new - c[4] * th / N)
        else:
            v1 = s_old
            v2 = s_new
        i1 = v1 / R + (i - v1 / R) * math.exp(-R * fr * c[0] / L)
        i2 = v2 / R + (i1 - v2 / R) * math.exp(-R * (1.0 - fr) * c[0] / L)
        if abs(K * i1) <= ts and abs(K * i2) <= ts:
            return i2, w, th, play
    return substeps(i, w, th, play, s_old, s_new, fr, pr, closed, S, c)


@numba.njit(cache=True, inline="always")
def loop_sample_alone(i, w, th, play, s_old, s_new, fr, pr, friction, S, c, T, p):
    """One sample of candidate ``p`` in a closed loop with its input map (loop table ``T``):
    exact in its piece (:func:`loop_step`), sub-stepped where the drive crosses a
    threshold inside it, a stuck rotor as :func:`friction_step` takes it, every sample
    sub-stepped for a quasi-static armature. The population kernel's lanes redo their
    flagged samples with it."""
    if T[p, 0, T_OK] == 0.0:  # (a quasi-static armature: sub-steps throughout)
        return substeps(i, w, th, play, s_old, s_new, fr, pr, 2, S, c)
    if friction and w == 0.0:
        return friction_step(i, w, th, play, s_old, s_new, fr, pr, 2, S, c)
    ni, nw, nt, npl, ok = loop_step(i, w, th, play, s_old, s_new, fr > 0.0, pr, c, T, p)
    if ok:
        return ni, nw, nt, npl
    # the drive crosses a threshold inside the sample: sub-steps
    return substeps(i, w, th, play, s_old, s_new, fr, pr, 2, S, c)


@numba.njit(cache=True)
def _candidate(p, s, m, frac, Ad, g_old, g_new, gf, prm, closed, S, c, out_w, out_th, out_i,
               store, wm, iw, tm, it, im, ii, sse, imap):
    """Candidate ``p`` through one run, one sample after the other: the reference the
    population kernel reproduces bit for bit, and the kernel of trajectories and of small
    populations (a Jacobian's rows), for which a block's per-sample overhead would cost
    more than its lanes save. ``imap`` (rows: candidates): the open-loop input map applied
    here to the shared input, as the lanes apply it (0 rows: ``s`` is the drive already).
    A closed loop with its input map inside is :func:`_loop_candidate`'s."""
    n = s.shape[0]
    col = 0 if s.shape[1] == 1 else p  # one input column for all, or one per candidate
    mapped = imap.shape[0] > 0
    if mapped:
        u0, mk, md, mdp, mdn, mvmax = (imap[p, M_U0], imap[p, M_K], imap[p, M_D],
                                       imap[p, M_DP], imap[p, M_DN], imap[p, M_VMAX])
    else:
        u0 = mk = md = mdp = mdn = mvmax = 0.0
    Ka = c[1]
    mapped_new = 0.0  # the mapped input of the sample before (its s_new is this one's s_old)
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
    a00, a01, a02, a10, a11, a12 = A[0, 0], A[0, 1], A[0, 2], A[1, 0], A[1, 1], A[1, 2]
    a20, a21, a22 = A[2, 0], A[2, 1], A[2, 2]
    gn0, gn1, gn2 = g_new[p, 0], g_new[p, 1], g_new[p, 2]
    go0, go1, go2 = g_old[p, 0], g_old[p, 1], g_old[p, 2]
    gf0, gf1, gf2 = gf[p, 0], gf[p, 1], gf[p, 2]
    delayed = go0 != 0.0 or go1 != 0.0 or go2 != 0.0
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
        ko = k - mp - 1
        kn = k - mp
        if mapped:  # each input mapped once: this sample's s_old is the last one's s_new
            s_old = mapped_new
            s_new = input_map(s[kn, 0], u0, mk, md, mdp, mdn, Ka, mvmax) if kn >= 0 else 0.0
            mapped_new = s_new
        else:
            s_old = s[ko, col] if ko >= 0 else 0.0
            s_new = s[kn, col] if kn >= 0 else 0.0
        if friction and w == 0.0:  # stuck rotor
            i, w, th, play = friction_step(i, w, th, play, s_old, s_new, frac[p], pr, closed,
                                           S, c)
            continue
        # the generic update, with the terms that are zero for this candidate skipped
        # (the hot path of every identifier: no friction, no delay, open loop)
        ni = a00 * i + a01 * w + gn0 * s_new
        nw = a10 * i + a11 * w + gn1 * s_new
        nt = a20 * i + a21 * w + th + gn2 * s_new
        if closed:
            ni += a02 * th
            nw += a12 * th
            nt += (a22 - 1.0) * th
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
            # the speed reaches zero inside this sample: resolve it finely
            i, w, th, play = substeps(i, w, th, play, s_old, s_new, frac[p], pr, closed, S, c)
            continue
        i, w, th = ni, nw, nt
        if a > 0.0:
            play = play_operator(play, th / N, a)
    sse[p] = acc


@numba.njit(cache=True, error_model="numpy")
def _loop_candidate(p, s, m, frac, prm, S, c, out_w, out_th, out_i, store, wm, iw, tm, it, im,
                    ii, sse, T):
    """Candidate ``p`` through one run in a closed loop with its input map inside (the loop
    table ``T``; the input ``s`` is the reference): :func:`loop_step`'s arithmetic sample
    after sample, bit for bit, keeping what stays the same from one sample to the next
    instead of finding it again. The slot's coefficients are loaded when the
    drive changes piece; a sample that starts where an exact one ended, with the same
    input and no backlash gap, is in that one's piece with its levels (its drive at the
    start is the last one's at the end: the same arithmetic on the same numbers); theta / N
    is divided once a sample. A sample that leaves its piece is sub-stepped; a stuck rotor
    and a quasi-static armature are :func:`loop_sample_alone`'s."""
    n = s.shape[0]
    col = 0 if s.shape[1] == 1 else p
    N, Ka, Kpot, kp = c[2], c[1], c[4], c[5]
    kvkt = c[6] * c[3]
    pr = prm[p]
    d, u0, ak, vmax, a, tc = pr[C_D], pr[C_U0], pr[C_ASYM], pr[C_VMAX], pr[C_A], pr[C_TC]
    friction = tc > 0.0 or pr[C_TS] > 0.0
    gap = a > 0.0
    exact = T[p, 0, T_OK] != 0.0
    fr = frac[p]
    delayed = fr > 0.0
    mp = m[p]
    acc = 0.0
    i = pr[C_I0]
    w = pr[C_W0]
    th = (c[7] + pr[C_TH0] + pr[C_GAP0] * pr[C_A]) * N
    play = c[7] + pr[C_TH0]
    x = th / N
    cur = -1  # the slot whose coefficients ``row`` holds
    row = slot_row(T, p, 0)
    steady = False  # the sample before was exact (in piece g0, levels cn and co)
    g0 = 0
    cn = co = ps_new = ps_old = 0.0
    for k in range(n):
        yth = play if gap else x
        # (as _candidate writes it: the same lines as one inline function made this kernel
        # several times slower)
        if store:
            out_w[p, k] = w
            out_th[p, k] = yth
            out_i[p, k] = i
        else:
            acc += (iw * (wm[k] - w)) ** 2 + (it * (tm[k] - yth)) ** 2
            if ii != 0.0:
                acc += (ii * (im[k] - i)) ** 2
        ko = k - mp - 1
        kn = k - mp
        s_old = s[ko, col] if ko >= 0 else 0.0
        s_new = s[kn, col] if kn >= 0 else 0.0
        if (not exact) or (friction and w == 0.0):
            i, w, th, play = loop_sample_alone(i, w, th, play, s_old, s_new, fr, pr, friction,
                                               S, c, T, p)
            x = th / N
            steady = False
            continue
        pl = play
        seen = pl if gap else x
        ep, en, gp, sc = gap_side(x, pl, w, a)
        again = steady & (s_new == ps_new) & (s_old == ps_old) & (not gap)
        if not again:
            g0 = drive_piece(kp * (s_new - Kpot * seen) - kvkt * w + u0, d, ak, Ka, vmax)
        ok = True
        if delayed:
            ok = drive_piece(kp * (s_old - Kpot * seen) - kvkt * w + u0, d, ak, Ka, vmax) == g0
        slot = piece_slot(g0, gp)
        if slot != cur:
            cur = slot
            row = slot_row(T, p, slot)
        if not again:
            cn = piece_level(g0, s_new, sc, kp, Kpot, u0, ak, d, Ka, vmax)
            co = piece_level(g0, s_old, sc, kp, Kpot, u0, ak, d, Ka, vmax)
        tf = tc if w > 0.0 else (-tc if w < 0.0 else 0.0)
        ni, nw, nt = piece_update(i, w, th, cn, co, tf, row)
        xn = nt / N
        npl = play_operator(pl, xn, a) if gap else pl
        seen1 = npl if gap else xn
        ok = ok & stays(g0, kp * (s_new - Kpot * seen1) - kvkt * nw + u0, d, ak, Ka, vmax, nw, w,
                        pl, npl, ep, en, gp, friction)
        if ok:
            i, w, th, play = ni, nw, nt, npl
            x = xn
        else:  # the drive crosses a threshold inside the sample: sub-steps
            i, w, th, play = substeps(i, w, th, play, s_old, s_new, fr, pr, 2, S, c)
            x = th / N
        steady = ok
        ps_new = s_new
        ps_old = s_old
    sse[p] = acc


@numba.njit(cache=True, inline="always")
def _one(p, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w, out_th,
         out_i, store, wm, iw, tm, it, im, ii, sse, T, imap):
    """Candidate ``p`` through one run, by the kernel its loop takes."""
    if nonlinear[p]:  # a closed loop with its input map: exact in each affine piece
        _loop_candidate(p, s, m, frac, prm, S, c, out_w, out_th, out_i, store, wm, iw, tm, it,
                        im, ii, sse, T)
    else:
        _candidate(p, s, m, frac, Ad, g_old, g_new, gf, prm, closed, S, c, out_w, out_th,
                   out_i, store, wm, iw, tm, it, im, ii, sse, imap)


# Two drivers with distinct code (numba's cache would otherwise hand the parallel
# dispatcher the serial build of a shared function). Threads pay off from about 16
# candidates; for the few rows of a finite-difference Jacobian the wake-up costs more.
@numba.njit(parallel=True, cache=True, nogil=True)
def each_par(idx, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w,
                    out_th, out_i, store, wm, iw, tm, it, im, ii, sse, T, imap):
    for j in numba.prange(idx.shape[0]):
        _one(idx[j], s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w,
             out_th, out_i, store, wm, iw, tm, it, im, ii, sse, T, imap)


@numba.njit(cache=True, nogil=True)
def each_ser(idx, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w,
                    out_th, out_i, store, wm, iw, tm, it, im, ii, sse, T, imap):
    for j in range(idx.shape[0]):
        _one(idx[j], s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w,
             out_th, out_i, store, wm, iw, tm, it, im, ii, sse, T, imap)
