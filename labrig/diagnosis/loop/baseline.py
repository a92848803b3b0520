"""The model a diagnosis round starts from: the linear model identified when none is
given, the channel weights that give each channel the same say, and a fit's parameters
at a bound, in words."""
from __future__ import annotations

import itertools

import numpy as np

from labrig.analysis.agreement import WINDOW_DECLARED_IN, channel_agreement
from labrig.analysis.noise import Weights
from labrig.diagnosis.evidence.evaluation import Evaluation
from labrig.diagnosis.loop.refit import refit, seed_or_design
from labrig.identification.engine import solve
from labrig.model.reach import Reach
from labrig.identification.problem import Problem
from labrig.model.plants import plant_of_runs
from labrig.identification.result import at_bounds as bound_sides
from labrig.model import drive_units
from labrig.model.model import Model
from labrig.model.simulate import prepare


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
    then both basins of the electrical pole; a torque or force plant (two parameters)
    also from the best points of a grid over its whole box (:func:`grid_starts`). The
    four starts are the default seed's design unless ``seed``'s fit clearly better
    (:func:`labrig.diagnosis.loop.refit.seed_or_design`)."""
    if start is not None:
        return refit(runs, start, seed=seed, fixed=fixed, weights=weights).model()

    # the grid's polishes start from no random point: fitted once, whatever the seed
    def linear():   # the problem without effects (one a fit: nothing shared between threads)
        return Problem(runs, [], fixed=fixed, reach=Reach.of(runs), weights=weights)

    grid = [solve(linear(), "co", seed=seed, start=pt, starts=1, identifiability=False)
            for pt in grid_starts(runs, fixed or {}, weights)]

    def from_starts(s):
        ident = solve(linear(), "co", seed=s, starts=4, identifiability=False)
        again = refit(runs, ident.model(), seed=s, fixed=fixed, weights=weights)
        return min([again, ident] + grid, key=lambda f: f.fitness)
    return seed_or_design(from_starts, seed).model()


#: points a side of the plant grid (:func:`grid_starts`), and how many of its best are polished
GRID_SIDE, GRID_POLISHED = 25, 2


def grid_starts(runs, fixed: dict, weights: Weights) -> list[dict]:
    """The best points of a log grid over a two-parameter plant's box (inertia and
    damping of a torque or force plant), scored in one population call of the simulator;
    [] for a voltage plant. A recording the linear model simulates poorly (a position
    loop's force record, open loop: the position drifts) has local minima far apart
    (the real EMPS record: linear fits 55 % apart by the seed of their four random
    starts), and every effect is then fitted from wherever the seed left the plant; the
    grid has no seed."""
    plant = plant_of_runs(runs)
    free = [n for n in plant.names if n not in fixed]
    if len(plant.names) != 2 or not free:
        return []
    problem = Problem(runs, [], fixed=fixed, weights=weights, plant=plant)
    space = problem.space
    fill = problem.initial_point()
    axes = []
    for n in free:
        k = space.names.index(n)
        lo, hi = space.lower[k], space.upper[k]
        axes.append(np.geomspace(lo, hi, GRID_SIDE) if space.log[k] else
                    np.linspace(lo, hi, GRID_SIDE))
    points = [{**fill, **dict(zip(free, map(float, combo)))}
              for combo in itertools.product(*axes)]
    f = problem.fitness(points)
    return [points[i] for i in np.argsort(f, kind="stable")[:GRID_POLISHED]]
