"""``labrig propose``: the experiment that tells two explanations apart (docs/physics.md,
'Experiments that decide').

Two model structures explain the data about equally well (a dead zone and Coulomb
friction, stiction and a dead zone, backlash and a delay). Each is fitted to the data,
with the sizes of its threshold the data cannot exclude (*plausible variants*: a dead zone
from one amplitude trades off against the gain, so 0.05 V and 1.5 V fit alike). Then:

1. **Which explanation may be the truth.** One whose size lands at its bound is the model
   without it, which the rival contains too: no input can tell them apart that way. One
   that already explains the data clearly worse is not designed for. The others are
   judged true at their best fit when the data pin its size, else at each plausible size.
2. **Candidate inputs** (:mod:`labrig.design.inputs`): levels around the threshold only
   when the data pin it, else spread across the whole range; steps that coast to rest at
   0 V, ramps, dwells, reversals, staircases; within the budget, the board's table and
   the input limit.
3. **The leaders by the predicted difference** (the sum of squared differences of the two
   predictions in noise units, :func:`_difference`, the worst over the plausible models)
   are each played, in simulation, on every plausible truth with the rig's noise; the
   rival is re-fitted to the old runs and that run together, from scanned starts, as
   ``diagnose`` will fit it. What it then fails to explain is the **predicted separation**:
   the decision's measure (:mod:`labrig.design.decide`: the worse rmse/noise over the
   better, minus one), the worst over the truths.
4. The input with the largest predicted separation is proposed when it reaches
   :data:`DECISIVE`; when no input within the budget does, the proposal says so and what
   would help instead, and no plan is written.
"""
from __future__ import annotations

import time

import numpy as np

from labrig.core.errors import UserError
from labrig.design.inputs import candidates, closed_candidates, loop_gains
from labrig.design.separation import (branch_and_bound, separation_after_refit,
                                         smallest_separable, smallest_unseparated)
from labrig.design.pairs import default_pair, threshold_of, varied_key
from labrig.design.hypotheses import Hypothesis, Judged
from labrig.design.proposal import DECISIVE, Proposal
from labrig.design.synthetic import synthetic_run
from labrig.model.effects import get_effect
from labrig.model.model import Model
from labrig.analysis.noise import Weights, channel_floors
from labrig.diagnosis.loop.refit import fit, refit_with, without
from labrig.io.runs import Run
from labrig.model.reach import Reach
from labrig.model.simulate import prepare
from labrig.simulation.warm import ready

#: candidate inputs judged by the re-fit: the leaders by the worst-case predicted
#: difference, at most :data:`PER_KIND` of a kind
LEADERS = 5
PER_KIND = 2
#: variants of a hypothesis: the threshold fixed at these shares of its data bound
VARIANT_SHARES = (0.1, 0.3, 0.6)
#: ... of a range no wider than this where the data leave a size open: a breakaway excess
#: may be fitted up to 8 (a small gearmotor's stiction breaks loose at 4.6 times its
#: kinetic level), but the variants judged as truths stand for the common breakaways
VARIANT_RANGE = {"excess": 3.0}
#: a variant is plausible while its fit is within this factor of the best; a hypothesis
#: this much worse than its rival is not designed for
PLAUSIBLE = 1.10


def variants(runs, hyp: Hypothesis, reach, *, seed: int, weights: Weights,
             rival: str = "") -> None:
    """Fill ``hyp.members`` (the sizes the data cannot exclude, best fit first) and
    ``hyp.degenerate``: its size (:func:`varied_key`) fixed across the range the data allow
    and the rest re-fitted; those within :data:`PLAUSIBLE` of the best fit stay. A
    threshold one run cannot pin down (a dead zone from a single amplitude: d and the gain
    trade off) then spans its range."""
    eff = get_effect(hyp.effect)
    key = varied_key(hyp.effect, rival)
    bounds = {p.name: (p.lower, p.upper) for p in eff.params}
    lo, hi = eff.data_bounds(reach).get(key, bounds.get(key, (None, None))) if key else \
        (None, None)
    if not key or hi is None:
        hyp.members = [(None, hyp.model)]
        return
    hyp.key = key
    hyp.unit = next(p.unit for p in eff.params if p.name == key)
    best = hyp.size
    # at a bound of the range the data allow: as the truth it is the model without it
    # (the lower end) or a size the data cannot hold (the upper end)
    hyp.degenerate = best <= 1.5 * lo or best >= 0.95 * hi
    hyp.members = [(best, hyp.model)]
    top = min(hi, VARIANT_RANGE.get(key, hi))
    for share in VARIANT_SHARES:
        v = share * top
        if abs(v / best - 1.0) < 0.3:
            continue   # the best fit already stands for it
        res = fit(runs, hyp.model.effects, hyp.model, {f"{hyp.effect}.{key}": v},
                  seed=seed, weights=weights, reach=reach, max_nfev=40)
        if res.metrics["rmse_over_noise"]["overall"] <= PLAUSIBLE * hyp.rmse_over_noise:
            hyp.members.append((v, res.model()))


