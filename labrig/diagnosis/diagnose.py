"""The missing-physics loop: where the model fails, which catalogue effect is missing,
and the evidence, in numbers and in words.

``diagnose(runs, model)``:

1. simulates the current model and locates its error by regime and amplitude against
   each channel's honest noise floor (``labrig.analysis.noise``), with the channels weighted so
   that neither drowns the other;
2. re-fits the model with every catalogue effect it lacks, from starts scanned over
   the range the data can see and in two basins of the electrical pole
   (``labrig.diagnosis.refit``), so no threshold starts on a plateau;
3. compares the candidates on equal terms: BIC with the sample count corrected for
   the colour of simulation residuals, and the error on data the fits did not see,
   by cross-validation (``labrig.diagnosis.crossval``: whole runs held out in turn, or blocks
   of a single long run), so an extra parameter cannot win by overfitting or by luck;
4. explains the winner: what it is in the rig, where its signature shows in these
   runs (the regimes that carry the held-out evidence), and the experiment that would
   confirm it. ``recommendation`` is None when nothing earns its parameters.
"""
from __future__ import annotations

import time

from labrig.core.parallel import each
from labrig.diagnosis.crossval import cross_validate, fold_evidence, make_folds
from labrig.diagnosis.resolution import unresolved
from labrig.diagnosis.ranking import Candidate, Diagnosis
from labrig.core.errors import FitDiverged, UserError
from labrig.diagnosis.evaluation import Evaluation, evaluate
from labrig.diagnosis.explain import context as explain_context, explain, round_verdict
from labrig.identification.engine import dataset_constants, identify
from labrig.identification.result import at_bounds as bound_sides
from labrig.model import drive_units
from labrig.diagnosis.candidates import candidate_names, refinements
# every threshold and rule of the decision (also under the names callers have used)
from labrig.diagnosis.criteria import (CV_CANDIDATES, FLOOR, MAX_REFINE, MIN_DBIC,  # noqa: F401
                                  MIN_GAIN, PARSIMONY, REFINE, SIMPLER_MARGIN, SWAP_GAIN, bic,
                                  score as _score, supported as _supported)
from labrig.model.effects import get_effect
from labrig.model.model import Model, param_keys
from labrig.model.reach import Reach
from labrig.analysis.agreement import WINDOW_DECLARED_IN
from labrig.analysis.noise import Weights
from labrig.diagnosis.refit import refit, refit_with, without
from labrig.diagnosis.residuals import worst_regime
from labrig.io.runs import require_excitation

def balanced_weights(ev: Evaluation, runs=None) -> Weights:
    """Channel weights that give each channel the same say at the starting model: each
    channel's squared error divided by its own mean square, normalised so the weights
    average to one over the samples (equal to p = q = 1 when both channels miss by the
    same factor, as on an analogue rig).

    With ``runs``, a position that drifts against the integral of the measured speed
    (:mod:`labrig.analysis.agreement`) is weighted by its drift as well as its noise:
    never more, in noise units, than the speed over ``1 + (drift/noise)^2``, so its
    wander cannot outweigh what the speed says; the weights then say so (``why``)."""
    r = ev.metrics["rmse_over_noise"]
    if "speed" not in r or "position" not in r:
        return Weights()
    q, p = 1.0 / max(r["speed"], 1.0) ** 2, 1.0 / max(r["position"], 1.0) ** 2
    why, decides = "", ""
    agree = agreement_of(runs, ev) if runs is not None else None
    if agree is not None and agree.drifts and p > q / agree.position_factor ** 2:
        p, decides = q / agree.position_factor ** 2, "speed"
        why = (f"the speed decides: {agree.describe()}, so the position is weighted by its "
               "drift as well as its noise")
    elif agree is not None and agree.lags and q > p / agree.speed_factor ** 2:
        q, decides = p / agree.speed_factor ** 2, "position"
        why = (f"the position decides: {agree.describe_lag()}; the speed is weighted by "
               f"its lag as well as its noise. Declare the window {WINDOW_DECLARED_IN} and it "
               "is modelled")
    n = ev.metrics.get("counts", {})
    nw, nt = n.get("speed", 1), n.get("position", 1)
    scale = (nw + nt) / (q * nw + p * nt)
    return Weights(p=p * scale, q=q * scale, why=why, decides=decides)


