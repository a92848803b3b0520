"""The compiled kernels behind :class:`labrig.model.simulate.Simulator`.

Two ways through a run, with the same arithmetic in the same order (so the results are
bit-for-bit those of either alone):

- the **population kernel** (:func:`_block`) advances a block of candidates one sample at
  a time, the candidates in the inner loop: the exact zero-order-hold update is then the
  same few multiply-adds on contiguous arrays, which the compiler turns into SIMD
  instructions (8 candidates per instruction with AVX-512). Samples where one candidate
  needs more than the exact update (the speed reaches zero or the rotor is stuck under
  friction) are flagged in the vector loop and redone for that candidate alone;
- the **per-candidate kernel** (:func:`_candidate`) takes candidates whose every sample
  is sub-stepped (an input nonlinearity or backlash inside a closed loop).

Inputs are laid out (samples, columns): one column shared by every candidate, or one per
candidate (an input map applied per candidate), so a sample's inputs are contiguous.
"""
from __future__ import annotations

import math

import numba
import numpy as np

# kernel parameter columns (labrig.model.simulate writes them)
C_D, C_U0, C_ASYM, C_VMAX, C_TC, C_TS, C_A, C_TD, C_KE = range(5, 14)
#: the open-loop input map the population kernel applies itself, in this order (every
#: simulator's order): offset, asymmetry, dead zone, asymmetric dead zone, the gain Ka,
#: the armature rail; each as the effect's own formula (labrig.model.effects), so the
#: result is the number numpy gives
MAP_COLUMNS = ("u0_v", "k", "d_v", "dpos_v", "dneg_v", "vmax_v")
M_U0, M_K, M_D, M_DP, M_DN, M_VMAX = range(6)
#: smaller populations go one candidate at a time (:func:`_candidate`): for a few lanes
#: the block's per-sample overhead costs more than the vector loop saves
SMALL = 8
#: candidates per block of the population kernel: a multiple of the SIMD width whose
#: state (a few arrays of BLOCK doubles) stays in the first-level cache
BLOCK = 64


def expm_batch(M):
    """Batched expm; threads only pay off for large populations."""
    return _expm_par(M) if M.shape[0] >= 32 else _expm_ser(M)


@numba.njit(cache=True)
def _expm_one(A0):
    n = A0.shape[0]
    nrm = 0.0
    for r in range(n):
        row = 0.0
        for q in range(n):
            row += abs(A0[r, q])
        nrm = max(nrm, row)
    sq = 0
    while nrm > 0.5:
        nrm *= 0.5
        sq += 1
    A = A0 / (2.0 ** sq)
    E = np.eye(n)
    term = np.eye(n)
    for k in range(1, 19):
        term = term @ A / k
        E = E + term
    for _ in range(sq):
        E = E @ E
    return E


@numba.njit(cache=True)
def _expm_ser(M):
    out = np.empty_like(M)
    for p in range(M.shape[0]):
        out[p] = _expm_one(M[p])
    return out


@numba.njit(parallel=True, cache=True)
def _expm_par(M):
    out = np.empty_like(M)
    for p in numba.prange(M.shape[0]):
        out[p] = _expm_one(M[p])
    return out


@numba.njit(cache=True, inline="always")
def _play(play, x, a):
    """The play operator (backlash of half gap a): the output follows x only at the gap's ends."""
    if play < x - a:
        return x - a
    if play > x + a:
        return x + a
    return play


@numba.njit(cache=True)
def _substeps(i, w, th, play, s_old, s_new, frac, prm, closed, S, c):
    """Semi-implicit sub-steps through one sample, Karnopp friction (as the truth)."""
    dt, Ka, N, Kt, Kpot, kp, kv = c[0], c[1], c[2], c[3], c[4], c[5], c[6]
    R, L, J, B, K, Ke = prm[0], prm[1], prm[2], prm[3], prm[4], prm[13]
    d, u0, ak, vmax, tc, ts, a = prm[5], prm[6], prm[7], prm[8], prm[9], prm[10], prm[11]
    h = dt / S
    quasi = L / R < h / 10.0
    for j in range(S):
        s = s_old if j < frac * S - 1e-9 else s_new
        if closed:
            seen = play if a > 0.0 else th / N
            e = kp * (s - Kpot * seen) - kv * Kt * w
            e = e + u0
            if ak != 0.0:
                e = e * (1.0 + ak) if e >= 0.0 else e * (1.0 - ak)
            if d > 0.0:
                e = math.copysign(max(abs(e) - d, 0.0), e)
            v = Ka * e
            if v > vmax:
                v = vmax
            elif v < -vmax:
                v = -vmax
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
            play = _play(play, th / N, a)
    return i, w, th, play


