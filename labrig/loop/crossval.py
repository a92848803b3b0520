"""Evidence from cross-validation, located in time.

A structure (a model's list of effects) is judged by how well it predicts data its fit
did not see. With several runs, whole runs are held out in turn (leave-one-run-out,
or a few folds of whole runs when there are many); a single long recording (a
staircase) is cut into contiguous blocks, each held out in turn, long compared with the
correlation time of the residuals (blocked cross-validation for dependent data). The
fold fits start from the full-data fit, so they cost little, but they never see the
held-out samples. The held-out residuals are stitched back into one prediction of
every run, so the regimes where a structure predicts better are named.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from labrig.model.model import Model
from labrig.model.simulate import prepare
from labrig.analysis.noise import run_speed
from labrig.loop.refit import fit
from labrig.loop.residuals import label_regimes

#: at most this many folds of whole runs, and blocks in a single run
MAX_FOLDS = 4
BLOCKS = 4


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


def make_folds(runs, max_folds: int = MAX_FOLDS, blocks: int = BLOCKS) -> Folds:
    """Whole runs held out when there are three or more, else contiguous blocks."""
    n = [len(r.u) for r in runs]
    if len(runs) >= 3:
        order = sorted(range(len(runs)), key=lambda i: (runs[i].loop, runs[i].amplitude))
        k = min(len(runs), max_folds)
        folds = []
        for j in range(k):
            held = set(order[j::k])
            test = [np.full(n[i], i in held) for i in range(len(runs))]
            folds.append(Fold(train=[~t for t in test], test=test))
        kind = "leave-one-run-out" if k == len(runs) else "whole runs held out in turn"
        return Folds(kind, folds)
    folds = []
    for j in range(blocks):
        test = []
        for i in range(len(runs)):
            t = np.zeros(n[i], bool)
            t[j * n[i] // blocks:(j + 1) * n[i] // blocks] = True
            test.append(t)
        folds.append(Fold(train=[~t for t in test], test=test))
    return Folds(f"contiguous blocks of each run ({100 // blocks} % of it) held out in turn", folds)


@dataclass
class CrossValidation:
    """Held-out error of one structure.

    Attributes
    ----------
    rmse : float
        Weighted held-out rmse/noise over every fold (the fit's objective, not seen).
    per_fold : list of float
        Held-out weighted mean square per fold.
    channels : dict
        Held-out rmse/noise per channel (unweighted).
    residuals : list of dict
        Per run, the stitched held-out residual of each channel (noise units).
    """

    rmse: float
    per_fold: list
    channels: dict
    residuals: list = field(default_factory=list, repr=False)
    labels: list = field(default_factory=list, repr=False)

    def to_json(self) -> dict:
        return {"rmse_over_noise": self.rmse, "per_fold_mean_square": self.per_fold,
                "channels": self.channels}


def cross_validate(runs, model: Model, folds: Folds, *, sigmas, weights, seed: int = 0,
                   fixed: dict | None = None, reach=None, max_nfev: int = 25) -> CrossValidation:
    """Fit ``model``'s structure on each fold's training samples (from ``model``'s
    parameters) and predict the held-out samples."""
    prepared = prepare(runs)
    sw, st = sigmas
    res = [{ch: np.zeros(len(r.u)) for ch, y in (("speed", r.w), ("position", r.theta))
            if y is not None} for r in prepared]
    per_fold = []
    start = {**model.flat(), **(fixed or {})}
    for fold in folds.folds:
        idx = [i for i, m in enumerate(fold.train) if m.any()]
        sub = [runs[i] for i in idx]
        masks = None if all(fold.train[i].all() for i in idx) else [fold.train[i] for i in idx]
        f = fit(sub, model.effects, start, dict(fixed or {}), seed=seed, weights=weights,
                reach=reach, max_nfev=max_nfev, masks=masks)
        fm = Model.from_flat(f.params, model.effects, model.constants, plant=model.plant)
        test_idx = [i for i, m in enumerate(fold.test) if m.any()]
        sims = fm.simulate([runs[i] for i in test_idx])
        sq, cnt = 0.0, 0
        for i, s in zip(test_idx, sims):
            r, m = prepared[i], fold.test[i]
            for ch, y, yh, sig, wt in (("speed", r.w, s["w"], sw, weights.q),
                                       ("position", r.theta, s["theta"], st, weights.p)):
                if y is None:
                    continue
                e = (y - yh) / sig
                res[i][ch][m] = e[m]
                sq += wt * float(np.sum(e[m] ** 2))
                cnt += int(m.sum())
        per_fold.append(sq / max(cnt, 1))
    total_sq, total_n, channels = 0.0, 0, {}
    for ch, wt in (("speed", weights.q), ("position", weights.p)):
        parts = [rr[ch] for rr in res if ch in rr]
        if parts:
            e = np.concatenate(parts)
            channels[ch] = float(np.sqrt(np.mean(e ** 2)))
            total_sq += wt * float(np.sum(e ** 2))
            total_n += len(e)
    labels = [label_regimes(r.u, run_speed(r)) for r in prepared]
    return CrossValidation(rmse=float(np.sqrt(total_sq / max(total_n, 1))), per_fold=per_fold,
                           channels=channels, residuals=res, labels=labels)


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
