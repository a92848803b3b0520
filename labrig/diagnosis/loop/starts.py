"""Where a re-fit starts: the new effect's parameters scanned over what the data reach,
in each basin of the plant the model before may have bent to stand in for it.

A local fit started from the current model stays on a plateau (a threshold outside what
the data reach has no gradient) or in a basin (the linear model's electrical pole can
absorb a delay; a model without friction bends its plant to mimic it). So the new
effect's grid (:meth:`labrig.model.effects.Effect.scan_grid`) is scored in one
population call of the simulator in the current basin and structurally different ones:
the electrical pole moved across, the poles swapped, the plant the analyser measures from
the steps (which a threshold does not bend), a lighter inertia where no step measures it,
and shares of an input threshold the model holds handed to the new effect.
:mod:`labrig.diagnosis.loop.refit` polishes the best of them.
"""
from __future__ import annotations

import itertools

import numpy as np

from labrig.analysis.noise import Weights
from labrig.identification.problem import Problem, dataset_constants
from labrig.model.plants import plant_of_runs
from labrig.model.start import is_start_key

#: a basin whose best scan point is this much worse than the other's is not polished
BASIN_MARGIN = 1.5

#: the effects whose thresholds are volts at the bridge input that the steady state cannot
#: tell apart: a dead zone and a friction level of the same volts give the same line of
#: speed against input. A model holding one has let it absorb the other; adding the other
#: from there meets a valley (the sum is pinned, the split is not) that a local fit does
#: not cross, so the scan also starts from shares of the threshold moved across.
INPUT_THRESHOLDS = {"deadband": ("d_v",), "asymmetric_deadband": ("dpos_v", "dneg_v"),
                    "coulomb_friction": ("tc_v",), "stiction": ("tc_v",)}
#: the shares of the held threshold handed to the new effect
SHARES = (0.5, 0.9)


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
    if starts_in_motion(base_params):
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


def starts_in_motion(params) -> bool:
    """Whether ``params`` hold a fitted start speed (a run that starts in motion)."""
    return any(is_start_key(k) and k.endswith(".w0") for k in params)
