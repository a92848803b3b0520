"""A closed loop with an input nonlinearity or backlash inside, exactly in each affine piece.

The drive of such a loop, ``v = rail(Ka * deadzone(asym(kp (r - Kpot seen) - kv Kt w + u0)))``
with ``seen`` the pot (after any backlash), is affine in the state inside each piece of
the map: the dead zone and the rail (flat: the loop is open), the linear part for a
positive and for a negative error (an asymmetry gives them different gains), with the
pot following the shaft or, inside a backlash gap, standing still. Each piece is a linear
closed (or open) loop with its own exact zero-order hold (a slot of the loop table,
:mod:`labrig.model.simulate` builds it); a sample is taken exactly when the drive stays
in its piece, and sub-stepped (as the truth integrator) where it crosses into another,
a gap opens or closes, or the speed reaches zero under friction.

:func:`loop_step` is one candidate's sample (the per-candidate kernel takes its pieces
one by one); :func:`loop_sample` the same for every lane of a block at once (the
population kernel's), with the same arithmetic in the same order.
"""
from __future__ import annotations

import math

import numba

from labrig.simulation.layout import (BLOCK, C_A, C_ASYM, C_D, C_TC, C_TS, C_U0, C_VMAX, DELAY,
                                 FRICTION, G_DEAD, G_NEG, G_POS, G_RAILN, G_RAILP, M_D, M_K,
                                 M_U0, M_VMAX, NO_KINK, PLAY, R_ACC, R_CN, R_CUR, R_DLY, R_FLAG,
                                 R_FRIC, R_G, R_GAP, R_SIDE, R_I, R_I0, R_MAP, R_PL, R_PL0, R_SLOT,
                                 R_SNEW, R_SOLD, R_TC, R_TH, R_TH0, R_W, R_W0, R_XN, S_FLAT,
                                 STEADY, T_GF, T_GN, T_GO)


@numba.njit(cache=True, inline="always")
def play_operator(play, x, a):
    """The play operator (backlash of half gap a): the output follows x only at the gap's ends."""
    if play < x - a:
        return x - a
    if play > x + a:
        return x + a
    return play


@numba.njit(cache=True, inline="always")
def loop_drive(s, seen, w, prm, c):
    """The armature voltage a closed loop with its input map applies (as the truth)."""
    Ka, Kt, Kpot, kp, kv = c[1], c[3], c[4], c[5], c[6]
    d, u0, ak, vmax = prm[5], prm[6], prm[7], prm[8]
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
    return v


@numba.njit(cache=True, inline="always")
def drive_piece(e, d, ak, Ka, vmax):
    """The piece of the drive map ``_loop_drive`` is in for the error ``e`` (G_*)."""
    pos = e >= 0.0
    eg = e * ((1.0 + ak) if pos else (1.0 - ak))
    dz = max(abs(eg) - d, 0.0)
    rail = Ka * dz > vmax
    # the error's sign is a piece's edge only where the map has a kink or a step there
    # (an asymmetry, a dead zone); a map linear through zero (an offset alone) is one piece
    lin = G_NEG if (not pos) & ((ak != 0.0) | (d > 0.0)) else G_POS
    railed = G_RAILP if pos else G_RAILN
    return G_DEAD if (d > 0.0) & (dz == 0.0) else (railed if rail else lin)


@numba.njit(cache=True, inline="always")
def drive_piece_no_kink(e, Ka, vmax):
    """:func:`drive_piece` of a map without a dead zone or an asymmetry (d = ak = 0): the
    same piece, without the arithmetic that is exact there (e (1 + 0), |e| - 0)."""
    return (G_RAILP if e >= 0.0 else G_RAILN) if Ka * abs(e) > vmax else G_POS


@numba.njit(cache=True, inline="always")
def piece_level(g, s, sc, kp, Kpot, u0, ak, d, Ka, vmax):
    """The constant part of the drive in piece ``g`` (the state's part is in the slot's
    matrix): ``sc`` is the pot's offset from theta/N (-a, +a or 0), or the pot inside a gap."""
    pos = g == G_POS
    lin = Ka * (((1.0 + ak) if pos else (1.0 - ak)) * (kp * (s - Kpot * sc) + u0)
                + (-d if pos else d))
    flat = vmax if g == G_RAILP else (-vmax if g == G_RAILN else 0.0)
    return lin if (g == G_POS) | (g == G_NEG) else flat


