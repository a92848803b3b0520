"""The identification objective (the paper's eq. 26, made dimensionless).

Each channel's residual is divided by its noise level, estimated from the data, so
the weights p (position) and q (speed) are pure numbers and ``rmse_over_noise``
of 1.0 means the model explains everything the noise allows:

    fitness = sqrt( (p sum (theta_m - theta_s)^2 / s_theta^2
                    + q sum (w_m - w_s)^2 / s_w^2) / (N_theta + N_w) )
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from labrig.core.errors import UserError
from labrig.core.timing import mark_once
from labrig.model import drive_units
from labrig.model.effects import Effect
from labrig.model.effectset import EffectSet
from labrig.model.plants import VoltagePlant
from labrig.model.simulate import Simulator, prepare
from labrig.model.start import WHAT, is_start_key, run_starts, start_key
from labrig.analysis.noise import channel_floors
from labrig.simulation.residual_rows import residual_rows

#: generic plant bounds of the voltage-driven servo (SI units)
DEFAULT_BOUNDS = VoltagePlant.bounds
#: the phase mark of the first candidates simulated in a process: the kernels are loaded
#: from numba's cache and have run once (benchmarks/bench_startup.py)
FIRST_POPULATION = "first-population"


@dataclass
class Space:
    """The search space: plant and effect parameters, fixed ones removed.

    Positive parameters spanning decades are searched as log10; the optimisers see
    only the free coordinates in ``lower``/``upper``.
    """

    names: list[str]               # all parameter names: the plant's, then "effect.param"
    lower: np.ndarray              # physical bounds of every parameter
    upper: np.ndarray
    log: np.ndarray                # bool per parameter
    fixed: dict = field(default_factory=dict)  # name -> physical value
    plant: type = VoltagePlant     # the plant class (labrig.model.plants)
    #: the runs' starts (labrig.model.start.RunStart); their fitted parameters follow the
    #: effects' in ``names``, and a start point without them takes the data's estimate
    starts: list = field(default_factory=list)
    estimates: dict = field(default_factory=dict)

    def add_starts(self, starts) -> None:
        """Append the fitted start parameters of ``starts`` (once)."""
        if self.starts:
            return
        self.starts = list(starts)
        keys, lo, hi = [], [], []
        for st in self.starts:
            for key, est, a, b in st.params():
                keys.append(key), lo.append(a), hi.append(b)
                self.estimates[key] = est
            for key, v in st.held().items():   # known from the data, not searched
                self.fixed.setdefault(key, v)
        if keys:
            self.names = list(self.names) + keys
            self.lower = np.concatenate([self.lower, lo])
            self.upper = np.concatenate([self.upper, hi])
            self.log = np.concatenate([self.log, np.zeros(len(keys), bool)])

    @property
    def free(self) -> list[str]:
        return [n for n in self.names if n not in self.fixed]

    @property
    def free_idx(self) -> np.ndarray:
        return np.array([i for i, n in enumerate(self.names) if n not in self.fixed], int)

    def _fwd(self, v, idx):
        return np.where(self.log[idx], np.log10(np.maximum(v, 1e-300)), v)

    def search_bounds(self):
        i = self.free_idx
        return self._fwd(self.lower[i], i), self._fwd(self.upper[i], i)

    def to_search(self, physical: dict) -> np.ndarray:
        i = self.free_idx
        v = np.array([self._value(physical, self.names[k]) for k in i], float)
        lo, hi = self.lower[i], self.upper[i]
        return self._fwd(np.clip(v, lo, hi), i)

    def to_physical(self, X: np.ndarray) -> np.ndarray:
        """(P, D_free) search coordinates -> (P, D_all) physical values."""
        X = np.atleast_2d(X)
        out = np.empty((X.shape[0], len(self.names)))
        i = self.free_idx
        out[:, i] = np.where(self.log[i], 10.0 ** X, X)
        for n, v in self.fixed.items():
            if n in self.names:   # (a fixed start of a run this space does not hold: none)
                out[:, self.names.index(n)] = v
        return out

    def _value(self, physical: dict, name: str) -> float:
        """A parameter's value from a flat dict; a run's start it lacks: the data's estimate."""
        if name not in physical and name in self.estimates:
            return self.estimates[name]
        return physical[name]

    def physical_row(self, physical: dict) -> np.ndarray:
        """Every parameter's physical value from a model's flat dict, in ``names``' order."""
        return np.array([self._value(physical, n) for n in self.names], float)

    def as_dict(self, row: np.ndarray) -> dict:
        return {n: float(v) for n, v in zip(self.names, row)}


