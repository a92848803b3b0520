"""The error ladder: the model's error after each added effect, against the noise floor."""
from __future__ import annotations

from pathlib import Path

from .diagnose import ModelState, diagnose, evaluate
from .identify.engine import identify
from .identify.modelfile import load_model, save_model


def _step(label, ev, effects, path=None):
    return {"label": label, "effects": effects, "rmse_over_noise": ev["metrics"]["rmse_over_noise"],
            "fit_percent": ev["metrics"]["fit_percent"], "fitness": ev["metrics"]["fitness"],
            "model": str(path) if path else None}


def evaluate_ladder(runs, model_paths) -> list[dict]:
    steps, prev = [], []
    for path in model_paths:
        st = ModelState.from_model(load_model(path))
        new = [n for n in st.names if n not in prev]
        label = "linear model" if not st.names else "+ " + ", ".join(new or st.names)
        steps.append(_step(label, evaluate(runs, st), st.names, path))
        prev = st.names
    return steps


def auto_ladder(runs, max_steps=3, outdir=None, seed=0, log=print) -> list[dict]:
    """identify -> diagnose -> add the recommendation -> identify --model ... until the
    diagnosis finds nothing more (or ``max_steps`` effects were added)."""
    from .commands.loop import res_model

    out = Path(outdir) if outdir else None
    ident = identify(runs, "co", [], seed=seed, starts=4, identifiability=False)
    model = ident.model_dict()
    model["effect_objects"] = []
    steps = [_step("linear model", evaluate(runs, ModelState.from_model(model)), [],
                   out / "step0.json" if out else None)]
    if out:
        save_model({k: v for k, v in model.items() if k != "effect_objects"}, out / "step0.json")
    for k in range(1, max_steps + 1):
        res = diagnose(runs, model, seed=seed)
        rec = res["recommendation"]
        log(f"step {k}: {res['verdict'][:160]}")
        if rec is None:
            break
        model = res_model(res, runs, rec)
        path = out / f"step{k}.json" if out else None
        if out:
            save_model(model, path)
        model = load_model(path) if out else {**model, "effect_objects": res["_states"][rec].effects}
        st = ModelState.from_model(model)
        steps.append(_step(f"+ {rec}", evaluate(runs, st), st.names, path))
    return steps
