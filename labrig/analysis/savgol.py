"""scipy's Savitzky-Golay filter, bit for bit, without importing ``scipy.signal``.

``scipy.signal`` (with ``scipy.ndimage`` and ``scipy.linalg`` under it) costs over half a
second to import in scipy 1.17 (its array-API layer reads every docstring), which every
command measuring a noise floor paid before it could start fitting. The noise floors and
the analyser's edges need one filter from it: :func:`scipy.signal.savgol_filter` in its
``'interp'`` mode. Here is the same algorithm with the same arithmetic in the same order:
LAPACK's ``gelsd`` least squares (the driver ``scipy.linalg.lstsq`` calls) with scipy's
cut-off for the coefficients and the edge fits, and the interior summed as
``scipy.ndimage.convolve1d`` sums it (a symmetric filter's pairs added, then weighted,
outermost first). The result is scipy's to the last bit, which matters: the fits
downstream are sensitive to the last bits of a floor (a closed-form filter, equal to
1e-14, once flipped a proposal). A test holds it equal to ``scipy.signal.savgol_filter``,
``savgol_coeffs`` and ``scipy.ndimage.convolve1d`` with ``==``.
"""
from __future__ import annotations

import math

import numpy as np


def _lstsq(a: np.ndarray, b: np.ndarray, rcond: float) -> np.ndarray:
    # LAPACK's gelsd, the driver scipy.linalg.lstsq calls, with the same relative cut-off
    return np.linalg.lstsq(a, b, rcond=rcond)[0]


def savgol_coeffs(window: int, polyorder: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """``scipy.signal.savgol_coeffs(window, polyorder, deriv, delta)`` (convolution order)."""
    if window % 2 != 1 or not 0 <= polyorder < window:
        raise ValueError("window must be odd and above polyorder")
    if deriv > polyorder:
        return np.zeros(window)
    pos = window // 2
    x = np.flip(np.arange(-pos, window - pos, dtype=np.float64))
    A = x ** np.reshape(np.arange(polyorder + 1, dtype=np.float64), (-1, 1))
    y = np.zeros(polyorder + 1, dtype=np.float64)
    y[deriv] = float(math.factorial(deriv)) / (delta ** deriv)
    # scipy.signal._polyutils._lstsq's default cut-off
    return _lstsq(A, y, np.finfo(A.dtype).eps * max(A.shape))


def _polyfit(x: np.ndarray, y: np.ndarray, deg: int) -> np.ndarray:
    # scipy.signal._polyutils.polyfit: a scaled Vandermonde matrix, least squares
    order = int(deg) + 1
    rcond = x.shape[0] * np.finfo(x.dtype).eps
    powers = np.flip(np.arange(order, dtype=x.dtype))
    lhs = x[:, None] ** powers[None, :]
    scale = np.sqrt(np.sum(lhs * lhs, axis=0))
    lhs /= scale
    c = _lstsq(lhs, y, rcond)
    return (c.T / scale).T


def _fit_edge(x, start, stop, istart, istop, polyorder, deriv, delta, y) -> None:
    edge = np.reshape(x[start:stop], (stop - start, -1))
    p = _polyfit(np.arange(0, stop - start, dtype=x.dtype), edge, polyorder)
    if deriv > 0:  # scipy.signal._savitzky_golay._polyder
        n = p.shape[0]
        if n <= deriv:
            p = np.zeros_like(p[:1, ...])
        else:
            p = np.asarray(p[:-deriv, ...], copy=True)
            for k in range(deriv):
                p *= np.reshape(np.arange(n - k - 1, deriv - k - 1, -1, dtype=p.dtype),
                                (n - deriv, 1))
    i = np.reshape(np.arange(istart - start, istop - start, dtype=p.dtype), (-1, 1))
    v = np.zeros_like(i)
    for j in range(p.shape[0]):  # scipy.signal._polyutils.polyval
        v = v * i + p[j, ...]
    y[istart:istop] = np.reshape(v / (delta ** deriv), (istop - istart,))


def convolve(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.convolve1d(x, w, mode='constant')`` of a 1-D signal, odd ``w``,
    summed as ndimage's ``NI_Correlate1D`` sums: a filter symmetric (or antisymmetric) to
    within one ulp of 1 takes its pairs together, outermost first."""
    f = np.asarray(w, dtype=np.float64)[::-1]
    n, N = f.shape[0], x.shape[0]
    if n % 2 != 1:
        raise ValueError("an odd filter")
    h = n // 2
    eps = np.finfo(np.float64).eps
    pairs = range(1, h + 1)
    sign = (1.0 if all(abs(f[h + i] - f[h - i]) <= eps for i in pairs) else
            -1.0 if all(abs(f[h + i] + f[h - i]) <= eps for i in pairs) else 0.0)
    xp = np.concatenate([np.zeros(h), np.asarray(x, np.float64), np.zeros(h)])

    def at(k):  # the input k samples from each output's centre
        return xp[h + k:h + k + N]

    if sign == 0.0:
        out = at(h) * f[2 * h]
        for k in range(-h, h):
            out += at(k) * f[h + k]
    else:
        out = at(0) * f[h]
        for j in range(h, 0, -1):
            out += ((at(-j) + at(j)) if sign > 0 else (at(-j) - at(j))) * f[h - j]
    return out


def savgol_filter(x, window: int, polyorder: int, deriv: int = 0,
                  delta: float = 1.0) -> np.ndarray:
    """``scipy.signal.savgol_filter(x, window, polyorder, deriv, delta, mode='interp')``
    of a 1-D signal: the local polynomial fit, its ends from one fit over the first and
    the last window."""
    x = np.asarray(x)
    if x.dtype != np.float64:  # (scipy would filter a float32 signal in float32)
        x = x.astype(np.float64)
    if x.ndim != 1 or window > x.shape[0]:
        raise ValueError("a 1-D signal at least a window long")
    coeffs = savgol_coeffs(window, polyorder, deriv, delta)
    y = convolve(x, coeffs)
    half, n = window // 2, x.shape[0]
    _fit_edge(x, 0, window, 0, half, polyorder, deriv, delta, y)
    _fit_edge(x, n - window, n, n - half, n, polyorder, deriv, delta, y)
    return y