@numba.njit(cache=True, inline="always")
def piece_level_no_kink(g, s, sc, kp, Kpot, u0, Ka, vmax):
    """:func:`piece_level` without a dead zone or an asymmetry: (1 + 0) y + (-0) is y."""
    flat = vmax if g == G_RAILP else (-vmax if g == G_RAILN else 0.0)
    return Ka * (kp * (s - Kpot * sc) + u0) if g == G_POS else flat


@numba.njit(cache=True, inline="always")
def gap_side(x, pl, w, a):
    """Where the pot ``pl`` is in a backlash gap of half width ``a`` (``x``: theta / N):
    pressed at the gap's lower end moving up (``ep``), at its upper end moving down
    (``en``), inside it (``gp``), and the pot's offset from x (``sc``: -a, +a, or the
    pot itself inside the gap; 0 without a gap)."""
    ep = (a > 0.0) & (x - a >= pl) & (w >= 0.0)  # pressed against the gap's ends
    en = (a > 0.0) & (x + a <= pl) & (w <= 0.0)
    gp = (a > 0.0) & (not ep) & (not en)
    sc = pl if gp else (-a if ep else (a if en else 0.0))
    return ep, en, gp, sc


@numba.njit(cache=True, inline="always")
def piece_slot(g0, gp):
    """The loop table's slot of the drive's piece ``g0`` (``gp``: the pot inside its gap)."""
    return S_FLAT if (g0 == G_DEAD) | (g0 >= G_RAILP) else (g0 + 2 if gp else g0)


@numba.njit(cache=True, inline="always")
def slot_row(T, p, slot):
    """Candidate ``p``'s coefficients in ``slot`` of the loop table: Ad (a22 - 1), g_old,
    g_new, g_f, as one tuple the update reads (:func:`piece_update`)."""
    return (T[p, slot, 0], T[p, slot, 1], T[p, slot, 2], T[p, slot, 3], T[p, slot, 4],
            T[p, slot, 5], T[p, slot, 6], T[p, slot, 7], T[p, slot, 8],
            T[p, slot, T_GO], T[p, slot, T_GO + 1], T[p, slot, T_GO + 2],
            T[p, slot, T_GN], T[p, slot, T_GN + 1], T[p, slot, T_GN + 2],
            T[p, slot, T_GF], T[p, slot, T_GF + 1], T[p, slot, T_GF + 2])


@numba.njit(cache=True, inline="always")
def piece_update(i, w, th, cn, co, tf, r):
    """One sample of the affine loop of a piece, its coefficients ``r`` (:func:`slot_row`),
    its constant drive before (``co``) and after (``cn``) the input's switch, the friction
    torque ``tf``: the new current, speed and motor angle."""
    ni = r[0] * i + r[1] * w + r[T_GN] * cn
    nw = r[3] * i + r[4] * w + r[T_GN + 1] * cn
    nt = r[6] * i + r[7] * w + th + r[T_GN + 2] * cn
    ni += r[2] * th
    nw += r[5] * th
    nt += r[8] * th
    ni += r[T_GO] * co
    nw += r[T_GO + 1] * co
    nt += r[T_GO + 2] * co
    ni += r[T_GF] * tf
    nw += r[T_GF + 1] * tf
    nt += r[T_GF + 2] * tf
    return ni, nw, nt


@numba.njit(cache=True, inline="always")
def stays(g0, e1, d, ak, Ka, vmax, nw, w, pl, npl, ep, en, gp, friction):
    """Whether a sample computed in piece ``g0`` stayed there: its drive at the end (error
    ``e1``) is in the same piece, no backlash gap opened or closed, and (under
    ``friction``) the speed kept its sign."""
    ok = drive_piece(e1, d, ak, Ka, vmax) == g0
    ok = ok & (not (ep & (nw < 0.0))) & (not (en & (nw > 0.0))) & (not (gp & (npl != pl)))
    if friction:
        ok = ok & (nw * w > 0.0)
    return ok


