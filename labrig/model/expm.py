"""The exact zero-order hold of the servo's three states, batched over candidates.

The hold of ``x' = A x + bs s + bf Tf`` over a time ``t`` is the exponential of the
augmented matrix ``M t``, ``M = [[A, bs, bf], [0, 0, 0]]`` (5 x 5): ``[[Phi, Gamma],
[0, I]]``. :func:`zoh_batch` computes it by scaling and squaring with 18 Taylor terms, in
plain loops over the three rows that are not zero: every product the 5 x 5 algorithm
forms on the last two rows is a multiplication by zero, so they are left out (a Taylor
term is 3 x 3 times 3 x 5, a squaring ``Phi Phi`` and ``Phi Gamma + Gamma``), with the
same sums in the same order; no BLAS call, so the coefficients are the same on every
machine whatever kernel its BLAS picks.
"""
from __future__ import annotations

import numba
import numpy as np

from labrig.model.layout import T_A, T_GF, T_GN, T_GO

#: Taylor terms after the scaling (the norm at most 0.5: the last term below 1e-21)
TERMS = 18


@numba.njit(cache=True, inline="always")
def _hold(A, bs, bf, p, t, Phi, G, term, tmp, E, nxt):
    """``exp([[A, bs, bf], [0, 0, 0]] t)`` of candidate ``p``: Phi (3 x 3) and Gamma
    (3 x 2, the columns of s and Tf), in place (``term``, ``tmp``, ``E``, ``nxt``: 3 x 5
    scratch)."""
    # M t, and the norm the scaling needs (the largest row sum; the zero rows are 0)
    for r in range(3):
        for q in range(3):
            tmp[r, q] = A[p, r, q] * t
        tmp[r, 3] = bs[p, r] * t
        tmp[r, 4] = bf[p, r] * t
    nrm = 0.0
    for r in range(3):
        row = 0.0
        for q in range(5):
            row += abs(tmp[r, q])
        nrm = max(nrm, row)
    sq = 0
    while nrm > 0.5:
        nrm *= 0.5
        sq += 1
    scale = 2.0 ** sq
    for r in range(3):
        for q in range(5):
            tmp[r, q] = tmp[r, q] / scale          # the scaled matrix's rows
            term[r, q] = 1.0 if r == q else 0.0    # the identity's
            E[r, q] = term[r, q]                   # E = I + the sum of the terms
    for k in range(1, TERMS + 1):
        for r in range(3):
            for q in range(5):
                acc = 0.0
                for s in range(3):
                    acc += term[r, s] * tmp[s, q]
                nxt[r, q] = acc / k
        for r in range(3):
            for q in range(5):
                term[r, q] = nxt[r, q]
                E[r, q] += nxt[r, q]
    for _ in range(sq):  # [[Phi, G], [0, I]]^2 = [[Phi Phi, Phi G + G], [0, I]]
        for r in range(3):
            for q in range(5):
                acc = 0.0
                for s in range(3):
                    acc += E[r, s] * E[s, q]
                nxt[r, q] = acc + E[r, q] if q >= 3 else acc
        for r in range(3):
            for q in range(5):
                E[r, q] = nxt[r, q]
    for r in range(3):
        for q in range(3):
            Phi[r, q] = E[r, q]
        G[r, 0] = E[r, 3]
        G[r, 1] = E[r, 4]


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
    Phi1 = np.empty((3, 3))
    G1 = np.empty((3, 2))
    Phi2 = np.empty((3, 3))
    G2 = np.empty((3, 2))
    term = np.empty((3, 5))
    tmp = np.empty((3, 5))
    E = np.empty((3, 5))
    nxt = np.empty((3, 5))
    for p in range(P):
        _hold(A, bs, bf, p, (1.0 - frac[p]) * h, Phi2, G2, term, tmp, E, nxt)
        if frac[p] > 0.0:  # the part before the switch, then the part after
            _hold(A, bs, bf, p, frac[p] * h, Phi1, G1, term, tmp, E, nxt)
            for r in range(3):
                for q in range(3):
                    acc = 0.0
                    for s in range(3):
                        acc += Phi2[r, s] * Phi1[s, q]
                    Ad[p, r, q] = acc
                go = 0.0
                gt = 0.0
                for s in range(3):
                    go += Phi2[r, s] * G1[s, 0]
                    gt += Phi2[r, s] * G1[s, 1]
                g_old[p, r] = go
                g_new[p, r] = G2[r, 0]
                gf[p, r] = gt + G2[r, 1]
        else:  # no delay: the first part is empty, its hold the identity
            for r in range(3):
                for q in range(3):
                    Ad[p, r, q] = Phi2[r, q]
                g_new[p, r] = G2[r, 0]
                gf[p, r] = G2[r, 1]
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
