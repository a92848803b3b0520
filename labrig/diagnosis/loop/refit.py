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

import itertools

import numpy as np

from labrig.core.defaults import SEED
from labrig.core.errors import FitDiverged
from labrig.core.parallel import each
from labrig.identification.engine import dataset_constants, identify
from labrig.model.plants import plant_of_runs
from labrig.identification.problem import Problem
from labrig.identification.result import at_bounds
from labrig.model.model import Model
from labrig.analysis.noise import Weights
from labrig.model.reach import Reach
from labrig.model.start import is_start_key

#: a seed's own random starts replace the default seed's design only when they fit this much
#: better (:func:`seed_or_design`)
SEED_GAIN = 0.01
#: the loop's re-fits see about this many residuals (every k-th)
SUBSAMPLE = 16000
#: the evaluations of the re-fit from the start the data show: the whole model moves with
#: the starts, so it gets more room than a polish from a scanned start
MOVING_START_NFEV = 200
#: a basin whose best scan point is this much worse than the other's is not polished
BASIN_MARGIN = 1.5
#: a friction law's re-fit still this far above the noise (its fitness, in noise units)
#: is polished once more without gradients (:func:`simplex_polish`), within this many
#: residuals' worth of simulation
POLISH_ABOVE, POLISH_BUDGET = 1.2, 3.0e6
#: simplex passes at most, each from where the last ended while it gains a per cent
POLISH_RESTARTS = 3
#: the share of the error a polished fit must gain to be kept (it left the basin)
POLISH_GAIN = 0.05

#: the effects whose thresholds are volts at the bridge input that the steady state cannot
#: tell apart: a dead zone and a friction level of the same volts give the same line of
#: speed against input. A model holding one has let it absorb the other; adding the other
#: from there meets a valley (the sum is pinned, the split is not) that a local fit does
#: not cross, so the scan also starts from shares of the threshold moved across.
INPUT_THRESHOLDS = {"deadband": ("d_v",), "asymmetric_deadband": ("dpos_v", "dneg_v"),
                    "coulomb_friction": ("tc_v",), "stiction": ("tc_v",)}
#: the shares of the held threshold handed to the new effect
SHARES = (0.5, 0.9)


def fit(runs, effects, start: dict, fixed: dict, *, seed: int, weights: Weights,
        reach, max_nfev: int = 60, masks=None, stop=None):
    """One CO fit from ``start`` (bounds from ``reach``); ``stop``: a rule that may end
    it early (:func:`labrig.diagnosis.evidence.criteria.screen`)."""
    return identify(runs, "co", effects, seed=seed, start=start, fixed=fixed, starts=1,
                    identifiability=False, max_nfev=max_nfev, p=weights.p, q=weights.q,
                    masks=masks, reach=reach, subsample=SUBSAMPLE, stop=stop)


def fresh_fit(runs, effects, *, seed: int, fixed: dict, weights: Weights, reach=None):
    """``effects`` fitted from the identification's own starts (its initial point and its
    multi-starts), not from a model fitted before: where the data put the plant without
    the compromise a simpler model made. A linear model absorbs a friction into a slow
    time constant, and a pair of effects added to it can stay in that basin.

    The multi-starts are the default seed's design (:data:`labrig.core.defaults.SEED`);
    another ``seed``'s random starts are fitted too and kept only where they fit clearly
    better (:func:`seed_or_design`)."""
    def one(s):
        return identify(runs, "co", effects, seed=s, fixed=fixed, identifiability=False,
                        p=weights.p, q=weights.q, reach=reach)
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
    problem = Problem(runs, model.effects, fixed=fixed, reach=reach, weights=weights)
    return problem.thinned_fitness(model, SUBSAMPLE)   # as the re-fit thins them


def _alternative_pole(params: dict, dt: float) -> dict:
    """The same plant with its electrical pole in the other basin: far below the sample
    period when it sits above it (room for a delay), onto it when it sits far below
    (where tau_e has no gradient at all). A torque/force plant has no electrical pole:
    one basin."""
    if "L" not in params:
        return None
    tau_e = params["L"] / params["R"]
    L = params["R"] * (0.05 * dt if tau_e > 0.5 * dt else 2.0 * dt)
    return {**params, "L": L}


def _swapped_poles(params: dict) -> dict | None:
    """The plant with its two time constants exchanged, when the electrical one is the
    slower: a second-order response barely tells which pole is which, and a fit can land
    with tau_e = 0.15 s and tau_m = 4 ms, the wrong way round for any servo motor."""
    if "L" not in params:
        return None
    R, L, J, B, K = (params[k] for k in ("R", "L", "J", "B", "K"))
    tau_e, tau_m = L / R, J * R / (B * R + K * K)
    if tau_e <= tau_m:
        return None
    return {**params, "L": R * tau_m, "J": tau_e * (B * R + K * K) / R}


