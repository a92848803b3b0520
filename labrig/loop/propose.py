"""``labrig propose``: the experiment that tells two explanations apart (docs/physics.md,
'Experiments that decide').

Two model structures explain the data about equally well (a dead zone and Coulomb
friction, stiction and a dead zone, backlash and a delay). Each is fitted to the data;
then every candidate input of :mod:`labrig.loop.inputs` is simulated with both (one
population call of the fast simulator per model), and the most promising few are judged
by the T-optimal criterion of Atkinson and Fedorov: the rival is re-fitted to the
other's predicted response (old data and the new run together, with the noise the rig
has) and what it still cannot explain is the predicted difference. A naive difference of
the two fitted models overstates it, because the rival adjusts. Both directions are tried
(either explanation may be the true one) and the input whose worse direction differs most
wins.

The *predicted difference* is the sum of squared differences of the two predictions, in
noise units (:func:`_difference`). It is not the *separation* that
:mod:`labrig.loop.decide` reports once the run is made (the worse explanation's
rmse/noise over the better one's, minus one); the JSON keys keep their names
(``separation``, ``naive``, ``after_refit``).
"""
from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from labrig.core.errors import UserError
from labrig.loop.inputs import Candidate, candidates, why
from labrig.model.effects import catalogue_name, get_effect
from labrig.model.model import Model
from labrig.analysis.noise import Weights, channel_floors
from labrig.loop.refit import fit, refit_with, without
from labrig.io.runs import Run
from labrig.core.display import Displayable
from labrig.core.tables import Table

LEAD_IN_S = 0.5
#: what a proposal predicts, in the words every text line uses ("separation" is the
#: decision's rmse ratio minus one, labrig.loop.decide)
DIFFERENCE = "sum of squared differences of the two predictions, in noise units"


@dataclass
class Hypothesis:
    """One explanation, fitted to the data."""

    effect: str
    model: Model
    rmse_over_noise: float


@dataclass
class Judged:
    """One candidate input and how well it separates the pair."""

    candidate: Candidate
    naive: float                      # predicted difference of the best fits (noise units)
    robust: float = 0.0               # the worst over plausible truths and rival variants
    refit: dict = field(default_factory=dict)   # true effect -> difference after the rival re-fits

    @property
    def worst(self) -> float | None:
        return min(self.refit.values()) if self.refit else None

    def to_json(self) -> dict:
        return {"kind": self.candidate.kind, "label": self.candidate.label,
                "duration_s": self.candidate.duration, "naive": self.naive,
                "worst_plausible": self.robust, "after_refit": dict(self.refit) or None}


