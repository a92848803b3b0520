"""The exact zero-order hold of the servo's three states, batched over candidates.

The hold of ``x' = A x + bs s + bf Tf`` over a time ``t`` is the exponential of the
augmented matrix ``M t``, ``M = [[A, bs, bf], [0, 0, 0]]`` (5 x 5): ``[[Phi, Gamma],
[0, I]]``. :func:`zoh_batch` computes it by scaling and squaring with 18 Taylor terms, in
plain loops over the three rows that are not zero (every product the 5 x 5 algorithm
forms on the last two rows is a multiplication by zero: a Taylor term is 3 x 3 times
3 x 5, a squaring ``Phi Phi`` and ``Phi Gamma + Gamma``), the candidates along the
innermost loop (SIMD lanes), each candidate's sums in the scalar algorithm's order; no
BLAS call, so the coefficients are the same on every machine whatever kernel its BLAS
picks.
"""
from __future__ import annotations

import numba
import numpy as np

from labrig.simulation.layout import T_A, T_GF, T_GN, T_GO

#: Taylor terms after the scaling (the norm at most 0.5: the last term below 1e-21)
TERMS = 18


@numba.njit(cache=True, inline="always")
def _holds(A, bs, bf, t, W, sq):
    """``exp([[A, bs, bf], [0, 0, 0]] t[p])`` of every candidate ``p``, into ``W[2]`` (15, P):
    row ``5 r + q`` holds entry (r, q) of ``[Phi, Gamma]``, candidates along the row, so
    that each step of the algorithm is one loop over the candidates (SIMD lanes); the
    sums in each candidate's lane are the scalar algorithm's, in its order. ``W``
    (4, 15, P) and ``sq`` (P,): scratch."""
    P = t.shape[0]
    tmp, term, E, nxt = W[0], W[1], W[2], W[3]
    # M t, and the norm the scaling needs (the largest row sum; the zero rows are 0)
    for p in range(P):
        for r in range(3):
            for q in range(3):
                tmp[5 * r + q, p] = A[p, r, q] * t[p]
            tmp[5 * r + 3, p] = bs[p, r] * t[p]
            tmp[5 * r + 4, p] = bf[p, r] * t[p]
        nrm = 0.0
        for r in range(3):
            row = 0.0
            for q in range(5):
                row += abs(tmp[5 * r + q, p])
            nrm = max(nrm, row)
        n = 0
        while nrm > 0.5:
            nrm *= 0.5
            n += 1
        sq[p] = n
        scale = 2.0 ** n
        for i in range(15):
            tmp[i, p] = tmp[i, p] / scale  # the scaled matrix's rows
    for r in range(3):
        for q in range(5):
            one = 1.0 if r == q else 0.0
            for p in range(P):
                term[5 * r + q, p] = one   # the identity's
                E[5 * r + q, p] = one      # E = I + the sum of the terms
    for k in range(1, TERMS + 1):
        for r in range(3):
            for q in range(5):
                a, b, c, o = term[5 * r], term[5 * r + 1], term[5 * r + 2], nxt[5 * r + q]
                m0, m1, m2 = tmp[q], tmp[5 + q], tmp[10 + q]
                for p in range(P):
                    o[p] = (((0.0 + a[p] * m0[p]) + b[p] * m1[p]) + c[p] * m2[p]) / k
        for i in range(15):
            ti, ei, ni = term[i], E[i], nxt[i]
            for p in range(P):
                ti[p] = ni[p]
                ei[p] += ni[p]
    most = 0
    for p in range(P):
        most = max(most, sq[p])
    for it in range(most):  # [[Phi, G], [0, I]]^2 = [[Phi Phi, Phi G + G], [0, I]]
        for r in range(3):
            for q in range(5):
                a, b, c, o = E[5 * r], E[5 * r + 1], E[5 * r + 2], nxt[5 * r + q]
                m0, m1, m2, e = E[q], E[5 + q], E[10 + q], E[5 * r + q]
                for p in range(P):
                    acc = ((0.0 + a[p] * m0[p]) + b[p] * m1[p]) + c[p] * m2[p]
                    o[p] = acc + e[p] if q >= 3 else acc
        for i in range(15):  # each candidate squares as often as its own scaling needs
            ei, ni = E[i], nxt[i]
            for p in range(P):
                ei[p] = ni[p] if it < sq[p] else ei[p]