def _drive_names(effects, plant, reach) -> dict:
    """``{"coulomb_friction.tc_nm": ("coulomb_friction.tc_v", kd)}``: the effects' levels
    as a torque or force drive's output names them (:func:`drive_units.shown_keys`),
    lower case, to their own names and factors; empty on a voltage drive."""
    consts = {"Ka": reach.Ka if reach is not None else 1.0}
    return {shown.lower(): (key, f) for key, (shown, f, _) in
            drive_units.shown_keys(effects, plant.kind, consts).items()}


def build_space(effects: list[Effect], bounds: dict | None = None, fixed: dict | None = None,
                reach=None, plant=VoltagePlant) -> Space:
    """The search space of ``plant`` (a class of :mod:`labrig.model.plants`) and
    ``effects``; ``reach`` (:class:`labrig.model.reach.Reach`) replaces the catalogue's
    bounds of threshold effects by what the data can see."""
    effects = EffectSet.parse(effects)
    data = {f"{e.name}.{k}": v for e in effects for k, v in
            (e.data_bounds(reach).items() if reach is not None else ())}
    # "Deadband.d_v" is deadband.d_v: an effect's name is user input in any case
    known = {key.lower(): key for key, *_ in effects.bounds()}
    user = {known.get(k.lower(), k): v for k, v in (bounds or {}).items()}
    fixed = {known.get(k.lower(), k): v for k, v in (fixed or {}).items()}
    # a torque or force drive's levels may be given as the output names them (tc_nm, N m)
    shown = _drive_names(effects, plant, reach)
    user = {shown[k.lower()][0] if k.lower() in shown else k:
            tuple(x / shown[k.lower()][1] for x in v) if k.lower() in shown else v
            for k, v in user.items()}
    fixed = {shown[k.lower()][0] if k.lower() in shown else k:
             v / shown[k.lower()][1] if k.lower() in shown else v for k, v in fixed.items()}
    bounds = {**data, **user}
    names, lo, hi, log = [], [], [], []
    for n in plant.names:
        names.append(n)
        a, b = bounds.pop(n, plant.bounds[n])
        lo.append(a), hi.append(b), log.append(True)
    for key, a0, b0, lg in effects.bounds():
        a, b = bounds.pop(key, (a0, b0))
        names.append(key), lo.append(a), hi.append(b), log.append(bool(lg and a > 0))
    back = {key: name for name, (key, _) in shown.items()}   # as the output names them
    listed = ", ".join(back.get(n, n) for n in names)
    if bounds:
        raise UserError(f"`bounds`: unknown parameter '{sorted(bounds)[0]}'; the model has "
                        f"{listed}")
    for n, v in fixed.items():
        if n not in names and not is_start_key(n):  # (a run's start joins with the runs)
            raise UserError(f"`fixed`: unknown parameter '{n}'; the model has {listed}")
    for n, a, b in zip(names, lo, hi):
        if not a < b:
            raise UserError(f"`bounds`: {n} has lower {a:g} >= upper {b:g}")
    if len([n for n in fixed if not is_start_key(n)]) >= len(names):
        raise UserError("`fixed`: every parameter is fixed; nothing left to identify")
    return Space(names, np.array(lo, float), np.array(hi, float), np.array(log), fixed, plant)