def agreement_of(runs, ev: Evaluation):
    """The position's agreement with the integral of the speed on ``runs``
    (:class:`labrig.analysis.agreement.ChannelAgreement`), with the noise floors of
    ``ev``; None without both channels."""
    from labrig.analysis.agreement import channel_agreement
    from labrig.model.simulate import prepare

    unit = ev.floors["position"].unit if "position" in ev.floors else "rad"
    speed_unit = ev.floors["speed"].unit if "speed" in ev.floors else "rad/s"
    return channel_agreement(prepare(runs), ev.sigmas[0], ev.sigmas[1], unit, speed_unit)


def at_bounds(ident) -> list[str]:
    """Effect parameters of a fit that ended at a bound of the search space, in words.

    The words name the side and the direction only: what a bound means differs by
    effect (a dead zone at its lower bound is absent, a rail at its upper one is)."""
    effects = getattr(ident, "effects", ())
    shown = drive_units.shown_keys(effects, ident.space.plant.kind,
                                   getattr(ident, "constants", {})) if effects else {}
    out = []
    for n, v, side, b in bound_sides(ident.space, ident.params):
        if "." not in n:
            continue
        n, f, _ = shown.get(n, (n, 1.0, ""))   # a torque drive's levels in N m
        out.append(f"{n} = {v * f:.3g} at the {side} bound {b * f:.3g} of its search range "
                   f"(the data may want a value {'below' if side == 'lower' else 'above'} it)")
    return out


def linear_model(runs, *, seed=0, fixed=None, weights=Weights(), start: Model | None = None) -> Model:
    """The model without effects, identified: CO from four starts (or from ``start``),
    then both basins of the electrical pole."""
    if start is None:
        ident = identify(runs, "co", [], seed=seed, starts=4, fixed=fixed, identifiability=False,
                         p=weights.p, q=weights.q)
        start = ident.model()
    else:
        ident = None
    again = refit(runs, start, seed=seed, fixed=fixed, weights=weights)
    return again.model() if ident is None else min([ident, again], key=lambda f: f.fitness).model()


