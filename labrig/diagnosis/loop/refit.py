"""Re-fitting a model with one effect more (or one fewer) without getting stuck.

A local optimiser started from the current model fails in two ways that real rigs
show at once:

- **plateaus**: a threshold (dead zone, rail, friction level, gear gap) that starts
  outside what the data reach has no gradient, so its re-fit "gains 0 %";
- **basins**: the linear model's electrical pole can absorb a transport delay
  (tau_e of 0.1 s for a 31 ms delay), and warm starts never leave that basin.

- **absorbed thresholds**: a model without friction (or with a dead zone standing in
  for it) bends its plant to mimic it -- a slow electrical pole, a slow tau_m, a low
  gain -- and the friction added from there makes every point worse before it makes
  any better.

So every re-fit first *scans* the new effect's parameters over the range the data can
see (:meth:`labrig.model.effects.Effect.scan_grid`, one population call of the fast
simulator, in two basins: the current electrical pole and a structurally different
one; for a dead zone or friction also the plant the analyser measures from the steps'
steady states and rise times, which a threshold does not bend, and shares of a dead
zone the model holds handed to the friction, or back), then polishes the best point of
the two best basins with CO and keeps the better fit. A friction law's fit that stays
well above the noise is polished once more by a simplex: its error is piecewise constant
in the friction's levels, and a gradient stops wherever the start left them.
"""
from __future__ import annotations

import numpy as np

from labrig.core.defaults import SEED
from labrig.core.errors import FitDiverged
from labrig.core.parallel import each
from labrig.identification.engine import solve
from labrig.identification.problem import Problem, start_of
from labrig.identification.result import at_bounds
from labrig.model.model import Model
from labrig.analysis.noise import Weights
from labrig.model.reach import Reach
from labrig.model.start import is_start_key
from labrig.diagnosis.loop.starts import starts_for, starts_in_motion

#: a seed's own random starts replace the default seed's design only when they fit this much
#: better (:func:`seed_or_design`)
SEED_GAIN = 0.01
#: the loop's re-fits see about this many residuals (every k-th)
SUBSAMPLE = 16000
#: the evaluations of the re-fit from the start the data show: the whole model moves with
#: the starts, so it gets more room than a polish from a scanned start
MOVING_START_NFEV = 200
#: a friction law's re-fit still this far above the noise (its fitness, in noise units)
#: is polished once more without gradients (:func:`simplex_polish`), within this many
#: residuals' worth of simulation
POLISH_ABOVE, POLISH_BUDGET = 1.2, 3.0e6
#: simplex passes at most, each from where the last ended while it gains a per cent
POLISH_RESTARTS = 3
#: the share of the error a polished fit must gain to be kept (it left the basin)
POLISH_GAIN = 0.05



def fit(runs, effects, start, fixed: dict, *, seed: int, weights: Weights,
        reach, max_nfev: int = 60, masks=None, stop=None, tol=None):
    """One CO fit from ``start`` (a Model or its flat values; bounds from ``reach``); ``stop``: a rule that may end
    it early (:func:`labrig.diagnosis.evidence.criteria.screen`); ``tol``: the trust region's
    tolerances (:class:`~labrig.identification.engine.FitOptions`)."""
    problem = Problem(runs, effects, fixed=fixed, reach=reach or Reach.of(runs),
                      weights=weights, masks=masks)
    return solve(problem, "co", seed=seed, start=start, starts=1, identifiability=False,
                 max_nfev=max_nfev, subsample=SUBSAMPLE, stop=stop, tol=tol)


def fresh_fit(runs, effects, *, seed: int, fixed: dict, weights: Weights, reach=None):
    """``effects`` fitted from the identification's own starts (its initial point and its
    multi-starts), not from a model fitted before: where the data put the plant without
    the compromise a simpler model made. A linear model absorbs a friction into a slow
    time constant, and a pair of effects added to it can stay in that basin.

    The multi-starts are the default seed's design (:data:`labrig.core.defaults.SEED`);
    another ``seed``'s random starts are fitted too and kept only where they fit clearly
    better (:func:`seed_or_design`)."""
    def one(s):
        problem = Problem(runs, effects, fixed=fixed, reach=reach or Reach.of(runs),
                          weights=weights)
        return solve(problem, "co", seed=s, identifiability=False)
    return seed_or_design(one, seed)


def seed_or_design(fit_from, seed: int):
    """``fit_from(SEED)``, the loop's seedless design of random starts, unless ``seed`` is
    another and ``fit_from(seed)`` fits more than :data:`SEED_GAIN` better.

    Random starts end in different local minima of a valley the data barely pin (the
    real EMPS record's offset + Coulomb friction: Fv 188 or 194 N s/m, 0.04 % apart in
    error); the seed must not pick between such equals, but a seed whose starts find a
    clearly better basin is kept (and says which seed it was, in the fit's record)."""
    design = fit_from(SEED)
    if int(seed) == SEED:
        return design
    own = fit_from(seed)
    if own.diverged or design.diverged:
        return design if own.diverged else own
    return own if own.fitness < (1.0 - SEED_GAIN) * design.fitness else design