@numba.njit(cache=True)
def _friction_step(i, w, th, play, s_old, s_new, fr, pr, closed, S, c):
    """One sample of a candidate under friction that the exact update cannot take: a stuck
    rotor (only the current moves, exactly, while friction holds), else sub-steps."""
    N = c[2]
    if w == 0.0:
        R, L, K, ts = pr[0], pr[1], pr[4], pr[C_TS]
        if closed:
            v1 = c[1] * c[5] * (s_old - c[4] * th / N)
            v2 = c[1] * c[5] * (s_new - c[4] * th / N)
        else:
            v1 = s_old
            v2 = s_new
        i1 = v1 / R + (i - v1 / R) * math.exp(-R * fr * c[0] / L)
        i2 = v2 / R + (i1 - v2 / R) * math.exp(-R * (1.0 - fr) * c[0] / L)
        if abs(K * i1) <= ts and abs(K * i2) <= ts:
            return i2, w, th, play
    return _substeps(i, w, th, play, s_old, s_new, fr, pr, closed, S, c)


@numba.njit(cache=True)
def _candidate(p, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w, out_th,
               out_i, store, wm, iw, tm, it, im, ii, sse):
    """Candidate ``p`` through one run, one sample after the other: the reference the
    population kernel reproduces bit for bit, and the kernel of candidates sub-stepped
    throughout (a nonlinear closed loop) and of small populations (a Jacobian's rows),
    for which a block's per-sample overhead would cost more than its lanes save."""
    n = s.shape[0]
    col = 0 if s.shape[1] == 1 else p  # one input column for all, or one per candidate
    N = c[2]
    acc = 0.0
    i = 0.0
    w = 0.0
    th = c[7] * N
    play = c[7]
    pr = prm[p]
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
        s_old = s[ko, col] if ko >= 0 else 0.0
        s_new = s[kn, col] if kn >= 0 else 0.0
        exact = not nonlinear[p] and (w != 0.0 or not friction)
        if not nonlinear[p] and friction and w == 0.0:  # stuck rotor
            i, w, th, play = _friction_step(i, w, th, play, s_old, s_new, frac[p], pr, closed,
                                            S, c)
            continue
        if exact:
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
                i, w, th, play = _substeps(i, w, th, play, s_old, s_new, frac[p], pr, closed, S, c)
                continue
            i, w, th = ni, nw, nt
            if a > 0.0:
                play = _play(play, th / N, a)
        else:
            i, w, th, play = _substeps(i, w, th, play, s_old, s_new, frac[p], pr, closed, S, c)
    sse[p] = acc


# Rows of a block's working array: coefficients, state and flags of each candidate, one
# row of BLOCK lanes each. One array with rows a constant BLOCK apart lets the compiler
# prove that the lanes' loads and stores never overlap, so it vectorises without checks.
(R_A00, R_A01, R_A02, R_A10, R_A11, R_A12, R_A20, R_A21, R_A22M1, R_GN0, R_GN1, R_GN2, R_GO0,
 R_GO1, R_GO2, R_GF0, R_GF1, R_GF2, R_TC, R_GAP, R_FRIC, R_I, R_W, R_TH, R_PL, R_ACC, R_FLAG,
 R_I0, R_W0, R_TH0, R_PL0, R_SNEW, R_SOLD, R_RR, R_KK, R_TS, R_E1, R_E2, R_MAP) = range(39)
N_ROWS = R_MAP + 6  # then the input map's six parameters