def diagnose(runs, model: Model | None = None, *, candidates=None, seed: int = 0,
             fixed: dict | None = None, progress=None, weights: Weights | None = None,
             folds=None, revise: bool = True, _refined: int = 0) -> Diagnosis:
    """Locate the model's error and rank the missing effects.

    Parameters
    ----------
    runs : list of Run
    model : Model, optional
        The current model; default: the linear model identified here (CO).
    candidates : list of str, optional
        Catalogue names to try (default: every effect the model lacks).
    seed : int
    fixed : dict, optional
        Parameters known from other measurements.
    progress : callable(i, name), optional
    weights : Weights, optional
        Channel weights (default: balanced on the starting model).
    folds : Folds, optional
        Cross-validation folds (default: :func:`labrig.diagnosis.crossval.make_folds`).
    revise : bool
        With a model that has effects, also test removing each of them and replacing
        each by its look-alikes and simpler family members (default True; the search of
        ``--auto`` revises on its own).

    Returns
    -------
    Diagnosis
    """
    from labrig.model.warm import ready

    ready()  # a first compile is announced and kept out of the timing
    t0 = time.perf_counter()
    if not runs:
        raise UserError("the data set is empty: give a folder with at least one run")
    require_excitation(runs, "diagnose")
    fixed = dict(fixed or {})
    if model is None:
        base = linear_model(runs, seed=seed, fixed=fixed)
        base_source = "identified without effects (co)"
        if weights is None:
            weights = balanced_weights(evaluate(runs, base), runs)
            if weights != Weights():  # the linear fit again, on the balanced objective
                base = linear_model(runs, seed=seed, fixed=fixed, weights=weights, start=base)
    else:
        base = model
        base_source = "the given model"
    weights = weights or balanced_weights(evaluate(runs, base), runs)
    ev0 = evaluate(runs, base, weights=weights)
    sig = ev0.sigmas
    n = ev0.n
    n_eff = ev0.n_effective
    k0 = len(param_keys(base)) - len(fixed)
    bic0 = bic(ev0.wsse, n, n_eff, k0)
    f0 = ev0.fitness
    reach = Reach.of(runs, base)

    folds = folds or make_folds(runs)
    cv0 = cross_validate(runs, base, folds, sigmas=sig, weights=weights, seed=seed,
                         fixed=fixed, reach=reach)

    def entry(ident, effect, move="add", replaces=None, params=None) -> Candidate:
        cand = ident.model()
        ev = evaluate(runs, cand, sig, weights=weights)
        k = len(param_keys(cand)) - len(fixed)
        c = Candidate(effect=effect, rmse_over_noise=ev.rmse,
                      failed_starts=ident.failed_starts,
                      improvement=1.0 - ev.fitness / f0,
                      delta_bic=bic(ev.wsse, n, n_eff, k) - bic0,
                      params=dict(params if params is not None else cand.effect_params[effect]),
                      fit_percent=ev.metrics["fit_percent"], model=cand, evaluation=ev,
                      at_bound=at_bounds(ident), move=move, replaces=replaces,
                      extra_params=k - k0)
        if move != "remove":
            off = switched_off(cand, effect)
            if off is not None:
                c.off_fitness = evaluate(runs, off, sig, weights=weights).fitness
                c.carried = 1.0 - ev.fitness / max(c.off_fitness, 1e-300)
                if c.carried < MIN_GAIN:
                    c.unresolved = (f"switched off in the re-fitted model, {effect} costs "
                                    f"{100 * c.carried:.1f} % of the error: the gain is the rest "
                                    "of the model re-fitted, not the effect")
        return c

    def candidate(job):
        i, name = job
        if progress:
            progress(i, name)
        try:
            ident = refit_with(runs, base, get_effect(name), seed=seed, fixed=fixed,
                               weights=weights, reach=reach)
        except FitDiverged:
            return name   # every start diverged: said in the verdict, not ranked
        return entry(ident, name)

    # the candidates side by side (labrig.core.parallel), in the catalogue's order
    tried = each(candidate, enumerate(candidate_names(base, candidates, runs, ev0)))
    diverged = [c for c in tried if isinstance(c, str)]
    ranking: list[Candidate] = [c for c in tried if not isinstance(c, str)]
    if diverged and not ranking:
        raise FitDiverged(
            f"every candidate's re-fit diverged ({', '.join(diverged)}: the simulation "
            "overflowed from every start); start from a model nearer the data (labrig "
            "identify DATA -o m0.json, then --model m0.json) or narrow the plant's range "
            "with --bounds")
    # a candidate whose gain comes from re-fitting the rest of the model, not from its
    # effect, shows that the base was not converged: refine it and start again
    stale = [c for c in ranking if c.carried is not None and c.carried < MIN_GAIN
             and c.off_fitness < (1 - REFINE) * f0]
    if stale and _refined < MAX_REFINE:
        best = min(stale, key=lambda c: c.off_fitness)
        better = Model.from_flat({k: v for k, v in best.model.flat().items()
                                  if k in base.flat()}, base.effects, base.constants,
                                 plant=base.plant, info=dict(base.info or {}))
        better = refit(runs, better, seed=seed, fixed=fixed, weights=weights,
                       reach=reach).model()
        d = diagnose(runs, better, candidates=candidates, seed=seed, fixed=fixed,
                     progress=progress, weights=weights, folds=folds, revise=revise,
                     _refined=_refined + 1)
        d.baseline["source"] = (f"{base_source}, refined: the re-fits of its candidates "
                                "found better values of its own parameters (fitness "
                                f"{f0:.4g} -> {d.baseline['fitness']:.4g})")
        return d
    revisions = []
    if revise and base.names and candidates is None:
        revisions = _revisions(runs, base, entry, seed=seed, fixed=fixed, weights=weights)

    by_fit = sorted(ranking, key=lambda c: -c.improvement)
    to_cv = [c for c in by_fit if c.improvement >= MIN_GAIN][:CV_CANDIDATES]
    # (a simpler replacement is judged "about as good": cross-validated when its in-sample
    # fit is within that margin too)
    to_cv += [c for c in revisions if c.move == "remove" or c.improvement >= SWAP_GAIN
              or (c.extra_params < 0 and c.improvement >= -SIMPLER_MARGIN)]
    cvs = each(lambda c: cross_validate(runs, c.model, folds, sigmas=sig, weights=weights,
                                        seed=seed, fixed=fixed, reach=Reach.of(runs, c.model)),
               to_cv)
    for c, cv in zip(to_cv, cvs):
        c.cross_validated = fold_evidence(cv0, cv, c.model, None if c.move == "remove" else c.effect)
        c.unresolved = None if c.move == "remove" else c.unresolved or unresolved(
            get_effect(c.effect), c.params, runs, _fold_sizes(cv, c))
    ranking += revisions
    for c in ranking:
        c.supported = _supported(c)
    ranking.sort(key=lambda c: (c.cross_validated is None,
                                _score(c) if c.cross_validated else 0.0, c.delta_bic))
    supported = [c for c in ranking if c.supported]
    rec = supported[0].label if supported else None
    for c in ranking:
        c.explanation = explain(c, ev0, explain_context(c.model, runs))
    worst = worst_regime(ev0.regimes)
    regimes = {"by_regime": ev0.regimes["by_regime"], "by_amplitude": ev0.regimes["by_amplitude"],
               "worst": None if worst is None else {"channel": worst[0], "regime": worst[1],
                                                     "rmse_over_noise": worst[2]},
               "noise": ev0.metrics["noise"]}
    ripple = _ripple(ev0, runs) if rec is None and ev0.rmse > FLOOR else None
    verdict = round_verdict(supported, ev0, weights, ripple, diverged, base.starts)
    return Diagnosis(
        diverged=diverged,
        baseline={"source": base_source, "effects": base.names,
                  "fitness": ev0.metrics["fitness"],
                  "rmse_over_noise": ev0.metrics["rmse_over_noise"],
                  "fit_percent": ev0.metrics["fit_percent"], "bic": bic0,
                  "n": n, "n_effective": n_eff, "cross_validated": cv0.rmse,
                  **({"starts": base.starts} if base.starts else {})},
        regimes=regimes, ranking=ranking, recommendation=rec, verdict=verdict,
        cross_validation={"kind": folds.kind, "folds": len(folds.folds),
                          "baseline": cv0.rmse, "channels": cv0.channels},
        noise={ch: f.to_json() for ch, f in ev0.floors.items()},
        weights=weights.to_json(),
        criteria={"min_improvement": MIN_GAIN, "max_delta_bic": MIN_DBIC, "floor": FLOOR},
        seconds=round(time.perf_counter() - t0, 2), base=base, evaluation=ev0,
        constants=dataset_constants(runs), dataset=[r.name for r in runs], folds=folds,
        cv_baseline=cv0)


