"""Open-ended effects: a smooth curve where no named mechanism fits.

The catalogue's named effects are one mechanism each (a dead zone, a hard rail). A hobby
shield whose PWM duty is not proportional to the motor's voltage, a bridge that rounds
off softly before its rail, a driver's own nonlinearity: these bend the steady speed
against the command smoothly over the whole range, and no named effect follows them.
:class:`InputCurve` is such a static map, the input nonlinearity of a Hammerstein model,
monotone and smooth, with a few knots. ``diagnose`` offers it only where the steady
curve the data show bends (:meth:`InputCurve.offered`), and a named effect that explains
as well wins on parsimony.
"""
from __future__ import annotations

import numpy as np

from labrig.model.effect_base import InputEffect, Param

#: a steady curve bends when a straight line with a threshold leaves this many noise
#: floors at one of its levels
BEND_FLOORS = 3.0
#: ... at no fewer than this many distinct input levels of one sign
MIN_LEVELS = 4


def _hermite(x, xk, yk):
    """Monotone cubic Hermite interpolation (Fritsch-Carlson slopes) through the four
    knots ``xk``, ``yk`` (lists of arrays that broadcast with ``x``) at ``x >= 0``; beyond
    the last knot a straight line with the curve's end slope."""
    h = [xk[j + 1] - xk[j] for j in range(3)]
    d = [(yk[j + 1] - yk[j]) / h[j] for j in range(3)]       # secants
    m = [d[0]]
    for j in (1, 2):
        hm, hp = 2 * h[j] + h[j - 1], h[j] + 2 * h[j - 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            harm = (hm + hp) / (hm / d[j - 1] + hp / d[j])
        m.append(np.where(d[j - 1] * d[j] > 0, harm, 0.0))
    m.append(d[2])
    out = 0.0
    for j in range(3):   # the three segments
        seg = (x >= xk[j]) & (x < xk[j + 1]) if j < 2 else (x >= xk[j])
        t = np.clip((x - xk[j]) / h[j], 0.0, 1.0)
        h00, h10 = 2 * t ** 3 - 3 * t ** 2 + 1, t ** 3 - 2 * t ** 2 + t
        h01, h11 = -2 * t ** 3 + 3 * t ** 2, t ** 3 - t ** 2
        y = h00 * yk[j] + h10 * h[j] * m[j] + h01 * yk[j + 1] + h11 * h[j] * m[j + 1]
        if j == 2:   # beyond the last knot: straight on
            y = np.where(x > xk[3], yk[3] + (x - xk[3]) * m[3], y)
        out = np.where(seg, y, out)
    return out


class InputCurve(InputEffect):
    """A static curve from the command to the drive: ``v = f(u)``, odd, monotone and
    smooth (a Hammerstein input).

    Physics: a PWM shield whose duty maps to the motor's voltage through the bridge's
    dead time and the motor's inductance, a bridge that saturates softly before its rail,
    a driver's nonlinearity: the steady speed against the command bends over the whole
    range, not at one threshold. The curve passes through 0 and through ``span_v`` (the
    largest input the data reach, where it meets the straight line: the overall gain is
    the plant's), and bends at a third and two thirds of it by ``b1`` and ``b2`` (its
    value there over the straight line's, minus 1: positive bends down towards a soft
    rail, negative up); beyond ``span_v`` it goes on straight with its end slope.
    Monotone cubic interpolation (Fritsch-Carlson) keeps it monotone and smooth.
    """

    name = "input_curve"
    size = "b2"
    open_ended = True
    family = "input curve"
    look_alikes = ("saturation", "deadband")
    params = (Param("span_v", "V", 1e-3, 1e3, "the input where the curve meets the straight "
                    "line again (the data's largest)"),
              Param("b1", "-", -0.9, 1.4, "the curve at a third of span_v over the straight "
                    "line's, minus 1", log=False),
              Param("b2", "-", -0.45, 0.45, "the curve at two thirds of span_v over the "
                    "straight line's, minus 1", log=False))
    summary = "a smooth static curve from the command to the drive (PWM mapping, soft rail)"
    signature = ("the steady speed against the command bends over the whole range, not at "
                 "one threshold: a straight line leaves residuals of one sign in the middle "
                 "and the other at the ends")
    experiment = ("a staircase of many levels over the whole range in one direction: the "
                  "steady speeds trace the curve")

    def apply(self, v, span_v, b1, b2):
        s = np.asarray(span_v, float)
        y2 = np.clip((1 + np.asarray(b2, float)) * 2 * s / 3, 1e-6 * s, s * (1 - 1e-6))
        y1 = np.clip((1 + np.asarray(b1, float)) * s / 3, 1e-6 * s, y2 * (1 - 1e-6))  # monotone
        v = np.asarray(v, float)
        return np.sign(v) * _hermite(np.abs(v), [0 * s, s / 3, 2 * s / 3, s], [0 * s, y1, y2, s])

    def inert(self) -> dict:
        return {"b1": 0.0, "b2": 0.0}

    def data_bounds(self, reach):
        return {"span_v": (0.5 * reach.amax, 1.5 * reach.amax)}

    def scan_grid(self, reach):
        b = np.array([-0.3, -0.1, 0.1, 0.25, 0.4])
        b1, b2 = np.meshgrid(b * 1.5, np.clip(b, -0.4, 0.4))
        n = b1.size
        return {"span_v": np.full(n, reach.amax), "b1": b1.ravel(), "b2": b2.ravel()}

    def initial_guess(self, runs, plant):
        amax = max(float(np.max(np.abs(r.u))) for r in runs)
        return {"span_v": amax, "b1": 0.0, "b2": 0.0}

    def explain_params(self, params, context):
        s, b1, b2 = params["span_v"], params["b1"], params["b2"]
        shape = ("bends down towards a soft rail" if b2 > 0.02 else
                 "bends up (little drive at small commands)" if b2 < -0.02 else
                 "is nearly straight")
        return (f"the drive {shape}: at {s / 3:.3g} V and {2 * s / 3:.3g} V it gets "
                f"{100 * (1 + b1):.0f} % and {100 * (1 + b2):.0f} % of the straight line's "
                f"(through 0 and {s:.3g} V)")

    def offered(self, evaluation, runs) -> bool:
        """Only where the steady curve bends in a way no named effect does: the steady
        speeds of at least :data:`MIN_LEVELS` input levels of one sign leave every
        straight line with a threshold, clipped or not at a rail (a dead zone, friction,
        a rail: the named effects' steady curves), by more than :data:`BEND_FLOORS` noise
        floors."""
        if evaluation is None or "speed" not in evaluation.floors \
                or any(r.loop == "closed" for r in runs):   # (simulated in open loop only)
            return False
        sigma = evaluation.floors["speed"].sigma
        u, w = steady_levels(runs, sigma)
        for sign in (1.0, -1.0):
            keep = np.sign(u) == sign
            if keep.sum() < MIN_LEVELS:
                continue
            x, y = np.abs(u[keep]), np.abs(w[keep])
            if _named_miss(x, y) > BEND_FLOORS * sigma:
                return True
        return False


def _named_miss(x, y) -> float:
    """The largest miss of the best steady curve the named effects draw through the
    points ``(x, y)`` (one sign): a straight line with a threshold, clipped above at a
    rail at any of the levels or not at all."""
    order = np.argsort(x)
    x, y = x[order], y[order]
    best = np.inf
    for j in range(2, len(x) + 1):     # levels j.. are on the rail (their mean)
        A = np.column_stack([x[:j], np.ones(j)])
        coef, *_ = np.linalg.lstsq(A, y[:j], rcond=None)
        miss = np.abs(y[:j] - A @ coef)
        if j < len(x):
            top = y[j:].mean()
            miss = np.concatenate([miss, np.abs(y[j:] - top)])
        best = min(best, float(np.max(miss)))
    return best


def steady_levels(runs, sigma: float, settle: float = 0.6):
    """The steady speed at each constant input of ``runs`` (prepared or not): per stretch
    of one input value lasting at least 0.5 s (and 25 samples), the mean speed over its
    last ``1 - settle``, when that tail is flat (its halves' means within 3 standard
    errors, from the speed's noise floor ``sigma``). Returns input levels and mean speeds
    (arrays)."""
    us, ws = [], []
    for r in runs:   # a Run (its .speed) or a prepared RunData (its .w)
        w = r.w if hasattr(r, "w") else getattr(r, "speed", None)
        if w is None or r.loop != "open":
            continue
        u = np.asarray(r.u, float)
        edges = np.flatnonzero(np.abs(np.diff(u)) > 1e-9) + 1
        bounds = np.concatenate([[0], edges, [len(u)]])
        min_len = max(25, int(0.5 / r.dt))   # a tail of 10 samples at least
        for a, b in zip(bounds[:-1], bounds[1:]):
            if b - a < min_len or u[a] == 0.0:
                continue
            tail = w[a + int(settle * (b - a)):b]
            half = len(tail) // 2
            if abs(tail[:half].mean() - tail[half:].mean()) > 3 * sigma * np.sqrt(2.0 / half):
                continue   # still settling: not a steady level
            us.append(u[a]), ws.append(float(np.mean(tail)))
    return np.array(us), np.array(ws)