@numba.njit(cache=True, error_model="numpy")
def _input_map(v, u0, k, d, dp, dn, Ka, vmax):
    """The built-in input and drive effects of one candidate on one held input (V -> V at
    the armature); an absent effect's parameters (0, or inf for the rail) leave v as is."""
    v = v + u0
    v = v * (1.0 + k) if v >= 0 else v * (1.0 - k)
    sg = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)  # np.sign
    v = sg * max(abs(v) - d, 0.0)
    v = max(v - dp, 0.0) if v >= 0 else min(v + dn, 0.0)
    v = v * Ka
    return min(max(v, -vmax), vmax)  # np.clip


#: the terms a block's update needs (bits of ``_sweep``'s mode; one build per mode used)
FEEDBACK, DELAY, FRICTION, PLAY = 1, 2, 4, 8
#: the modes built: the short update, Coulomb friction alone, a linear closed loop, and
#: every term in open and in closed loop (the feedback bit also says how a stuck rotor's
#: drive is formed: through the loop, or the input itself)
MODES = (0, FRICTION, FEEDBACK, DELAY | FRICTION | PLAY, FEEDBACK | DELAY | FRICTION | PLAY)


@numba.njit(cache=True, error_model="numpy")
def _sweep(X, q, N, iw, it, ii, wmk, tmk, imk, kakp, kpot, mode):
    """The exact update of every lane of a block through one sample; returns 1 if
    friction needs some lane's sample redone (their ``R_FLAG`` is 1).

    Branch-free so that it vectorises: every term is computed for every lane in the order
    of the per-candidate code, and a term that is zero for a lane (no friction in this
    lane) adds an exact 0. ``mode`` (a compile-time constant: one build per mode) says
    which terms any lane of the block needs: feedback, delay, friction, play.
    """
    numba.literally(mode)
    B = BLOCK
    fb = mode & FEEDBACK
    dl = mode & DELAY
    fr = mode & FRICTION
    pa = mode & PLAY
    nflag = 0
    for j in range(q):
        i = X[R_I * B + j]
        w = X[R_W * B + j]
        th = X[R_TH * B + j]
        s_new = X[R_SNEW * B + j]
        if pa:
            pl = X[R_PL * B + j]
            gap = X[R_GAP * B + j]
            yth = pl if gap > 0.0 else th / N
        else:
            yth = th / N
        dw = iw * (wmk - w)  # d * d, not d ** 2: numba's power loop stops vectorising
        dth = it * (tmk - yth)
        r = X[R_ACC * B + j] + (dw * dw + dth * dth)
        if ii != 0.0:
            di = ii * (imk - i)
            r += di * di
        X[R_ACC * B + j] = r
        ni = X[R_A00 * B + j] * i + X[R_A01 * B + j] * w + X[R_GN0 * B + j] * s_new
        nw = X[R_A10 * B + j] * i + X[R_A11 * B + j] * w + X[R_GN1 * B + j] * s_new
        nt = X[R_A20 * B + j] * i + X[R_A21 * B + j] * w + th + X[R_GN2 * B + j] * s_new
        if fb:
            ni += X[R_A02 * B + j] * th
            nw += X[R_A12 * B + j] * th
            nt += X[R_A22M1 * B + j] * th
        if dl:
            s_old = X[R_SOLD * B + j]
            ni += X[R_GO0 * B + j] * s_old
            nw += X[R_GO1 * B + j] * s_old
            nt += X[R_GO2 * B + j] * s_old
        hold = False
        if fr:
            tc = X[R_TC * B + j]  # friction against the motion: copysign(tc, w), w != 0
            tf = tc if w > 0.0 else (-tc if w < 0.0 else 0.0)
            ni += X[R_GF0 * B + j] * tf
            nw += X[R_GF1 * B + j] * tf
            nt += X[R_GF2 * B + j] * tf
            # a stuck rotor that friction still holds: only the current moves, exactly
            # (the first branch of _friction_step, here for every lane at once)
            fric = X[R_FRIC * B + j] != 0.0
            s_prev = X[R_SOLD * B + j]
            if fb:
                v1 = kakp * (s_prev - kpot * th / N)
                v2 = kakp * (s_new - kpot * th / N)
            else:
                v1 = s_prev
                v2 = s_new
            rr = X[R_RR * B + j]
            kk = X[R_KK * B + j]
            ts = X[R_TS * B + j]
            i1 = v1 / rr + (i - v1 / rr) * X[R_E1 * B + j]
            i2 = v2 / rr + (i1 - v2 / rr) * X[R_E2 * B + j]
            hold = fric & (w == 0.0) & (abs(kk * i1) <= ts) & (abs(kk * i2) <= ts)
            # breaking away, or the speed reaches zero inside the sample: redone alone
            f = 1 if fric & (not hold) & ((w == 0.0) | (nw * w <= 0.0)) else 0
            nflag |= f  # an "or" reduction vectorises; a count or a float sum does not
            X[R_FLAG * B + j] = f
            X[R_I0 * B + j] = i
            X[R_W0 * B + j] = w
            X[R_TH0 * B + j] = th
            ni = i2 if hold else ni
            nw = w if hold else nw
            nt = th if hold else nt
        if pa:
            X[R_PL0 * B + j] = pl
            x = nt / N  # the play operator, as _play
            lo = x - gap
            hi = x + gap
            npl = (lo if pl < lo else (hi if pl > hi else pl)) if gap > 0.0 else pl
            X[R_PL * B + j] = pl if hold else npl
        X[R_I * B + j] = ni
        X[R_W * B + j] = nw
        X[R_TH * B + j] = nt
    return nflag


