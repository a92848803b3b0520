"""The search for the model's structure: not greedy, judged on held-out data.

Each round diagnoses the current model (every missing effect re-fitted from scanned
starts, the best cross-validated) and then:

- **adds** the recommended effect, or, when no single effect brings the error near the
  noise floor, the best **pair** of the leading candidates (two effects that only
  explain the data together: a dead zone in front of a rail); when no single effect
  earns its parameters at all and the model still misses, the pairs of the effects
  that set how much drive it takes to move (offset, friction, dead zone) are fitted
  together in place of the model's own such effects (an offset with Coulomb friction
  looks like a lopsided dead zone to a search that adds one effect at a time);
- **swaps** an earlier choice for a look-alike when the new model makes the look-alike
  predict better (stiction for a dead zone, stiction for Coulomb friction);
- **removes** an earlier effect that no longer earns its place once a later one is in
  (backward elimination).

It stops when the cross-validated error stops falling. Folds, noise floors and channel
weights are fixed in the first round, so every rung of the ladder is judged alike.
"""
from __future__ import annotations

from itertools import combinations
from pathlib import Path

from labrig.diagnosis.evidence.crossval import cross_validate
from labrig.diagnosis.loop.candidates import candidate_names, refinements
from labrig.diagnosis.evidence.criteria import (MIN_DBIC, MIN_GAIN, NEAR_FLOOR, PAIR_POOL, SIMPLER_MARGIN,
                                  SWAP_GAIN, bic, decide_ties, simpler_first)
from labrig.diagnosis.loop.diagnose import diagnose, linear_model
from labrig.diagnosis.evidence.evaluation import evaluate
from labrig.diagnosis.results.ladder import Ladder, LadderStep, rung_label
from labrig.core.parallel import each
from labrig.model.effects import CATALOGUE, get_effect
from labrig.model.model import Model, param_keys
from labrig.model.reach import Reach
from labrig.diagnosis.loop.refit import fresh_fit, refit, refit_with, without
from labrig.diagnosis.loop.moves import Move, SearchResult, Step, say
from labrig.diagnosis.evidence.resolution import unresolved

#: the catalogue's effects that set how much drive it takes to move (``Effect.pair_rank``,
#: in its order): their pairs are tried whenever no single effect earns its parameters and
#: the model still misses
THRESHOLD_FAMILY = tuple(sorted((n for n, c in CATALOGUE.items() if c.pair_rank is not None),
                                key=lambda n: CATALOGUE[n].pair_rank))
# a swap must lower the cross-validated error by SWAP_GAIN; a simpler family member may
# be SIMPLER_MARGIN worse (the step-by-step diagnose uses the same two, hence imported)
class _Judge:
    """Evaluates and cross-validates models on the first round's terms."""

    def __init__(self, runs, first, seed, fixed):
        self.runs, self.seed, self.fixed = runs, seed, fixed
        self.folds, self.sigmas = first.folds, first.evaluation.sigmas
        self.weights = first.evaluation.weights
        ev0 = first.evaluation
        self.n = ev0.n
        self.n_eff = ev0.n_effective
        self._cvs: dict = {}   # id(model) -> (model, CrossValidation): each computed once

    def evaluate(self, model):
        return evaluate(self.runs, model, self.sigmas, weights=self.weights)

    def cross_validation(self, model):
        """``model``'s cross-validation on the first round's terms, computed once."""
        known = self.known(model)
        if known is None:
            known = cross_validate(self.runs, model, self.folds, sigmas=self.sigmas,
                                   weights=self.weights, seed=self.seed, fixed=self.fixed,
                                   reach=Reach.of(self.runs, model))
            self.remember(model, known)
        return known

    def cv(self, model) -> float:
        return self.cross_validation(model).rmse

    def remember(self, model, cv) -> None:
        if cv is not None:
            self._cvs[id(model)] = (model, cv)

    def known(self, model):
        """``model``'s cross-validation when one was computed (by a round's ranking or
        here), else None."""
        hit = self._cvs.get(id(model))
        return hit[1] if hit is not None and hit[0] is model else None

    def bic(self, model, ev) -> float:
        k = len(param_keys(model)) - len(self.fixed)
        return bic(ev.wsse, self.n, self.n_eff, k)

    def unresolved(self, model, names) -> str | None:
        """Why one of ``names`` in ``model`` is below what the data resolve (one step of
        the input, a fraction of a sample); None when every one is resolved."""
        for n in names:
            why = unresolved(get_effect(n), model.effect_params[n], self.runs)
            if why:
                return why
        return None

    def add(self, model, name, carried=None):
        return refit_with(self.runs, model, get_effect(name), seed=self.seed, fixed=self.fixed,
                          weights=self.weights, carried=carried).model()

    def or_fresh(self, model, ev):
        """``model`` (evaluated ``ev``) or the same effects fitted from the identification's
        own starts, whichever fits better, with its evaluation: a pair warm-started from one
        of its members can stay in the basin that member's fit left it in."""
        other = fresh_fit(self.runs, model.effects, seed=self.seed, fixed=self.fixed,
                          weights=self.weights, reach=Reach.of(self.runs, model)).model()
        ev2 = self.evaluate(other)
        return (other, ev2) if ev2.fitness < ev.fitness else (model, ev)