def thinned_fitness(runs, model: Model, fixed: dict, weights: Weights, reach) -> float:
    """``model``'s fitness on the residuals a re-fit sees (every k-th, :data:`SUBSAMPLE`):
    what a re-fit's own history is compared with (the screen,
    :func:`labrig.diagnosis.evidence.criteria.screen`); on all residuals it differs by a per cent
    or so, as much as a small effect gains."""
    problem = Problem.of(runs, model, fixed=fixed, reach=reach, weights=weights)
    return problem.thinned_fitness(model, SUBSAMPLE)   # as the re-fit thins them


def refit_with(runs, base: Model, effect, *, seed: int = 0, fixed: dict | None = None,
               weights: Weights = Weights(), reach=None, carried: dict | None = None,
               stop=None):
    """``base`` plus ``effect``, re-fitted from scanned starts in two basins; returns the
    best :class:`labrig.identification.fit.Identification`. ``carried``: the values of
    the effect's parameters where the model it replaces left them (a replacement also
    starts there, when they are all of its parameters: a simpler family member), or a
    list of such starts (a refinement's, ``Effect.from_simpler``). ``stop``: the screen
    that may end each start's fit early (:func:`labrig.diagnosis.evidence.criteria.screen`); the
    result's ``stopped`` says when it ended every one."""
    reach = reach or Reach.of(runs, base)
    effects = base.effects_with([effect])
    fixed = dict(fixed or {})
    params = start_of(base, fixed)
    extra = []
    for c in ([carried] if isinstance(carried, dict) else carried or []):
        if set(effect.param_names()) <= set(c):
            extra.append({**params, **{f"{effect.name}.{k}": float(c[k])
                                       for k in effect.param_names()}})
    return _best_of_starts(runs, effects, effect, params, reach=reach, fixed=fixed, seed=seed,
                           weights=weights, extra=extra, stop=stop)


def refit_as_member(runs, base: Model, effect, other: Model, name: str, *, seed: int = 0,
                    fixed: dict | None = None, weights: Weights = Weights(), reach=None):
    """``base`` plus ``effect`` fitted from ``other`` (``base`` plus ``name``, a member of
    ``effect``'s family, fitted): the plant and the rest where ``other`` put them,
    ``effect`` standing where ``name`` stood (``Effect.as_member``). Two nested effects
    fitted each from its own scan can end in different basins, and then the seed, not the
    data, says which explains the runs better. None when ``effect`` cannot stand for it."""
    starts = effect.as_member(name, other.effect_params[name])
    if not starts:
        return None
    reach = reach or Reach.of(runs, base)
    fixed = dict(fixed or {})
    rest = start_of(without(other, name), fixed)
    effects = base.effects_with([effect])
    points = [{**rest, **{f"{effect.name}.{k}": float(v) for k, v in s.items()}} for s in starts]
    # each start also kept as it stands: the fit sees every k-th residual, and where the
    # error is piecewise constant in a level it can end worse on all of them than it began
    jobs = [(s, n) for s in points for n in (60, 1)]
    return best_fit(each(lambda j: fit(runs, effects, j[0], fixed, seed=seed, weights=weights,
                                       reach=reach, max_nfev=j[1]), jobs),
                    f"the re-fit with {effect.name}")


def _best_of_starts(runs, effects, new, params, *, reach, fixed, seed, weights, extra=(),
                    stop=None):
    """Fit ``effects`` from each scanned start (and each of ``extra``), side by side, and
    keep the best."""
    starts = starts_for(runs, params, effects, new, reach, fixed, weights) + list(extra)
    what = f"the re-fit with {new.name}" if new is not None else "the re-fit"
    best = best_fit(each(lambda s: fit(runs, effects, s, fixed, seed=seed, weights=weights,
                                       reach=reach, stop=stop), starts), what)
    if getattr(new, "stage", None) == "friction" and not best.stopped \
            and best.fitness > POLISH_ABOVE:
        polished = simplex_polish(runs, effects, best.model(), fixed,
                                  weights, reach)
        if polished is not None:   # (a short gradient fit from there: the result's form)
            moved = fit(runs, effects, polished, fixed, seed=seed, weights=weights,
                        reach=reach, max_nfev=20)
            # kept only when it left the basin: a smaller gain is a slide along what the
            # data leave flat, where each machine's rounding stops the simplex elsewhere
            # (a mystery rig's Coulomb fit: 0.15 % in-sample, 5 % apart held out on two
            # BLAS kernels)
            if not moved.diverged and moved.fitness <= (1.0 - POLISH_GAIN) * best.fitness:
                best = best_fit([best, moved], what)
        if _level_at_floor(best, new):
            # the friction stayed at the bottom of its range: the plant the model before
            # bent to mimic it (a heavy carriage, a slow tau_m) holds it there; the same
            # effects from the identification's own starts, where the data put the plant
            again = fresh_fit(runs, effects, seed=seed, fixed=fixed, weights=weights,
                              reach=reach)
            if not again.diverged and again.fitness <= (1.0 - POLISH_GAIN) * best.fitness:
                best = best_fit([best, again], what)
    if not starts_in_motion(params):
        return best
    # a run that starts in motion had its start fitted by the model before, bent to that
    # model's compromise (a linear model's coast is too slow: its start speed runs to its
    # bound); with the plant and the effects where this fit put them, the start the data
    # show is tried too
    own = {k: v for k, v in start_of(best.model(), fixed).items() if not is_start_key(k)}
    again = fit(runs, effects, own, fixed, seed=seed, weights=weights, reach=reach,
                max_nfev=MOVING_START_NFEV)
    return best_fit([best, again], what)


