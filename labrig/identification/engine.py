"""Identification: fit the servo model (R, L, J, B, K + chosen effects) to a data set
with JFO, PSO or CO, then report fit quality and identifiability.

``identify(runs, method=...)`` is the thin public function; the optimisers live in
``jellyfish.py``, ``pso.py`` and ``local.py`` and share one result type.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from labrig.core.defaults import METHOD, SEED
from labrig.core.errors import UserError
from labrig.core.timing import mark
from labrig.model.effects import Effect
from labrig.model.start import start_report
from labrig.model.model import Model
from labrig.model.reach import Reach
from labrig.io.runs import require_excitation
from labrig.identification.identifiability import analyse_identifiability, time_constants
from labrig.identification.jellyfish import jellyfish
from labrig.identification.local import local, polish as _polish
from labrig.identification.problem import Problem
from labrig.identification.pso import pso
from labrig.identification.settle import settle
from labrig.identification.result import IdentResult
from labrig.analysis.agreement import channel_agreement, lag_explained
from labrig.analysis.noise import Weights
from labrig.identification.fit import Identification


def _run_jfo(obj, lo, hi, x0, o):
    return jellyfish(obj.fitness_batch, lo, hi, pop=o["pop"], iters=o["iters"], seed=o["seed"],
                     rule=o.get("rule", "paper"), callback=o.get("callback"))


def _run_pso(obj, lo, hi, x0, o):
    return pso(obj.fitness_batch, lo, hi, pop=o["pop"], iters=o["iters"], seed=o["seed"],
               callback=o.get("callback"))


#: a start of CO's multi-start search still going after this many evaluations of the
#: residuals is crawling (along an electrical pole the data do not resolve, typically, one
#: start in four) and is ended there: such a start loses by far when it reaches scipy's
#: limit of 100 per parameter, while the starts that win converge well within this many.
#: The best start's fit is unchanged: it ends long before.
START_MAX_NFEV = 100


def _run_co(obj, lo, hi, x0, o):
    """Multi-start least squares. The starts are screened on every k-th residual (about
    8000 of them; the simulation runs on every sample, only the residuals are thinned),
    and the best start is then polished on all residuals, which also gives the
    covariance. (The trust region itself works on n + 1 reduced rows whatever the
    number of residuals: :func:`labrig.identification.local.reduced`.)"""
    # local's fun and history are mean squares of the solver residuals; the callback,
    # the stop rule and the result hear the fitness (Objective.fitness_of_mean_square)
    fitness = obj.fitness_of_mean_square
    cb = o.get("callback")
    root_cb = (lambda k, f: cb(k, fitness(f))) if cb else None
    stride = max(1, obj.m // 8000)
    if o.get("subsample") and o["starts"] == 1:
        # the loop's many warm re-fits: every k-th residual (at 1 kHz neighbours are
        # strongly correlated, so the optimum barely moves; the residuals cost k times less)
        k = obj.thinning(o["subsample"])
        rule = o.get("stop")
        # (on every k-th residual: the fitness on that thinning)
        stop = (lambda h: rule([fitness(v) for v in h])) if rule else None
        tol = o.get("tol")
        res = local(lambda x: obj.solver_residuals(x, k), lo, hi, x0=x0, starts=1,
                    seed=o["seed"], jac_batch=lambda X: obj.solver_residuals_batch(X, k),
                    max_nfev=o.get("max_nfev"), callback=root_cb, stop=stop,
                    options=None if tol is None else {"xtol": tol, "ftol": tol})
        return _as_fitness(res, fitness)
    full = lambda x: local(obj.solver_residuals, lo, hi, x0=x, starts=1,  # noqa: E731
                           seed=o["seed"], jac_batch=obj.solver_residuals_batch,
                           max_nfev=o.get("max_nfev"))
    starts_nfev = o.get("max_nfev") or START_MAX_NFEV
    if o["starts"] > 1 and stride > 1:
        screen = local(lambda x: obj.solver_residuals(x, stride), lo, hi, x0=x0,
                       starts=o["starts"], seed=o["seed"],
                       jac_batch=lambda X: obj.solver_residuals_batch(X, stride),
                       max_nfev=starts_nfev, callback=root_cb, threads=True)
        res = full(screen.x)
        res.nfev += screen.nfev
        res.nit = screen.nit
        res.history = list(screen.history) + list(res.history)
        res.message = (f"best of {o['starts']} starts screened on every {stride}th residual, "
                       f"then polished on all: {res.message}")
    else:
        res = local(obj.solver_residuals, lo, hi, x0=x0, starts=o["starts"], seed=o["seed"],
                    jac_batch=obj.solver_residuals_batch, callback=root_cb, threads=True,
                    max_nfev=starts_nfev if o["starts"] > 1 else o.get("max_nfev"))
    return _as_fitness(res, fitness)


def _as_fitness(res, fitness):
    """A local fit's result with its fun and history (mean squares) as the fitness."""
    res.fun = fitness(res.fun)
    res.history = [fitness(h) for h in res.history]
    return res


