"""How well one proposed input separates two explanations (``labrig propose``, steps 5-7
of docs/physics.md, 'Experiments that decide'): the separation the decision will report
once the run is made, with the rival re-fitted; the branch and bound over the leading
inputs and the truths; the smallest size an input separates, and the sizes no input
within the budget separates (the noise hides them).
"""
from __future__ import annotations

import numpy as np

from labrig.diagnosis.evidence.evaluation import evaluate
from labrig.design.inputs import InputCandidate
from labrig.design.proposal import DECISIVE
from labrig.design.synthetic import synthetic_run
from labrig.diagnosis.loop.refit import fit, refit_with
from labrig.io.runs import Run
from labrig.model.effects import get_effect
from labrig.model.model import Model
from labrig.analysis.noise import Weights


def separation_after_refit(runs, base: Model, rival: str, truth: Model, cand: InputCandidate,
                           template: Run, sig: dict, *, seed, weights, rng) -> tuple:
    """The decision's separation predicted for ``cand`` when ``truth`` is the truth: the
    run it would record (with the rig's noise) added to ``runs``, the rival re-fitted to
    them all from scanned starts (as ``diagnose`` fits it), its rmse/noise over the
    truth's, minus one; and the re-fitted rival."""
    clean = truth.simulate([synthetic_run(template, cand, "p")])[0]
    new = synthetic_run(template, cand, "proposed", clean, sig, rng)
    data = runs + [new]
    res = refit_with(data, base, get_effect(rival), seed=seed, weights=weights)
    r_rival = float(res.metrics["rmse_over_noise"]["overall"])
    r_truth = float(evaluate(data, truth, weights=weights).metrics["rmse_over_noise"]["overall"])
    return max(0.0, r_rival / r_truth - 1.0), res.model()


#: bisection steps (on a log scale) for the smallest size the proposed input separates
SIZE_STEPS = 3


def smallest_separable(runs, base: Model, h, rival: str, chosen, template: Run, sig: dict, *,
                       seed: int, weights: Weights, reach) -> dict | None:
    """The smallest size of the explanation ``h`` (judged true across the sizes the data
    cannot exclude) at which the proposed input still separates it from ``rival``: from
    the smallest plausible size (its best fit, not judged above) up to the smallest size
    judged at which it separates and does at every larger one, bisected on a log scale,
    ``h`` fitted with its size fixed at each and the rival re-fitted. The bracket's upper
    end is reported: an input proven there. None when no judged size separates.

    Below that size the two explanations differ, on this input, by less than the noise
    lets the decision see: a threshold that small is the model without it, near enough."""
    judged = []
    for size, _ in h.members[1:]:
        sep = chosen.refit.get(h.label(size))
        if sep is not None:
            judged.append((size, sep))
    judged.sort()
    ok = None
    for size, sep in reversed(judged):   # the smallest size from which every one separates
        if sep < DECISIVE:
            break
        ok = size
    if ok is None:
        return None
    lo = min(size for size, _ in h.members)
    out = {"effect": h.effect, "key": h.key, "unit": h.unit, "plausible_from": lo}

    def separates(size, step):
        truth = fit(runs, h.model.effects, h.model, {f"{h.effect}.{h.key}": size},
                    seed=seed, weights=weights, reach=reach, max_nfev=40).model()
        sep, _ = separation_after_refit(runs, base, rival, truth, chosen.candidate, template,
                                        sig, seed=seed, weights=weights,
                                        rng=np.random.default_rng([seed, 7, step]))
        return sep >= DECISIVE

    if lo >= ok or separates(lo, 0):
        return {**out, "size": min(lo, ok), "every_plausible_size": True}
    for step in range(1, SIZE_STEPS + 1):
        mid = float(np.sqrt(lo * ok))
        lo, ok = (lo, mid) if separates(mid, step) else (mid, ok)
    return {**out, "size": ok, "every_plausible_size": False}


def branch_and_bound(leaders, truths, judge) -> None:
    """Judge the leading inputs on the truths until the best is known. The next re-fit
    always goes to the input whose worst so far is the highest; once that input has been
    judged on every truth, no other can beat it (their worst so far bounds their worst),
    and they stop there. (One fit at a time: the simulator's kernels already use both
    cores; fits in two processes, each held to one core, were slower.)"""
    while True:
        k = max(range(len(leaders)), key=lambda k: (leaders[k].worst if leaders[k].refit
                                                    else np.inf, -k))
        todo = [t for t in truths if t[1] not in leaders[k].refit]   # judged in order
        if not todo:
            return
        judge(k, todo[0])


def smallest_unseparated(hyps, truths, chosen):
    """The smallest size of an explanation judged across sizes the data cannot narrow at
    which the best input does not separate the pair, when a larger size of it stays to be
    judged; else None (a pinned size, or its last, is never set aside)."""
    for hi, h in enumerate(hyps):
        if h.pinned or not h.key:
            continue
        mine = [t for t in truths if t[0] == hi]
        if len(mine) > 1 and chosen.refit.get(mine[0][1], np.inf) < DECISIVE:
            return mine[0]
    return None
