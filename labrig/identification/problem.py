"""What a fit is asked, in one object: the runs, the model's structure, what is fixed,
the channel weights, the folds' samples and what the data reach.

Identification alone turns a problem into the optimisers' form (the search space, the
objective over the runs, a model's parameters as a search vector); the loop above asks
a problem for a model's fitness or hands it to :func:`labrig.identification.engine.solve`,
and never builds a space or an objective itself.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np

from labrig.analysis.noise import Weights
from labrig.core.defaults import LOOP_GAINS
from labrig.identification.objective import Objective, Space, build_space
from labrig.model.effectset import EffectSet
from labrig.model.model import Model
from labrig.model.plants import plant_of_runs


def dataset_constants(runs) -> dict:
    """Known rig constants from the runs' sidecars (the first run speaks for all)."""
    closed = [r.gains for r in runs if r.loop == "closed"]
    # step metrics are for the data's own loop, else for the lab's standard loop (the
    # MS150's, with tacho feedback): a rig without a tacho has no such loop, and an
    # Arduino's model gets no step metrics of a loop it never ran
    if closed:
        gains = closed[0]
    elif all(r.has_tacho for r in runs):
        gains = {"kp": LOOP_GAINS["position_gain"], "kv": LOOP_GAINS["velocity_gain"]}
    else:
        gains = {}
    return {**runs[0].constants, **gains}


def start_of(model, fixed: dict | None = None) -> dict:
    """The flat values a search of ``model`` starts from: its parameters (effects' under
    dotted keys, the runs' starts) with what is ``fixed`` over them. The one place a
    :class:`Model` is flattened for a search (a flat dict is taken as it stands)."""
    flat = model.flat() if isinstance(model, Model) else dict(model)
    return {**flat, **(fixed or {})}


def initial_point(space: Space, effects, runs, constants, start: dict | None) -> dict:
    """A physical starting point: the start model where given, else the middle of the
    (log) box for the plant and each effect's data-driven guess."""
    mid = {n: float(np.sqrt(lo * hi)) if lg else 0.5 * (lo + hi)
           for n, lo, hi, lg in zip(space.names, space.lower, space.upper, space.log)}
    point = dict(mid)
    if start:
        point.update({k: v for k, v in start.items() if k in point})
    plant = space.plant.servo(point, constants)
    for key, v in EffectSet.parse(effects).initial_guess(runs, plant).items():
        if not (start and key in start):
            point[key] = v
    point.update(space.fixed)
    return point