@numba.njit(cache=True, inline="always")
def loop_step(i, w, th, pl, s_old, s_new, delayed, pr, c, T, p):
    """One sample of candidate ``p`` in a closed loop with its input map, exactly: the piece
    of the map the drive is in at the start is an affine closed (or, flat, open) loop with
    its own exact ZOH (``T[p, slot]``; ``T`` the loop table, (P, N_SLOTS, SLOT_W)).
    Returns the new state and ``ok``: False when the drive leaves the piece, a backlash gap
    opens or closes, or the speed reaches zero under friction within the sample (the
    caller then sub-steps it). The per-candidate kernel takes the same steps, keeping
    what a steady input leaves unchanged from one sample to the next."""
    N, Ka, Kpot, kp = c[2], c[1], c[4], c[5]
    kvkt = c[6] * c[3]
    d, u0, ak, vmax, a, tc = pr[C_D], pr[C_U0], pr[C_ASYM], pr[C_VMAX], pr[C_A], pr[C_TC]
    x = th / N
    seen = pl if a > 0.0 else x
    ep, en, gp, sc = gap_side(x, pl, w, a)
    g0 = drive_piece(kp * (s_new - Kpot * seen) - kvkt * w + u0, d, ak, Ka, vmax)
    ok = True
    if delayed:
        ok = drive_piece(kp * (s_old - Kpot * seen) - kvkt * w + u0, d, ak, Ka, vmax) == g0
    cn = piece_level(g0, s_new, sc, kp, Kpot, u0, ak, d, Ka, vmax)
    co = piece_level(g0, s_old, sc, kp, Kpot, u0, ak, d, Ka, vmax)
    tf = tc if w > 0.0 else (-tc if w < 0.0 else 0.0)
    ni, nw, nt = piece_update(i, w, th, cn, co, tf, slot_row(T, p, piece_slot(g0, gp)))
    xn = nt / N
    npl = play_operator(pl, xn, a) if a > 0.0 else pl
    seen1 = npl if a > 0.0 else xn
    ok = ok & stays(g0, kp * (s_new - Kpot * seen1) - kvkt * nw + u0, d, ak, Ka, vmax, nw, w,
                    pl, npl, ep, en, gp, tc > 0.0 or pr[C_TS] > 0.0)
    return ni, nw, nt, npl, ok


@numba.njit(cache=True, inline="always")
def loop_slot(w, th, pl, s, pr, c):
    """The slot of the loop table a sample starting in this state with input ``s`` takes
    (as :func:`loop_step` finds it): the lanes' guess for their next sample."""
    N, Ka, Kpot, kp = c[2], c[1], c[4], c[5]
    kvkt = c[6] * c[3]
    d, u0, ak, vmax, a = pr[C_D], pr[C_U0], pr[C_ASYM], pr[C_VMAX], pr[C_A]
    x = th / N
    seen = pl if a > 0.0 else x
    gp = gap_side(x, pl, w, a)[2]
    return piece_slot(drive_piece(kp * (s - Kpot * seen) - kvkt * w + u0, d, ak, Ka, vmax), gp)


