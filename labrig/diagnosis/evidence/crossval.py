"""Evidence from cross-validation, located in time.

A structure (a model's list of effects) is judged by how well it predicts data its fit
did not see. The held-out parts are the *segments* of the input (the stretches between
its edges: a half-period of a square wave, a step of a staircase), interleaved across
amplitude and direction: every fold holds out some steps of each direction and
amplitude band and trains on the others, so no fold has to predict a direction or an
amplitude its training part never showed (whole runs held out in turn fail exactly
there: the run just above a threshold, or the negative half of a staircase recorded
after the positive one). A segment is long compared with the correlation time of the
residuals (blocked cross-validation for dependent data). Data with too few segments to
interleave (a step or two) are cut into contiguous blocks instead.

The fold fits start from the full-data fit, so they cost little, but they never see the
held-out samples. The held-out residuals are stitched back into one prediction of every
run, so the regimes where a structure predicts better are named, and every fold's own
evidence is kept: a fold whose training part does not pin the new effect's threshold
(:func:`unpinned_folds`) is reported, and :mod:`labrig.diagnosis.loop.diagnose` does not let it
outvote the others.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any

from pydantic import Field

import numpy as np

from labrig.core.parallel import each
from labrig.core.record import Live, Record
from labrig.identification.problem import start_of
from labrig.model.model import Model
from labrig.model.start import is_start_key
from labrig.model.simulate import prepare
from labrig.analysis.noise import run_speed
from labrig.diagnosis.loop.refit import fit
from labrig.diagnosis.evidence.residuals import input_edges, regimes_of
from labrig.model.effects import get_effect

#: a fold fit's tolerances on its step and its cost (scipy's xtol and ftol; 1e-8 for every
#: other fit): it is used only for its prediction of the held-out samples, which moves far
#: less than the parameters at the end of a fit. Measured on the README's round (20 fold
#: fits): 309 -> 171 evaluations, every held-out rmse/noise within 2e-5 of the 1e-8 fits'
CV_TOL = 1e-6
#: folds, and blocks per run when the input has too few segments to interleave
MAX_FOLDS = 4
BLOCKS = 4
#: a segment shorter than this (s) joins the one before it
MIN_SEGMENT_S = 0.25
#: a long stretch of ramping input is cut wherever it has moved this share of the run's span
RAMP_BAND = 0.1


@dataclass
class Fold:
    """Per run, the samples the fit sees (``train``) and those it predicts (``test``)."""

    train: list
    test: list


@dataclass
class Folds:
    kind: str
    folds: list

    def describe(self) -> str:
        return f"{len(self.folds)} folds, {self.kind}"


def segments(run) -> list[tuple[int, int, float]]:
    """``(first, end, level)`` of each stretch of constant input, short ones merged into
    the stretch before them."""
    u = np.asarray(run.u, float)
    n = len(u)
    bounds = [0] + [int(k) for k in input_edges(u)] + [n]
    min_len = max(int(MIN_SEGMENT_S / max(float(run.dt), 1e-9)), 1)
    out: list[list] = []
    for k0, k1 in zip(bounds[:-1], bounds[1:]):
        if k1 <= k0:
            continue
        if out and k1 - k0 < min_len:
            out[-1][1] = k1
            continue
        out.append([k0, k1])
    if len(out) > 1 and out[0][1] - out[0][0] < min_len:   # a short first stretch
        out[1][0] = out[0][0]
        out.pop(0)
    return [(k0, k1, float(np.median(u[k0 + (k1 - k0) // 2:k1]))) for k0, k1 in out]


def pieces(u, k0: int, k1: int) -> list[tuple[int, int, float]]:
    """The stretch ``u[k0:k1]`` cut where its input ramps (a triangle, a slow sine: no edge
    anywhere), wherever it has moved a tenth of the run's span since the piece began, so
    each piece has a level of its own; ``(first, end, level)`` each. A stretch held at one
    level stays whole (a data set of one or two such steps is cut into blocks instead)."""
    u = np.asarray(u, float)
    band = RAMP_BAND * max(float(np.ptp(u)), 1e-9)
    cuts, at = [k0], k0
    for j in range(k0 + 1, k1):
        if abs(u[j] - u[at]) > band:
            cuts.append(j)
            at = j
    cuts.append(k1)
    return [(a, b, float(np.median(u[a:b]))) for a, b in zip(cuts[:-1], cuts[1:])]


def make_folds(runs, max_folds: int = MAX_FOLDS, blocks: int = BLOCKS) -> Folds:
    """Segments interleaved across amplitude and direction; contiguous blocks when the
    input has too few segments for every fold to leave each direction in training. A
    ramping stretch holding more than a ``1 / (2 max_folds)`` share of all samples is cut
    by level (:func:`pieces`): held out whole, it would be most of its fold, and its one
    prediction would outvote every other segment."""
    n = [len(r.u) for r in runs]
    k = max_folds
    most = max(sum(n) // (2 * k), 1)
    strata: dict = {}
    for i, r in enumerate(runs):
        scale = max(float(np.max(np.abs(r.u))) if n[i] else 0.0, 1e-9)
        cut = [p for k0, k1, level in segments(r)
               for p in ([(k0, k1, level)] if k1 - k0 <= most else pieces(r.u, k0, k1))]
        for k0, k1, level in cut:
            sign = 0 if abs(level) < 0.02 * scale else int(np.sign(level))
            strata.setdefault((r.loop, sign), []).append((abs(level), i, k0, k1))
    moving = [v for (loop, sign), v in strata.items() if sign != 0]
    total = sum(len(v) for v in strata.values())
    if moving and all(len(v) >= 2 for v in moving) and total >= 2 * k:
        tests = [[np.zeros(m, bool) for m in n] for _ in range(k)]
        slot = 0
        for key in sorted(strata, key=lambda s: (s[0], s[1])):
            # neighbouring amplitudes go to different folds
            for _, i, k0, k1 in sorted(strata[key]):
                tests[slot % k][i][k0:k1] = True
                slot += 1
        folds = [Fold(train=[~t for t in test], test=test) for test in tests]
        return Folds(f"{total} input segments (steps, half-periods) interleaved across "
                     "amplitude and direction, each held out once", folds)
    folds = []
    for j in range(blocks):
        test = []
        for i in range(len(runs)):
            t = np.zeros(n[i], bool)
            t[j * n[i] // blocks:(j + 1) * n[i] // blocks] = True
            test.append(t)
        folds.append(Fold(train=[~t for t in test], test=test))
    return Folds(f"contiguous blocks of each run ({100 // blocks} % of it) held out in turn "
                 "(too few input steps to interleave)", folds)




@dataclass
class CrossValidation(Record):
    """Held-out error of one structure.

    Attributes
    ----------
    rmse : float
        Weighted held-out rmse/noise over every fold (the fit's objective, not seen).
    per_fold : list of float
        Held-out weighted mean square per fold.
    fold_sq, fold_n : list
        Per fold, the held-out weighted sum of squares and the samples it holds out
        (``per_fold`` is their ratio; the pooled ``rmse`` is the root of their sums).
    fold_params : list of dict
        Per fold, the parameters its fit reached.
    channels : dict
        Held-out rmse/noise per channel (unweighted).
    residuals : list of dict
        Per run, the stitched held-out residual of each channel (noise units).
    """

    rmse: Annotated[float, Field(alias="rmse_over_noise")]
    per_fold: Annotated[list[float], Field(alias="per_fold_mean_square")]
    channels: dict[str, Any]
    # (not in the JSON: the residuals, and each fold's sums and parameters)
    residuals: Annotated[list, Live] = field(default_factory=list, repr=False)
    labels: Annotated[list, Live] = field(default_factory=list, repr=False)
    fold_sq: Annotated[list, Live] = field(default_factory=list, repr=False)
    fold_n: Annotated[list, Live] = field(default_factory=list, repr=False)
    fold_params: Annotated[list, Live] = field(default_factory=list, repr=False)

    def pooled(self, skip=()) -> float:
        """The held-out rmse/noise over every fold but those in ``skip``."""
        keep = [j for j in range(len(self.fold_sq)) if j not in set(skip)]
        n = sum(self.fold_n[j] for j in keep)
        return float(np.sqrt(sum(self.fold_sq[j] for j in keep) / max(n, 1)))


def cross_validate(runs, model: Model, folds: Folds, *, sigmas, weights, seed: int = 0,
                   fixed: dict | None = None, reach=None, max_nfev: int = 25) -> CrossValidation:
    """Fit ``model``'s structure on each fold's training samples (from ``model``'s
    parameters) and predict the held-out samples."""
    prepared = prepare(runs)
    sw, st = sigmas
    res = [{ch: np.zeros(len(r.u)) for ch, y in (("speed", r.w), ("position", r.theta))
            if y is not None} for r in prepared]
    per_fold, fold_sq, fold_n, fold_params = [], [], [], []
    start = start_of(model, fixed)
    # a run's start (labrig.model.start) is held where the model has it: a held-out stretch
    # is given its own starting state and nothing more, and a fold whose training part
    # lacks a run's first samples could not pin it
    starts = {k: v for k, v in start.items() if is_start_key(k)}

    def train(fold):
        idx = [i for i, m in enumerate(fold.train) if m.any()]
        sub = [runs[i] for i in idx]
        masks = None if all(fold.train[i].all() for i in idx) else [fold.train[i] for i in idx]
        return fit(sub, model.effects, start, {**(fixed or {}), **starts}, seed=seed,
                   weights=weights, reach=reach, max_nfev=max_nfev, masks=masks, tol=CV_TOL)

    for fold, f in zip(folds.folds, each(train, folds.folds)):   # the folds side by side
        fm = Model.from_flat({**starts, **f.params}, model.effects, model.constants,
                             plant=model.plant)
        test_idx = [i for i, m in enumerate(fold.test) if m.any()]
        sims = fm.simulate([runs[i] for i in test_idx])
        sq, cnt = 0.0, 0
        for i, s in zip(test_idx, sims):
            r = prepared[i]
            m = fold.test[i] & r.keep()  # a sample the link lost is not scored
            for ch, y, yh, sig, wt in (("speed", r.w, s["w"], sw, weights.q),
                                       ("position", r.theta, s["theta"], st, weights.p)):
                if y is None:
                    continue
                e = (y - yh) / sig
                res[i][ch][m] = e[m]
                sq += wt * float(np.sum(e[m] ** 2))
                cnt += int(m.sum())
        per_fold.append(sq / max(cnt, 1))
        fold_sq.append(sq)
        fold_n.append(cnt)
        fold_params.append(dict(f.params))
    total_sq, total_n, channels = 0.0, 0, {}
    for ch, wt in (("speed", weights.q), ("position", weights.p)):
        parts = [rr[ch] for rr in res if ch in rr]
        if parts:
            e = np.concatenate(parts)
            channels[ch] = float(np.sqrt(np.mean(e ** 2)))
            total_sq += wt * float(np.sum(e ** 2))
            total_n += len(e)
    labels = [regimes_of(r.u, run_speed(r)) for r in prepared]
    return CrossValidation(rmse=float(np.sqrt(total_sq / max(total_n, 1))), per_fold=per_fold,
                           channels=channels, residuals=res, labels=labels, fold_sq=fold_sq,
                           fold_n=fold_n, fold_params=fold_params)


#: a fold's fit pins a threshold when it lands within this factor of the full-data value
PIN_FACTOR = 2.0


def unpinned_folds(cv: CrossValidation, model: Model, effect: str) -> dict:
    """Folds whose training part does not pin ``effect``'s threshold: its fold fit lands
    more than :data:`PIN_FACTOR` away from the fit to all data (the held-out part held
    what set it). ``{fold index: (parameter, fold value, all-data value)}``."""
    name = get_effect(effect).threshold
    if not name:
        return {}
    key = f"{effect}.{name}"
    value = float(model.flat().get(key, 0.0))
    full = abs(value)
    if full == 0:
        return {}
    out = {}
    for j, p in enumerate(cv.fold_params):
        v = float(p.get(key, value))
        if not full / PIN_FACTOR <= abs(v) <= full * PIN_FACTOR:
            out[j] = (key, v, value)
    return out


def regime_evidence(base: CrossValidation, cand: CrossValidation, top: int = 2) -> list[dict]:
    """The regimes where ``cand`` predicts held-out data better than ``base``, most first:
    ``{"channel", "regime", "base", "candidate", "share_of_time"}`` (rmse/noise)."""
    acc = {}
    for rb, rc, lab in zip(base.residuals, cand.residuals, base.labels):
        for ch in rb:
            for reg in np.unique(lab):
                m = lab == reg
                a = acc.setdefault((ch, str(reg)), [0.0, 0.0, 0])
                a[0] += float(np.sum(rb[ch][m] ** 2))
                a[1] += float(np.sum(rc[ch][m] ** 2))
                a[2] += int(m.sum())
    total = {ch: sum(v[2] for (c, _), v in acc.items() if c == ch) for ch, _ in acc}
    out = []
    for (ch, reg), (sb, sc, n) in acc.items():
        if n < 0.005 * total[ch]:
            continue
        b, c = np.sqrt(sb / n), np.sqrt(sc / n)
        out.append({"channel": ch, "regime": reg, "base": float(b), "candidate": float(c),
                    "share_of_time": n / total[ch], "gain": float(b - c)})
    out.sort(key=lambda d: -d["gain"])
    return [d for d in out[:top] if d["gain"] > 0]


def fold_evidence(base: CrossValidation, cand: CrossValidation, model: Model,
                  effect: str | None) -> dict:
    """The held-out comparison of a candidate with the model it changes, fold by fold.

    A fold whose training part does not pin the new effect's threshold
    (:func:`unpinned_folds`) and predicts worse is reported under ``not_counted`` and
    left out of the pooled errors and the fold count, unless such folds are half or
    more: then the data do not pin the threshold at all and every fold counts."""
    k = len(base.per_fold)
    loose = unpinned_folds(cand, model, effect) if effect else {}
    skip = [j for j in loose if cand.per_fold[j] > base.per_fold[j]]
    if 2 * len(skip) >= k:
        skip = []
    counted = [j for j in range(k) if j not in skip]
    b, c = base.pooled(skip), cand.pooled(skip)
    return {"baseline": b, "with_effect": c, "improvement": 1.0 - c / b if b > 0 else 0.0,
            "folds_improved": sum(cand.per_fold[j] < base.per_fold[j] for j in counted),
            "folds": len(counted),
            "per_fold": [{"fold": j + 1, "baseline": float(np.sqrt(base.per_fold[j])),
                          "with_effect": float(np.sqrt(cand.per_fold[j])),
                          "counted": j not in skip} for j in range(k)],
            "not_counted": [{"fold": j + 1, "parameter": loose[j][0], "fold_value": loose[j][1],
                             "value": loose[j][2]} for j in skip],
            "evidence": regime_evidence(base, cand)}
