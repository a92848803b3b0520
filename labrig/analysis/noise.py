"""The noise floor of a sensor channel, measured the way the sensor behaves.

A model's error is judged against the error a perfect model would leave: the sensor's
scatter. That scatter is not the same everywhere. An analogue tacho scatters about
equally at rest and while moving; an encoder-derived speed does not scatter at all at
rest (the count stands still) and jumps by a whole count step while moving, so a floor
taken at rest is several times too small. Hence, per channel:

1. every run is cut into blocks (about 64 samples); each block is detrended locally by
   a quadratic Savitzky-Golay fit (smooth motion removed, scatter kept) and its
   variance corrected for what the fit absorbs, which depends on the noise's colour
   (solved from the residual's lag-1 correlation: white, or the negatively correlated
   scatter of a difference of encoder counts);
2. blocks are sorted into *moving* and *at rest* by the speed; within each class the
   blocks holding an edge (a kink the quadratic cannot follow) are dropped as outliers
   against the class median;
3. each class's variance is floored at the channel's quantisation ``q^2/12`` (a quiet
   quantised signal is only known to within a step), and the floor is the
   time-weighted root mean of the two: the rms error of a perfect model over these runs.

:func:`noise_floor` returns a :class:`NoiseFloor` that says how it was measured.
"""
from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field
from typing import Annotated, Optional

import numpy as np
from pydantic import Field, computed_field, model_serializer

from labrig.core.record import Record

from labrig.model.sensors import (count_quantum, found_count,  # noqa: F401 (re-exported)
                                  quantisation_step, still_reads_like_a_count)

from .savgol import savgol_coeffs, savgol_filter

#: samples per block, and of the local quadratic fit
BLOCK = 64
WINDOW = 7
#: a block whose variance exceeds this multiple of its class median holds an edge
OUTLIER = 5.0
#: a block is moving when its median |speed| exceeds this share of the largest speed
MOVING = 0.05


@dataclass(frozen=True)
class Weights(Record):
    """Channel weights of the fit (position p, speed q), each already in noise units.

    ``why`` says, when one channel was weighted down for what it is (a position that
    drifts against the speed), which channel decides (``decides``: "speed" or
    "position") and why; neither is part of the weights' identity."""

    p: Annotated[float, Field(alias="position")] = 1.0
    q: Annotated[float, Field(alias="speed")] = 1.0
    why: str = field(default="", compare=False)
    decides: str = field(default="", compare=False)

    @model_serializer(mode="wrap")
    def _why_when_weighted(self, handler):
        # (equal weights need no reason: the JSON gives the two numbers alone)
        d = handler(self)
        return d if self.why else {k: d[k] for k in ("position", "speed")}


@dataclass(frozen=True)
class NoiseFloor(Record):
    """The noise level of one channel (in the channel's units) and how it was found.

    Attributes
    ----------
    sigma : float
        The floor: rms error a perfect model would leave.
    moving, rest : float or None
        The scatter while moving and at rest (None: no such block).
    share_moving : float
        Share of samples in moving blocks.
    q : float
        Quantisation step (0 if none seen); ``q/sqrt(12)`` is the lowest floor allowed.
        For a count over a window, the speed one count reads.
    counted : bool
        The channel is a count over a window (:func:`count_quantum`): its floor while
        moving is the counting noise ``q/sqrt(6)``, at rest what the still count shows.
    found : bool
        A count found in the readings (:func:`still_reads_like_a_count`), its window not
        declared (the import takes it as the sample before).
    blocks : int
        Blocks used.
    """

    channel: str
    unit: str
    sigma: float
    moving: Optional[float]
    rest: Optional[float]
    share_moving: float
    q: Annotated[float, Field(alias="quantisation_step")]
    blocks: int
    counted: bool = False
    found: bool = False

    @property
    def quantisation(self) -> float:
        return self.q / np.sqrt(12.0)

    def describe(self) -> str:
        parts = []
        if self.moving is not None:
            parts.append(f"moving {self.moving:.3g}")
        if self.rest is not None:
            parts.append(f"at rest {self.rest:.3g}")
        qtxt = (f"; quantisation step {self.q:.3g}, q/sqrt(12) = {self.quantisation:.3g}"
                if self.q > 0 else "")
        if self.counted:
            return (f"{self.channel}: {self.sigma:.3g} {self.unit} rms, a count over a window "
                    f"(one count reads {self.q:.4g} {self.unit}): moving, the counting noise "
                    f"q/sqrt(6) = {self.moving:.3g}; at rest the count stands still (0); "
                    f"{100 * self.share_moving:.0f} % of the readings moving"
                    + ("; found in the readings (whole counts, still at rest), taken as "
                       "counted over the sample before (declare sensors.speed_window_s if "
                       "another)" if self.found else ""))
        return (f"{self.channel}: {self.sigma:.3g} {self.unit} rms ({', '.join(parts)}; "
                f"{100 * self.share_moving:.0f} % of the time moving; {self.blocks} blocks of "
                f"{BLOCK} samples detrended by a {WINDOW}-sample quadratic{qtxt})")

    @computed_field(alias="method")
    @property
    def _method(self) -> str:
        return self.describe()


