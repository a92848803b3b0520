"""The compiled kernels behind :class:`labrig.model.simulate.Simulator`.

Two ways through a run, with the same arithmetic in the same order (so the results are
bit-for-bit those of either alone):

- the **population kernel** (:func:`_block`) advances a block of candidates one sample at
  a time, the candidates in the inner loop: the exact zero-order-hold update is then the
  same few multiply-adds on contiguous arrays, which the compiler turns into SIMD
  instructions (8 candidates per instruction with AVX-512). Samples where one candidate
  needs more than the exact update (the speed reaches zero or the rotor is stuck under
  friction) are flagged in the vector loop and redone for that candidate alone;
- the **per-candidate kernel** (:mod:`labrig.simulation.candidate_kernel`) takes trajectories
  and a Jacobian's few rows.

A closed loop with an input nonlinearity or backlash inside goes through the same blocks
with its own lane sweep (:mod:`labrig.simulation.loop_kernel`): exact in each affine piece of
its drive, the samples where the drive changes piece redone alone.

Inputs are laid out (samples, columns): one column shared by every candidate, or one per
candidate (an input map applied per candidate), so a sample's inputs are contiguous.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from labrig.simulation.candidate_kernel import (each_par, each_ser, friction_step, input_map,
                                          loop_sample_alone)
from labrig.simulation.layout import (BLOCK, C_A, C_ASYM, C_D, C_GAP0, C_I0, C_TC, C_TH0, C_TS, C_U0,
                                 C_VMAX, C_W0, DELAY,
                                 FEEDBACK, FRICTION, MODES, MOVING, M_D, M_DN, M_DP, M_K, M_U0,
                                 M_VMAX, N_ROWS, N_ROWS_LOOP, PLAY, R_A00, R_A01, R_A02, R_A10,
                                 R_A11, R_A12, R_A20, R_A21, R_A22M1, R_ACC, R_CUR, R_DLY, R_DI,
                                 R_E1, R_E2, R_FLAG, R_FRIC, R_GAP, R_GF0, R_GF1, R_GF2, R_GN0,
                                 R_GN1, R_GN2, R_GO0, R_GO1, R_GO2, R_I, R_I0, R_KK, R_MAP, R_PL,
                                 R_PL0, R_RR, R_SLOT, R_SNEW, R_SOLD, R_TC, R_TH, R_TH0, R_TS, R_W,
                                 R_W0, R_XN, SMALL, S_POS, T_OK)
from labrig.simulation.loop_kernel import loop_sample, loop_slot


@numba.njit(cache=True, error_model="numpy")
def _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, mode):
    """The exact update of every lane of a block through one sample; returns 1 if
    friction needs some lane's sample redone (their ``R_FLAG`` is 1), + 2 if some lane
    with friction ends the sample at rest (the next sample needs the stuck rotor's build).

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
    mv = mode & MOVING
    nflag = False
    nrest = False
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
        # (a measured current's residual: added by the caller, after the lanes)
        X[R_ACC * B + j] = X[R_ACC * B + j] + (dw * dw + dth * dth)
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
            # (the first branch of friction_step, here for every lane at once)
            fric = X[R_FRIC * B + j] != 0.0
            if mv:  # no lane at rest: nothing held (hold needs w == 0)
                i2 = i
            else:
                rr = X[R_RR * B + j]
                kk = X[R_KK * B + j]
                ts = X[R_TS * B + j]
                s_prev = X[R_SOLD * B + j]
                if fb:
                    v1 = kakp * (s_prev - kpot * th / N)
                    v2 = kakp * (s_new - kpot * th / N)
                else:
                    v1 = s_prev
                    v2 = s_new
                i1 = v1 / rr + (i - v1 / rr) * X[R_E1 * B + j]
                i2 = v2 / rr + (i1 - v2 / rr) * X[R_E2 * B + j]
                hold = fric & (w == 0.0) & (abs(kk * i1) <= ts) & (abs(kk * i2) <= ts)
            # breaking away, or the speed reaches zero inside the sample: redone alone
            f = fric & (not hold) & ((w == 0.0) | (nw * w <= 0.0))
            # a mask's "or" vectorises (one instruction per eight lanes); a count or a
            # float sum does not
            nflag = nflag | f
            X[R_FLAG * B + j] = 1.0 if f else 0.0
            X[R_I0 * B + j] = i
            X[R_W0 * B + j] = w
            X[R_TH0 * B + j] = th
            ni = i2 if hold else ni
            nw = w if hold else nw
            nt = th if hold else nt
            nrest = nrest | (fric & (nw == 0.0))
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
    return (1 if nflag else 0) | (2 if nrest else 0)


@numba.njit(cache=True, inline="always")
def _add_current(X, q, ii):
    """A measured current's squared residual (``R_DI``) added to each lane's sum after the
    lanes' own, in the per-candidate code's order of sums (a test for it inside the lanes
    made the compiler form it in every build)."""
    if ii != 0.0:
        for j in range(q):
            X[R_ACC * BLOCK + j] = X[R_ACC * BLOCK + j] + X[R_DI * BLOCK + j]


@numba.njit(cache=True, error_model="numpy")
def _block(p0, p1, s, m, frac, Ad, g_old, g_new, gf, prm, skip, closed, S, c, wm, iw, tm, it,
           im, ii, sse, imap, table):
    """Candidates p0..p1-1 (at most BLOCK) through one run, the candidates in the inner
    (SIMD) loop.

    The update is the exact ZOH ``x+ = Ad x + g_new s_new + g_old s_old + gf Tf`` written
    term by term in the order of the per-candidate code; a term that is zero for one
    candidate of the block (no delay, no friction) adds an exact zero. ``skip`` marks the
    candidates another kernel takes (their lanes compute and are discarded). A closed loop
    with its input map inside (``table``, the loop tables, has rows) goes through
    :func:`_sweep_loop` instead.
    """
    n = s.shape[0]
    q = p1 - p0
    B = BLOCK
    shared = s.shape[1] == 1
    N = c[2]
    loop = closed != 0 and table.shape[0] > 0
    # the loop's lanes rounded up to whole vectors (the spare lanes hold zeros and are
    # never read): a remainder lane would run scalar and cost as much as a vector of eight
    qv = min(B, (q + 7) // 8 * 8)
    # the rows start on a cache line (64 bytes: eight doubles), so a vector of eight lanes
    # is one line, never two (numba's allocator aligns less)
    size = (N_ROWS_LOOP if loop else N_ROWS) * B
    Xr = np.zeros(size + 8)
    off = (-(Xr.ctypes.data // 8)) % 8
    X = Xr[off:off + size]
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
                     (R_TH, (c[7] + prm[p, C_TH0] + prm[p, C_GAP0] * prm[p, C_A]) * N), (R_PL, c[7] + prm[p, C_TH0]),
                     (R_I, prm[p, C_I0]), (R_W, prm[p, C_W0]),
                     (R_RR, prm[p, 0]), (R_KK, prm[p, 4]),
                     (R_TS, prm[p, C_TS]),
                     # the stuck rotor's exact current decay over the two parts of a
                     # sample, as friction_step computes them
                     (R_E1, math.exp(-prm[p, 0] * frac[p] * c[0] / prm[p, 1])),
                     (R_E2, math.exp(-prm[p, 0] * (1.0 - frac[p]) * c[0] / prm[p, 1]))):
            X[r * B + j] = v
        if loop:  # the map's parameters where the open loop keeps its input map's
            X[(R_MAP + M_U0) * B + j] = prm[p, C_U0]
            X[(R_MAP + M_K) * B + j] = prm[p, C_ASYM]
            X[(R_MAP + M_D) * B + j] = prm[p, C_D]
            X[(R_MAP + M_VMAX) * B + j] = prm[p, C_VMAX]
            X[R_DLY * B + j] = 1.0 if frac[p] > 0.0 else 0.0
            # no slot yet: the first sample is taken alone (and every sample of a lane whose
            # pieces are not exact, its slot staying -1)
            X[R_SLOT * B + j] = -1.0
            X[R_XN * B + j] = X[R_TH * B + j] / N
        f = (prm[p, C_TC] > 0.0 or prm[p, C_TS] > 0.0) and not skip[p]
        X[R_FRIC * B + j] = 1.0 if f else 0.0
        friction |= f
        play |= prm[p, C_A] > 0.0
        mp[j] = m[p]
        delay |= m[p] != 0 or g_old[p, 0] != 0.0 or g_old[p, 1] != 0.0 or g_old[p, 2] != 0.0
    # the loop's map without a dead zone or an asymmetry, and a gap, in every lane (the
    # builds of backlash alone, or with an offset or a rail)
    no_kink = True
    for j in range(q):
        no_kink &= prm[p0 + j, C_D] == 0.0 and prm[p0 + j, C_ASYM] == 0.0 \
            and prm[p0 + j, C_A] > 0.0
    # the terms any lane needs, rounded up to a mode that is built
    mode = (FEEDBACK if closed else 0) | (DELAY if delay else 0) \
        | (FRICTION if friction else 0) | (PLAY if play else 0)
    if mode not in MODES:  # every term (feedback only in a closed loop)
        mode = (FEEDBACK if closed else 0) | DELAY | FRICTION | PLAY
    if loop:  # the spare lanes: zeros, in the + slot (never flagged)
        for j in range(q, qv):
            X[R_SLOT * B + j] = S_POS
    # a shared input delayed per lane: read from a copy with zeros in front, so a lane's
    # held inputs are two loads without a test (a delay beyond the run reads zeros only)
    pad = 0
    sp = np.zeros(0)
    if delay and shared:
        for j in range(q):
            mp[j] = min(mp[j], n + 1)
            pad = max(pad, mp[j] + 1)
        sp = np.zeros(n + pad)
        for k in range(n):
            sp[k + pad] = s[k, 0]
    rest = True  # a lane may be at rest (w = 0): the build with the stuck rotor's test
    last = 1  # the loop's lanes redone alone in the sample before (the first: every lane)
    held = False  # s_old's row holds s_new (a shared input steady since the last copy)
    for k in range(n):
        wmk = wm[k]
        tmk = tm[k]
        imk = im[k] if ii != 0.0 else 0.0
        # a shared input that did not change (a square wave's every sample but its edges):
        # the lanes' inputs, mapped or not, are those of the sample before, and the held
        # input before (s_old) is s_new, copied once after each change
        steady = shared and not delay and k > 0 and s[k, 0] == s[k - 1, 0]
        # this sample's inputs per lane (shared, per candidate, or delayed per candidate)
        if steady:
            if (mode & FRICTION or loop) and not held:
                for j in range(q):
                    X[R_SOLD * B + j] = X[R_SNEW * B + j]
                held = True
        elif delay and shared:
            for j in range(q):
                kn = k + pad - mp[j]   # >= 1
                X[R_SNEW * B + j] = sp[kn]
                X[R_SOLD * B + j] = sp[kn - 1]
        elif delay:
            for j in range(q):
                kn = k - mp[j]
                X[R_SNEW * B + j] = s[kn, p0 + j] if kn >= 0 else 0.0
                X[R_SOLD * B + j] = s[kn - 1, p0 + j] if kn >= 1 else 0.0
        else:
            if mode & FRICTION or loop:  # the held input before: a stuck rotor's s_old
                for j in range(q):
                    X[R_SOLD * B + j] = X[R_SNEW * B + j]
            held = False
            if shared:
                su = s[k, 0]
                for j in range(q):
                    X[R_SNEW * B + j] = su
            else:
                for j in range(q):
                    X[R_SNEW * B + j] = s[k, p0 + j]
        if mapped and not steady:  # the candidates' own input maps (no (n, P) input array)
            Ka = c[1]
            for j in range(q):  # (without delay, s_old is the sample before: mapped already)
                X[R_SNEW * B + j] = input_map(
                    X[R_SNEW * B + j], X[(R_MAP + M_U0) * B + j], X[(R_MAP + M_K) * B + j],
                    X[(R_MAP + M_D) * B + j], X[(R_MAP + M_DP) * B + j],
                    X[(R_MAP + M_DN) * B + j], Ka, X[(R_MAP + M_VMAX) * B + j])
            if delay:
                for j in range(q):
                    X[R_SOLD * B + j] = input_map(
                        X[R_SOLD * B + j], X[(R_MAP + M_U0) * B + j],
                        X[(R_MAP + M_K) * B + j], X[(R_MAP + M_D) * B + j],
                        X[(R_MAP + M_DP) * B + j], X[(R_MAP + M_DN) * B + j], Ka,
                        X[(R_MAP + M_VMAX) * B + j])
        kakp, kpot = c[1] * c[5], c[4]
        if ii != 0.0:  # a measured current's residual, from the state the sample starts in,
            for j in range(q):  # added to the sum after the lanes' own (_add_current)
                di = ii * (imk - X[R_I * B + j])
                X[R_DI * B + j] = di * di
        if loop:
            nflag = loop_sample(X, qv, N, iw, it, wmk, tmk, c, delay, friction, play,
                                steady and last == 0, no_kink and play)
            last = nflag
            _add_current(X, q, ii)
            if nflag > 0:  # the samples where the drive is in another piece, one lane at a
                for j in range(q):  # time, as the per-candidate kernel takes them
                    if X[R_FLAG * B + j] != 0.0:
                        p = p0 + j
                        so, sn = X[R_SOLD * B + j], X[R_SNEW * B + j]
                        ni, nw, nt, npl = loop_sample_alone(
                            X[R_I0 * B + j], X[R_W0 * B + j], X[R_TH0 * B + j],
                            X[R_PL0 * B + j], so, sn, frac[p], prm[p], X[R_FRIC * B + j] != 0.0,
                            S, c, table, p)
                        X[R_I * B + j] = ni
                        X[R_W * B + j] = nw
                        X[R_TH * B + j] = nt
                        X[R_XN * B + j] = nt / N
                        X[R_PL * B + j] = npl
                        if table[p, 0, T_OK] != 0.0:  # the next sample's guess: the piece
                            slot = loop_slot(nw, nt, npl, sn, prm[p], c)  # this one ends in
                            X[R_SLOT * B + j] = slot
                            for r in range(T_OK):
                                X[(R_CUR + r) * B + j] = table[p, slot, r]
            continue
        # friction: the build without the stuck rotor when no lane is at rest
        moving = (mode & FRICTION) != 0 and not rest
        if mode == 0:  # each call site a constant mode: its own vectorised build
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 0)
        elif mode == FRICTION and moving:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 20)
        elif mode == FRICTION:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 4)
        elif mode == FEEDBACK:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 1)
        elif mode == DELAY:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 2)
        elif mode == FEEDBACK | DELAY:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 3)
        elif mode == FEEDBACK | FRICTION and moving:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 21)
        elif mode == FEEDBACK | FRICTION:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 5)
        elif mode == DELAY | FRICTION | PLAY and moving:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 30)
        elif mode == DELAY | FRICTION | PLAY:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 14)
        elif moving:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 31)
        else:
            r = _sweep(X, q, N, iw, it, wmk, tmk, kakp, kpot, 15)
        _add_current(X, q, ii)
        nflag = r & 1
        rest = (r & 2) != 0
        if nflag > 0:  # the few samples the exact update cannot take, one at a time
            for j in range(q):
                if X[R_FLAG * B + j] != 0.0:
                    ni, nw, nt, npl = friction_step(
                        X[R_I0 * B + j], X[R_W0 * B + j], X[R_TH0 * B + j], X[R_PL0 * B + j],
                        X[R_SOLD * B + j], X[R_SNEW * B + j], frac[p0 + j], prm[p0 + j],
                        closed, S, c)
                    X[R_I * B + j] = ni
                    X[R_W * B + j] = nw
                    X[R_TH * B + j] = nt
                    X[R_PL * B + j] = npl
                    rest |= (X[R_FRIC * B + j] != 0.0) & (nw == 0.0)
    for j in range(q):
        if not skip[p0 + j]:
            sse[p0 + j] = X[R_ACC * B + j]