def _travel(runs) -> tuple[float, float]:
    """How far the data moved the axis from a run's start (either way: the data do not
    say where the sensor's ends are)."""
    spans = [float(np.ptp(r.position)) for r in runs if r.position is not None]
    return (1.05 * max(spans),) * 2 if spans else (np.inf, np.inf)


def _sensor_range(rig) -> tuple[float, float]:
    """How far the rig's position sensor follows the axis from 0 (where the simulated rig
    starts every run), forwards and backwards, with a 10 % margin; an encoder has no end."""
    s, lo_hi = rig.sensors, rig.bridge.adc_range_v
    if s.encoder_counts_per_unit > 0:
        return np.inf, np.inf
    ends = sorted(((v - s.pos_offset_v) / s.pos_v_per_rad) for v in lo_hi)
    return 0.9 * max(ends[1], 0.0), 0.9 * max(-ends[0], 0.0)


def _difference(pa: dict, pb: dict, template: Run, sig: dict) -> float:
    """The predicted difference: sum of squared differences of two responses (``w``,
    ``theta``) in noise units, over the channels ``template``'s rig records."""
    d = 0.0
    if template.has_speed and "speed" in sig:
        d += float(np.sum(((pa["w"] - pb["w"]) / sig["speed"]) ** 2))
    if template.has_pos and "position" in sig:
        d += float(np.sum(((pa["theta"] - pb["theta"]) / sig["position"]) ** 2))
    return d


def _judge_truths(hyps) -> None:
    """Set ``skipped`` on the explanations no input can show true against the rival, or
    that the data already rank clearly worse."""
    for h, other in ((hyps[0], hyps[1]), (hyps[1], hyps[0])):
        # (at its bound but with larger sizes as plausible, it is judged at those)
        if h.degenerate and h.pinned:
            h.skipped = (f"fitted at its bound ({h.key} = {h.size:.3g}{h.units}): as the "
                         f"truth it is the model without it, which {other.effect} "
                         "explains as well")
        elif get_effect(other.effect).simpler == h.effect and other.key and not other.pinned:
            # the rival contains it (stiction with no excess is Coulomb friction) and may
            # be that at any size the data allow: whatever it does, the rival re-fits to it
            h.skipped = (f"{other.effect} with {other.key} at zero is {h.effect}, and the "
                         f"data allow that: whatever {h.effect} does, {other.effect} "
                         "re-fits to it; only the other way round can be shown")
        elif h.rmse_over_noise > PLAUSIBLE * other.rmse_over_noise:
            h.skipped = (f"it already explains the data worse (rmse/noise "
                         f"{h.rmse_over_noise:.2f} against {other.rmse_over_noise:.2f})")


def _levels_threshold(hyps) -> float | None:
    """The threshold (V) to set levels around, or None: spread them across the whole
    range (a size the data do not pin, or only degenerate ones)."""
    sized = [h for h in hyps if not h.degenerate]
    if not sized or any(not h.pinned for h in sized):
        return None
    if any(not h.pinned for h in hyps if not h.skipped):   # judged across its sizes
        return None
    return float(np.mean([threshold_of(h.model) for h in sized]))


def _truth_order(hyps) -> list:
    """``[(index in the pair, label, Model)]`` of every truth to judge, the smallest size
    of each explanation first (the hardest to tell from the rival), alternating between
    the two, so that an input that cannot win is found out after few re-fits."""
    lists = [[(hi, lab, m) for lab, m in h.truths()] for hi, h in enumerate(hyps)]
    out = []
    for k in range(max(map(len, lists))):
        out += [lst[k] for lst in lists if k < len(lst)]
    return out


def _leaders(judged: list) -> list:
    """The candidates the re-fit judges: the best by worst-case predicted difference,
    at most :data:`PER_KIND` of a kind (a candidate and its mirror image count as two)."""
    out, kinds = [], {}
    for j in sorted(judged, key=lambda j: (-j.robust, j.candidate.duration)):
        k = j.candidate.kind
        if kinds.get(k, 0) < PER_KIND:
            out.append(j)
            kinds[k] = kinds.get(k, 0) + 1
        if len(out) == LEADERS:
            break
    return out