def _pool(ranking) -> list:
    """The leading candidates, one per family: the simplest member unless a richer one
    gains MIN_GAIN more (an asymmetric dead zone only when it is clearly asymmetric)."""
    best: dict = {}
    for c in sorted(ranking, key=lambda c: len(get_effect(c.effect).params)):
        fam = get_effect(c.effect).family_name
        if fam not in best or c.improvement >= best[fam].improvement + MIN_GAIN:
            best[fam] = c
    return sorted(best.values(), key=lambda c: -c.improvement)[:PAIR_POOL]


def _pair(judge: _Judge, diag, log) -> Step | None:
    """The best pair of the leading candidates, when no single one is near the floor."""
    pool = _pool(diag.ranking)
    if not pool or min(c.rmse_over_noise for c in pool) <= NEAR_FLOOR:
        return None
    tried = []
    for i, a in enumerate(pool):
        for b in pool[i + 1:]:
            if b.effect not in candidate_names(a.model):
                continue  # two friction laws, two dead zones: not a pair
            m = judge.add(a.model, b.effect)
            ev = judge.evaluate(m)
            if ev.fitness > (1 - MIN_GAIN) * min(a.evaluation.fitness, b.evaluation.fitness):
                # no better than its members: b's fit from a's model stayed where a left
                # the plant; from b's model too (else the last digits say which pair gained)
                m2 = judge.add(b.model, a.effect)
                ev2 = judge.evaluate(m2)
                if ev2.fitness < ev.fitness:
                    m, ev = m2, ev2
            if judge.unresolved(m, [a.effect, b.effect]):
                continue
            tried.append((m, ev, [a.effect, b.effect]))
    if not tried:
        return None
    best = decide_ties(tried, lambda t: t[1].fitness, lambda t: simpler_first(t[2]))[0]
    m, ev = judge.or_fresh(best[0], best[1])
    say(log, f"  trying the pair {' + '.join(best[2])} (no single effect is near the floor)")
    return Step("pair", best[2], m, ev, judge.cv(m))


def _threshold_pair(judge: _Judge, model, cv_now: float, log) -> Step | None:
    """The best pair of :data:`THRESHOLD_FAMILY`, fitted together in place of the model's
    own members of that family (``replaced``), when it predicts held-out data clearly
    better (and BIC agrees), else None."""
    replaced = [e.name for e in model.effects if e.pair_rank is not None]
    reduced = model
    for n in replaced:
        reduced = without(reduced, n)
    # what a model can hold is candidate_names' rule (not one family, not two friction
    # laws); it reads only the effects, so the first member is added unfitted to ask it
    free = candidate_names(reduced, THRESHOLD_FAMILY, judge.runs)
    pairs = [(a, b) for a, b in combinations(free, 2) if {a, b} != set(replaced)
             and b in candidate_names(reduced.with_effect(get_effect(a), {}), [b])]
    if not pairs:
        return None
    firsts = sorted({a for a, _ in pairs}, key=free.index)
    one = dict(zip(firsts, each(lambda a: judge.add(reduced, a), firsts)))
    fits = each(lambda ab: judge.add(one[ab[0]], ab[1]), pairs)
    evs = each(judge.evaluate, fits)
    ok = [i for i, ab in enumerate(pairs) if not judge.unresolved(fits[i], list(ab))]
    if not ok:
        return None
    k = decide_ties(ok, lambda i: evs[i].fitness, lambda i: simpler_first(pairs[i]))[0]
    m, ev, names = fits[k], evs[k], list(pairs[k])
    if judge.bic(m, ev) - judge.bic(model, judge.evaluate(model)) >= MIN_DBIC:
        return None
    cv = judge.cv(m)
    say(log, f"  trying the pair {' + '.join(names)}"
              + (f" in place of {', '.join(replaced)}" if replaced else "")
              + f" (no single effect earns its parameters): cross-validated {cv_now:.2f} -> "
                f"{cv:.2f}")
    if cv >= (1 - MIN_GAIN) * cv_now:
        return None
    return Step("pair", names, m, ev, cv, replaced)