class Problem:
    """A fitting problem: ``runs`` and a structure (``effects`` on the runs' plant).

    Parameters
    ----------
    runs : list of Run
        The data; the plant is theirs unless ``plant`` is given.
    effects : EffectSet, list of Effect or str
        The model's effects (its structure); see :meth:`of` to take them from a
        :class:`~labrig.model.model.Model`.
    fixed : dict, optional
        ``{name: value}`` held where they are (plant names and ``effect.param``).
    bounds : dict, optional
        ``{name: (lower, upper)}`` in place of the catalogue's.
    reach : Reach, optional
        What the data can see (the bounds of threshold effects); None keeps the
        catalogue's bounds.
    weights : Weights, optional
        The position and speed channels' weights (in noise units).
    masks : list of bool arrays, optional
        Per run, the samples to fit (a cross-validation fold's training part).
    plant : plant class, optional
        Default: the runs' (:func:`labrig.model.plants.plant_of_runs`).
    c : float
        The measured current's weight (voltage plant).
    start_state : str
        Each run's start: ``"auto"``, ``"rest"`` or ``"estimate"`` (labrig.model.start).

    Examples
    --------
    >>> import labrig as lr
    >>> from labrig.identification.problem import Problem
    >>> runs = lr.read_runs("data/sweep_default")
    >>> model = lr.identify(runs).model()  # doctest: +SKIP
    >>> Problem.of(runs, model).fitness([model])  # doctest: +SKIP
    """

    def __init__(self, runs, effects=(), *, fixed: dict | None = None,
                 bounds: dict | None = None, reach=None, weights: Weights | None = None,
                 masks=None, plant=None, c: float = 1.0, start_state: str = "auto"):
        self.runs = list(runs)
        self.effects = EffectSet.parse(effects)
        self.fixed = dict(fixed or {})
        self.bounds = bounds
        self.reach = reach
        self.weights = weights or Weights()
        self.masks = masks
        self._plant = plant
        self.c = c
        self.start_state = start_state
        self._sealed = True

    def __setattr__(self, name, value):
        # the space and the objective are built from these once (cached): a problem
        # changed afterwards would be fitted as it was. A new problem, not a changed one.
        if getattr(self, "_sealed", False):
            raise AttributeError(f"Problem.{name}: a problem is fixed once made (its space "
                                 "and objective are built from it); make a new Problem")
        object.__setattr__(self, name, value)

    @classmethod
    def of(cls, runs, model: Model, **kw) -> "Problem":
        """The problem of ``model``'s structure (its effects, its plant) on ``runs``."""
        return cls(runs, model.effects, plant=model.plant_class, **kw)

    @cached_property
    def plant(self):
        """The plant class: the one given, else the runs'."""
        return self._plant if self._plant is not None else plant_of_runs(self.runs)

    @cached_property
    def constants(self) -> dict:
        """The rig's known constants from the runs' sidecars (:func:`dataset_constants`)."""
        return dataset_constants(self.runs)

    @cached_property
    def _bare_space(self) -> Space:
        return build_space(self.effects, self.bounds, self.fixed, reach=self.reach,
                           plant=self.plant)

    @property
    def space(self) -> Space:
        """The search space (bounds, scaling, what is fixed), with the runs' fitted starts
        the objective adds to it: it is whole only once the objective is built, so asking
        for it builds both."""
        self.objective
        return self._bare_space

    @cached_property
    def objective(self) -> Objective:
        """The runs' residuals and fitness over the space."""
        return Objective(self.runs, self.effects, self._bare_space, p=self.weights.p,
                         q=self.weights.q, masks=self.masks, c=self.c,
                         start=self.start_state)

    def initial_point(self, start: dict | None = None) -> dict:
        """A physical starting point: ``start`` where it gives a value, else the middle of
        the (log) box for the plant and each effect's data-driven guess
        (:func:`initial_point`)."""
        return initial_point(self.space, self.effects, self.runs, self.constants, start)

    # -- a model's values in the optimisers' form --------------------------------------------
    def point(self, values) -> np.ndarray:
        """The search vector of ``values`` (a Model or a flat dict), what is fixed over it."""
        return self.space.to_search(start_of(values, self.fixed))

    def values(self, x: np.ndarray) -> dict:
        """The flat physical parameters of the search vector ``x``."""
        return self.space.as_dict(self.space.to_physical(np.asarray(x)[None, :])[0])

    def bounds_of_search(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the search vector."""
        return self.space.search_bounds()

    def simulate(self, model: Model) -> list[dict]:
        """``model`` simulated on the runs (the objective's prepared runs): per run, its
        channels as one-row arrays (:meth:`Objective.simulate_physical`)."""
        return self.objective.simulate_physical(self.space.physical_row(model.flat())[None, :])

    def fitness(self, points) -> np.ndarray:
        """The fitness of each of ``points`` (Models or flat dicts), one population call."""
        return self.objective.fitness_batch(np.array([self.point(p) for p in points]))

    def fitness_of_vectors(self, X) -> np.ndarray:
        """The fitness of each row of ``X`` (search vectors)."""
        return self.objective.fitness_batch(np.asarray(X))

    def thinned_fitness(self, values, k: int) -> float:
        """The fitness of ``values`` on every ``k``-th residual's thinning (what a re-fit on
        a subsample sees, :meth:`Objective.thinning`)."""
        stride = self.objective.thinning(k)
        R = self.objective.noise_residuals(self.point(values)[None, :], stride)[0]
        return float(np.sqrt(np.mean(R ** 2)))