@numba.njit(cache=True, error_model="numpy")
def _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, mode):
    """Every lane of a block through one sample of a closed loop with its input map inside:
    :func:`loop_step` for all lanes at once, the same arithmetic in the same order, with
    the coefficients of the slot the lane's drive was last in (``R_CUR``). Returns 1 if
    some lane's sample must be redone alone (``R_FLAG``: the drive is in another piece
    than that slot's, left its piece, a gap opened or closed, friction). ``mode``: the
    DELAY, FRICTION and PLAY terms the block needs (one build per mode).

    Loading the slot's row once per piece, not every slot's every sample to pick one, is
    what keeps the lanes short: a drive changes piece in a few samples of a thousand.
    STEADY (the input as in the sample before, and no lane redone there): every drive
    starts where the sample before ended it, in the piece it started in, so the piece,
    its level and the gap's side are read back (``R_G``, ``R_CN``, ``R_SIDE``) instead of
    found; a pot on another side of its gap is redone alone. NO_KINK: the map is the gain
    and the rail, and every lane has a gap."""
    numba.literally(mode)
    B = BLOCK
    dl = mode & DELAY
    fr = mode & FRICTION
    pa = mode & PLAY
    st = mode & STEADY
    nk = mode & NO_KINK
    nflag = False
    for j in range(q):
        i = X[R_I * B + j]
        w = X[R_W * B + j]
        th = X[R_TH * B + j]
        s_new = X[R_SNEW * B + j]
        s_old = X[R_SOLD * B + j]
        x = X[R_XN * B + j]  # th / N, as the sample before left it
        if pa:
            pl = X[R_PL * B + j]
            a = X[R_GAP * B + j]
            gap = True if nk else a > 0.0  # (NO_KINK: every lane has one)
            seen = pl if gap else x
        else:
            pl = 0.0
            a = 0.0
            gap = False
            seen = x
        dw = iw * (wmk - w)
        dth = it * (tmk - seen)
        # (a measured current's residual is added after the lanes, by the caller: a test
        # inside them made the compiler compute it in every build, needed or not)
        X[R_ACC * B + j] = X[R_ACC * B + j] + (dw * dw + dth * dth)
        u0 = X[(R_MAP + M_U0) * B + j]
        vmax = X[(R_MAP + M_VMAX) * B + j]
        if nk:
            ak = 0.0
            d = 0.0
        else:
            ak = X[(R_MAP + M_K) * B + j]
            d = X[(R_MAP + M_D) * B + j]
        if pa and nk:  # (a gap in every lane: pressed at one end, the other, or inside;
            ep = (x - a >= pl) & (w >= 0.0)  # written out, the selects are 3 instructions
            en = (x + a <= pl) & (w <= 0.0)  # shorter than with gap's constant True)
            gp = (not ep) & (not en)
            sc = pl if gp else (-a if ep else a)
            side = 1.0 if ep else (-1.0 if en else 2.0)
        elif pa:
            ep = gap & (x - a >= pl) & (w >= 0.0)  # pressed against the gap's ends
            en = gap & (x + a <= pl) & (w <= 0.0)
            gp = gap & (not ep) & (not en)
            sc = pl if gp else (-a if ep else (a if en else 0.0))
            side = 1.0 if ep else (-1.0 if en else (2.0 if gp else 0.0))
        else:
            ep = False
            en = False
            gp = False
            sc = 0.0
            side = 0.0
        bad = False
        if st:
            # the input as before and no lane redone: the drive starts where the sample
            # before ended it (the same formula with the same numbers), in the piece it
            # started in (or that sample would have been redone); with the pot on the same
            # side of the gap (and, inside it, where it was) the slot and the piece's level
            # are those of the sample before. Another side: redone alone (exactly as here,
            # or sub-stepped where it must be)
            g0 = X[R_G * B + j]
            cn = X[R_CN * B + j]
            if pa:
                bad = bad | (side != X[R_SIDE * B + j])
        else:
            if nk:
                g0 = drive_piece_no_kink(kp * (s_new - Kpot * seen) - kvkt * w + u0, Ka, vmax)
            else:
                g0 = drive_piece(kp * (s_new - Kpot * seen) - kvkt * w + u0, d, ak, Ka, vmax)
            if dl:
                go = drive_piece(kp * (s_old - Kpot * seen) - kvkt * w + u0, d, ak, Ka, vmax)
                bad = bad | ((X[R_DLY * B + j] != 0.0) & (go != g0))
            slot = S_FLAT if (g0 == G_DEAD) | (g0 >= G_RAILP) else (g0 + 2 if gp else g0)
            # another piece (or none: a lane sub-stepped throughout) is redone alone
            bad = bad | (slot != X[R_SLOT * B + j])
            if nk:
                cn = piece_level_no_kink(g0, s_new, sc, kp, Kpot, u0, Ka, vmax)
            else:
                cn = piece_level(g0, s_new, sc, kp, Kpot, u0, ak, d, Ka, vmax)
            X[R_G * B + j] = g0
            X[R_CN * B + j] = cn
            if pa:
                X[R_SIDE * B + j] = side
        ni = X[R_CUR * B + j] * i + X[(R_CUR + 1) * B + j] * w + X[(R_CUR + T_GN) * B + j] * cn
        nw = X[(R_CUR + 3) * B + j] * i + X[(R_CUR + 4) * B + j] * w \
            + X[(R_CUR + T_GN + 1) * B + j] * cn
        nt = X[(R_CUR + 6) * B + j] * i + X[(R_CUR + 7) * B + j] * w + th \
            + X[(R_CUR + T_GN + 2) * B + j] * cn
        ni += X[(R_CUR + 2) * B + j] * th
        nw += X[(R_CUR + 5) * B + j] * th
        nt += X[(R_CUR + 8) * B + j] * th
        if dl:
            # (steady: s_old is s_new, so its level is cn)
            co = cn if st else piece_level(g0, s_old, sc, kp, Kpot, u0, ak, d, Ka, vmax)
            ni += X[(R_CUR + T_GO) * B + j] * co
            nw += X[(R_CUR + T_GO + 1) * B + j] * co
            nt += X[(R_CUR + T_GO + 2) * B + j] * co
        if fr:
            tc = X[R_TC * B + j]
            tf = tc if w > 0.0 else (-tc if w < 0.0 else 0.0)
            ni += X[(R_CUR + T_GF) * B + j] * tf
            nw += X[(R_CUR + T_GF + 1) * B + j] * tf
            nt += X[(R_CUR + T_GF + 2) * B + j] * tf
        xn = nt / N
        if pa:
            lo = xn - a
            hi = xn + a
            npl = lo if pl < lo else (hi if pl > hi else pl)
            if not nk:
                npl = npl if gap else pl
            seen1 = npl if gap else xn
        else:
            npl = pl
            seen1 = xn
        if nk:
            g1 = drive_piece_no_kink(kp * (s_new - Kpot * seen1) - kvkt * nw + u0, Ka, vmax)
        else:
            g1 = drive_piece(kp * (s_new - Kpot * seen1) - kvkt * nw + u0, d, ak, Ka, vmax)
        bad = bad | (g1 != g0)
        if pa:
            bad = bad | (ep & (nw < 0.0)) | (en & (nw > 0.0)) | (gp & (npl != pl))
            X[R_PL0 * B + j] = pl
            X[R_PL * B + j] = npl
        if fr:
            bad = bad | ((X[R_FRIC * B + j] != 0.0) & ((w == 0.0) | (nw * w <= 0.0)))
        nflag = nflag | bad  # (a mask's "or": one instruction per eight lanes)
        X[R_FLAG * B + j] = 1.0 if bad else 0.0
        X[R_I0 * B + j] = i
        X[R_W0 * B + j] = w
        X[R_TH0 * B + j] = th
        X[R_I * B + j] = ni
        X[R_W * B + j] = nw
        X[R_TH * B + j] = nt
        X[R_XN * B + j] = xn
    return 1 if nflag else 0