@dataclass(repr=False)
class Proposal(Displayable):
    """The proposed experiment, why it separates the pair, and by how much."""

    pair: tuple
    hypotheses: list
    judged: list
    chosen: Judged
    sigmas: dict
    template: Run
    budget_s: float
    amax: float
    seconds: float = 0.0
    plausible: list = field(default_factory=list)   # plausible models per hypothesis

    def headline(self) -> str:
        return (f"Proposal between {self.pair[0]} and {self.pair[1]}: "
                f"{self.chosen.candidate.label} ({self.chosen.candidate.duration:.1f} s)")

    @property
    def why(self) -> str:
        return why(self.chosen.candidate.kind, self.pair)

    def experiment(self, name: str = "proposed") -> dict:
        """The plan's ``[[experiment]]`` table."""
        return {"name": name, "loop": "open", "waveform": "pwl", "lead_in_s": LEAD_IN_S,
                "sample_rate_hz": float(self.template.fs),
                "points": [[float(t), float(u)] for t, u in self.chosen.candidate.points],
                "between": list(self.pair)}

    def to_toml(self) -> str:
        """The plan file: an ordinary plan with one ``pwl`` experiment."""
        e = self.experiment()
        a, b = self.pair
        lines = [f"# Proposed by `labrig propose`: the experiment that best tells {a} and {b} "
                 "apart.", f"# {self.chosen.candidate.label}: {self.why}.",
                 f"# Predicted difference ({DIFFERENCE}): {self.chosen.naive:.0f} "
                 f"before the rival re-fits, {self.chosen.worst:.0f} after.", "",
                 "[[experiment]]"]
        for k in ("name", "loop", "waveform", "lead_in_s", "sample_rate_hz"):
            v = e[k]
            lines.append(f"{k} = {v!r}".replace("'", '"') if isinstance(v, str) else f"{k} = {v}")
        lines.append("between = [" + ", ".join(f'"{x}"' for x in e["between"]) + "]")
        lines.append("points = [" + ", ".join(f"[{t:g}, {u:g}]" for t, u in e["points"]) + "]")
        return "\n".join(lines) + "\n"

    def to_json(self) -> dict:
        c = self.chosen
        return {"between": list(self.pair),
                "hypotheses": [{"effect": h.effect, "rmse_over_noise": h.rmse_over_noise,
                                "model": h.model.describe()} for h in self.hypotheses],
                "proposed": {"kind": c.candidate.kind, "label": c.candidate.label,
                             "duration_s": c.candidate.duration, "why": self.why,
                             "points": c.candidate.points,
                             "separation": {"naive": c.naive, "after_refit": dict(c.refit),
                                            "worst_after_refit": c.worst}},
                "candidates": [j.to_json() for j in self.judged],
                "noise": self.sigmas, "budget_s": self.budget_s, "amax_v": self.amax,
                "seconds": round(self.seconds, 2)}

    def to_text(self) -> str:
        c = self.chosen
        a, b = self.pair
        fits = "; ".join(f"with {h.effect}: rmse/noise {h.rmse_over_noise:.2f}"
                         for h in self.hypotheses)
        best = sorted(self.judged, key=lambda j: -j.robust)[:8]
        w = max([45] + [len(j.candidate.label) for j in best])   # labels whole, aligned
        rows = "\n".join(f"  {j.candidate.label:<{w}} {j.naive:12.0f} {j.robust:14.0f}"
                         for j in best)
        return (f"between {a} and {b} ({fits})\n\n"
                f"candidate inputs (at most {self.budget_s:g} s, within +-{self.amax:.2f} V) "
                f"and their predicted difference ({DIFFERENCE}): of the best fits, and the "
                "worst case over the models the data cannot exclude "
                f"({' and '.join(map(str, self.plausible))}):\n"
                f"  {'input':<{w}} {'best fits':>12} {'worst case':>14}\n{rows}\n\n"
                f"proposed: {c.candidate.label} ({c.candidate.duration:.1f} s)\n"
                f"why: {self.why}.\n"
                f"predicted difference ({DIFFERENCE}): {c.naive:.0f} before the rival re-fits, "
                + ", ".join(f"{v:.0f} after it with {k} the true one" for k, v in c.refit.items())
                + " (a few hundred is decisive)")

    def table_rows(self) -> list[Table]:
        """The explanations' fits, and the candidate inputs by worst-case difference."""
        fits = Table(f"between {self.pair[0]} and {self.pair[1]}", ["explanation", "rmse/noise"],
                     numeric=(1,))
        fits.rows = [[h.effect, f"{h.rmse_over_noise:.2f}"] for h in self.hypotheses]
        inputs = Table(f"candidate inputs (at most {self.budget_s:g} s, within "
                       f"+-{self.amax:.2f} V)", ["input", "best fits", "worst case"],
                       numeric=(1, 2))
        inputs.rows = [[j.candidate.label, f"{j.naive:.0f}", f"{j.robust:.0f}"]
                       for j in sorted(self.judged, key=lambda j: -j.robust)[:8]]
        inputs.notes.append(f"predicted difference ({DIFFERENCE}); "
                            f"proposed: {self.chosen.candidate.label}")
        return [fits, inputs]

    def predicted(self):
        """The proposed run as the template's rig would record it, and each explanation's
        prediction of it (``w``, ``theta``)."""
        run = synthetic_run(self.template, self.chosen.candidate, "proposed")
        return run, [h.model.simulate([run])[0] for h in self.hypotheses]

    def plot(self, ax=None):
        """Both explanations' predicted responses to the proposed input, with the noise band."""
        from labrig.loop.propose_plots import plot_proposal

        return plot_proposal(self, ax=ax)


