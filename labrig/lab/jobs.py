"""The lab page's work, done in a worker process through the public verbs.

Each job takes plain arguments (folders, model JSON) and returns a plain dict: the
result's own ``to_json()`` (the numbers the CLI's ``--json`` prints for the same data and
seed), its tables as HTML and its figures as PNG bytes, drawn by the result's own
``plot()``. The page computes nothing of its own: it shows what these return.
"""
from __future__ import annotations

from pathlib import Path

import labrig.verbs as lr
from labrig.core.defaults import SEED
from labrig.core.errors import UserError
from labrig.core.figures import png_bytes
from labrig.core.tables import Table, table_html

#: the seed of every fit the page makes (the CLI gives the same numbers with --seed 0)
LAB_SEED = SEED


def _png(fig) -> bytes:
    return png_bytes(fig, dpi=90)


def _html(tables) -> list[str]:
    tables = [tables] if isinstance(tables, Table) else list(tables)
    return [table_html(t) for t in tables]


def _model(doc):
    return None if doc is None else lr.model_from_json(doc, "the lab page's model")


def _runs(folders):
    return lr.read_runs([str(f) for f in folders])


def fit(folders, model_doc=None, add=(), remove=(), label="", from_here=False) -> dict:
    """A rung: the model (``model_doc``, or the linear model) with ``add`` effects added and
    ``remove`` taken out, fitted on the runs (CO, the lab's seed), with its overlay on the
    worst run (``runs`` names them all; :func:`overlays` draws the others: each figure
    costs about half a second, and the diagnosis should not wait for them).
    ``from_here``: start from ``model_doc``'s values even without effects (values set by
    hand on the page)."""
    runs = _runs(folders)
    base = _model(model_doc)
    for name in remove:
        base = lr.remove_effect(base, name)
    if base is not None and not base.names and not add and not from_here:
        base = None     # back to the linear model: fitted afresh, as identify does
    ident = lr.identify(runs, effects=list(add), model=base, seed=LAB_SEED)
    return _rung(runs, ident.model(), ident.to_json(), label)


def take(folders, model_doc) -> dict:
    """A rung of a model fitted already (a diagnosis's re-fit, as ``diagnose -o`` writes
    it), as it stands: :func:`fit`'s rung without a fit (``fit`` None)."""
    runs = _runs(folders)
    return _rung(runs, _model(model_doc), None, "")


def _rung(runs, model, fit_json, label) -> dict:
    ev = lr.compare(runs, model)
    worst = ev.worst_run()["name"]
    return {"label": label or "linear model", "model": model.to_json(),
            "effects": model.names, "fit": fit_json,
            "rmse_over_noise": ev.metrics["rmse_over_noise"],
            "fit_percent": ev.metrics["fit_percent"],
            "runs": [rr["name"] for rr in ev.per_run], "worst": worst,
            "overlays": {worst: _png(ev.plot(run=worst))}, "tables": _html(ev.table_rows())}


def overlays(folders, model_doc, names) -> dict:
    """The model on the runs ``names``: ``{name: PNG}`` (the figures :func:`fit` left)."""
    ev = lr.compare(_runs(folders), _model(model_doc))
    return {name: _png(ev.plot(run=name)) for name in names}


def diagnose(folders, model_doc, log=None) -> dict:
    """The ranking of the effects the model lacks, with the evidence, the confusable pairs
    and each effect's physics sentence; ``log`` hears each candidate as it is re-fitted
    and cross-validated (the ranking forming on the page)."""
    def progress(event):
        if log is not None and event.kind in ("fitted", "validated"):
            log(_candidate_entry(event))

    diag = lr.diagnose(_runs(folders), _model(model_doc), seed=LAB_SEED, progress=progress)
    pairs = lr.confusable_pairs(diag, 1)
    rows = []
    for c in diag.ranking:
        cv = c.cross_validated
        rows.append({"effect": c.effect, "move": c.move, "label": c.label,
                     "replaces": c.replaces, "rmse_over_noise": c.rmse_over_noise,
                     "delta_bic": c.delta_bic,
                     "cross_validated": cv["with_effect"] if cv else None,
                     "folds": f"{cv['folds_improved']}/{cv['folds']}" if cv else "-",
                     "supported": c.supported, "at_bound": list(c.at_bound),
                     "screened": c.screened is not None,
                     "confusable_with": [p.second if p.first == c.effect else p.first
                                         for p in pairs if c.effect in (p.first, p.second)],
                     "physics": lr.effect(c.effect).summary,
                     # its re-fitted model: a click shows its curves on the runs
                     "model": c.model.to_json() if c.model is not None else None})
    # nothing to add, but the candidates' re-fits placed the model's own parameters
    # better: that model (what ``diagnose -o`` writes) is offered as the next rung
    refined = diag.recommended_model() if diag.recommendation is None else None
    return {"json": diag.to_json(), "rows": rows, "recommendation": diag.recommendation,
            "refined": refined.to_json() if refined is not None else None,
            "verdict": diag.verdict, "pairs": [p.to_json() for p in pairs],
            "tables": _html(diag.table_rows())}   # (its figure: the page draws it, Bokeh)