#: the loop's builds, one call site each (a constant: numba compiles one build per mode);
#: friction runs in the build with the delay's terms (the only one the compiler vectorised)
_GAP_ALL = DELAY | FRICTION | PLAY
_GAP_ST, _GAP_NK, _GAP_NK_ST = PLAY | STEADY, PLAY | NO_KINK, PLAY | NO_KINK | STEADY
_FRICTION, _FRICTION_ST = DELAY | FRICTION, DELAY | FRICTION | STEADY


@numba.njit(cache=True, inline="always")
def loop_sample(X, q, N, iw, it, wmk, tmk, c, delay, friction, play, steady, no_kink):
    """:func:`_sweep_loop` with the build for the terms the block needs. Five builds for the
    terms: the compiler did not vectorise the others (a build with friction but without
    the delay's terms came out scalar, several times slower). An asymmetry needs no build of
    its own (its slot's coefficients are the lane's, as every slot's). ``steady``: the
    input did not change and no lane was redone in the sample before (builds without the
    piece's search, STEADY); ``no_kink``: no lane of the block has a dead zone or an
    asymmetry, and every lane a gap (backlash's builds without those tests, NO_KINK)."""
    Ka, Kpot, kp, kvkt = c[1], c[4], c[5], c[6] * c[3]
    if play:
        if delay or friction:
            return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, _GAP_ALL)
        if no_kink and steady:
            return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, _GAP_NK_ST)
        if no_kink:
            return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, _GAP_NK)
        if steady:
            return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, _GAP_ST)
        return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, PLAY)
    if friction and steady:
        return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, _FRICTION_ST)
    if friction:
        return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, _FRICTION)
    if delay:
        return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, DELAY)
    if steady:
        return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, STEADY)
    return _sweep_loop(X, q, N, iw, it, wmk, tmk, Ka, Kpot, kp, kvkt, 0)