@numba.njit(cache=True, nogil=True)
def zoh_batch(A, bs, bf, frac, h):
    """The exact ZOH of every candidate over one sample of ``h`` seconds whose input
    switches from s_old to s_new at ``frac`` of it (a fractional delay; 0: none).

    Parameters: ``A`` (P, 3, 3), ``bs`` and ``bf`` (P, 3), ``frac`` (P,). Returns ``Ad``
    (P, 3, 3), ``g_old``, ``g_new``, ``gf`` (P, 3): ``x+ = Ad x + g_old s_old + g_new s_new
    + gf Tf``."""
    P = A.shape[0]
    Ad = np.empty((P, 3, 3))
    g_old = np.zeros((P, 3))
    g_new = np.empty((P, 3))
    gf = np.empty((P, 3))
    W = np.empty((4, 15, P))
    sq = np.empty(P, np.int64)
    t = np.empty(P)
    delayed = False
    for p in range(P):
        t[p] = (1.0 - frac[p]) * h
        delayed |= frac[p] > 0.0
    _holds(A, bs, bf, t, W, sq)
    E2 = W[2].copy()  # the part after the switch (all of the sample without a delay)
    for p in range(P):
        for r in range(3):
            for q in range(3):
                Ad[p, r, q] = E2[5 * r + q, p]
            g_new[p, r] = E2[5 * r + 3, p]
            gf[p, r] = E2[5 * r + 4, p]
    if not delayed:
        return Ad, g_old, g_new, gf
    for p in range(P):
        t[p] = frac[p] * h
    _holds(A, bs, bf, t, W, sq)
    E1 = W[2]  # the part before the switch
    for p in range(P):
        if frac[p] > 0.0:
            for r in range(3):
                for q in range(3):
                    acc = 0.0
                    for s in range(3):
                        acc += E2[5 * r + s, p] * E1[5 * s + q, p]
                    Ad[p, r, q] = acc
                go = 0.0
                gt = 0.0
                for s in range(3):
                    go += E2[5 * r + s, p] * E1[5 * s + 3, p]
                    gt += E2[5 * r + s, p] * E1[5 * s + 4, p]
                g_old[p, r] = go
                gf[p, r] = gt + E2[5 * r + 4, p]
    return Ad, g_old, g_new, gf


@numba.njit(cache=True, nogil=True)
def loop_slot_fill(T, slot, A0, bs, bf, frac, h, L, gain, Ka, kv, Kt, kp, Kpot, N, loop, pot,
                   full):
    """One slot of a closed loop's table ``T`` (P, N_SLOTS, SLOT_W), in place: the exact
    ZOH of the plant ``A0`` (P, 3, 3) in one piece of the drive, written as the lanes read
    it (Ad with a22 - 1, then g_old, g_new, g_f) for the candidates in ``full``.
    ``loop``: the loop is closed through the drive's gain ``gain`` (P,) in this piece (the
    speed's feedback, and with ``pot`` the position's); otherwise it is open (the flat
    piece). The feedback terms as numpy forms them, left to right."""
    P = A0.shape[0]
    A = A0.copy()
    if loop:
        for p in range(P):
            A[p, 0, 1] -= Ka * gain[p] * kv * Kt / L[p]
            if pot:
                A[p, 0, 2] -= Ka * gain[p] * kp * Kpot / N / L[p]
    Ad, g_old, g_new, gf = zoh_batch(A, bs, bf, frac, h)
    for p in range(P):
        if full[p]:
            for r in range(3):
                for q in range(3):
                    T[p, slot, T_A + 3 * r + q] = Ad[p, r, q]
                T[p, slot, T_GO + r] = g_old[p, r]
                T[p, slot, T_GN + r] = g_new[p, r]
                T[p, slot, T_GF + r] = gf[p, r]
            T[p, slot, T_A + 8] -= 1.0  # a22 - 1, as the update adds theta itself