@numba.njit(cache=True, error_model="numpy")
def _block(p0, p1, s, m, frac, Ad, g_old, g_new, gf, prm, skip, closed, S, c, out_w, out_th,
           out_i, store, wm, iw, tm, it, im, ii, sse, imap):
    """Candidates p0..p1-1 (at most BLOCK) through one run, the candidates in the inner
    (SIMD) loop.

    The update is the exact ZOH ``x+ = Ad x + g_new s_new + g_old s_old + gf Tf`` written
    term by term in the order of the per-candidate code; a term that is zero for one
    candidate of the block (no delay, no friction) adds an exact zero. ``skip`` marks the
    candidates another kernel takes (their lanes compute and are discarded).
    """
    n = s.shape[0]
    q = p1 - p0
    B = BLOCK
    shared = s.shape[1] == 1
    N = c[2]
    X = np.zeros(N_ROWS * B)
    mp = np.zeros(B, np.int64)
    delay = False
    mapped = imap.shape[0] > 0
    friction = False
    play = False
    for j in range(q):
        p = p0 + j
        if mapped:
            for r in range(6):
                X[(R_MAP + r) * B + j] = imap[p, r]
        A = Ad[p]
        for r, v in ((R_A00, A[0, 0]), (R_A01, A[0, 1]), (R_A02, A[0, 2]), (R_A10, A[1, 0]),
                     (R_A11, A[1, 1]), (R_A12, A[1, 2]), (R_A20, A[2, 0]), (R_A21, A[2, 1]),
                     (R_A22M1, A[2, 2] - 1.0), (R_GN0, g_new[p, 0]), (R_GN1, g_new[p, 1]),
                     (R_GN2, g_new[p, 2]), (R_GO0, g_old[p, 0]), (R_GO1, g_old[p, 1]),
                     (R_GO2, g_old[p, 2]), (R_GF0, gf[p, 0]), (R_GF1, gf[p, 1]),
                     (R_GF2, gf[p, 2]), (R_TC, prm[p, C_TC]), (R_GAP, prm[p, C_A]),
                     (R_TH, c[7] * N), (R_PL, c[7]), (R_RR, prm[p, 0]), (R_KK, prm[p, 4]),
                     (R_TS, prm[p, C_TS]),
                     # the stuck rotor's exact current decay over the two parts of a
                     # sample, as _friction_step computes them
                     (R_E1, math.exp(-prm[p, 0] * frac[p] * c[0] / prm[p, 1])),
                     (R_E2, math.exp(-prm[p, 0] * (1.0 - frac[p]) * c[0] / prm[p, 1]))):
            X[r * B + j] = v
        f = (prm[p, C_TC] > 0.0 or prm[p, C_TS] > 0.0) and not skip[p]
        X[R_FRIC * B + j] = 1.0 if f else 0.0
        friction |= f
        play |= prm[p, C_A] > 0.0
        mp[j] = m[p]
        delay |= m[p] != 0 or g_old[p, 0] != 0.0 or g_old[p, 1] != 0.0 or g_old[p, 2] != 0.0
    # the terms any lane needs, rounded up to a mode that is built
    mode = (FEEDBACK if closed else 0) | (DELAY if delay else 0) \
        | (FRICTION if friction else 0) | (PLAY if play else 0)
    if mode not in (0, FRICTION, FEEDBACK):  # every term; feedback only in a closed loop
        mode = (FEEDBACK if closed else 0) | DELAY | FRICTION | PLAY
    for k in range(n):
        if store:  # the trajectories (simulate): the state at the start of the sample
            for j in range(q):
                out_w[p0 + j, k] = X[R_W * B + j]
                out_th[p0 + j, k] = X[R_PL * B + j] if X[R_GAP * B + j] > 0.0 \
                    else X[R_TH * B + j] / N
                out_i[p0 + j, k] = X[R_I * B + j]
        wmk = 0.0 if store else wm[k]
        tmk = 0.0 if store else tm[k]
        imk = im[k] if ii != 0.0 else 0.0
        # this sample's inputs per lane (shared, per candidate, or delayed per candidate)
        if delay:
            for j in range(q):
                kn = k - mp[j]
                cj = 0 if shared else p0 + j
                X[R_SNEW * B + j] = s[kn, cj] if kn >= 0 else 0.0
                X[R_SOLD * B + j] = s[kn - 1, cj] if kn >= 1 else 0.0
        else:
            if mode & FRICTION:  # the held input of the sample before: a stuck rotor's s_old
                for j in range(q):
                    X[R_SOLD * B + j] = X[R_SNEW * B + j]
            if shared:
                su = s[k, 0]
                for j in range(q):
                    X[R_SNEW * B + j] = su
            else:
                for j in range(q):
                    X[R_SNEW * B + j] = s[k, p0 + j]
        if mapped:  # the candidates' own input maps, applied here (no (n, P) input array)
            Ka = c[1]
            for j in range(q):  # (without delay, s_old is the sample before: mapped already)
                X[R_SNEW * B + j] = _input_map(
                    X[R_SNEW * B + j], X[(R_MAP + M_U0) * B + j], X[(R_MAP + M_K) * B + j],
                    X[(R_MAP + M_D) * B + j], X[(R_MAP + M_DP) * B + j],
                    X[(R_MAP + M_DN) * B + j], Ka, X[(R_MAP + M_VMAX) * B + j])
            if delay:
                for j in range(q):
                    X[R_SOLD * B + j] = _input_map(
                        X[R_SOLD * B + j], X[(R_MAP + M_U0) * B + j],
                        X[(R_MAP + M_K) * B + j], X[(R_MAP + M_D) * B + j],
                        X[(R_MAP + M_DP) * B + j], X[(R_MAP + M_DN) * B + j], Ka,
                        X[(R_MAP + M_VMAX) * B + j])
        kakp, kpot = c[1] * c[5], c[4]
        if mode == 0:  # each call site a constant mode: its own vectorised build
            nflag = _sweep(X, q, N, iw, it, ii, wmk, tmk, imk, kakp, kpot, 0)
        elif mode == FRICTION:
            nflag = _sweep(X, q, N, iw, it, ii, wmk, tmk, imk, kakp, kpot, 4)
        elif mode == FEEDBACK:
            nflag = _sweep(X, q, N, iw, it, ii, wmk, tmk, imk, kakp, kpot, 1)
        elif mode == DELAY | FRICTION | PLAY:
            nflag = _sweep(X, q, N, iw, it, ii, wmk, tmk, imk, kakp, kpot, 14)
        else:
            nflag = _sweep(X, q, N, iw, it, ii, wmk, tmk, imk, kakp, kpot, 15)
        if nflag > 0:  # the few samples the exact update cannot take, one at a time
            for j in range(q):
                if X[R_FLAG * B + j] != 0.0:
                    ni, nw, nt, npl = _friction_step(
                        X[R_I0 * B + j], X[R_W0 * B + j], X[R_TH0 * B + j], X[R_PL0 * B + j],
                        X[R_SOLD * B + j], X[R_SNEW * B + j], frac[p0 + j], prm[p0 + j],
                        closed, S, c)
                    X[R_I * B + j] = ni
                    X[R_W * B + j] = nw
                    X[R_TH * B + j] = nt
                    X[R_PL * B + j] = npl
    if not store:
        for j in range(q):
            if not skip[p0 + j]:
                sse[p0 + j] = X[R_ACC * B + j]