def _level_at_floor(ident, new) -> bool:
    """Whether the friction law ``new`` ended with a level at the lower bound of its
    search range (absent: the fit never left the basin of the model without it)."""
    return any(n.startswith(f"{new.name}.") and side == "lower"
               for n, _, side, _ in at_bounds(ident.space, ident.params))


def simplex_polish(runs, effects, start, fixed: dict, weights: Weights,
                   reach) -> dict | None:
    """``start`` (a Model or its flat values) polished by a simplex (Nelder-Mead) over every free parameter: the
    parameters where it ended, or None when it found nothing better.

    A friction law makes the error piecewise constant in its levels: the rotor breaks
    loose at the first held input above the breakaway, stops at the first sub-step its
    speed crosses zero, so a finite difference sees either nothing or a jump, and a
    gradient fit stops wherever its start left the thresholds (a rig whose friction is
    large against its drive keeps the linear model's slow time constant). A simplex
    compares whole values and walks across; restarted from where it ended while a pass
    gains a per cent (:data:`POLISH_RESTARTS` passes at most), each pass's evaluations
    capped at :data:`POLISH_BUDGET` residuals' worth of simulation."""
    from scipy.optimize import minimize

    problem = Problem(runs, effects, fixed=fixed, reach=reach, weights=weights)
    lo, hi = problem.bounds_of_search()
    x0 = problem.point(start)
    f0 = float(problem.fitness_of_vectors(x0[None, :])[0])
    n = sum(len(r.u) for r in runs)
    x, f = x0, f0
    for _ in range(POLISH_RESTARTS):
        # a simplex collapses along the valley it found: a fresh one from where it ended
        # walks on while a pass still gains (a restarted Nelder-Mead)
        res = minimize(lambda v: float(problem.fitness_of_vectors(np.clip(v, lo, hi)[None, :])[0]), x,
                       method="Nelder-Mead",
                       options=dict(maxfev=int(np.clip(POLISH_BUDGET / max(n, 1), 100, 2000)),
                                    xatol=1e-7, fatol=1e-10, adaptive=True))
        if not np.isfinite(res.fun) or res.fun >= f:
            break
        gained, x, f = 1.0 - res.fun / f, np.clip(res.x, lo, hi), float(res.fun)
        if gained < 0.01:
            break
    if f >= f0:
        return None
    return problem.values(x)


def best_fit(fits, what: str = "the re-fit"):
    """The lowest fitness; within 1 % of it, a plant whose electrical pole is the faster
    (the physical reading of an almost symmetric pair of poles).

    A start whose simulation overflowed or went non-finite (a stiff mechanical pole
    under explicit friction sub-steps, say) is a failed start: it is dropped and counted
    (``failed_starts`` of the result). When every start failed there is nothing to
    choose from: :class:`~labrig.core.errors.FitDiverged` says so and what to try."""
    fits = list(fits)
    good = [f for f in fits if not f.diverged]
    if not good:
        raise FitDiverged(
            f"{what}: every start ({len(fits)}) diverged (the simulation overflowed); "
            "start from a model nearer the data (labrig identify DATA -o m0.json, then "
            "--model m0.json) or narrow the plant's range with `bounds`")
    low = min(f.fitness for f in good)
    near = [f for f in good if f.fitness <= 1.01 * low]
    right = [f for f in near if "L" not in f.params or f.params["L"] / f.params["R"]
             <= f.params["J"] * f.params["R"] / (f.params["B"] * f.params["R"] + f.params["K"] ** 2)]
    best = min(right or near, key=lambda f: f.fitness)
    best.failed_starts = len(fits) - len(good) + sum(f.failed_starts for f in good)
    return best


def refit(runs, model: Model, *, seed: int = 0, fixed: dict | None = None,
          weights: Weights = Weights(), reach=None):
    """``model`` re-fitted as it is (both basins of the electrical pole)."""
    reach = reach or Reach.of(runs, model)
    fixed = dict(fixed or {})
    params = start_of(model, fixed)
    return _best_of_starts(runs, model.effects, None, params, reach=reach, fixed=fixed,
                           seed=seed, weights=weights)


def without(model: Model, name: str) -> Model:
    """``model`` with the effect ``name`` taken out (its parameters dropped)."""
    return Model(params=dict(model.params),
                 effects=[e for e in model.effects if e.name != name],
                 effect_params={e: dict(ps) for e, ps in model.effect_params.items()
                                if e != name},
                 constants=dict(model.constants), plant=model.plant,
                 info=dict(model.info or {}), starts={r: dict(s) for r, s in model.starts.items()})