#: method name -> runner(objective, lower, upper, x0, options) -> IdentResult
METHODS = {"jfo": _run_jfo, "pso": _run_pso, "co": _run_co}


@dataclass(frozen=True)
class FitOptions:
    """How hard an identifier works: the solver's side of a fit (``labrig identify``'s
    tuning options). What is fitted -- the channels' weights, the runs' starts, the
    folds -- is the :class:`~labrig.identification.problem.Problem`'s.

    ``pop``, ``iters``: population and iterations of JFO/PSO; ``starts``: CO's scanned
    starts; ``polish``: finish JFO/PSO with CO; ``rule``: JFO's time-control rule;
    ``max_nfev``: CO's evaluation budget; ``subsample``: CO from a start on about this
    many residuals; ``identifiability``: compute the intervals and warnings.
    """

    pop: int = 50
    iters: int = 200
    starts: int = 8
    polish: bool = False
    rule: str = "paper"
    max_nfev: int | None = None
    subsample: int | None = None
    identifiability: bool = True
    #: end a local fit at the settled member of a family of equal fits
    #: (:mod:`labrig.identification.settle`)
    settle: bool = True
    #: CO from a start on a subsample only: the trust region's tolerances on the step and
    #: on the cost (scipy's ``xtol`` and ``ftol``; None: scipy's 1e-8), for fits whose
    #: answer is needed to fewer digits (the cross-validation's fold fits)
    tol: float | None = None
    #: CO from a start on a subsample only: ``stop(fitness history) -> bool`` after each
    #: iteration may end the fit there (the loop's screen of its candidates,
    #: :func:`labrig.diagnosis.evidence.criteria.screen`); the history is the fitness (root mean
    #: square, as :attr:`Identification.fitness`) at the start and after each iteration
    stop: object = None

    @classmethod
    def of(cls, settings: dict) -> "FitOptions":
        """The options named in ``settings`` (keywords of :func:`identify` or
        :func:`solve`); an unknown name, or one that belongs to the problem, is the
        caller's mistake, said with its name."""
        known = {f.name for f in dataclasses.fields(cls)}
        for name in settings:
            if name in PROBLEM_SETTINGS:
                raise UserError(f"`{name}`: {PROBLEM_SETTINGS[name]} belongs to the problem "
                                "(identify's own argument, or Problem's), not the solver's "
                                "options")
            if name not in known:
                raise UserError(f"`{name}`: not an option of the identifiers; they take "
                                f"{', '.join(sorted(known))}")
        return cls(**settings)


#: what a fit is asked that is not how hard it works: the Problem's (identify takes them)
PROBLEM_SETTINGS = {"p": "the position channel's weight", "q": "the speed channel's weight",
                    "c": "the current channel's weight", "start_state": "the runs' start",
                    "masks": "the fold's samples", "weights": "the channels' weights"}