def search(runs, model: Model | None = None, *, max_rounds: int = 3, seed: int = 0,
           fixed: dict | None = None, weights=None, log=None, on_step=None,
           screen: bool = True, on_candidate=None) -> SearchResult:
    """Add, pair, swap and remove effects until the cross-validated error stops falling.

    ``on_step(k, model)`` is called for every rung (k = 0 is the starting model);
    ``on_candidate(candidate, cv)``: each round's candidates as they are re-fitted and
    cross-validated (:func:`~labrig.diagnosis.loop.diagnose.diagnose`'s);
    ``max_rounds`` bounds the number of effects added; ``screen``: as
    :func:`~labrig.diagnosis.loop.diagnose.diagnose`'s, in every round.
    """
    fixed = dict(fixed or {})
    rounds, moves = [], []
    diag = diagnose(runs, model, seed=seed, fixed=fixed, weights=weights, revise=False,
                    screen=screen, on_candidate=on_candidate)
    rounds.append(diag)
    judge = _Judge(runs, diag, seed, fixed)
    model = diag.base
    cv_now = diag.cv_baseline.rmse
    ladder = Ladder([LadderStep.of("linear model" if not model.names else "given model", model,
                                   diag.evaluation, cv=cv_now)])
    if on_step:
        model.info = {**(model.info or {}),
                      "rmse_over_noise": ladder.steps[0].rmse_over_noise, "cross_validated": cv_now}
        on_step(0, model)
    added = 0
    for k in range(1, max_rounds + 1):
        say(log, f"round {k}: {diag.verdict}")
        step = None
        if diag.recommendation:
            c = diag.candidate(diag.recommendation)
            judge.remember(c.model, c.held_out)
            step = Step("add", [c.effect], c.model, c.evaluation,
                        c.cross_validated["with_effect"])
        pair = _pair(judge, diag, log) if added + 2 <= max_rounds else None
        if pair is not None:
            single_cv = step.cv if step else cv_now
            dbic = judge.bic(pair.model, pair.evaluation) - judge.bic(
                step.model if step else model, step.evaluation if step else diag.evaluation)
            if pair.cv < (1 - MIN_GAIN) * single_cv and dbic < MIN_DBIC:
                step = pair
        if step is None and diag.evaluation.fitness > NEAR_FLOOR:
            found = _threshold_pair(judge, model, cv_now, log)
            if found is not None and added + 2 - len(found.replaced) <= max_rounds:
                step = found
        if step is None:
            break
        names, model, ev, cv, replaced = step.names, step.model, step.evaluation, step.cv, \
            step.replaced
        moves.append(Move(step.kind, names, cv_now, cv, k, replaces=replaced))
        cv_now = cv
        added += len(names) - len(replaced)
        ladder.steps.append(LadderStep.of(rung_label(model.names, ladder.steps[-1].effects),
                                          model, ev, cv=cv))
        if on_step:
            on_step(len(ladder.steps) - 1, model)
        model, cv_now = _revise(judge, model, names, cv_now, moves, ladder, k, log, on_step)
        if added >= max_rounds:
            break
        diag = diagnose(runs, model, seed=seed, fixed=fixed, weights=judge.weights,
                        folds=judge.folds, revise=False, screen=screen,
                        baseline_cv=judge.known(model), on_candidate=on_candidate)
        rounds.append(diag)
        if diag.base is not model:
            # the round's candidates found better values of the model's own parameters (a
            # run's start, a threshold's split): the same effects, better placed, are the
            # rung the next round climbs from and the answer if nothing more is added
            model, cv_now = diag.base, diag.cv_baseline.rmse
            say(log, f"  {' + '.join(model.names) or 'the model'} re-fitted where the "
                      f"candidates' fits found better values: held-out rmse/noise "
                      f"{ladder.steps[-1].cross_validated:.2f} -> {cv_now:.2f}")
            ladder.steps[-1] = LadderStep.of(ladder.steps[-1].label, model, diag.evaluation,
                                             cv=cv_now)
            judge.remember(model, diag.cv_baseline)
            if on_step:
                on_step(len(ladder.steps) - 1, model)
    return SearchResult(rounds=rounds, ladder=ladder, model=model, moves=moves)