def _ripple(ev: Evaluation, runs):
    """A line locked to the shaft in the speed residual (:mod:`labrig.analysis.ripple`)."""
    from labrig.analysis.ripple import ripple_line
    from labrig.model.simulate import prepare

    return ripple_line(ev.per_run, prepare(runs))


def _revisions(runs, base: Model, entry, *, seed, fixed, weights) -> list[Candidate]:
    """``base`` without each of its effects, and with each replaced by its simpler family
    member and its look-alikes, re-fitted."""
    out = []
    for old in base.names:
        reduced = without(base, old)
        out.append(entry(refit(runs, reduced, seed=seed, fixed=fixed, weights=weights), old,
                         move="remove", params=base.effect_params[old]))
        eff = get_effect(old)
        for new in dict.fromkeys(([eff.simpler] if eff.simpler else []) + list(eff.look_alikes)):
            if new in base.names or new not in candidate_names(reduced, runs=runs):
                continue
            out.append(entry(refit_with(runs, reduced, get_effect(new), seed=seed, fixed=fixed,
                                        weights=weights, carried=base.effect_params[old]),
                             new, move="replace", replaces=old))
    for old, new, start in refinements(base, runs):   # a refinement, from where old was fitted
        out.append(entry(refit_with(runs, without(base, old), get_effect(new), seed=seed,
                                    fixed=fixed, weights=weights, carried=start),
                         new, move="replace", replaces=old))
    return out


def switched_off(model: Model, effect: str) -> Model | None:
    """``model`` with ``effect`` made inert (:meth:`Effect.inert`), the rest unchanged;
    None when the effect does not say how."""
    off = get_effect(effect).inert()
    if not off:
        return None
    flat = {**model.flat(), **{f"{effect}.{k}": v for k, v in off.items()}}
    return Model.from_flat(flat, model.effects, model.constants, plant=model.plant)


def _fold_sizes(cv, c: Candidate) -> list:
    """The effect's size in the folds that pin it (for the jackknife of its interval)."""
    size = get_effect(c.effect).size
    skip = {d["fold"] for d in (c.cross_validated or {}).get("not_counted", [])}
    return [p.get(f"{c.effect}.{size}", float("nan")) for j, p in enumerate(cv.fold_params)
            if size and j + 1 not in skip]