def default_pair(model: Model, between: str | None) -> tuple:
    """``--between a,b``; else the model's effect and its usual rival."""
    if between:
        names = [catalogue_name(n.strip()) for n in between.split(",") if n.strip()]
        if len(names) != 2:
            raise UserError(f"--between: give two effects, e.g. deadband,coulomb_friction; got "
                            f"{between!r}")
        for n in names:
            get_effect(n)   # an unknown name fails here, with the catalogue listed
        if names[0] == names[1]:
            raise UserError("--between: the two effects must differ")
        return tuple(names)
    for e in model.effects:
        if e.rival:
            return e.name, e.rival
    raise UserError("the model has no effect with a usual look-alike (dead zone, friction, "
                    "stiction, delay, backlash); name the pair with --between a,b")


def pair_from_diagnosis(model_path) -> str | None:
    """The first confusable pair of the ``diagnosis.json`` that ``diagnose --auto -o DIR``
    wrote beside the model, as ``"a,b"``; None when there is none. The file is data: its
    names are checked against the catalogue like ``--between``."""
    from pathlib import Path

    from labrig.core.schemas import read_json

    path = Path(model_path).parent / "diagnosis.json"
    if not path.is_file():
        return None
    doc = read_json(path, "diagnosis", UserError)
    pairs = doc.get("confusable") if isinstance(doc, dict) else None
    if not isinstance(pairs, list) or not pairs:
        return None
    pair = pairs[0].get("pair") if isinstance(pairs[0], dict) else None
    if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(n, str) for n in pair)):
        raise UserError(f"{path}: key 'confusable.0.pair' is not two effect names; give the "
                        "pair with --between a,b")
    return ",".join(proposed_as(n) for n in pair)


def proposed_as(name: str) -> str:
    """The effect a proposal tests in place of ``name`` (the symmetric form of an
    asymmetric one; :attr:`~labrig.model.effect_base.Effect.proposed_as`)."""
    return get_effect(name).proposed_as or name


def threshold_of(model: Model) -> float:
    """The input level where the model's threshold effect acts (V), 0 when it has none."""
    out = []
    for e, ps in model.effect_params.items():
        if "d_v" in ps:
            out.append(ps["d_v"])
        elif "dpos_v" in ps:
            out.append(0.5 * (ps["dpos_v"] + ps["dneg_v"]))
        elif "tc_v" in ps:
            out.append(ps["tc_v"] * (1.0 + ps.get("excess", 0.0)))
    return float(max(out)) if out else 0.0


def synthetic_run(template: Run, cand: Candidate, name: str, sim: dict | None = None,
                  noise: dict | None = None, rng=None) -> Run:
    """A run of ``cand`` as ``template``'s rig would record it: volts through the same
    sensors, the model's prediction ``sim`` (``w``, ``theta``) plus seeded noise."""
    fs = template.fs
    u = cand.values(fs, LEAD_IN_S)
    n = len(u)
    cols = {"t": np.arange(n) / fs, "u": u}
    w = np.zeros(n) if sim is None else sim["w"]
    th = np.zeros(n) if sim is None else sim["theta"]
    if noise is not None:
        w = w + rng.normal(0.0, noise.get("speed", 0.0), n)
        th = th + rng.normal(0.0, noise.get("position", 0.0), n)
    if template.has_tacho:
        cols["tacho"] = w * template.kt
    elif template.has_speed:  # imported speed: stored as speed, as the template's is
        cols["speed"] = w
    if template.has_pos:
        cols["pos"] = th * template.kpot + template.pos_offset
    meta = copy.deepcopy(template.meta)
    meta["experiment"] = {"loop": "open", "waveform": "pwl", "lead_in_s": LEAD_IN_S,
                          "points": cand.points}
    return Run(name=name, data=pd.DataFrame(cols), meta=meta)


