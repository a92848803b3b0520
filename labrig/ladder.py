"""The error ladder: the model's error after each added effect, against the noise floor.

:func:`evaluate_ladder` judges a chain of saved models; :func:`auto_ladder` builds the
chain itself (identify, diagnose, add the recommendation, repeat). Both return a
:class:`Ladder`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .diagnose import diagnose
from .evaluation import Evaluation, evaluate
from .identify.engine import identify
from .model.model import Model
from .tables import Table, fmt


@dataclass
class LadderStep:
    """One rung: the model's label, its effects and how well it explains the runs."""

    label: str
    effects: list
    rmse_over_noise: dict
    fit_percent: dict
    fitness: float
    model: str | None = None

    @classmethod
    def of(cls, label: str, model: Model, ev: Evaluation, path=None) -> "LadderStep":
        return cls(label=label, effects=list(model.names),
                   rmse_over_noise=ev.metrics["rmse_over_noise"],
                   fit_percent=ev.metrics["fit_percent"], fitness=ev.metrics["fitness"],
                   model=str(path) if path else None)

    def to_json(self) -> dict:
        return {"label": self.label, "effects": self.effects,
                "rmse_over_noise": self.rmse_over_noise, "fit_percent": self.fit_percent,
                "fitness": self.fitness, "model": self.model}


@dataclass
class Ladder:
    """The error after each step; ``to_json()`` is ``labrig ladder --json``."""

    steps: list[LadderStep] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"steps": [s.to_json() for s in self.steps]}

    def to_pandas(self):
        import pandas as pd

        return pd.DataFrame([{"step": s.label,
                              **{f"rmse/noise {k}": v for k, v in s.rmse_over_noise.items()},
                              **{f"fit % {k}": v for k, v in s.fit_percent.items()}}
                             for s in self.steps])

    def table_rows(self) -> Table:
        t = Table("the error ladder (rmse/noise; 1.00 is the noise floor)",
                  ["step", "rmse/noise", "speed", "position", "fit % w", "fit % th"],
                  numeric=(1, 2, 3, 4, 5))
        for s in self.steps:
            r, f = s.rmse_over_noise, s.fit_percent
            t.rows.append([s.label, fmt(r.get("overall"), ".2f"), fmt(r.get("speed"), ".2f"),
                           fmt(r.get("position"), ".2f"), fmt(f.get("speed"), ".2f"),
                           fmt(f.get("position"), ".2f")])
        return t

    def plot(self, ax=None):
        from .report.compare_plots import plot_ladder

        return plot_ladder(self, ax=ax)


def _label(model: Model, previous: list[str]) -> str:
    new = [n for n in model.names if n not in previous]
    return "linear model" if not model.names else "+ " + ", ".join(new or model.names)


def evaluate_ladder(runs, model_paths) -> Ladder:
    """Evaluate saved models in order (``labrig ladder --models m0.json,m1.json``)."""
    ladder, prev = Ladder(), []
    for path in model_paths:
        model = Model.load(path)
        ladder.steps.append(LadderStep.of(_label(model, prev), model, evaluate(runs, model), path))
        prev = model.names
    return ladder


def add_effects(runs, model: Model | None = None, *, max_rounds: int = 3, seed: int = 0,
                fixed: dict | None = None, log=None, on_step=None):
    """The loop itself: diagnose, add the recommended effect, repeat until nothing more
    earns its parameters (or ``max_rounds`` effects were added).

    ``on_step(k, model)`` is called for every rung (k = 0 is the starting model).
    Returns ``(rounds, ladder, model)``: every round's :class:`Diagnosis`, the
    :class:`Ladder` and the final model.
    """
    rounds, ladder = [], None
    for k in range(1, max_rounds + 1):
        diag = diagnose(runs, model, seed=seed, fixed=fixed)
        rounds.append(diag)
        if ladder is None:  # the first round's baseline is the ladder's first rung
            model = diag.base
            ladder = Ladder([LadderStep.of("linear model" if not model.names else "given model",
                                           model, diag.evaluation)])
            if on_step:
                on_step(0, model)
        if log:
            log(f"round {k}: {diag.verdict[:160]}")
        if diag.recommendation is None:
            break
        model = diag.recommended_model()
        # the diagnosis evaluated this model already, on the same runs
        ladder.steps.append(LadderStep.of(f"+ {diag.recommendation}", model,
                                          diag.candidate(diag.recommendation).evaluation))
        if on_step:
            on_step(k, model)
    return rounds, ladder, model


def auto_ladder(runs, max_steps=3, outdir=None, seed=0, log=print) -> Ladder:
    """The ladder of :func:`add_effects` from the linear model; each rung's model is
    saved as ``outdir/step<k>.json`` when ``outdir`` is given."""
    out = Path(outdir) if outdir else None

    def save(k, model):
        if out:
            path = out / f"step{k}.json"
            model.save(path)
            ladder_paths[k] = str(path)

    ladder_paths: dict = {}
    if max_steps < 1:  # no round: the linear model alone
        model = identify(runs, "co", [], seed=seed, starts=4, identifiability=False).model()
        save(0, model)
        return Ladder([LadderStep.of("linear model", model, evaluate(runs, model),
                                     ladder_paths.get(0))])
    _, ladder, _ = add_effects(runs, max_rounds=max_steps, seed=seed, log=log, on_step=save)
    for k, step in enumerate(ladder.steps):
        step.model = ladder_paths.get(k)
    return ladder