class Objective:
    """Population-vectorised residuals and fitness of a model on a data set."""

    def __init__(self, runs, effects: list[Effect], space: Space, p: float = 1.0,
                 q: float = 1.0, substeps: int | None = None, masks=None, c: float = 1.0,
                 start: str = "auto"):
        if not runs:
            raise UserError("the data set is empty: give a folder with at least one run")
        self.runs = prepare(runs)
        self.effects = EffectSet.parse(effects)
        self.space = space
        self.p, self.q, self.c = float(p), float(q), float(c)
        if self.p < 0 or self.q < 0 or self.c < 0 or self.p + self.q == 0:
            raise UserError("weights: p, q and i must be >= 0, and p and q not both 0")
        self.plant = space.plant
        self.n_plant = len(self.plant.names)
        self.sim = Simulator(self.runs, self.effects, substeps=substeps, plant=self.plant)
        #: each channel's noise floor, measured moving and at rest (labrig.analysis.noise)
        self.floors = channel_floors(self.runs, (self.plant.position_unit(),
                                                   self.plant.speed_unit()))
        if not self.plant.current_output:  # a current-mode drive's current says nothing new
            self.floors.pop("current", None)
        self.sigma_w = self.floors["speed"].sigma if "speed" in self.floors else 1.0
        self.sigma_theta = self.floors["position"].sigma if "position" in self.floors else 1.0
        self.sigma_i = self.floors["current"].sigma if "current" in self.floors else 1.0
        self.use_w = "speed" in self.floors and self.q > 0
        self.use_theta = "position" in self.floors and self.p > 0
        self.use_i = "current" in self.floors and self.c > 0
        # each run's start: from rest, or its initial state fitted (labrig.model.start); a
        # space shared by several objectives keeps the starts it was given first
        space.add_starts(run_starts(self.runs, self.sigma_w if "speed" in self.floors else None,
                                    self.sigma_theta if "position" in self.floors else None,
                                    start, self.sigma_i if self.use_i else None,
                                    play=any("a" in e.kernel_columns.values()
                                             for e in self.effects)))
        self._start_cols = [{what: space.names.index(start_key(r.name, what)) for what in WHAT
                             if start_key(r.name, what) in space.names} for r in self.runs]
        self._started = any(self._start_cols)
        #: per run, the samples the fit sees (cross-validation folds, and never a sample
        #: the link lost); None: all
        self.masks = None if masks is None else [np.asarray(m, bool) for m in masks]
        if any(r.measured is not None for r in self.runs):
            self.masks = [r.keep() if self.masks is None else self.masks[j] & r.keep()
                          for j, r in enumerate(self.runs)]
        #: samples lost on the link, left out of the fit
        self.n_gaps = sum(int(np.count_nonzero(~r.measured)) for r in self.runs
                          if r.measured is not None)
        counts = [len(r.u) if self.masks is None else int(m.sum())
                  for r, m in zip(self.runs, self.masks or [None] * len(self.runs))]
        self.n_w = sum(c for r, c in zip(self.runs, counts) if r.w is not None) if self.use_w else 0
        self.n_theta = sum(c for r, c in zip(self.runs, counts)
                           if r.theta is not None) if self.use_theta else 0
        self.n_i = sum(c for r, c in zip(self.runs, counts)
                       if r.current is not None) if self.use_i else 0
        self.m = self.n_w + self.n_theta + self.n_i
        self.nfev = 0
        self._layouts: dict = {}   # stride -> the residual vector's layout (_layout)
        self._weights = [(r.w, np.sqrt(self.q) / self.sigma_w if self.use_w and r.w is not None else 0.0,
                          r.theta, np.sqrt(self.p) / self.sigma_theta
                          if self.use_theta and r.theta is not None else 0.0,
                          r.current, np.sqrt(self.c) / self.sigma_i
                          if self.use_i and r.current is not None else 0.0) for r in self.runs]

    # -- parameters -------------------------------------------------------------------
    def split(self, phys: np.ndarray):
        """(P, D_all) physical -> plant (P, n_plant), {effect: {param: (P,)}}."""
        return phys[:, :self.n_plant], self.effects.split(phys, offset=self.n_plant)

    def run_starts(self, phys: np.ndarray) -> list | None:
        """(P, D_all) physical -> per run None or ``{"w0": (P,), "i0": (P,), "dtheta": (P,),
        "gap0": (P,)}`` (what is fitted of it)."""
        if not self._started:
            return None
        return [{what: phys[:, c] for what, c in cols.items()} or None
                for cols in self._start_cols]

    def simulate_physical(self, phys: np.ndarray) -> list[dict]:
        phys = np.atleast_2d(phys)
        plant, ep = self.split(phys)
        return self.sim.simulate(plant, ep, self.run_starts(phys))

    # -- residuals ----------------------------------------------------------------------
    def thinning(self, about: int) -> int:
        """The stride at which a fit sees about ``about`` residuals (every k-th)."""
        return max(1, self.m // about)

    def _layout(self, stride: int) -> list:
        """Per run and channel: (run, simulated key, measured samples kept, their index
        in the run, scale), in the residual vector's order; every ``stride``-th residual
        of the whole vector (computed once per stride: the measured side never changes)."""
        if stride in self._layouts:
            return self._layouts[stride]
        out, k = [], 0   # k: where the next channel starts among all residuals
        for j, r in enumerate(self.runs):
            for use, meas, key, scale in (
                    (self.use_theta, r.theta, "theta", np.sqrt(self.p) / self.sigma_theta),
                    (self.use_w, r.w, "w", np.sqrt(self.q) / self.sigma_w),
                    (self.use_i, r.current, "i", np.sqrt(self.c) / self.sigma_i)):
                if use and meas is not None:
                    first = -k % stride
                    if self.masks is None:
                        idx, k = np.arange(first, len(meas), stride), k + len(meas)
                    else:
                        kept = np.flatnonzero(self.masks[j])
                        idx, k = np.ascontiguousarray(kept[first::stride]), k + len(kept)
                    out.append((j, key, np.ascontiguousarray(meas[idx], dtype=float), idx,
                                float(scale)))
        self._layouts[stride] = out
        return out

    def _stack(self, sims, stride: int = 1) -> np.ndarray:
        """(P, m) residuals, or every ``stride``-th of them (the same ones as
        ``[:, ::stride]`` of all, without computing the rest)."""
        P = sims[0]["w"].shape[0]
        R = np.empty((P, -(-self.m // stride)))
        o = 0
        for j, key, meas, idx, scale in self._layout(stride):
            # clipped: a wild candidate (unstable, overflowing) must not poison the sums
            residual_rows(R, o, meas, np.ascontiguousarray(sims[j][key]), idx, scale)
            o += len(meas)
        return R

    # Two scales of the same residuals, each named for what its squares sum to:
    # noise_residuals, each in its channel's noise units (their root mean square over
    # the m residuals is the fitness); solver_residuals, those divided by sqrt(m) (the sum
    # of their squares is the fitness squared: what least squares minimises, and a
    # solver's mean square of them, local's ``fun``, is the fitness squared over m).
    def noise_residuals(self, X: np.ndarray, stride: int = 1) -> np.ndarray:
        """(P, D_free) search points -> (P, m) residuals in noise units (every
        ``stride``-th: the loop's re-fits see a subsample); their root mean square is
        the fitness."""
        X = np.atleast_2d(X)
        self.nfev += X.shape[0]
        with np.errstate(all="ignore"):
            R = self._stack(self.simulate_physical(self.space.to_physical(X)), stride)
        mark_once(FIRST_POPULATION)
        return R

    def solver_residuals(self, x: np.ndarray, stride: int = 1) -> np.ndarray:
        """One search point -> (m,) residuals whose sum of squares is the fitness squared
        (:meth:`noise_residuals` over sqrt(m), m all of them even when thinned)."""
        return self.noise_residuals(x[None, :], stride)[0] / np.sqrt(self.m)

    def solver_residuals_batch(self, X: np.ndarray, stride: int = 1) -> np.ndarray:
        """(P, D_free) -> (P, m) :meth:`solver_residuals` (a Jacobian's rows)."""
        return self.noise_residuals(X, stride) / np.sqrt(self.m)

    def fitness_of_mean_square(self, mean_square: float) -> float:
        """The fitness of a solver's mean square of :meth:`solver_residuals` (local's
        ``fun`` and history): sqrt(mean square * m), thinned or not."""
        return float(np.sqrt(mean_square * self.m))

    def fitness_batch(self, X: np.ndarray) -> np.ndarray:
        """(P, D_free) -> (P,) fitness; the fused kernel never stores trajectories."""
        X = np.atleast_2d(X)
        if self.masks is not None:  # a fold: the residuals of its samples
            R = self.noise_residuals(X)
            f = np.sqrt(np.sum(R ** 2, axis=1) / self.m)
            return np.where(np.isfinite(f), f, np.inf)
        self.nfev += X.shape[0]
        phys = self.space.to_physical(X)
        plant, ep = self.split(phys)
        with np.errstate(all="ignore"):
            f = np.sqrt(self.sim.sse(plant, ep, self._weights, self.run_starts(phys)) / self.m)
        mark_once(FIRST_POPULATION)
        return np.where(np.isfinite(f), f, np.inf)

    # -- adequacy measures (docs/physics.md, 'The objective') -------------------------
    def metrics(self, phys_row: np.ndarray) -> dict:
        sims = self.simulate_physical(phys_row[None, :])
        return adequacy(self.runs, sims, self.sigma_w, self.sigma_theta, self.p, self.q,
                        sigma_i=self.sigma_i if self.use_i else None, c=self.c,
                        units=self.plant.position_unit())


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """MATLAB ``compare``'s fit: 100 (1 - ||y - yhat|| / ||y - mean(y)||)."""
    return float(100 * (1 - np.linalg.norm(y - yhat) / max(np.linalg.norm(y - y.mean()), 1e-300)))


def adequacy(runs, sims, sigma_w, sigma_theta, p=1.0, q=1.0, index=0, sigma_i=None,
             c=1.0, units="rad") -> dict:
    """fitness, rmse_over_noise (overall/per channel/per run) and fit_percent; the
    current is a channel when ``sigma_i`` is given (a voltage plant with current measured).
    A simulation that overflowed gives a non-finite fitness (a failed start, said by the
    caller), without a warning."""
    with np.errstate(over="ignore", invalid="ignore"):
        return _adequacy(runs, sims, sigma_w, sigma_theta, p, q, index, sigma_i, c, units)


def _adequacy(runs, sims, sigma_w, sigma_theta, p, q, index, sigma_i, c, units) -> dict:
    sq = {"speed": [], "position": [], "current": []}
    meas = {"speed": [], "position": [], "current": []}
    per_run = {}
    for r, s in zip(runs, sims):
        entry = {}
        keep = r.keep()  # a sample the link lost has no residual
        for ch, y, yh, sig in (("speed", r.w, s["w"][index], sigma_w),
                               ("position", r.theta, s["theta"][index], sigma_theta),
                               ("current", getattr(r, "current", None) if sigma_i else None,
                                s["i"][index] if "i" in s else None, sigma_i)):
            if y is None:
                continue
            y, yh = y[keep], yh[keep]
            e = (y - yh) / sig
            sq[ch].append(e ** 2)
            meas[ch].append((y, yh))
            entry[ch] = float(np.sqrt(np.mean(e ** 2)))
        per_run[r.name] = entry
    # the keys keep the rotary names (speed_rad_s, position_rad); ``units`` says the axis's
    noise = {"speed_rad_s": sigma_w, "position_rad": sigma_theta}
    if units != "rad":
        noise["units"] = {"position": units, "speed": units + "/s"}
    if sigma_i:
        noise["current_a"] = sigma_i
    out = {"rmse_over_noise": {}, "fit_percent": {}, "per_run": per_run, "noise": noise}
    tot, n = 0.0, 0
    for ch, w in (("speed", q), ("position", p), ("current", c)):
        if not sq[ch]:
            continue
        e2 = np.concatenate(sq[ch])
        out["rmse_over_noise"][ch] = float(np.sqrt(np.mean(e2)))
        tot += w * e2.sum()
        n += len(e2)
        y = np.concatenate([a for a, _ in meas[ch]])
        yh = np.concatenate([b for _, b in meas[ch]])
        out["fit_percent"][ch] = fit_percent(y, yh)
    allsq = np.concatenate([np.concatenate(v) for v in sq.values() if v])
    out["rmse_over_noise"]["overall"] = float(np.sqrt(np.mean(allsq)))
    out["fitness"] = float(np.sqrt(tot / n))
    return out