#: variants of a hypothesis: the threshold fixed at these shares of its data bound
VARIANT_SHARES = (0.1, 0.3, 0.6)
#: a variant is plausible while its fit is within this factor of the best
PLAUSIBLE = 1.10


def variants(runs, hyp: Hypothesis, reach, *, seed: int, weights: Weights):
    """The hypothesis and its plausible neighbours: the threshold parameter fixed across
    the range the data allow and the rest re-fitted; those the data cannot exclude (fit
    within :data:`PLAUSIBLE` of the best) stay. A threshold one run cannot pin down (a
    dead zone from a single step: d and the gain trade off) then spans its range."""
    out = [hyp.model]
    eff = get_effect(hyp.effect)
    key = eff.threshold or None
    if key is None:
        return out
    _, hi = eff.data_bounds(reach).get(key, (None, None))
    if hi is None:
        return out
    best = hyp.model.effect_params[hyp.effect][key]
    for share in VARIANT_SHARES:
        v = share * hi
        if abs(v / best - 1.0) < 0.3:
            continue   # the best fit already stands for it
        res = fit(runs, hyp.model.effects, hyp.model.flat(), {f"{hyp.effect}.{key}": v},
                  seed=seed, weights=weights, reach=reach, max_nfev=40)
        if res.metrics["rmse_over_noise"]["overall"] <= PLAUSIBLE * hyp.rmse_over_noise:
            out.append(res.model())
    return out


def _travel(runs) -> tuple[float, float]:
    """How far the data moved the axis from a run's start (either way: the data do not
    say where the sensor's ends are)."""
    spans = [float(np.ptp(r.position)) for r in runs if r.position is not None]
    return (1.05 * max(spans),) * 2 if spans else (np.inf, np.inf)


def _sensor_range(rig) -> tuple[float, float]:
    """How far the rig's position sensor follows the axis from 0 (where the simulated rig
    starts every run), forwards and backwards, with a 10 % margin; an encoder has no end."""
    s, lo_hi = rig.sensors, rig.bridge.adc_range_v
    if s.encoder_counts_per_unit > 0:
        return np.inf, np.inf
    ends = sorted(((v - s.pos_offset_v) / s.pos_v_per_rad) for v in lo_hi)
    return 0.9 * max(ends[1], 0.0), 0.9 * max(-ends[0], 0.0)


def _difference(pa: dict, pb: dict, template: Run, sig: dict) -> float:
    """The predicted difference: sum of squared differences of two responses (``w``,
    ``theta``) in noise units, over the channels ``template``'s rig records."""
    d = 0.0
    if template.has_speed and "speed" in sig:
        d += float(np.sum(((pa["w"] - pb["w"]) / sig["speed"]) ** 2))
    if template.has_pos and "position" in sig:
        d += float(np.sum(((pa["theta"] - pb["theta"]) / sig["position"]) ** 2))
    return d


