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
from dataclasses import dataclass, field

import numpy as np

from .errors import UserError
from .identify.engine import identify, dataset_constants
from .identify.objective import Objective, build_space
from .model.effects import CATALOGUE, get_effect
from .model.simulate import prepare
from .residuals import REGIME_TEXT, autocorr, regime_table, run_residuals, worst_regime
from .runs import require_excitation

#: a candidate must beat the model by this much (relative) on all runs and on held-out runs
MIN_GAIN = 0.05
#: and be strongly supported by BIC (Kass & Raftery: |dBIC| > 10 is "very strong")
MIN_DBIC = -10.0
#: below this rmse/noise the model is at the noise floor (simulation residuals are
#: slightly coloured even for the right model; docs/physics.md, "The noise floor")
FLOOR = 1.15


@dataclass
class ModelState:
    """A model in flat form: plant params, effect objects and their params."""

    params: dict                         # R..K and "effect.param"
    effects: list = field(default_factory=list)

    @classmethod
    def from_model(cls, model: dict) -> "ModelState":
        params = dict(model["params"])
        for e, ps in model.get("effect_params", {}).items():
            params.update({f"{e}.{k}": v for k, v in ps.items()})
        return cls(params=params, effects=list(model.get("effect_objects", [])))

    @classmethod
    def from_identification(cls, ident) -> "ModelState":
        return cls(params=dict(ident.params), effects=list(ident.effects))

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]


def evaluate(runs, state: ModelState, sigmas=None) -> dict:
    """Simulate a model on runs: metrics, per-run residuals and the regime table."""
    space = build_space(state.effects)
    obj = Objective(runs, state.effects, space)
    if sigmas is not None:
        obj.sigma_w, obj.sigma_theta = sigmas
    phys = np.array([state.params[n] for n in space.names])
    sims = obj.simulate_physical(phys[None, :])
    from .identify.objective import adequacy

    metrics = adequacy(obj.runs, sims, obj.sigma_w, obj.sigma_theta)
    per_run = [run_residuals(rd, {"w": s["w"][0], "theta": s["theta"][0]}, obj.sigma_w,
                             obj.sigma_theta) for rd, s in zip(obj.runs, sims)]
    r = np.concatenate([c["residual"] for rr in per_run for c in rr["channels"].values()])
    return {"metrics": metrics, "per_run": per_run, "regimes": regime_table(per_run),
            "sse": float(np.sum(r ** 2)), "n": int(len(r)), "sigmas": (obj.sigma_w, obj.sigma_theta),
            "rho1": float(np.mean([autocorr(c["residual"], 1)[0] for rr in per_run
                                   for c in rr["channels"].values()]))}


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


def refit_with(runs, base: ModelState, effect, seed=0, user_fixed=None) -> ModelState:
    """Warm-started re-fit: the new effect's parameters first (all else fixed at the
    current model), then every parameter from there."""
    effects = base.effects + [effect]
    fixed = {k: v for k, v in base.params.items()}
    fixed.update(user_fixed or {})
    stage1 = _fit(runs, effects, base.params, fixed, starts=3, seed=seed)
    stage2 = _fit_from(runs, effects, stage1.params, dict(user_fixed or {}), seed)
    best = stage2 if stage2.fitness <= stage1.fitness else stage1
    return ModelState(params=dict(best.params), effects=effects)


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