def _channel_notes(obj, p: float, q: float, params: dict, constants: dict) -> dict | None:
    """What the channels say of each other (:mod:`labrig.analysis.agreement`): a position
    that drifts against the integral of the speed and, at these weights, outweighs it; a
    fitted lag (electrical pole, delay) that is the speed sensor's own."""
    agree = None
    if "position" in obj.floors and "speed" in obj.floors:
        agree = channel_agreement(obj.runs, obj.sigma_w, obj.sigma_theta,
                                  obj.floors["position"].unit, obj.floors["speed"].unit)
    out = {}
    if agree is not None and agree.drifts and p > 0 and q > 0 \
            and p > q / agree.position_factor ** 2:
        out["position_drift"] = {**agree.to_json(), "description": agree.describe(),
                                 "suggested_p": round(q / agree.position_factor ** 2, 6)}
    if "speed" not in obj.floors:
        return out or None
    tc = time_constants(obj.plant, params, constants)
    # (a window the import found is its guess, not the owner's word)
    declared = max(0.5 * r.speed_window * r.dt if r.speed_window >= 1 and not r.window_found
                   else 0.0 for r in obj.runs)
    lag = lag_explained(agree, tc.get("tau_e_s"), params.get("delay.td_s"), tc.get("tau_m_s"),
                        declared)
    if lag:
        out["sensor_lag"] = lag
    return out or None


def identify(runs, method: str = METHOD, effects: list[Effect] = (), *, seed: int | None = SEED,
             bounds: dict | None = None, fixed: dict | None = None, start: dict | None = None,
             options: FitOptions | None = None, callback=None, dataset: dict | None = None,
             masks=None, reach=None, p: float = 1.0, q: float = 1.0, c: float = 1.0,
             start_state: str = "auto", **settings) -> Identification:
    """Fit the servo model to ``runs``.

    Parameters
    ----------
    runs : list of Run
    method : {"jfo", "pso", "co"}
    effects : list of Effect
    seed : int or None
        Recorded in the result; the same seed reproduces the fit exactly. Default
        :data:`labrig.core.defaults.SEED`; None draws a fresh one (recorded too).
    bounds, fixed : dict
        ``{name: (lower, upper)}`` and ``{name: value}``; names are R, L, J, B, K
        and ``effect.param``.
    options : FitOptions, optional
        The solver's options; or give its fields as keywords (``settings``: ``pop=30``).
    p, q, c : float
        The position, speed and (voltage plant, when measured) current channels'
        weights, each already divided by its noise level (the problem's).
    start_state : {"auto", "rest", "estimate"}
        Each run's start (:mod:`labrig.model.start`): the run file's, else its first
        samples; every run from rest; every run's fitted.
    start : dict, optional
        Physical parameters to start from (a saved model): CO starts there, JFO and
        PSO are polished from the better of their result and the start.
    masks : list of bool arrays, optional
        Per run, the samples to fit (a cross-validation fold); default all.
    reach : Reach, optional
        What the data can see (bounds of threshold effects); default from ``runs``.
    subsample : int, optional
        CO from ``start`` with one start: fit on about this many residuals (every k-th).
    """
    o = options if options is not None else FitOptions.of(settings)
    method = method.lower() if isinstance(method, str) else method  # "JFO" is jfo
    if method not in METHODS:
        raise UserError(f"`method`: unknown method '{method}'; choose {', '.join(METHODS)} or all")
    if not runs:
        raise UserError("the data set is empty: give a folder with at least one run")
    problem = Problem(runs, effects, fixed=fixed, bounds=bounds, reach=reach or Reach.of(runs),
                      weights=Weights(p=p, q=q), masks=masks, c=c, start_state=start_state)
    return solve(problem, method, seed=seed, start=start, options=o, callback=callback,
                 dataset=dataset)