#: the shares of the model's inertia the scan also tries a threshold in, where
#: no open-loop step measures the plant (:func:`_lighter_plants`)
LIGHTER = (0.5, 0.25, 0.125)


def _lighter_plants(params: dict, fixed: dict) -> list[dict]:
    """A torque or force plant with its inertia (``M`` of a force axis, ``J`` of a torque
    drive) a half, a quarter and an eighth of the model's: a coarse scan of its slowest
    pole. A model without the threshold has bent its plant to stand in for it (a
    heavier, slower load), and the threshold added from there makes every point worse
    before any better; where no open-loop step gives the analyser's plant
    (:func:`_analysed_plant`: a voltage plant's), this is where the data may put it."""
    key = "M" if "M" in params else "J" if "L" not in params and "J" in params else None
    if key is None or key in fixed:
        return []
    return [{**params, key: params[key] * f} for f in LIGHTER]


def _analysed_plant(runs, params: dict, dt: float) -> dict | None:
    """The voltage plant with the analyser's Km and tau_m (the slope of the steady states
    beyond their intercept, the steps' rise), R and K kept and the electrical pole far
    below the sample period; None when the plant has no electrical pole or the runs give
    the analyser no open-loop step."""
    if "L" not in params:
        return None
    measured = _analysis_of(runs)
    if measured is None:
        return None
    km, tau = measured
    servo = plant_of_runs(runs).servo(params, dataset_constants(runs))
    R, K = params["R"], params["K"]
    damping = servo.Ka * K / km                      # B R + K Ke at the measured gain
    return {**params, "B": max((damping - K * servo.ke) / R, 1e-12),
            "J": tau * damping / R, "L": R * 0.05 * dt}


#: the analyser's (Km, tau_m) of the runs last seen: one analysis per set of runs, however
#: many effects a round re-fits
_ANALYSED: dict = {}


def _analysis_of(runs) -> tuple[float, float] | None:
    key = tuple((r.name, len(r), float(np.nansum(r.u))) for r in runs)
    if key not in _ANALYSED:
        from labrig.analysis.dataset import analyse
        from labrig.core.errors import LabrigError

        try:
            res = analyse(list(runs))
            ok = res.km and res.tau_s and np.isfinite(res.km) and np.isfinite(res.tau_s)
            _ANALYSED.clear()
            _ANALYSED[key] = (float(res.km), float(res.tau_s)) if ok and res.km > 0 else None
        except (LabrigError, ValueError, ArithmeticError):
            _ANALYSED[key] = None   # no open-loop steps to analyse: no such basin
    return _ANALYSED[key]


def starts_for(runs, base_params: dict, effects, new, reach, fixed: dict,
               weights: Weights) -> list[dict]:
    """The best scanned start in each basin, best first (at most two), and the best start
    that shares a held threshold with the new effect (:data:`INPUT_THRESHOLDS`)."""
    problem = Problem(runs, effects, fixed=fixed, reach=reach, weights=weights)
    grid = new.scan_grid(reach) if new is not None else {}
    npts = len(next(iter(grid.values()))) if grid else 1
    basins = [b for b in (base_params, _alternative_pole(base_params, reach.dt)) if b]
    swapped = _swapped_poles(base_params) if not {"L", "J"} & set(fixed) else None
    if swapped is not None:
        basins = [swapped, base_params]
    if getattr(new, "name", None) in INPUT_THRESHOLDS and not {"B", "J", "L"} & set(fixed):
        analysed = _analysed_plant(runs, base_params, reach.dt)
        if analysed is not None:
            basins.append(analysed)
        else:   # no open-loop step to measure the plant by: a coarse scan of its inertia
            basins += _lighter_plants(base_params, fixed)
    if _starts_in_motion(base_params):
        # the same plant from the start the data show (see _best_of_starts)
        basins.append({k: v for k, v in base_params.items() if not is_start_key(k)})
    points, sizes, shared_at = [], [], []
    for b in basins:
        pts = [{**b, **{f"{new.name}.{name}": float(values[k]) for name, values in grid.items()}}
               for k in range(npts)]
        shared = _shared_threshold_starts(b, effects, new, grid)
        at = len(points) + len(pts)
        shared_at.extend(range(at, at + len(shared)))
        points += pts + shared
        sizes.append(len(pts) + len(shared))
    # parameters neither the base nor the grid sets (a user effect without a scan):
    # the identifiers' own starting point, once
    fill = problem.initial_point(base_params)
    f = problem.fitness([{**fill, **pt} for pt in points])
    best, at = [], 0
    for size in sizes:
        seg = f[at:at + size]
        k = int(np.argmin(seg))
        best.append((float(seg[k]), points[at + k]))
        at += size
    if swapped is None:
        best.sort(key=lambda t: t[0])
    else:   # the swapped and the base basin are polished, best first; then any better one
        best = best[:2] + sorted(best[2:], key=lambda t: t[0])
        if len(best) > 2 and best[2][0] < min(best[0][0], best[1][0]):
            best = [best[2], best[0]]
    # (with swapped poles both are polished: the right way round is tried first)
    keep = [best[0][1]]
    if len(best) > 1 and (swapped is not None or best[1][0] <= BASIN_MARGIN * best[0][0]):
        keep.append(best[1][1])
    if shared_at:   # the best share of a held threshold is always polished too: the scan
        # cannot see that its valley leads down, only the fit can
        k = min(shared_at, key=lambda i: f[i])
        if not any(points[k] is q for q in keep):
            keep.append(points[k])
    return keep