def _advice(budget_s: float, amax: float, rig, pair, best: Judged, loop: str,
            can_close: bool) -> str:
    """What would help when nothing within the limits separates the pair."""
    tips = []
    if best.candidate.duration >= 0.5 * budget_s:
        tips.append(f"a longer budget (--budget-s {2 * budget_s:g}): more of the "
                    "regime where they differ")
    if rig is None:
        tips.append(f"larger inputs than the data's +-{amax:.2f} V (--rig RIG.toml lets "
                    "the proposal use the rig's output limit)")
    else:
        tips.append(f"another amplitude: a run at an input level the data lack (the rig "
                    f"allows +-{amax:.2f} V)")
    if loop == "open":
        how = ("--loop any" if can_close else "--loop any, once the data hold a "
               "closed-loop run or --rig names a rig with its analog loop")
        if {"backlash", "delay"} & set(pair):
            tips.append(f"a position loop ({how}: a closed-loop step, where a gap makes the "
                        "loop hunt and a delay does not)")
        else:
            tips.append(f"a position loop ({how}: closed-loop steps settle against the "
                        "friction or the dead zone differently)")
    return "; ".join(tips)


def propose(runs: list[Run], model: Model, between: str | None = None, *,
            budget_s: float = 20.0, amax: float | None = None, seed: int = 0,
            weights: Weights = Weights(), log=None, rig=None, loop: str = "open") -> Proposal:
    """Propose the input of at most ``budget_s`` seconds that best separates the pair.

    Parameters
    ----------
    runs : list of Run
    model : Model
        The current model; the pair's effects are swapped in and out of it.
    between : str, optional
        ``"a,b"``; default the model's effect and its usual rival (its ``rival``).
    amax : float, optional
        Largest input allowed (V); default the largest the data already use.
    rig : RigConfig, optional
        The rig: its position sensor's range bounds the travel (default: the travel the
        data show, either way).
    loop : {"open", "closed", "any"}
        Which inputs: the amplifier's input (open), the reference of the rig's own position
        loop (closed: the gains of a closed-loop run of the data, else those of a rig file
        with the analog loop), or both, judged alike.

    Returns
    -------
    Proposal
        ``separates`` False when no input within the limits is predicted to separate the
        pair by :data:`DECISIVE`; ``advice`` then says what would.
    """
    ready()  # a first compile is announced and kept out of the timing
    t0 = time.perf_counter()
    if not 1.0 <= budget_s <= 600.0:
        raise UserError(f"`budget_s`: {budget_s:g} s; give 1 to 600 s of new data")
    opened = [r for r in runs if r.loop == "open"]
    if not opened:
        raise UserError("propose needs at least one open-loop run (its rig plays the input)")
    if loop not in ("open", "closed", "any"):
        raise UserError(f"`loop`: {loop!r}; give open, closed or any")
    gains = None if loop == "open" else loop_gains(runs, rig)
    if loop != "open" and gains is None:
        raise UserError(f"`loop={loop}`: neither the data nor the rig file show the rig's "
                        "analog position loop; record a closed-loop run (a plan's loop = "
                        "\"closed\") or give `rig` with a tacho and a pot")
    pair = default_pair(model, between)
    say = log or (lambda s: None)
    # the pair's effects, and any of their families (a dead zone for a dead zone), go out
    families = {get_effect(n).family_name for n in pair}
    base = model
    for e in list(model.effects):
        if e.name in pair or e.family_name in families:
            base = without(base, e.name)
    reach = Reach.of(runs, base)
    hyps = []
    for name in pair:
        say(f"fitting the model with {name}, and the sizes the data cannot exclude")
        ident = refit_with(runs, base, get_effect(name), seed=seed, weights=weights, reach=reach)
        h = Hypothesis(name, ident.model(), float(ident.metrics["rmse_over_noise"]["overall"]))
        variants(runs, h, reach, seed=seed, weights=weights, rival=pair[1 - len(hyps)])
        hyps.append(h)
    _judge_truths(hyps)
    family = [[m for _, m in h.members] for h in hyps]
    floors = channel_floors(prepare(runs))
    sig = {ch: floors[ch].sigma for ch in ("speed", "position") if ch in floors}
    template = opened[0]
    data_amax = max(float(np.max(np.abs(r.u))) for r in opened)
    amax = data_amax if amax is None else float(amax)
    tau = float(np.median([h.model.servo().tau_m for h in hyps]))
    threshold = _levels_threshold(hyps)
    cands = [] if loop == "closed" else \
        candidates(threshold=threshold, amax=amax, tau=tau, budget_s=budget_s, dt=template.dt)
    if gains is not None:   # the loop's slowest time constant sets its steps' holds
        tau_loop = np.median([h.model.servo().closed_tau(gains["kp"], gains["kv"])
                              for h in hyps])
        cands += closed_candidates(threshold=threshold, amax=amax, gains=gains,
                                   tau=float(tau_loop), budget_s=budget_s, dt=template.dt)
    if not cands:
        raise UserError(f"`budget_s`: no candidate input fits in {budget_s:g} s; allow more")
    say(f"simulating {len(cands)} candidate inputs with {sum(map(len, family))} plausible "
        "models")
    syn = [synthetic_run(template, c, f"cand{k}") for k, c in enumerate(cands)]
    preds = [[m.simulate(syn) for m in fam] for fam in family]
    # the travel the sensors are known to follow, each way from where a run starts: an
    # input that drives the axis further (a pot beyond its range, off the end of a linear
    # axis) is not proposed
    up, down = _travel(runs) if rig is None else _sensor_range(rig)
    judged = []
    for k, c in enumerate(cands):
        ups = max(float(np.max(fam[0][k]["theta"] - fam[0][k]["theta"][0])) for fam in preds)
        downs = max(float(np.max(fam[0][k]["theta"][0] - fam[0][k]["theta"])) for fam in preds)
        if ups > up or downs > down:
            continue
        j = Judged(c, _difference(preds[0][0][k], preds[1][0][k], template, sig))
        # the worst case over every plausible truth, the rival taking its closest variant:
        # an input that only separates the best fits is a bet on their thresholds
        j.robust = min(min(_difference(pt[k], pr[k], template, sig) for pr in preds[1 - h])
                       for h in (0, 1) for pt in preds[h])
        judged.append(j)
    if not judged:
        raise UserError(f"every candidate input drives the axis further than the data did "
                        f"(+{up:.3g} / -{down:.3g} {template.units[0]} from the start) in "
                        f"{budget_s:g} s; record a run with more travel, or give a shorter "
                        "`budget_s`")
    leaders = _leaders(judged)
    truths = _truth_order(hyps)
    say(f"re-fitting the rival to each of {len(leaders)} leading inputs played on "
        f"{len(truths)} plausible truth(s)")
    # (the noise of each (input, truth) is seeded by both: the same answer whatever the
    # order in which the branch and bound judges them)
    fits = {}

    def judge(k, truth):
        hi, label, m = truth
        leaders[k].refit[label], rival = separation_after_refit(
            runs, base, pair[1 - hi], m, leaders[k].candidate, template, sig, seed=seed,
            weights=weights, rng=np.random.default_rng([seed, k, truth_index[label]]))
        fits[k, label] = (hi, label, m, rival)

    truth_index = {lab: t for t, (_, lab, _) in enumerate(truths)}
    unseen = []     # sizes no leading input separates: the noise hides them in the budget
    while truths:
        branch_and_bound(leaders, truths, judge)
        chosen = max(leaders, key=lambda j: (j.worst, -j.candidate.duration))
        if chosen.worst >= DECISIVE:
            break
        hidden = smallest_unseparated(hyps, truths, chosen)
        if hidden is None:
            break
        for k, j in enumerate(leaders):   # every leading input judged at that size
            if hidden[1] not in j.refit:
                judge(k, hidden)
        best = max(j.refit[hidden[1]] for j in leaders)
        if best >= DECISIVE:   # an input separates it there: no size is set aside
            break
        # judged over the sizes at which the two explanations differ by more than the
        # noise can hide (within the budget); the smallest size it separates is stated
        unseen.append((hidden[1], best))
        truths.remove(hidden)
        for j in leaders:
            j.refit.pop(hidden[1])
    for k, j in enumerate(leaders):
        j.stopped = 0 < len(j.refit) < len(truths)
        if j.refit:
            j.hardest = fits[k, min(j.refit, key=j.refit.get)]
    if truths:
        chosen = max(leaders, key=lambda j: (j.worst, -j.candidate.duration))
        separates = chosen.worst >= DECISIVE
    else:   # neither may be the truth: nothing to design for
        chosen, separates = leaders[0], False
    smallest = []
    if separates:   # an explanation judged across sizes: the smallest this input separates
        for hi, h in enumerate(hyps):
            if not h.skipped and not h.pinned and h.key:
                say(f"finding the smallest {h.effect} the proposed input separates")
                found = smallest_separable(runs, base, h, pair[1 - hi], chosen, template, sig,
                                           seed=seed, weights=weights, reach=reach)
                if found is not None:
                    smallest.append(found)
    prop = Proposal(pair=pair, hypotheses=hyps, judged=judged, chosen=chosen, sigmas=sig,
                    template=template, budget_s=budget_s, amax=amax,
                    seconds=time.perf_counter() - t0, plausible=[len(f) for f in family],
                    separates=separates, smallest=smallest, unseen=unseen)
    if not separates:
        can_close = gains is not None or loop_gains(runs, rig) is not None
        prop.advice = (_advice(budget_s, amax, rig, pair, chosen, loop, can_close) if truths else
                       "neither explanation can be the truth on these data: "
                       + "; ".join(h.skipped for h in hyps))
    return prop


# -- deciding ---------------------------------------------------------------------------
