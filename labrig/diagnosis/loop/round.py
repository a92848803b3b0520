"""One diagnosis round as an object (scipy's solver shape): its state — the runs, the
base model, how it is judged (noise floors, channel weights, folds, its own BIC and
held-out error) — set once by :meth:`Round.start`, then its jobs as methods: each
candidate re-fitted and entered (:meth:`Round.candidates`), a base that its candidates'
re-fits show unconverged refined into a new round (:meth:`Round.refined`), the
revisions of the effects it has (:meth:`Round.revisions`), the leaders cross-validated
and ranked (:meth:`Round.rank`) and the result (:meth:`Round.result`). The criteria
live in :mod:`labrig.diagnosis.evidence.criteria`, the words in :mod:`labrig.diagnosis.words.explain`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

from labrig.analysis.noise import Weights
from labrig.core.errors import FitDiverged, UserError
from labrig.core.parallel import each
from labrig.diagnosis.loop.baseline import at_bounds, balanced_weights, linear_model
from labrig.diagnosis.loop.candidates import candidate_names, refinements
from labrig.diagnosis.evidence.criteria import (CV_CANDIDATES, FLOOR, MIN_DBIC, MIN_GAIN, REFINE,
                                       SCREEN_AFTER, SIMPLER_MARGIN, SWAP_GAIN, UNDECIDED, bic,
                                       candidate_order, out_of_reach, score, screen, supported)
from labrig.diagnosis.evidence.crossval import CrossValidation, Folds, cross_validate, fold_evidence, \
    make_folds
from labrig.diagnosis.evidence.evaluation import Evaluation, evaluate
from labrig.diagnosis.words.explain import context as explain_context, explain, round_verdict
from labrig.diagnosis.results.diagnosis import Candidate, Diagnosis
from labrig.diagnosis.loop.refit import (refit, refit_as_member, refit_with, thinned_fitness,
                                    without)
from labrig.diagnosis.evidence.residuals import worst_regime
from labrig.diagnosis.evidence.resolution import unresolved
from labrig.identification.problem import dataset_constants
from labrig.io.runs import require_excitation
from labrig.model.effects import get_effect
from labrig.model.model import Model, param_keys
from labrig.model.reach import Reach
from labrig.analysis.ripple import ripple_line
from labrig.model.simulate import prepare

#: a nested pair's simpler member this much worse (fitness) than the richer one is fitted
#: from the richer one's result too (:meth:`Round.nested`)
NESTED_MARGIN = 0.02
#: turns of fitting a nested pair's members each from the other, while a turn gains
NESTED_TURNS = 3


@dataclass
class Round:
    """A round's state: everything a candidate is judged against.

    Attributes
    ----------
    runs, base : the data and the model the round starts from
    source : how ``base`` came to be, in words
    seed, fixed, weights, folds : as :func:`labrig.diagnosis.loop.diagnose.diagnose` takes them
    ev0 : the base's evaluation (noise floors ``ev0.sigmas``, samples, effective samples)
    bic0, cv0 : the base's BIC and held-out error
    reach : what the data reach (the re-fits' bounds and scans)
    """

    runs: list
    base: Model
    source: str
    seed: int
    fixed: dict
    weights: Weights
    folds: Folds
    ev0: Evaluation
    bic0: float
    cv0: CrossValidation
    reach: Reach
    t0: float = field(default_factory=time.perf_counter)

    # -- the start -------------------------------------------------------------------
    @classmethod
    def start(cls, runs, model: Model | None = None, *, seed: int = 0,
              fixed: dict | None = None, weights: Weights | None = None, folds=None,
              t0: float | None = None, baseline_cv: CrossValidation | None = None) -> "Round":
        """The round on ``model`` (default: the linear model identified here, on channel
        weights balanced on it). ``baseline_cv``: ``model``'s cross-validation on these
        ``folds``, ``weights``, ``seed`` and ``fixed`` when it is known already (the last
        round's, for the model it recommended): not computed again."""
        if not runs:
            raise UserError("the data set is empty: give a folder with at least one run")
        require_excitation(runs, "diagnose")
        fixed = dict(fixed or {})
        if model is None:
            base = linear_model(runs, seed=seed, fixed=fixed)
            source = "identified without effects (co)"
            if weights is None:
                weights = balanced_weights(evaluate(runs, base), runs)
                if weights != Weights():  # the linear fit again, on the balanced objective
                    base = linear_model(runs, seed=seed, fixed=fixed, weights=weights,
                                        start=base)
        else:
            base, source = model, "the given model"
        weights = weights or balanced_weights(evaluate(runs, base), runs)
        ev0 = evaluate(runs, base, weights=weights)
        bic0 = bic(ev0.wsse, ev0.n, ev0.n_effective, len(param_keys(base)) - len(fixed))
        reach = Reach.of(runs, base)
        folds = folds or make_folds(runs)
        cv0 = baseline_cv if baseline_cv is not None and model is not None else \
            cross_validate(runs, base, folds, sigmas=ev0.sigmas, weights=weights, seed=seed,
                           fixed=fixed, reach=reach)
        return cls(runs, base, source, seed, fixed, weights, folds, ev0, bic0, cv0, reach,
                   t0=time.perf_counter() if t0 is None else t0)

    @property
    def f0(self) -> float:
        return self.ev0.fitness

    @property
    def k0(self) -> int:
        return len(param_keys(self.base)) - len(self.fixed)

    # -- the candidates --------------------------------------------------------------
    def entry(self, ident, effect: str, move: str = "add", replaces=None,
              params=None) -> Candidate:
        """A re-fit (:class:`~labrig.identification.fit.Identification`) as a ranked
        candidate: its error, gain and BIC against the base, and whether the effect
        itself carries the gain (the effect switched off in the re-fitted model)."""
        cand = ident.model()
        ev = evaluate(self.runs, cand, self.ev0.sigmas, weights=self.weights)
        k = len(param_keys(cand)) - len(self.fixed)
        c = Candidate(effect=effect, rmse_over_noise=ev.rmse,
                      failed_starts=ident.failed_starts,
                      improvement=1.0 - ev.fitness / self.f0,
                      delta_bic=bic(ev.wsse, self.ev0.n, self.ev0.n_effective, k) - self.bic0,
                      params=dict(params if params is not None else cand.effect_params[effect]),
                      fit_percent=ev.metrics["fit_percent"], model=cand, evaluation=ev,
                      at_bound=at_bounds(ident), move=move, replaces=replaces,
                      extra_params=k - self.k0)
        if ident.stopped:   # screened out: never cross-validated, nothing more to ask
            c.screened = SCREEN_AFTER
            return c
        if move != "remove":
            off = switched_off(cand, effect)
            if off is not None:
                c.off_fitness = evaluate(self.runs, off, self.ev0.sigmas,
                                         weights=self.weights).fitness
                c.carried = 1.0 - ev.fitness / max(c.off_fitness, 1e-300)
                if c.carried < MIN_GAIN:
                    c.unresolved = (f"switched off in the re-fitted model, {effect} costs "
                                    f"{100 * c.carried:.1f} % of the error: the gain is the rest "
                                    "of the model re-fitted, not the effect")
        return c

    def candidates(self, names=None, progress=None, on_candidate=None,
                   screen_out: bool = True) -> tuple[list[Candidate], list[str]]:
        """Every effect the base could take (or ``names``), re-fitted side by side
        (:mod:`labrig.core.parallel`) in the catalogue's order: ``(ranked, diverged)``,
        the second naming those whose every start diverged. With ``screen_out``, a re-fit
        that stalls without gaining is ended early (:func:`~labrig.diagnosis.evidence.criteria.screen`).
        ``progress(i, name)`` hears each re-fit start, ``on_candidate(candidate, None)``
        each one done."""
        rule = screen(thinned_fitness(self.runs, self.base, self.fixed, self.weights, self.reach),
                      self.ev0.n_effective) if screen_out else None

        def one(job):
            i, name = job
            if progress:
                progress(i, name)
            try:
                ident = refit_with(self.runs, self.base, get_effect(name), seed=self.seed,
                                   fixed=self.fixed, weights=self.weights, reach=self.reach,
                                   stop=rule)
            except FitDiverged:
                return name   # every start diverged: said in the verdict, not ranked
            c = self.entry(ident, name)
            if on_candidate:
                on_candidate(c, None)
            return c

        tried = each(one, enumerate(candidate_names(self.base, names, self.runs, self.ev0)))
        diverged = [c for c in tried if isinstance(c, str)]
        ranking = self.nested([c for c in tried if not isinstance(c, str)], on_candidate)
        if diverged and not ranking:
            raise FitDiverged(
                f"every candidate's re-fit diverged ({', '.join(diverged)}: the simulation "
                "overflowed from every start); start from a model nearer the data (labrig "
                "identify DATA -o m0.json, then --model m0.json) or narrow the plant's range "
                "with `bounds`")
        return ranking, diverged

    def nested(self, ranking: list[Candidate], on_candidate=None) -> list[Candidate]:
        """``ranking`` with each nested pair (an effect and its :attr:`simpler` family
        member, stiction and Coulomb friction, say) fitted each from the other's result
        too (:func:`~labrig.diagnosis.loop.refit.refit_as_member`), the better kept: the richer
        when it explains the runs worse than the one it contains, the simpler when it is
        more than :data:`NESTED_MARGIN` worse than the richer. Each fitted from its own
        scan alone, the two can end in different basins, and the seed would decide between
        near equals. ``on_candidate(candidate, None)`` hears each one that takes the place
        of its own re-fit (a page listing the re-fits as they come ends with the kept one)."""
        by = {c.effect: c for c in ranking}

        def one(job):
            name, other = job
            try:
                ident = refit_as_member(self.runs, self.base, get_effect(name), by[other].model,
                                        other, seed=self.seed, fixed=self.fixed,
                                        weights=self.weights, reach=self.reach)
            except FitDiverged:
                return None
            return None if ident is None else self.entry(ident, name)

        # in turns while one gains: a richer member fitted from the simpler can end well
        # below it, and then the simpler is fitted from the richer's new result (a job
        # whose source has not changed since it was tried would give what it gave then)
        tried = set()
        for _ in range(NESTED_TURNS):
            changed = False
            jobs = []
            for rich in list(by):
                simple = get_effect(rich).simpler
                if simple not in by:
                    continue
                fr, fs = by[rich].evaluation.fitness, by[simple].evaluation.fitness
                if fr > fs:
                    jobs.append((rich, simple))
                elif fs > (1.0 + NESTED_MARGIN) * fr:
                    jobs.append((simple, rich))
            jobs = [j for j in jobs if (j, id(by[j[1]])) not in tried]
            tried.update((j, id(by[j[1]])) for j in jobs)
            for (name, _), c in zip(jobs, each(one, jobs)):
                if c is not None and c.evaluation.fitness < by[name].evaluation.fitness:
                    by[name], changed = c, True
                    if on_candidate:
                        on_candidate(c, None)
            if not changed:
                break
        return [by[c.effect] for c in ranking]

    def stale(self, ranking) -> Candidate | None:
        """A candidate whose re-fit, with its effect switched off, explains the runs better
        than the base: the base was not converged (its own parameters have better values,
        whether or not the effect carries a gain of its own), the best such; None when
        there is none."""
        stale = [c for c in ranking if c.off_fitness is not None
                 and c.off_fitness < (1 - REFINE) * self.f0]
        return min(stale, key=lambda c: c.off_fitness) if stale else None

    def refined(self, best: Candidate) -> "Round":
        """A new round on the base with its own parameters where ``best``'s re-fit found
        them better, re-fitted (same weights, folds and seed)."""
        better = refit(self.runs, self.base.values_from(best.model), seed=self.seed, fixed=self.fixed,
                       weights=self.weights, reach=self.reach).model()
        return Round.start(self.runs, better, seed=self.seed, fixed=self.fixed,
                           weights=self.weights, folds=self.folds, t0=self.t0)

    def revisions(self) -> list[Candidate]:
        """The base without each of its effects, with each replaced by its simpler family
        member and its look-alikes, and by its refinements (from where it was fitted),
        re-fitted."""
        runs, base, kw = self.runs, self.base, dict(seed=self.seed, fixed=self.fixed,
                                                    weights=self.weights)
        out = []
        for old in base.names:
            reduced = without(base, old)
            out.append(self.entry(refit(runs, reduced, **kw), old, move="remove",
                                  params=base.effect_params[old]))
            eff = get_effect(old)
            for new in dict.fromkeys(([eff.simpler] if eff.simpler else [])
                                     + list(eff.look_alikes)):
                if new in base.names or new not in candidate_names(reduced, runs=runs):
                    continue
                out.append(self.entry(refit_with(runs, reduced, get_effect(new),
                                                 carried=base.effect_params[old], **kw),
                                      new, move="replace", replaces=old))
        for old, new, start in refinements(base, runs):   # from where old was fitted
            out.append(self.entry(refit_with(runs, without(base, old), get_effect(new),
                                             carried=start, **kw),
                                  new, move="replace", replaces=old))
        return out

    # -- the ranking -----------------------------------------------------------------
    def rank(self, ranking: list[Candidate], revisions: list[Candidate],
             on_candidate=None) -> list[Candidate]:
        """The leaders cross-validated (the largest gains; every removal, and each
        replacement that gains or, simpler, fits about as well), each judged by the
        criteria, best first; ``on_candidate(candidate, held_out_rmse)`` hears each
        cross-validation done."""
        by_fit = sorted(ranking, key=lambda c: -c.improvement)
        adds = [c for c in by_fit if c.improvement >= MIN_GAIN][:CV_CANDIDATES]
        # (a simpler replacement is judged "about as good": cross-validated when its
        # in-sample fit is within that margin too)
        first = adds[:1] + [c for c in revisions if c.move == "remove" or c.improvement >= SWAP_GAIN
                            or (c.extra_params < 0 and c.improvement >= -SIMPLER_MARGIN)]
        def held_out(c):
            cv = cross_validate(self.runs, c.model, self.folds, sigmas=self.ev0.sigmas,
                                weights=self.weights, seed=self.seed, fixed=self.fixed,
                                reach=Reach.of(self.runs, c.model))
            if on_candidate:
                on_candidate(c, cv.rmse)
            return cv

        def judged(batch):
            for c, cv in zip(batch, each(held_out, batch)):
                c.held_out = cv
                c.cross_validated = fold_evidence(self.cv0, cv, c.model,
                                                  None if c.move == "remove" else c.effect)
                c.unresolved = None if c.move == "remove" else c.unresolved or unresolved(
                    get_effect(c.effect), c.params, self.runs, _fold_sizes(cv, c))
            return [score(c) for c in batch if supported(c)]

        # the in-sample leader and the revisions first; the other leaders only where they
        # can come near the best supported one (criteria.out_of_reach)
        best = min(judged(first), default=None)
        for c in adds[1:]:
            c.out_of_reach = best if best is not None and out_of_reach(c, best) else None
        judged([c for c in adds[1:] if c.out_of_reach is None])
        ranking = ranking + revisions
        for c in ranking:
            c.supported = supported(c)
        ranking.sort(key=lambda c: (c.cross_validated is None,
                                    score(c) if c.cross_validated else 0.0, c.delta_bic))
        # supported moves the held-out data do not tell apart: the simpler first, by the
        # stated rule (the recommendation must not be the seed's)
        good = [c for c in ranking if c.supported]
        near = [c for c in good if score(c) <= (1 + UNDECIDED) * score(good[0])]
        lead = sorted(near, key=candidate_order)   # (near: already within UNDECIDED)
        return lead + [c for c in ranking if c not in lead]

    def result(self, ranking: list[Candidate], diverged: list[str],
               refined_from: "Round | None" = None) -> Diagnosis:
        """The round's :class:`~labrig.diagnosis.results.diagnosis.Diagnosis`, with its words;
        ``refined_from``: the round on the given model, when this one is on its
        re-fit (:meth:`refined`)."""
        runs, ev0, base, weights = self.runs, self.ev0, self.base, self.weights
        source = self.source
        if refined_from is not None:
            source = (f"{refined_from.source}, refined: the re-fits of its candidates found "
                      f"better values of its own parameters (fitness {refined_from.f0:.4g} "
                      f"-> {self.f0:.4g})")
        good = [c for c in ranking if c.supported]
        rec = good[0].label if good else None
        for c in ranking:
            c.explanation = explain(c, ev0, explain_context(c.model, runs))
        worst = worst_regime(ev0.regimes)
        regimes = {"by_regime": ev0.regimes["by_regime"],
                   "by_amplitude": ev0.regimes["by_amplitude"],
                   "worst": None if worst is None else {"channel": worst[0], "regime": worst[1],
                                                         "rmse_over_noise": worst[2]},
                   "noise": ev0.metrics["noise"]}
        ripple = _ripple(ev0, runs) if rec is None and ev0.rmse > FLOOR else None
        verdict = round_verdict(good, ev0, weights, ripple, diverged, base.starts)
        if refined_from is not None and rec is None:
            # the same effects, better placed: the model to keep (--auto goes on from it)
            verdict += (" The model's own parameters were re-fitted to better values "
                        f"(rmse/noise {refined_from.ev0.rmse:.2f} -> {ev0.rmse:.2f}): the re-fitted "
                        "model is this round's answer.")
        return Diagnosis(
            diverged=diverged,
            baseline={"source": source, "effects": base.names,
                      "fitness": ev0.metrics["fitness"],
                      "rmse_over_noise": ev0.metrics["rmse_over_noise"],
                      "fit_percent": ev0.metrics["fit_percent"], "bic": self.bic0,
                      "n": ev0.n, "n_effective": ev0.n_effective,
                      "cross_validated": self.cv0.rmse,
                      **({"starts": base.starts} if base.starts else {})},
            regimes=regimes, ranking=ranking, recommendation=rec, verdict=verdict,
            cross_validation={"kind": self.folds.kind, "folds": len(self.folds.folds),
                              "baseline": self.cv0.rmse, "channels": self.cv0.channels},
            noise={ch: f.to_json() for ch, f in ev0.floors.items()},
            weights=weights.to_json(),
            criteria={"min_improvement": MIN_GAIN, "max_delta_bic": MIN_DBIC, "floor": FLOOR},
            seconds=round(time.perf_counter() - self.t0, 2), base=base, evaluation=ev0,
            constants=dataset_constants(runs), dataset=[r.name for r in runs],
            folds=self.folds, cv_baseline=self.cv0, refined=refined_from is not None)


def switched_off(model: Model, effect: str) -> Model | None:
    """``model`` with ``effect`` made inert (:meth:`Effect.inert`), the rest unchanged;
    None when the effect does not say how."""
    off = get_effect(effect).inert()
    return model.with_params(effect, **off) if off else None


def _ripple(ev: Evaluation, runs):
    """A line locked to the shaft in the speed residual (:mod:`labrig.analysis.ripple`)."""
    return ripple_line(ev.per_run, prepare(runs))


def _fold_sizes(cv, c: Candidate) -> list:
    """The effect's size in the folds that pin it (for the jackknife of its interval)."""
    size = get_effect(c.effect).size
    skip = {d["fold"] for d in (c.cross_validated or {}).get("not_counted", [])}
    return [p.get(f"{c.effect}.{size}", float("nan")) for j, p in enumerate(cv.fold_params)
            if size and j + 1 not in skip]