def _candidate_entry(event) -> dict:
    """A candidate re-fitted (``fitted``) or cross-validated, as the page lists it."""
    c = event.data
    return {"kind": event.kind, "label": c.label, "rmse_over_noise": c.rmse_over_noise,
            "cross_validated": event.done}


def ladder(folders, model_docs) -> dict:
    """The error ladder of the rungs so far."""
    lad = lr.ladder(_runs(folders), [_model(d) for d in model_docs])
    return {"json": lad.to_json(), "tables": _html(lad.table_rows())}


def auto(folders, max_rounds=3, log=None) -> dict:
    """``diagnose --auto``: the rungs it climbed, each fitted as a rung of the page."""
    def progress(event):   # the rounds' lines and the ladder growing, rung by rung
        if log is None:
            return
        if event.kind == "note":
            log(event.text)
        elif event.kind in ("fitted", "validated"):   # the round's ranking forming
            log(_candidate_entry(event))
        elif event.kind == "rung":
            info = event.data.info or {}
            rmse = (info.get("rmse_over_noise") or {}).get("overall")
            cv = info.get("cross_validated")
            log(event.text + (f" — rmse/noise {rmse:.2f}" if rmse is not None else "")
                + (f", cross-validated {cv:.2f}" if cv is not None else ""))
            # the rung's model, so the page redraws its curves as the search climbs
            log({"kind": "rung", "label": event.text, "model": event.data.to_json(),
                 "rmse_over_noise": rmse, "cross_validated": cv})

    res = lr.auto(_runs(folders), max_rounds=max_rounds, seed=LAB_SEED, progress=progress)
    return {"json": res.to_json(), "model": res.model.to_json(), "effects": res.model.names,
            "tables": _html(res.ladder.table_rows()),
            "verdict": res.verdict}


def propose(folders, model_doc, between: str, loop: str = "open", rig=None) -> dict:
    """The experiment that separates the pair: its plan, both predictions and why."""
    prop = lr.propose(_runs(folders), _model(model_doc), between, seed=LAB_SEED, loop=loop,
                      rig=rig, rig_amplitude=False)
    return {"json": prop.to_json(), "plan": prop.to_toml() if prop.separates else None,
            "text": prop.to_text(),
            "figure": _png(prop.plot()), "pair": list(prop.pair)}


def ask_until_sure(folders, model_doc, between: str, step_s: float = 5.0,
                   budget_s: float = 20.0, loop: str = "open", rig=None, log=None,
                   ask_rig=None) -> dict:
    """Ask the rig until sure: short experiments, each played by the page on the rig
    (``ask_rig``: it answers with the folder of the step's runs, or that the student
    stopped the rig) and judged after each; ``log`` hears every step."""
    played = []   # the folders of the steps played, in order

    def play(plan, k):
        answer = ask_rig({"plan": plan, "k": k})
        if answer.get("stopped"):
            return []
        played.append(answer["folder"])
        return lr.read_runs(answer["folder"])

    def on_step(step, runs):   # both explanations, as fitted now: the page draws them
        if log is not None:
            log({"kind": "ask_step", "k": len(played), "label": step.label,
                 "folder": played[-1],
                 "models": {e: m.to_json() for e, m in step.decision.models.items()},
                 "after": dict(step.decision.after)})

    a = lr.ask_until_sure(_runs(folders), _model(model_doc), between, play,
                          budget_s=budget_s, step_s=step_s, seed=LAB_SEED, log=log,
                          on_step=on_step, loop=loop, rig=rig, rig_amplitude=False)
    return {"json": a.to_json(), "text": a.to_text(), "leader": a.leader,
            "tables": _html(a.table_rows())}


def decide(folders, model_doc) -> dict:
    """Both explanations fitted with and without the proposed runs."""
    d = lr.decide(_runs(folders), _model(model_doc), seed=LAB_SEED)
    if d is None:
        return {"json": None, "text": "no proposed run in these folders"}
    return {"json": d.to_json(), "text": d.to_text(), "leader": d.leader,
            "tables": _html(d.table_rows())}


def save_model(model_doc, path, overwrite: bool = False) -> str:
    """Write a rung's model as the CLI's model file (refused if it exists, unless told)."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise UserError(f"{path} exists; tick 'replace' to overwrite it")
    _model(model_doc).save(path)
    return str(path)