@numba.njit(parallel=True, cache=True)
def _population_par(threads, s, m, frac, Ad, g_old, g_new, gf, prm, skip, closed, S, c, out_w,
                    out_th, out_i, store, wm, iw, tm, it, im, ii, sse, imap):
    P = prm.shape[0]
    nb = (P + BLOCK - 1) // BLOCK
    # at least as many blocks as threads: a swarm of 50 is two blocks of 25, not 32 + 18
    nb = max(nb, min(threads, (P + 7) // 8))
    size = (P + nb - 1) // nb
    for b in numba.prange(nb):
        p0 = b * size
        p1 = min(P, p0 + size)
        if p0 < p1:
            _block(p0, p1, s, m, frac, Ad, g_old, g_new, gf, prm, skip, closed, S, c, out_w,
                   out_th, out_i, store, wm, iw, tm, it, im, ii, sse, imap)


# Two drivers with distinct code for each kernel (numba's cache would otherwise hand the
# parallel dispatcher the serial build of a shared function). Threads pay off for a
# swarm; for the few rows of a finite-difference Jacobian the wake-up costs more.
@numba.njit(parallel=True, cache=True)
def _each_par(idx, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w,
                    out_th, out_i, store, wm, iw, tm, it, im, ii, sse):
    for j in numba.prange(idx.shape[0]):
        _candidate(idx[j], s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c,
                   out_w, out_th, out_i, store, wm, iw, tm, it, im, ii, sse)


@numba.njit(cache=True)
def _each_ser(idx, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w,
                    out_th, out_i, store, wm, iw, tm, it, im, ii, sse):
    for j in range(idx.shape[0]):
        _candidate(idx[j], s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c,
                   out_w, out_th, out_i, store, wm, iw, tm, it, im, ii, sse)


def run_kernels(s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w, out_th,
                out_i, store, wm, iw, tm, it, im, ii, sse, imap):
    """Every candidate through one run: the population kernel for those the exact update
    serves, the per-candidate kernel for those sub-stepped throughout.

    ``imap`` (P, 6): the open-loop input map per candidate, applied in the kernel to the
    shared input ``s`` (see :data:`MAP_COLUMNS`); an array of 0 rows when ``s`` is the
    armature voltage already (always for trajectories and for fewer than :data:`SMALL`
    candidates: those go one candidate at a time)."""
    P = prm.shape[0]
    if store or P < SMALL:
        # trajectories: each candidate writes its own contiguous rows (the lanes of a block
        # would scatter across them every sample); a Jacobian's few rows: no block
        # overhead. One candidate at a time, threads across candidates.
        (_each_par if P >= 16 else _each_ser)(  # threads wake slower than 16 candidates run
            np.arange(P), s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c,
            out_w, out_th, out_i, store, wm, iw, tm, it, im, ii, sse)
        return
    idx = np.flatnonzero(nonlinear)
    if idx.size < P:
        _population_par(numba.get_num_threads(), s, m, frac, Ad, g_old, g_new, gf, prm,
                        nonlinear, closed, S, c, out_w, out_th, out_i, store, wm, iw, tm, it,
                        im, ii, sse, imap)
    if idx.size:
        (_each_par if idx.size >= 16 else _each_ser)(
            idx, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w, out_th,
            out_i, store, wm, iw, tm, it, im, ii, sse)
