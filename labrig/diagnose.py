"""The missing-physics loop: where the model fails, which catalogue effect is missing,
and the evidence, in numbers and in words.

``diagnose(runs, model)``:

1. simulates the current model and locates its error by regime and amplitude against
   the noise floor (``labrig.residuals``);
2. re-fits the model with every catalogue effect it lacks, warm-started from the
   current model (the new effect's parameters first, then all of them);
3. compares the candidates on equal terms: BIC with the sample count corrected for
   the colour of simulation residuals, and the error on a held-out run that none of
   the fits saw, so an extra parameter cannot win by overfitting;
4. explains the winner: what it is in the rig, where its signature shows in these
   runs, and the experiment that would confirm it. ``recommendation`` is None when
   nothing earns its parameters.
"""
from __future__ import annotations

import math
import time

from .diagnosis import Candidate, Diagnosis
from .errors import UserError
from .evaluation import Evaluation, evaluate
from .identify.engine import dataset_constants, identify
from .model.effects import CATALOGUE, get_effect
from .model.model import Model, param_keys
from .residuals import REGIME_TEXT, worst_regime
from .runs import require_excitation

#: a candidate must beat the model by this much (relative) on all runs and on held-out runs
MIN_GAIN = 0.05
#: and be strongly supported by BIC (Kass & Raftery: |dBIC| > 10 is "very strong")
MIN_DBIC = -10.0
#: below this rmse/noise the model is at the noise floor (simulation residuals are
#: slightly coloured even for the right model; docs/physics.md, "The noise floor")
FLOOR = 1.15


def _fit(runs, effects, start, fixed, starts, seed, max_nfev=60):
    return identify(runs, "co", effects, seed=seed, start=start, fixed=fixed, starts=starts,
                    identifiability=False, max_nfev=max_nfev)


def _plateau_starts(params: dict, runs) -> list[dict]:
    """The start itself, plus one with the electrical pole moved onto the sample period
    when it sits far below it: there tau_e has no gradient and a local optimiser cannot
    climb off the plateau, even when the data do see the pole."""
    starts = [params]
    dt = min(r.dt for r in runs)
    if params["L"] / params["R"] < 0.1 * dt:
        starts.append({**params, "L": params["R"] * dt})
    return starts


def _fit_from(runs, effects, start, fixed, seed):
    """CO from ``start`` (and its plateau-escape twin); the better fit wins."""
    fits = [_fit(runs, effects, s, fixed, starts=1, seed=seed)
            for s in _plateau_starts(start, runs) if "L" not in fixed]
    if not fits:
        fits = [_fit(runs, effects, start, fixed, starts=1, seed=seed)]
    return min(fits, key=lambda f: f.fitness)


def refit_with(runs, base: Model, effect, seed=0, user_fixed=None) -> Model:
    """Warm-started re-fit: the new effect's parameters first (all else fixed at the
    current model), then every parameter from there."""
    effects = base.effects + [effect]
    fixed = base.flat()
    fixed.update(user_fixed or {})
    stage1 = _fit(runs, effects, base.flat(), fixed, starts=3, seed=seed)
    stage2 = _fit_from(runs, effects, stage1.params, dict(user_fixed or {}), seed)
    best = stage2 if stage2.fitness <= stage1.fitness else stage1
    return best.model()