def propose(runs: list[Run], model: Model, between: str | None = None, *,
            budget_s: float = 20.0, amax: float | None = None, seed: int = 0,
            weights: Weights = Weights(), log=None, rig=None) -> Proposal:
    """Propose the input of at most ``budget_s`` seconds that best separates the pair.

    Parameters
    ----------
    runs : list of Run
    model : Model
        The current model; the pair's effects are swapped in and out of it.
    between : str, optional
        ``"a,b"``; default the model's effect and its usual rival (its ``rival``).
    amax : float, optional
        Largest input allowed (V); default the largest the data already use.
    rig : RigConfig, optional
        The rig: its position sensor's range bounds the travel (default: the travel the
        data show, either way).
    """
    from labrig.model.reach import Reach
    from labrig.model.simulate import prepare
    from labrig.model.warm import ready

    ready()  # a first compile is announced and kept out of the timing
    t0 = time.perf_counter()
    if not 1.0 <= budget_s <= 600.0:
        raise UserError(f"--budget-s: {budget_s:g} s; give 1 to 600 s of new data")
    opened = [r for r in runs if r.loop == "open"]
    if not opened:
        raise UserError("propose needs at least one open-loop run (its rig plays the input)")
    pair = default_pair(model, between)
    say = log or (lambda s: None)
    # the pair's effects, and any of their families (a dead zone for a dead zone), go out
    families = {get_effect(n).family_name for n in pair}
    base = model
    for e in list(model.effects):
        if e.name in pair or e.family_name in families:
            base = without(base, e.name)
    reach = Reach.of(runs, base)
    hyps, family = [], []
    for name in pair:
        say(f"fitting the model with {name}")
        ident = refit_with(runs, base, get_effect(name), seed=seed, weights=weights, reach=reach)
        h = Hypothesis(name, ident.model(), float(ident.metrics["rmse_over_noise"]["overall"]))
        hyps.append(h)
        family.append(variants(runs, h, reach, seed=seed, weights=weights))
    floors = channel_floors(prepare(runs))
    sig = {ch: floors[ch].sigma for ch in ("speed", "position") if ch in floors}
    template = opened[0]
    data_amax = max(float(np.max(np.abs(r.u))) for r in opened)
    amax = data_amax if amax is None else float(amax)
    tau = float(np.median([h.model.servo().tau_m for h in hyps]))
    threshold = float(np.mean([threshold_of(h.model) for h in hyps]))
    cands = candidates(threshold=threshold, amax=amax, tau=tau, budget_s=budget_s,
                       dt=template.dt)
    if not cands:
        raise UserError(f"--budget-s: no candidate input fits in {budget_s:g} s; allow more")
    say(f"simulating {len(cands)} candidate inputs with {sum(map(len, family))} plausible "
        "models")
    syn = [synthetic_run(template, c, f"cand{k}") for k, c in enumerate(cands)]
    preds = [[m.simulate(syn) for m in fam] for fam in family]
    # the travel the sensors are known to follow, each way from where a run starts: an
    # input that drives the axis further (a pot beyond its range, off the end of a linear
    # axis) is not proposed
    up, down = _travel(runs) if rig is None else _sensor_range(rig)
    judged = []
    for k, c in enumerate(cands):
        ups = max(float(np.max(fam[0][k]["theta"] - fam[0][k]["theta"][0])) for fam in preds)
        downs = max(float(np.max(fam[0][k]["theta"][0] - fam[0][k]["theta"])) for fam in preds)
        if ups > up or downs > down:
            continue
        j = Judged(c, _difference(preds[0][0][k], preds[1][0][k], template, sig))
        # the worst case over every plausible truth, the rival taking its closest variant:
        # an input that only separates the best fits is a bet on their thresholds
        j.robust = min(min(_difference(pt[k], pr[k], template, sig) for pr in preds[1 - h])
                       for h in (0, 1) for pt in preds[h])
        judged.append(j)
    if not judged:
        raise UserError(f"every candidate input drives the axis further than the data did "
                        f"(+{up:.3g} / -{down:.3g} {template.units[0]} from the start) in "
                        f"{budget_s:g} s; record a run with more travel, or give a shorter "
                        "--budget-s")
    chosen = max(judged, key=lambda j: (j.robust, -j.candidate.duration))
    say(f"re-fitting each explanation to the other's prediction: {chosen.candidate.label}")
    rng = np.random.default_rng(seed)
    for ti, truth in enumerate(hyps):
        rival = hyps[1 - ti]
        clean = truth.model.simulate([synthetic_run(template, chosen.candidate, "p")])[0]
        new = synthetic_run(template, chosen.candidate, "proposed", clean, sig, rng)
        res = fit(runs + [new], rival.model.effects, rival.model.flat(), {}, seed=seed,
                  weights=weights, reach=None, max_nfev=40)
        measured = {"w": new.speed, "theta": new.position}
        chosen.refit[truth.effect] = max(
            0.0, _difference(res.model().simulate([new])[0], measured, template, sig)
            - _difference(clean, measured, template, sig))
    return Proposal(pair=pair, hypotheses=hyps, judged=judged, chosen=chosen, sigmas=sig,
                    template=template, budget_s=budget_s, amax=amax,
                    seconds=time.perf_counter() - t0, plausible=[len(f) for f in family])


# -- deciding ---------------------------------------------------------------------------