def _revise(judge, model, new, cv_now, moves, ladder, k, log, on_step):
    """Simpler family members, swaps of earlier choices for look-alikes, then backward
    elimination."""
    for old in list(model.names):
        alt = get_effect(old).simpler or None
        if alt is None:
            continue
        m = judge.add(without(model, old), alt)
        cv = judge.cv(m)
        if cv <= (1 + SIMPLER_MARGIN) * cv_now:
            say(log, f"  {alt} instead of {old}: as good on held-out data ({cv_now:.2f} -> "
                      f"{cv:.2f}) with fewer parameters")
            moves.append(Move("swap", [old, alt], cv_now, cv, k))
            model, cv_now = m, cv
            _rung(ladder, model, judge, cv, on_step)
            new = [alt if n == old else n for n in new]
    for old, alt, start in refinements(model, judge.runs):
        # a refinement from where the simpler law was fitted: a parameter more, so it
        # must earn it as an addition does
        m = judge.add(without(model, old), alt, carried=start)
        cv = judge.cv(m)
        if cv < (1 - MIN_GAIN) * cv_now and not judge.unresolved(m, [alt]):
            say(log, f"  {alt} in place of {old}: cross-validated {cv_now:.2f} -> {cv:.2f}")
            moves.append(Move("swap", [old, alt], cv_now, cv, k))
            model, cv_now = m, cv
            _rung(ladder, model, judge, cv, on_step)
            new = [alt if n == old else n for n in new]
    for old in [n for n in model.names if n not in new]:
        for alt in get_effect(old).look_alikes:
            if alt in model.names:
                continue
            reduced = without(model, old)
            if alt not in candidate_names(reduced, runs=judge.runs):
                continue
            m = judge.add(reduced, alt)
            cv = judge.cv(m)
            if cv < (1 - SWAP_GAIN) * cv_now:
                say(log, f"  swap {old} -> {alt}: cross-validated {cv_now:.2f} -> {cv:.2f}")
                moves.append(Move("swap", [old, alt], cv_now, cv, k))
                model, cv_now = m, cv
                _rung(ladder, model, judge, cv, on_step)
                break
    if len(model.names) >= 2:
        for old in [n for n in model.names if n not in new]:
            m = refit(judge.runs, without(model, old), seed=judge.seed, fixed=judge.fixed,
                      weights=judge.weights).model()
            cv = judge.cv(m)
            # the mirror of adding: an effect stays when taking it out costs MIN_GAIN
            if cv < cv_now / (1 - MIN_GAIN):
                say(log, f"  remove {old}: cross-validated {cv_now:.2f} -> {cv:.2f} "
                          "without it")
                moves.append(Move("remove", [old], cv_now, cv, k))
                model, cv_now = m, cv
                _rung(ladder, model, judge, cv, on_step)
    return model, cv_now


def _rung(ladder, model, judge, cv, on_step):
    # the rung names its model's effects (a swap or removal drops one), not the move
    step = LadderStep.of(rung_label(model.names, ladder.steps[-1].effects), model,
                         judge.evaluate(model), cv=cv)
    ladder.steps.append(step)
    if on_step:   # the rung's errors ride along in the model's fit record
        model.info = {**(model.info or {}), "rmse_over_noise": step.rmse_over_noise,
                      "cross_validated": cv}
        on_step(len(ladder.steps) - 1, model)


def auto_ladder(runs, max_steps=3, outdir=None, seed=0, log=print) -> Ladder:
    """The ladder of :func:`search` from the linear model; each rung's model is saved as
    ``outdir/step<k>.json`` when ``outdir`` is given."""
    out = Path(outdir) if outdir else None
    paths: dict = {}

    def save(k, model):
        if out:
            path = out / f"step{k}.json"
            model.save(path)
            paths[k] = str(path)

    if max_steps < 1:  # no round: the linear model alone
        model = linear_model(runs, seed=seed)
        save(0, model)
        return Ladder([LadderStep.of("linear model", model, evaluate(runs, model), paths.get(0))])
    res = search(runs, max_rounds=max_steps, seed=seed, log=log, on_step=save)
    for k, step in enumerate(res.ladder.steps):
        step.model = paths.get(k)
    return res.ladder