def _residual_filter(window: int) -> np.ndarray:
    """g = delta - h: what the local quadratic fit leaves of a sample's neighbourhood."""
    g = -savgol_coeffs(window, 2)
    g[window // 2] += 1.0
    return g


def _gamma(g: np.ndarray, m: int) -> float:
    return float(np.dot(g[:len(g) - m], g[m:])) if m < len(g) else 0.0


def _block_variances(y: np.ndarray, speed: np.ndarray, window: int, measured=None):
    """(mean square, lag-1 product mean, moving) per block of one run's detrended signal;
    a block holding a sample the link lost (interpolated, so smoother than noise) is left
    out."""
    if len(y) < max(window + 2, 16):
        return np.empty(0), np.empty(0), np.empty(0, bool)
    # scipy's filter to the last bit (labrig.analysis.savgol): the fits downstream are
    # sensitive to the last bits of the floors
    r = y - savgol_filter(y, window, 2)
    n = len(y) // BLOCK if len(y) >= 2 * BLOCK else 1
    size = len(y) // n
    smax = max(float(np.max(np.abs(speed))), 1e-300)
    rb = r[:n * size].reshape(n, size)
    ms = np.mean(rb ** 2, axis=1)
    lag1 = np.mean(rb[:, 1:] * rb[:, :-1], axis=1)
    moving = np.median(np.abs(speed[:n * size]).reshape(n, size), axis=1) > MOVING * smax
    if measured is not None:
        # the local fit reaches half a window each way: a lost sample that near is in
        # the block's residuals too
        lost = np.convolve(~np.asarray(measured, bool), np.ones(window), "same") > 0
        whole = ~lost[:n * size].reshape(n, size).any(axis=1)
        return ms[whole], lag1[whole], moving[whole]
    return ms, lag1, moving


def _class_variance(ms: np.ndarray, lag1: np.ndarray, window: int,
                    floor: float) -> tuple[float | None, int]:
    """The noise variance of one class of blocks.

    The local fit absorbs part of the noise, how much depends on its colour: white
    noise keeps Gamma(0) = 1 - h0 of its variance, noise whose neighbours are correlated
    by rho keeps Gamma(0) + 2 rho Gamma(1) (an encoder speed, a difference of counts, has
    rho = -0.5). rho is solved from the residual's own lag-1 correlation, between -0.5
    and 0."""
    if len(ms) == 0:
        return None, 0
    g = _residual_filter(window)
    G0, G1, G2 = _gamma(g, 0), _gamma(g, 1), _gamma(g, 2)
    var = ms / G0
    keep = var <= OUTLIER * max(float(np.median(var)), floor, 1e-300)
    m, c = float(np.mean(ms[keep])), float(np.mean(lag1[keep]))
    rho = 0.0
    if m > 0:
        c1 = c / m
        den = 2 * c1 * G1 - G0 - G2
        # a positive correlation is motion the local fit could not follow, not noise
        rho = float(np.clip((G1 - c1 * G0) / den, -0.5, 0.0)) if den else 0.0
    est = ms[keep] / (G0 + 2 * rho * G1)
    return float(np.mean(np.maximum(est, floor))), int(keep.sum())


def noise_floor(signals, speeds, channel: str = "speed", unit: str = "rad/s",
                quantum: float = 0.0, measured=None, counts: bool | None = None,
                found: bool = False) -> NoiseFloor:
    """The noise floor of one channel over several runs.

    Parameters
    ----------
    signals : list of arrays
        The channel in each run.
    speeds : list of arrays
        A speed signal per run (to tell moving from resting stretches).
    quantum : float
        The sensor's quantum when it is known (an encoder's count); the step seen in
        the data is used when larger (an ADC's code on top).
    measured : list of bool arrays or None, optional
        Per run, False where the link lost the sample; blocks holding one are left out.
    counts : bool or None, optional
        True: the channel is declared a count over a window (a speed's
        ``speed_window_s``): where its readings are whole counts (:func:`count_quantum`),
        its floor is the counting noise (:attr:`NoiseFloor.counted`). False: it is not.
        None (default): a speed channel is a count where its readings are whole counts
        and its still stretches read as a count does (:func:`still_reads_like_a_count`).
    found : bool, optional
        The window was found in the readings, not declared (said in the description).
    """
    signals = [np.asarray(y, float) for y in signals]
    measured = measured or [None] * len(signals)
    find = counts is None and channel == "speed"
    if find:
        counted = found_count(signals)
        found = bool(counted)
    else:
        counted = count_quantum(np.concatenate(signals)) if signals and counts else 0.0
    q = counted or max([quantisation_step(y if m is None else y[np.asarray(m, bool)])
                        for y, m in zip(signals, measured)] + [float(quantum)])
    floor = q * q / 12.0
    window = WINDOW
    parts = [_block_variances(y, np.asarray(s, float), window, m)
             for y, s, m in zip(signals, speeds, measured)]
    ms = np.concatenate([p[0] for p in parts]) if parts else np.empty(0)
    l1 = np.concatenate([p[1] for p in parts]) if parts else np.empty(0)
    mov = np.concatenate([p[2] for p in parts]) if parts else np.empty(0, bool)
    vm, km = _class_variance(ms[mov], l1[mov], window, floor)
    vr, kr = _class_variance(ms[~mov], l1[~mov], window, floor)
    if counted:
        # a count over a window, moving: the difference of two truncated counts, each off
        # by a uniform part of a count, scatters by q^2/6 -- what a perfect model leaves
        # (the blocks' own scatter holds steps a slow record cannot resolve); at rest the
        # count stands still, and a reading of zero is exact
        kept = [y if m is None else y[np.asarray(m, bool)] for y, m in zip(signals, measured)]
        share = float(np.mean(np.concatenate(kept) != 0.0))
        return NoiseFloor(channel=channel, unit=unit,
                          sigma=float(max(np.sqrt(share * 2.0 * floor), 1e-12)),
                          moving=float(np.sqrt(2.0 * floor)), rest=0.0, share_moving=share,
                          q=q, blocks=km + kr, counted=True, found=found)
    share = float(mov.mean()) if len(mov) else 0.0
    if vm is None and vr is None:  # too short to block: all of it, detrended once
        y = np.concatenate(signals)
        sd = float(np.std(np.diff(y))) / np.sqrt(2.0) if len(y) > 2 else 0.0
        sigma = max(sd, np.sqrt(floor), 1e-12)
        return NoiseFloor(channel, unit, sigma, None, None, 0.0, q, 0)
    total = share * (vm if vm is not None else vr) + (1 - share) * (vr if vr is not None else vm)
    return NoiseFloor(channel=channel, unit=unit, sigma=float(max(np.sqrt(total), 1e-12)),
                      moving=None if vm is None else float(np.sqrt(vm)),
                      rest=None if vr is None else float(np.sqrt(vr)),
                      share_moving=share, q=q, blocks=km + kr)


def run_speed(rd) -> np.ndarray:
    """The speed that says whether a run is moving: the measured speed (a tacho or an
    imported speed column), else the position's derivative (motor side)."""
    if rd.w is not None:
        return rd.w
    return np.gradient(rd.theta * rd.N, rd.dt)


#: floors already measured, by the content of the runs (the loop builds an objective on
#: the same runs for every candidate and fold: the floors are the data's, not the fit's)
_FLOORS: dict = {}
_FLOORS_LOCK = threading.Lock()   # fits in threads (labrig.core.parallel) share it


def _digest(runs, units) -> bytes:
    h = hashlib.blake2b(repr(units).encode(), digest_size=20)
    for r in runs:
        h.update(repr((r.dt, r.N, getattr(r, "pos_q", 0.0),
                       getattr(r, "speed_window", 0), getattr(r, "window_found", False))).encode())
        for a in (r.w, r.theta, getattr(r, "current", None), getattr(r, "measured", None)):
            h.update(b"-" if a is None else np.ascontiguousarray(a).view(np.uint8).data)
    return h.digest()


def channel_floors(runs, units: tuple = ("rad", "rad/s")) -> dict:
    """``{"speed": NoiseFloor, "position": NoiseFloor, "current": NoiseFloor}`` for the
    channels present in prepared runs (:class:`labrig.model.simulate.RunData`); an
    encoder's known count is the position's quantum."""
    key = _digest(runs, units)
    with _FLOORS_LOCK:
        known = _FLOORS.get(key)
    if known is None:
        known = _channel_floors(runs, units)
        with _FLOORS_LOCK:
            if len(_FLOORS) >= 64:
                _FLOORS.pop(next(iter(_FLOORS)))
            _FLOORS[key] = known
    return dict(known)


def _channel_floors(runs, units) -> dict:
    out = {}
    speeds = [run_speed(r) for r in runs]
    for ch, attr, unit in (("speed", "w", units[1]), ("position", "theta", units[0]),
                           ("current", "current", "A")):
        pairs = [(getattr(r, attr, None), s, getattr(r, "measured", None))
                 for r, s in zip(runs, speeds) if getattr(r, attr, None) is not None]
        if pairs:
            known = max((getattr(r, "pos_q", 0.0) for r in runs), default=0.0) \
                if ch == "position" else 0.0
            counts = ch == "speed" and any(getattr(r, "speed_window", 0) >= 1 for r in runs)
            found = counts and any(getattr(r, "window_found", False) for r in runs)
            out[ch] = noise_floor([p[0] for p in pairs], [p[1] for p in pairs], ch, unit,
                                  quantum=known, measured=[p[2] for p in pairs], counts=counts,
                                  found=found)
    return out