def _held_out_split(runs):
    """Hold out the middle-amplitude open-loop run (an interpolation test) when there are
    at least three; otherwise no split (BIC alone decides, and the report says so)."""
    open_runs = sorted([r for r in runs if r.loop == "open"], key=lambda r: r.amplitude)
    if len(open_runs) < 3:
        return runs, []
    held = [open_runs[len(open_runs) // 2]]
    return [r for r in runs if r not in held], held


def _bic(sse, n, n_eff, k):
    return n_eff * math.log(max(sse, 1e-300) / n) + k * math.log(n_eff)


def diagnose(runs, model: Model | None = None, *, candidates=None, seed: int = 0,
             fixed: dict | None = None, progress=None) -> Diagnosis:
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

    Returns
    -------
    Diagnosis
    """
    t0 = time.perf_counter()
    if not runs:
        raise UserError("the data set is empty: give a folder with at least one run")
    require_excitation(runs, "diagnose")
    if model is None:
        ident = identify(runs, "co", [], seed=seed, starts=4, fixed=fixed, identifiability=False)
        ident = min([ident, _fit_from(runs, [], ident.params, dict(fixed or {}), seed)],
                    key=lambda f: f.fitness)
        base = ident.model()
        base_source = "identified without effects (co)"
    else:
        base = model
        base_source = "the given model"
    ev0 = evaluate(runs, base)
    sig = ev0.sigmas
    n = ev0.n
    rho = min(max(ev0.rho1, 0.0), 0.995)
    n_eff = max(n * (1 - rho) / (1 + rho), 10.0)
    k0 = len(param_keys(base)) - len(fixed or {})
    bic0 = _bic(ev0.sse, n, n_eff, k0)
    rmse0 = ev0.rmse

    train, held = _held_out_split(runs)
    if held:
        fit = _fit_from(train, base.effects, base.flat(), dict(fixed or {}), seed)
        held0 = evaluate(held, fit.model(), sig).rmse

    names = candidates or [n_ for n_ in CATALOGUE if n_ not in base.names]
    taken = {e.stage for e in base.effects if e.stage in ("friction", "output", "delay")}
    ranking: list[Candidate] = []
    for i, name in enumerate(names):
        eff = get_effect(name)
        if eff.stage in taken:
            continue  # one friction law, one output map, one delay per model
        if progress:
            progress(i, name)
        cand = refit_with(runs, base, eff, seed=seed, user_fixed=fixed)
        ev = evaluate(runs, cand, sig)
        bic = _bic(ev.sse, n, n_eff, k0 + len(eff.params))
        entry = Candidate(effect=name, rmse_over_noise=ev.rmse, improvement=1.0 - ev.rmse / rmse0,
                          delta_bic=bic - bic0, params=dict(cand.effect_params[name]),
                          fit_percent=ev.metrics["fit_percent"], model=cand, evaluation=ev)
        if held:
            fit = _fit_from(train, cand.effects, cand.flat(), dict(fixed or {}), seed)
            held1 = evaluate(held, fit.model(), sig).rmse
            entry.held_out = {"runs": [r.name for r in held], "baseline": held0,
                              "with_effect": held1, "improvement": 1.0 - held1 / held0}
        ranking.append(entry)
    ranking.sort(key=lambda e: e.delta_bic)
    const = dict(dataset_constants(runs),
                 amin=min([r.amplitude for r in runs if r.loop == "open"] or [1.0]))
    at_floor = rmse0 <= FLOOR
    for e in ranking:
        ho = e.held_out
        e.supported = bool(not at_floor and e.delta_bic < MIN_DBIC and e.improvement >= MIN_GAIN
                           and (ho is None or ho["improvement"] >= MIN_GAIN))
        e.explanation = explain(e, ev0, rmse0, const)
    supported = [e for e in ranking if e.supported]
    rec = supported[0].effect if supported else None
    worst = worst_regime(ev0.regimes)
    regimes = {"by_regime": ev0.regimes["by_regime"], "by_amplitude": ev0.regimes["by_amplitude"],
               "worst": None if worst is None else {"channel": worst[0], "regime": worst[1],
                                                     "rmse_over_noise": worst[2]},
               "noise": ev0.metrics["noise"]}
    if at_floor:
        verdict = (f"The model is at the noise floor (rmse/noise {rmse0:.2f} <= {FLOOR}): "
                   "nothing is missing that these data can show.")
    elif rec is None:
        verdict = (f"The model misses (rmse/noise {rmse0:.2f}) but no catalogue effect earns its "
                   "parameters on BIC and held-out data; the cause may be outside the catalogue "
                   "(write your own effect: docs/physics.md, 'Writing your own effect') or "
                   "in the sensors' calibration.")
    else:
        verdict = f"Add {rec}: " + supported[0].explanation
    return Diagnosis(
        baseline={"source": base_source, "effects": base.names,
                  "fitness": ev0.metrics["fitness"],
                  "rmse_over_noise": ev0.metrics["rmse_over_noise"],
                  "fit_percent": ev0.metrics["fit_percent"], "bic": bic0,
                  "n": n, "n_effective": n_eff},
        regimes=regimes, ranking=ranking, recommendation=rec, verdict=verdict,
        held_out=[r.name for r in held] if held else None,
        criteria={"min_improvement": MIN_GAIN, "max_delta_bic": MIN_DBIC, "floor": FLOOR},
        seconds=round(time.perf_counter() - t0, 2), base=base, evaluation=ev0,
        constants=dataset_constants(runs), dataset=[r.name for r in runs])


def explain(entry: Candidate, ev0: Evaluation, rmse0: float, const: dict) -> str:
    """Plain words with numbers: what, where in these runs, how much, how to confirm."""
    eff = entry.model.effects.by_name(entry.effect)
    # the regime where this candidate removes the most error
    gains = []
    for ch, regs in ev0.regimes["by_regime"].items():
        for reg, v in regs.items():
            new = entry.regimes["by_regime"].get(ch, {}).get(reg)
            if new and v["share_of_time"] > 0.005:
                gains.append((v["rmse_over_noise"] - new["rmse_over_noise"], ch, reg,
                              v["rmse_over_noise"], new["rmse_over_noise"]))
    gains.sort(reverse=True)
    where = ""
    if gains and gains[0][0] > 0:
        _, ch, reg, a, b = gains[0]
        where = f" Its signature is in the {REGIME_TEXT[reg]} stretches of the {ch}: rmse/noise {a:.2f} -> {b:.2f}."
    ho = entry.held_out
    held = (f" On the held-out run {', '.join(ho['runs'])}: {ho['baseline']:.2f} -> {ho['with_effect']:.2f}."
            if ho else " (No held-out run: fewer than three open-loop amplitudes.)")
    verdict = ("It earns its parameters." if entry.supported else
               "It does not earn its parameters on these data.")
    return (f"{eff.summary[0].upper()}{eff.summary[1:]}. Fitted: "
            f"{eff.explain_params(entry.params, const)}. "
            f"rmse/noise {rmse0:.2f} -> {entry.rmse_over_noise:.2f} on all runs, "
            f"delta BIC {entry.delta_bic:.0f}.{held}{where} {verdict} "
            f"Expected signature: {eff.signature}. To confirm: {eff.experiment}.")
