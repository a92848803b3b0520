"""The matrix exponential of the exact zero-order hold, batched over candidates."""
from __future__ import annotations

import numba
import numpy as np


def expm_batch(M):
    """Batched expm; threads only pay off for large populations."""
    return expm_par(M) if M.shape[0] >= 32 else expm_ser(M)


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


@numba.njit(cache=True, nogil=True)
def expm_small(M):
    """Batched expm of small matrices (the loop table's 5 x 5): the algorithm of
    :func:`_expm_one` (scaling, 18 Taylor terms, squaring) in plain loops on scratch
    arrays (a BLAS call and an allocation per 5 x 5 product cost more than the product)."""
    out = np.empty_like(M)
    n = M.shape[1]
    A = np.empty((n, n))
    E = np.empty((n, n))
    term = np.empty((n, n))
    tmp = np.empty((n, n))
    for p in range(M.shape[0]):
        nrm = 0.0
        for r in range(n):
            row = 0.0
            for q in range(n):
                row += abs(M[p, r, q])
            nrm = max(nrm, row)
        sq = 0
        while nrm > 0.5:
            nrm *= 0.5
            sq += 1
        scale = 2.0 ** sq
        for r in range(n):
            for q in range(n):
                A[r, q] = M[p, r, q] / scale
                E[r, q] = 1.0 if r == q else 0.0
                term[r, q] = E[r, q]
        for k in range(1, 19):
            for r in range(n):
                for q in range(n):
                    acc = 0.0
                    for t in range(n):
                        acc += term[r, t] * A[t, q]
                    tmp[r, q] = acc / k
            for r in range(n):
                for q in range(n):
                    term[r, q] = tmp[r, q]
                    E[r, q] += tmp[r, q]
        for _ in range(sq):
            for r in range(n):
                for q in range(n):
                    acc = 0.0
                    for t in range(n):
                        acc += E[r, t] * E[t, q]
                    tmp[r, q] = acc
            for r in range(n):
                for q in range(n):
                    E[r, q] = tmp[r, q]
        for r in range(n):
            for q in range(n):
                out[p, r, q] = E[r, q]
    return out


@numba.njit(cache=True, nogil=True)
def expm_ser(M):
    out = np.empty_like(M)
    for p in range(M.shape[0]):
        out[p] = _expm_one(M[p])
    return out


@numba.njit(parallel=True, cache=True, nogil=True)
def expm_par(M):
    out = np.empty_like(M)
    for p in numba.prange(M.shape[0]):
        out[p] = _expm_one(M[p])
    return out
