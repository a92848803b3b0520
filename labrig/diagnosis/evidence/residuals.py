"""Where a model fails: residuals by regime, the noise band, whiteness (docs/physics.md,
'Diagnosis').

Every sample of a run gets a regime label from the measured input and speed:

``start``     start from rest: the rotor was (nearly) still when the input stepped
``reversal``  the input reversed while the rotor was turning: from the edge until the
              speed has crossed zero and come off it
``accel``     the rest of a transient towards a new speed
``steady``    the speed has settled on a non-zero input
``coast``     the input went to zero and the rotor runs down
``rest``      zero input, rotor still (lead-in)

Computation only; the figures live in ``labrig.diagnosis.results.plots``.
"""
from __future__ import annotations

import hashlib
import threading

import numpy as np

from labrig.identification.objective import fit_percent

REGIMES = ("start", "reversal", "accel", "steady", "coast", "rest")
REGIME_TEXT = {"start": "start from rest", "reversal": "reversal through zero speed",
               "accel": "acceleration", "steady": "steady state", "coast": "coast-down",
               "rest": "at rest"}
Z99 = 2.58


def input_edges(u: np.ndarray) -> np.ndarray:
    """Sample indices where the held input changes (beyond DAC-step noise)."""
    du = np.abs(np.diff(u))
    scale = max(np.ptp(u), 1e-9)
    return np.flatnonzero(du > 0.02 * scale) + 1


#: regime labels of the runs seen lately, by the digest of their input and speed: a run's
#: regimes are its data's, not a model's, and a search evaluates the same runs dozens of
#: times (a long record of many holds: a tenth of a second each)
_LABELS: dict = {}
_LABELS_KEPT = 64
_LABELS_LOCK = threading.Lock()   # (a search's fits evaluate on threads)