def _shared_threshold_starts(params: dict, effects, new, grid: dict) -> list[dict]:
    """Starts where ``new`` takes a share of an input threshold the model already holds
    in another effect (:data:`INPUT_THRESHOLDS`), that effect keeping the rest; the new
    effect's other parameters at each of their scanned values."""
    mine = INPUT_THRESHOLDS.get(getattr(new, "name", None))
    if not mine or not grid:
        return []
    out = []
    for held in effects:
        if held.name == new.name or held.name not in INPUT_THRESHOLDS:
            continue
        keys = [f"{held.name}.{k}" for k in INPUT_THRESHOLDS[held.name]]
        if not all(k in params for k in keys):
            continue
        volts = float(np.mean([params[k] for k in keys]))
        others = {n: sorted(set(map(float, v))) for n, v in grid.items() if n not in mine}
        combos = [dict(zip(others, vals)) for vals in itertools.product(*others.values())]
        for share in SHARES:
            for combo in combos:
                pt = dict(params)
                for k in keys:   # the held effect keeps the rest (never below its floor)
                    pt[k] = max(params[k] * (1.0 - share), 1e-3)
                for k in mine:
                    pt[f"{new.name}.{k}"] = share * volts
                pt.update({f"{new.name}.{n}": v for n, v in combo.items()})
                out.append(pt)
    return out


def refit_with(runs, base: Model, effect, *, seed: int = 0, fixed: dict | None = None,
               weights: Weights = Weights(), reach=None, carried: dict | None = None,
               stop=None):
    """``base`` plus ``effect``, re-fitted from scanned starts in two basins; returns the
    best :class:`labrig.identification.engine.Identification`. ``carried``: the values of
    the effect's parameters where the model it replaces left them (a replacement also
    starts there, when they are all of its parameters: a simpler family member), or a
    list of such starts (a refinement's, ``Effect.from_simpler``). ``stop``: the screen
    that may end each start's fit early (:func:`labrig.diagnosis.evidence.criteria.screen`); the
    result's ``stopped`` says when it ended every one."""
    reach = reach or Reach.of(runs, base)
    effects = base.effects_with([effect])
    fixed = dict(fixed or {})
    params = {**base.flat(), **fixed}
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
    rest = {**without(other, name).flat(), **fixed}
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
        polished = simplex_polish(runs, effects, {**best.model().flat(), **fixed}, fixed,
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
    if not _starts_in_motion(params):
        return best
    # a run that starts in motion had its start fitted by the model before, bent to that
    # model's compromise (a linear model's coast is too slow: its start speed runs to its
    # bound); with the plant and the effects where this fit put them, the start the data
    # show is tried too
    own = {k: v for k, v in {**best.model().flat(), **fixed}.items() if not is_start_key(k)}
    again = fit(runs, effects, own, fixed, seed=seed, weights=weights, reach=reach,
                max_nfev=MOVING_START_NFEV)
    return best_fit([best, again], what)


def _level_at_floor(ident, new) -> bool:
    """Whether the friction law ``new`` ended with a level at the lower bound of its
    search range (absent: the fit never left the basin of the model without it)."""
    return any(n.startswith(f"{new.name}.") and side == "lower"
               for n, _, side, _ in at_bounds(ident.space, ident.params))


def simplex_polish(runs, effects, start: dict, fixed: dict, weights: Weights,
                   reach) -> dict | None:
    """``start`` polished by a simplex (Nelder-Mead) over every free parameter: the
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


def _starts_in_motion(params) -> bool:
    """Whether ``params`` hold a fitted start speed (a run that starts in motion)."""
    return any(is_start_key(k) and k.endswith(".w0") for k in params)


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
            "--model m0.json) or narrow the plant's range with --bounds")
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
    params = {**model.flat(), **fixed}
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