def solve(problem: Problem, method: str = METHOD, *, seed: int | None = SEED,
          start=None, options: FitOptions | None = None, callback=None,
          dataset: dict | None = None, **settings) -> Identification:
    """Fit a :class:`~labrig.identification.problem.Problem`: the one entry to fitting
    (:func:`identify` builds the problem from its arguments and calls this).

    Parameters
    ----------
    problem : Problem
        The runs, the structure, what is fixed, the weights, the runs' starts, the
        folds' samples and the reach: what is fitted.
    method : {"jfo", "pso", "co"}
    seed : int or None
        As :func:`identify`'s.
    start : Model or dict, optional
        Where to start: a model, or its flat parameters.
    options : FitOptions, optional
        The solver's options; or give its fields as keywords (``settings``; a weight or
        a start state there is refused: they are the problem's).
    callback : callable, optional
        ``callback(iteration, fitness)`` as the optimiser goes.
    dataset : dict, optional
        What the fit's record says of its data set.

    Returns
    -------
    Identification
        The fit; :meth:`Identification.model` is the fitted Model.
    """
    o = options if options is not None else FitOptions.of(settings)
    method = method.lower() if isinstance(method, str) else method
    if method not in METHODS:
        raise UserError(f"`method`: unknown method '{method}'; choose {', '.join(METHODS)}")
    runs = problem.runs
    require_excitation(runs, "identify")
    if isinstance(start, Model):
        start = start.flat()
    effects, space, obj = problem.effects, problem.space, problem.objective
    t0 = time.perf_counter()  # after the simulator is ready: a first compile is not fitting
    constants = problem.constants
    lo, hi = space.search_bounds()
    x0 = space.to_search(problem.initial_point(start))
    seed = int(np.random.default_rng().integers(2 ** 31)) if seed is None else int(seed)
    opts = {"pop": o.pop, "iters": o.iters, "seed": seed, "starts": o.starts, "callback": callback,
            "max_nfev": o.max_nfev, "rule": o.rule, "subsample": o.subsample, "stop": o.stop,
            "tol": o.tol}
    mark("fit-start")
    try:
        res = METHODS[method](obj, lo, hi, x0 if (start or method == "co") else None, opts)
    except ValueError as exc:  # the optimisers name the bad argument
        raise UserError(str(exc)) from None
    mark("fit-end")
    name = method
    if method != "co" and (o.polish or start):
        best = res
        if start is not None and \
                obj.fitness_of_mean_square(np.mean(obj.solver_residuals(x0) ** 2)) < res.fun:
            best = IdentResult(x=x0, fun=float(res.fun), nfev=res.nfev, nit=res.nit,
                               history=res.history, seed=res.seed, method=method)
        res = _polish(best, obj.solver_residuals, lo, hi, jac_batch=obj.solver_residuals_batch)
        # (polish keeps the global history: the fitness already)
        res.fun = obj.fitness_of_mean_square(res.fun)
        name = f"{method}+co"
    if name.endswith("co") and not o.subsample and o.settle:
        # where the data leave the plant's parameters unpinned, the fit ends at the
        # family's settled member, not wherever the machine's rounding left it
        res = settle(res, obj, lo, hi)
        if "settled" in (res.extra or {}):   # local's mean square again
            res.fun = obj.fitness_of_mean_square(res.fun)
    mark("settle-end")
    res.nfev = max(int(res.nfev), obj.nfev)
    phys = space.to_physical(res.x[None, :])[0]
    metrics = obj.metrics(phys)
    ident = analyse_identifiability(obj, res.x, constants["Ka"]) if o.identifiability else {}
    mark("identifiability-end")
    dataset = dict(dataset or {})
    if any(r.current is not None for r in runs) and not space.plant.current_output:
        dataset["current_unused"] = True
    if obj.n_gaps:  # the samples the link lost, left out (reported, never fitted)
        dataset["gap_samples"] = int(obj.n_gaps)
    if any(st.fitted for st in space.starts):  # the runs' starts, as decided and fitted
        dataset["starts"] = start_report(space.starts, space.as_dict(phys))
    # with the identifiability report only: the loop's re-fits never show them
    notes = _channel_notes(obj, problem.weights.p, problem.weights.q, space.as_dict(phys),
                           constants) \
        if o.identifiability else None
    if notes:
        dataset.update(notes)
    return Identification(method=name, effects=effects, space=space,
                          params=space.as_dict(phys), result=res, metrics=metrics,
                          identifiable=ident, seconds=time.perf_counter() - t0,
                          constants=constants, dataset=dataset or {}, runs=list(runs))