def diagnose(runs, model: dict | None = None, *, candidates=None, seed: int = 0,
             fixed: dict | None = None, progress=None) -> dict:
    """Locate the model's error and rank the missing effects (keys: docs/design.md, 'Commands')."""
    t0 = time.perf_counter()
    if not runs:
        raise UserError("the data set is empty: give a folder with at least one run")
    require_excitation(runs, "diagnose")
    if model is None:
        ident = identify(runs, "co", [], seed=seed, starts=4, fixed=fixed, identifiability=False)
        ident = min([ident, _fit_from(runs, [], ident.params, dict(fixed or {}), seed)],
                    key=lambda f: f.fitness)
        base = ModelState.from_identification(ident)
        base_source = "identified without effects (co)"
    else:
        base = ModelState.from_model(model)
        base_source = "the given model"
    ev0 = evaluate(runs, base)
    sig = ev0["sigmas"]
    n = ev0["n"]
    rho = min(max(ev0["rho1"], 0.0), 0.995)
    n_eff = max(n * (1 - rho) / (1 + rho), 10.0)
    k0 = len(build_space(base.effects).names) - len(fixed or {})
    bic0 = _bic(ev0["sse"], n, n_eff, k0)
    rmse0 = ev0["metrics"]["rmse_over_noise"]["overall"]

    train, held = _held_out_split(runs)
    base_train = None
    if held:
        fit = _fit_from(train, base.effects, base.params, dict(fixed or {}), seed)
        base_train = ModelState.from_identification(fit)
        held0 = evaluate(held, base_train, sig)["metrics"]["rmse_over_noise"]["overall"]

    names = candidates or [n_ for n_ in CATALOGUE if n_ not in base.names]
    taken = {e.stage for e in base.effects if e.stage in ("friction", "output", "delay")}
    ranking = []
    for i, name in enumerate(names):
        eff = get_effect(name)
        if eff.stage in taken:
            continue  # one friction law, one output map, one delay per model
        if progress:
            progress(i, name)
        cand = refit_with(runs, base, eff, seed=seed, user_fixed=fixed)
        ev = evaluate(runs, cand, sig)
        k = k0 + len(eff.params)
        bic = _bic(ev["sse"], n, n_eff, k)
        entry = {"effect": name, "rmse_over_noise": ev["metrics"]["rmse_over_noise"]["overall"],
                 "improvement": 1.0 - ev["metrics"]["rmse_over_noise"]["overall"] / rmse0,
                 "delta_bic": bic - bic0,
                 "params": {p.name: cand.params[f"{name}.{p.name}"] for p in eff.params},
                 "fit_percent": ev["metrics"]["fit_percent"], "_regimes": ev["regimes"],
                 "_state": cand}
        if held:
            fit = _fit_from(train, cand.effects, cand.params, dict(fixed or {}), seed)
            held1 = evaluate(held, ModelState.from_identification(fit), sig)["metrics"]["rmse_over_noise"]["overall"]
            entry["held_out"] = {"runs": [r.name for r in held], "baseline": held0,
                                 "with_effect": held1, "improvement": 1.0 - held1 / held0}
        ranking.append(entry)
    ranking.sort(key=lambda e: e["delta_bic"])
    const = dict(dataset_constants(runs),
                 amin=min([r.amplitude for r in runs if r.loop == "open"] or [1.0]))
    at_floor = rmse0 <= FLOOR
    for e in ranking:
        ho = e.get("held_out")
        e["supported"] = bool(not at_floor and e["delta_bic"] < MIN_DBIC and e["improvement"] >= MIN_GAIN
                              and (ho is None or ho["improvement"] >= MIN_GAIN))
        e["explanation"] = explain(e, ev0, rmse0, base, const)
    supported = [e for e in ranking if e["supported"]]
    rec = supported[0]["effect"] if supported else None
    worst = worst_regime(ev0["regimes"])
    regimes = {"by_regime": ev0["regimes"]["by_regime"], "by_amplitude": ev0["regimes"]["by_amplitude"],
               "worst": None if worst is None else {"channel": worst[0], "regime": worst[1],
                                                     "rmse_over_noise": worst[2]},
               "noise": ev0["metrics"]["noise"]}
    if at_floor:
        verdict = (f"The model is at the noise floor (rmse/noise {rmse0:.2f} <= {FLOOR}): "
                   "nothing is missing that these data can show.")
    elif rec is None:
        verdict = (f"The model misses (rmse/noise {rmse0:.2f}) but no catalogue effect earns its "
                   "parameters on BIC and held-out data; the cause may be outside the catalogue "
                   "(write your own effect: docs/physics.md, 'Writing your own effect') or "
                   "in the sensors' calibration.")
    else:
        verdict = f"Add {rec}: " + supported[0]["explanation"]
    return {"baseline": {"source": base_source, "effects": base.names,
                         "fitness": ev0["metrics"]["fitness"],
                         "rmse_over_noise": ev0["metrics"]["rmse_over_noise"],
                         "fit_percent": ev0["metrics"]["fit_percent"], "bic": bic0,
                         "n": n, "n_effective": n_eff},
            "regimes": regimes,
            "ranking": [{k: v for k, v in e.items() if not k.startswith("_")} for e in ranking],
            "recommendation": rec, "verdict": verdict,
            "held_out": [r.name for r in held] if held else None,
            "criteria": {"min_improvement": MIN_GAIN, "max_delta_bic": MIN_DBIC, "floor": FLOOR},
            "seconds": round(time.perf_counter() - t0, 2),
            "_states": {e["effect"]: e["_state"] for e in ranking}, "_base": base,
            "_evaluation": ev0}