@numba.njit(parallel=True, cache=True, nogil=True)
def population_par(threads, s, m, frac, Ad, g_old, g_new, gf, prm, skip, closed, S, c, wm, iw,
                   tm, it, im, ii, sse, imap, table):
    """The fitness (sum of squared residuals) of every candidate the exact update serves,
    blocks of candidates across threads; trajectories go one candidate at a time."""
    P = prm.shape[0]
    nb = (P + BLOCK - 1) // BLOCK
    # at least as many blocks as threads: a swarm of 50 is two blocks of 25, not 32 + 18
    nb = max(nb, min(threads, (P + 7) // 8))
    size = (P + nb - 1) // nb
    for b in numba.prange(nb):
        p0 = b * size
        p1 = min(P, p0 + size)
        if p0 < p1:
            _block(p0, p1, s, m, frac, Ad, g_old, g_new, gf, prm, skip, closed, S, c, wm, iw,
                   tm, it, im, ii, sse, imap, table)


def run_kernels(s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w, out_th,
                out_i, store, wm, iw, tm, it, im, ii, sse, imap, table):
    """Every candidate through one run: the population kernel for those the exact update
    serves, the per-candidate kernel for those sub-stepped throughout.

    ``imap`` (P, 6): the open-loop input map per candidate, applied in either kernel to
    the shared input ``s`` (see :data:`MAP_COLUMNS`); an array of 0 rows when ``s`` is the
    armature voltage already (or a user's input map was applied per candidate: ``s`` is
    then (samples, candidates))."""
    P = prm.shape[0]
    if store or P < SMALL:
        # trajectories: each candidate writes its own contiguous rows (the lanes of a block
        # would scatter across them every sample); a Jacobian's few rows: no block
        # overhead. One candidate at a time, threads across candidates.
        (each_par if P >= 16 else each_ser)(  # threads wake slower than 16 candidates run
            np.arange(P), s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c,
            out_w, out_th, out_i, store, wm, iw, tm, it, im, ii, sse, table, imap)
        return
    # (a closed loop with its input map: every candidate in the loop's lanes, none skipped)
    population_par(numba.get_num_threads(), s, m, frac, Ad, g_old, g_new, gf, prm,
                   np.zeros(P, np.bool_), closed, S, c, wm, iw, tm, it, im, ii, sse, imap,
                   table if nonlinear.any() else table[:0])