def regimes_of(u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """:func:`label_regimes` of ``u`` and ``w``, computed once for the same data (the
    array returned is read-only: it is shared)."""
    u, w = np.ascontiguousarray(u, dtype=float), np.ascontiguousarray(w, dtype=float)
    key = (len(u), hashlib.blake2b(u.tobytes(), digest_size=16).digest(),
           hashlib.blake2b(w.tobytes(), digest_size=16).digest())
    hit = _LABELS.get(key)
    if hit is None:
        hit = label_regimes(u, w)
        hit.flags.writeable = False
        with _LABELS_LOCK:
            while len(_LABELS) >= _LABELS_KEPT:
                _LABELS.pop(next(iter(_LABELS)))
            _LABELS[key] = hit
    return hit


def label_regimes(u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """One regime label per sample (array of str), from the input and a speed signal."""
    n = len(u)
    lab = np.empty(n, dtype=object)
    wmax = max(np.max(np.abs(w)), 1e-9)
    still = 0.05 * wmax
    bounds = np.r_[0, input_edges(u), n]
    for k0, k1 in zip(bounds[:-1], bounds[1:]):
        if k1 <= k0:
            continue
        seg_u = float(np.median(u[k0:k1]))
        tail = w[k0 + int(0.8 * (k1 - k0)):k1]
        w_end = float(np.median(tail)) if len(tail) else float(w[k1 - 1])
        w0 = float(w[k0])
        span = max(abs(w_end - w0), still)
        settled = np.flatnonzero(np.abs(w[k0:k1] - w_end) < 0.05 * span)
        ks = k0 + (int(settled[0]) if len(settled) else k1 - k0)
        zero_cmd = abs(seg_u) < 1e-6 * max(np.max(np.abs(u)), 1e-9) or abs(seg_u) < 1e-3
        if zero_cmd:
            lab[k0:ks] = "coast" if abs(w0) > still else "rest"
            lab[ks:k1] = "rest"
            continue
        if abs(w0) <= still:
            lab[k0:ks] = "start"
        elif np.sign(w0) != np.sign(w_end):
            cross = np.flatnonzero(np.sign(w[k0:k1]) != np.sign(w0))
            kz = k0 + (int(cross[0]) if len(cross) else ks - k0)
            kr = min(ks, kz + max(1, (kz - k0) // 2))
            lab[k0:kr] = "reversal"
            lab[kr:ks] = "accel"
        else:
            lab[k0:ks] = "accel"
        lab[ks:k1] = "steady"
    return lab


def moving_rms(x: np.ndarray, width: int) -> np.ndarray:
    width = max(1, int(width))
    c = np.convolve(x ** 2, np.ones(width) / width, mode="same")
    return np.sqrt(c)


def stretches(r_norm: np.ndarray, labels: np.ndarray, width: int, level: float = 2.0):
    """Contiguous stretches where the noise-normalised residual leaves the band.

    A moving RMS over ``width`` samples above ``level`` (the noise band is 1.0) marks
    a stretch; each is named by its dominant regime.
    """
    m = moving_rms(r_norm, width) > level
    idx = np.flatnonzero(m)
    if not idx.size:
        return []
    labels = np.asarray(labels)
    # one piece per regime, so a long excursion shows where it starts and turns: a piece
    # starts where the band is left again or the regime changes
    new = np.ones(idx.size, bool)
    new[1:] = (np.diff(idx) != 1) | (labels[idx[1:]] != labels[idx[:-1]])
    first = np.flatnonzero(new)
    starts = idx[first]
    stops = np.append(idx[first[1:] - 1] + 1, idx[-1] + 1)
    return [{"start": int(a), "stop": int(b), "regime": str(labels[a]),
             "rms": float(np.sqrt(np.mean(r_norm[a:b] ** 2)))} for a, b in zip(starts, stops)]


def autocorr(r: np.ndarray, lags: int = 25) -> np.ndarray:
    r = r - r.mean()
    d = float(np.dot(r, r)) or 1.0
    return np.array([np.dot(r[:-k], r[k:]) / d for k in range(1, lags + 1)])


def crosscorr(r: np.ndarray, u: np.ndarray, lags: int = 25) -> tuple[np.ndarray, np.ndarray]:
    """Cross-correlation of the residual with the input increments, lags -L..L.

    The increments (not the levels) because a square wave's levels are almost
    constant: what the model mistimes is the response to each change.
    """
    du = np.diff(u, prepend=u[0])
    r = r - r.mean()
    du = du - du.mean()
    d = np.sqrt(np.dot(r, r) * np.dot(du, du)) or 1.0
    ks = np.arange(-lags, lags + 1)
    out = []
    for k in ks:
        if k >= 0:
            out.append(np.dot(r[k:], du[:len(du) - k]) / d)
        else:
            out.append(np.dot(r[:k], du[-k:]) / d)
    return ks, np.array(out)


#: the channels' units on each axis, as figures label them
AXIS_UNITS = {"rotary": {"speed": "rad/s (motor)", "position": "rad (output)"},
              "linear": {"speed": "m/s", "position": "m"}}


def run_residuals(rd, sim: dict, sigma_w: float, sigma_theta: float,
                  quanta: dict | None = None, detail: bool = True,
                  counted: bool = False) -> dict:
    """Residuals of one run in noise units, with regimes and stretches.

    ``quanta`` maps a channel to its quantisation step in the channel's units
    (:attr:`labrig.analysis.noise.NoiseFloor.q`; 0 or absent: none seen). Each channel carries
    it as ``quantum`` with ``quantum_kind`` (an encoder's count or an ADC step), so a
    figure can show the staircase a quantised reading leaves in the residual;
    ``counted``: the speed is a count over a window (:attr:`NoiseFloor.counted`).

    ``detail=False``: the residuals and their numbers only (no regimes, stretches or
    correlations): two thirds of the time of a slider's re-simulation went to them."""
    quanta = quanta or {}
    w_ref = rd.w if rd.w is not None else np.gradient(rd.theta * rd.N, rd.dt)
    labels = regimes_of(rd.u, w_ref) if detail else None
    keep = rd.keep()
    out = {"name": rd.name, "labels": labels, "amplitude": rd.amplitude, "loop": rd.loop,
           # samples the link lost: residual 0 (no evidence), drawn as gaps, not counted
           "lost": None if keep.all() else ~keep,
           "t": np.arange(len(rd.u)) * rd.dt, "channels": {},
           "units": AXIS_UNITS[getattr(rd, "axis", "rotary")]}
    width = max(3, int(0.02 / rd.dt))  # 20 ms: long enough to beat the noise, short for edges
    for ch, y, yh, sig in (("speed", rd.w, sim["w"], sigma_w),
                           ("position", rd.theta, sim["theta"], sigma_theta)):
        if y is None:
            continue
        c = out["channels"][ch] = _residual(y, yh, sig, keep)
        if detail:
            r = c["residual"]
            c.update(stretches=stretches(r, labels, width), autocorr=autocorr(r),
                     crosscorr=crosscorr(r, rd.u))
        c.update({"quantum": float(quanta.get(ch) or 0.0),
                  "quantum_kind": "encoder count" if ch == "position" and
                  getattr(rd, "pos_q", 0.0) > 0 else
                  "count over the speed's window" if ch == "speed" and counted
                  else "ADC step"})
    return out


def _residual(y, yh, sig, keep) -> dict:
    """One channel measured against the model: the residual in noise units (a sample the
    link lost is no evidence: 0), fit %, rmse/noise over the kept samples, the band."""
    r = np.where(keep, (y - yh) / sig, 0.0)
    return {"measured": y, "simulated": yh, "residual": r, "sigma": sig,
            "fit_percent": fit_percent(y[keep], yh[keep]),
            "rmse_over_noise": float(np.sqrt(np.mean(r[keep] ** 2))),
            "band": Z99 / np.sqrt(len(r))}


def current_residual(rd, i_sim: np.ndarray, sigma_i: float) -> dict | None:
    """The measured armature current against the model's, in noise units, as a channel of
    :func:`run_residuals` (None: the run has no current). Kept apart from the run's
    ``channels``: the numbers of an evaluation (rmse/noise overall, by regime, BIC) are
    the speed's and the position's; the current is drawn beside them."""
    if rd.current is None:
        return None
    return {**_residual(rd.current, i_sim, sigma_i, rd.keep()), "quantum": 0.0,
            "quantum_kind": "ADC step"}


def worst_run(per_run: list[dict]) -> dict:
    """The run whose worst channel is furthest from the noise floor."""
    return max(per_run, key=lambda rr: max((c["rmse_over_noise"] for c in rr["channels"].values()),
                                           default=0.0))


def regime_table(per_run: list[dict]) -> dict:
    """rmse/noise per regime (all runs) and per amplitude, per channel, with shares."""
    table = {"by_regime": {}, "by_amplitude": {}}
    for ch in ("speed", "position"):
        acc = {}
        amp = {}
        for rr in per_run:
            c = rr["channels"].get(ch)
            if c is None:
                continue
            keep = np.ones(len(c["residual"]), bool) if rr.get("lost") is None else ~rr["lost"]
            r2 = c["residual"][keep] ** 2  # a sample the link lost is not counted
            labels = rr["labels"][keep]
            for reg in REGIMES:
                m = labels == reg
                if m.any():
                    a = acc.setdefault(reg, [0.0, 0])
                    a[0] += float(r2[m].sum())
                    a[1] += int(m.sum())
            key = f"{'closed' if rr['loop'] == 'closed' else 'open'} {rr['amplitude']:.2f} V"
            b = amp.setdefault(key, [0.0, 0])
            b[0] += float(r2.sum())
            b[1] += len(r2)
        tot = sum(v[0] for v in acc.values()) or 1.0
        ntot = sum(v[1] for v in acc.values()) or 1
        table["by_regime"][ch] = {reg: {"rmse_over_noise": float(np.sqrt(s / n)),
                                        "share_of_error": s / tot, "share_of_time": n / ntot}
                                  for reg, (s, n) in acc.items()}
        # by loop, then by amplitude as a number ("open 10.00 V" after "open 2.50 V")
        order = sorted(amp, key=lambda k: (k.split()[0], float(k.split()[1])))
        table["by_amplitude"][ch] = {k: float(np.sqrt(amp[k][0] / amp[k][1])) for k in order}
    return table


def worst_regime(table: dict) -> tuple[str, str, float] | None:
    """(channel, regime, rmse/noise) where the error is most over-represented."""
    best = None
    for ch, regs in table["by_regime"].items():
        for reg, v in regs.items():
            if v["share_of_time"] < 0.005:
                continue
            score = v["rmse_over_noise"]
            if best is None or score > best[2]:
                best = (ch, reg, score)
    return best