def _param_words(name, params, base: ModelState, const) -> str:
    p = base.params
    if name in ("coulomb_friction", "stiction"):
        # Tc in N m is not identifiable (it slides along the model's symmetry with R
        # and J); its size relative to the drive is
        s = (f"tc_v = {params['tc_v']:.3g} V: friction cancels the first {params['tc_v']:.3g} V "
             f"of drive ({100 * params['tc_v'] / const['amin']:.0f} % of the smallest amplitude, "
             f"{const['amin']:.2g} V)")
        if name == "stiction":
            s += f", breakaway {1 + params['excess']:.2f} x Coulomb"
        return s
    if name == "deadband":
        return f"d = {params['d_v']:.3g} V at the bridge input"
    if name == "saturation":
        return (f"vmax = {params['vmax_v']:.3g} V at the armature, i.e. inputs above "
                f"{params['vmax_v'] / const['Ka']:.3g} V saturate")
    if name == "backlash":
        return f"half gap a = {params['a_rad']:.3g} rad = {math.degrees(params['a_rad']):.2f} deg at the output shaft"
    if name == "delay":
        return f"Td = {params['td_s'] * 1e3:.3g} ms"
    return ", ".join(f"{k} = {v:.3g}" for k, v in params.items())


def explain(entry, ev0, rmse0, base, const) -> str:
    """Plain words with numbers: what, where in these runs, how much, how to confirm."""
    eff = get_effect(entry["effect"])
    # the regime where this candidate removes the most error
    gains = []
    for ch, regs in ev0["regimes"]["by_regime"].items():
        for reg, v in regs.items():
            new = entry["_regimes"]["by_regime"].get(ch, {}).get(reg)
            if new and v["share_of_time"] > 0.005:
                gains.append((v["rmse_over_noise"] - new["rmse_over_noise"], ch, reg,
                              v["rmse_over_noise"], new["rmse_over_noise"]))
    gains.sort(reverse=True)
    where = ""
    if gains and gains[0][0] > 0:
        _, ch, reg, a, b = gains[0]
        where = f" Its signature is in the {REGIME_TEXT[reg]} stretches of the {ch}: rmse/noise {a:.2f} -> {b:.2f}."
    ho = entry.get("held_out")
    held = (f" On the held-out run {', '.join(ho['runs'])}: {ho['baseline']:.2f} -> {ho['with_effect']:.2f}."
            if ho else " (No held-out run: fewer than three open-loop amplitudes.)")
    verdict = ("It earns its parameters." if entry.get("supported") else
               "It does not earn its parameters on these data.")
    return (f"{eff.summary[0].upper()}{eff.summary[1:]}. Fitted: "
            f"{_param_words(entry['effect'], entry['params'], entry['_state'], const)}. "
            f"rmse/noise {rmse0:.2f} -> {entry['rmse_over_noise']:.2f} on all runs, "
            f"delta BIC {entry['delta_bic']:.0f}.{held}{where} {verdict} "
            f"Expected signature: {eff.signature}. To confirm: {eff.experiment}.")
