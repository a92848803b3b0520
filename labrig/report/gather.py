"""Collect what the report shows into a :class:`~labrig.report.story.Story`.

Each section's content is read from the work folder when the earlier stage left it
there (validated once, :mod:`labrig.report.artefacts`) and computed here otherwise: the
analysis always, identification with CO only, where-the-model-fails by simulating the
model, the diagnosis (about 30 s) and the ladder unless ``quick``. An artefact fitted on
other runs than the data set is ignored with a note. Figures are drawn (or read from
``figures/``) one at a time straight to PNG bytes.
"""
from __future__ import annotations

from pathlib import Path

import labrig.verbs as lr
import labrig.verbs.figures as lrf
from labrig.core.errors import UserError
from labrig.report.artefacts import read_artefact
from labrig.report.story import Figure, Story, fig_bytes
from labrig.verbs.types import (AnalysisResult, Diagnosis, IdentifyAllDoc, IdentRecord, Ladder,
                                LadderStep, Regimes)


def gather(data_dir, work=None, quick=False, seed=1, log=None) -> Story:
    """Read or compute every section's content.

    Parameters
    ----------
    data_dir : str or Path
        Folder of runs.
    work : str, Path or None
        Work folder of the earlier stages (None: compute everything).
    quick : bool
        Do not compute the diagnosis and the ladder.
    seed : int
        Seed of what is identified or diagnosed here.
    log : callable(str) or None
        Progress messages.

    Returns
    -------
    Story
    """
    data_dir = Path(data_dir)
    story = Story(data_dir=data_dir, work=Path(work) if work else None,
                  runs=lr.read_runs(data_dir, through=None), quick=quick)
    say = log or (lambda text: None)
    _sweep(story)
    _analysis(story, say)
    live = _models(story, seed, say)
    _model0(story, live)
    ev0 = _failures(story, say)
    diag_live = _diagnosis(story, seed, say)
    _ladder(story, diag_live, ev0, say, seed)
    return story


# -- helpers ---------------------------------------------------------------------------

def _artefact(story: Story, name: str, schema):
    return read_artefact(story.work / name, schema, story.notes) if story.work else None


def _work_png(story: Story, name: str) -> bytes | None:
    """``figures/<name>`` of the work folder, if it is there and readable."""
    if story.work is None:
        return None
    p = story.work / "figures" / name
    try:
        return p.read_bytes() if p.is_file() else None
    except OSError:
        return None


def _same_runs(names, story: Story) -> bool:
    """An artefact that names its runs must name exactly the data set's runs."""
    names = set(names or ())
    return not names or names == {r.name for r in story.runs}


# -- the sections ----------------------------------------------------------------------

def _sweep(story: Story) -> None:
    story.sources["sweep"] = str(story.data_dir)
    story.figures["sweep"] = [Figure("Measured runs", fig_bytes(lrf.runs_figure(story.runs)),
                                     "Every run of the data set: the measured response (top) "
                                     "and what the bridge applied (bottom).")]


def _analysis(story: Story, say) -> None:
    w = story.work
    doc = _artefact(story, "analysis.json", AnalysisResult)
    if doc is not None and not _same_runs([r.name for r in doc.runs], story):
        story.notes.append(f"{w / 'analysis.json'} describes other runs than {story.data_dir}; "
                           "the analysis was recomputed.")
        doc = None
    pngs = {}
    for name in ("speed_vs_voltage.png", "km_vs_amplitude.png",
                 *(f"edges_{r.name}.png" for r in story.runs)):
        if (b := _work_png(story, name)) is not None:
            pngs[name] = b
    res = doc
    if res is not None:
        story.sources["analysis"] = str(w / "analysis.json")
    if res is None or not pngs:
        say("report: analysing the runs")
        try:
            live = lr.analyse([story.data_dir])
        except Exception as exc:  # a data set analyse cannot read (e.g. closed loop only)
            story.analysis_error = str(exc) or type(exc).__name__
            live = None
        if live is not None:
            if res is None:
                res = live
                story.sources["analysis"] = "computed by this report (labrig.analysis)"
            if not pngs:
                # figures() draws on access: one figure in memory at a time
                for name, fig in live.figures().items():
                    pngs[name] = fig_bytes(fig)
    story.analysis = res
    if res is None:
        story.missing["analysis"] = (f"labrig analyse {story.data_dir} --json > analysis.json "
                                     f"(it failed here: {story.analysis_error})")
    figs = [Figure(title, pngs.pop(name), wide=False)
            for name, title in (("speed_vs_voltage.png", "Steady speed against input voltage"),
                                ("km_vs_amplitude.png", "Km = w/V against amplitude"))
            if name in pngs]
    figs += [Figure(f"Edges of {name[len('edges_'):-4]}", b,
                    "Each edge with its first-order fit and the 63 % point.")
             for name, b in sorted(pngs.items())]
    story.figures["analysis"] = figs


def _models(story: Story, seed, say) -> list:
    """The identified models: identify_all.json, else model0.json's fit, else CO now.
    Returns the live Identification objects (empty when read from files)."""
    w = story.work
    doc = _artefact(story, "identify_all.json", IdentifyAllDoc)
    if doc is not None:
        records, best = doc.records()
        if records and not _same_runs(set().union(*(r.run_names for r in records)), story):
            story.notes.append(f"{w / 'identify_all.json'} was fitted on other runs than "
                               f"{story.data_dir}; the model was re-identified.")
        elif records:
            story.idents, story.best = records, best
            story.sources["models"] = str(w / "identify_all.json")
    if not story.idents and w and (w / "model0.json").is_file():
        rec = _artefact(story, "model0.json", IdentRecord)
        if rec is not None and _same_runs(rec.dataset.get("runs"), story):
            story.idents, story.best = [rec], rec.method
            story.sources["models"] = (f"{w / 'model0.json'} (run `labrig identify "
                                       f"{story.data_dir} --method all --json > "
                                       "identify_all.json` for JFO, PSO and CO side by side)")
    live = []
    if not story.idents:
        say("report: identifying the linear model with CO (a few seconds)")
        res = lr.identify(story.runs, "co", [], seed=seed, through=None, starts=4,
                          dataset={"paths": [str(story.data_dir)],
                                   "runs": [r.name for r in story.runs]})
        live = [res]
        story.idents = [IdentRecord.model_validate(res.to_dict())]
        story.best = res.method
        story.sources["models"] = (f"computed by this report (CO, seed {seed}); run "
                                   f"`labrig identify {story.data_dir} --method all --json` "
                                   "for JFO and PSO side by side")
    if story.best is None:
        story.best = min(story.idents, key=lambda r: r.fitness).method
    # drawn from the histories rather than taken from figures/: a local method (CO)
    # records its starts' screening error, not the fitness, so it gets a flat line
    curves = [r.model_copy(update={"history": []}) if r.method.startswith("co") else r
              for r in story.idents]
    story.figures["models"] = [Figure("Convergence of the identifiers",
                                      fig_bytes(lrf.convergence_figure(curves)),
                                      "Best fitness against iteration: the weighted RMSE "
                                      "of position and speed, each residual divided by its "
                                      "noise floor (eq. 26 of the seed paper, made "
                                      "dimensionless); 1.0 is the noise floor.", wide=False)]
    return live


def _model0(story: Story, live) -> None:
    """The linear model the later sections judge: model0.json, else the best fit."""
    w = story.work
    if w and (w / "model0.json").is_file():
        try:
            story.model0 = lr.load_model(w / "model0.json")
            story.model0_source = str(w / "model0.json")
            return
        except UserError as exc:
            story.notes.append(f"{w / 'model0.json'} was ignored: {exc}")
    best = story.best_ident
    try:
        model = live[0].model() if live else lr.model_from_json(
            {"params": best.params, "effects": best.effects,
             "effect_params": best.effect_params}, "identify_all.json")
    except UserError as exc:  # e.g. a user effect that is not trusted (or not here)
        story.notes.append(f"the identified model's effects could not be loaded ({exc})")
        return
    story.model0 = model
    story.model0_source = f"the {story.best} fit of section 6"


def _failures(story: Story, say):
    """Regime table, regimes figure and the worst run's comparison. Returns the live
    evaluation of the linear model when it had to be computed (else None)."""
    w = story.work
    doc = _artefact(story, "diagnosis.json", Diagnosis)
    if doc is not None:
        story.diagnosis = doc
        story.regimes = doc.regimes
        story.sources["failures"] = str(w / "diagnosis.json")
    reg_png = _work_png(story, "regimes.png")
    cmp_png, worst = None, None
    if w and (w / "figures").is_dir():
        names = {r.name for r in story.runs}
        for p in sorted((w / "figures").glob("compare_*_model0.png")):
            n = p.name[len("compare_"):-len("_model0.png")]
            if n in names:
                cmp_png, worst = p.read_bytes(), n
                break
    ev0 = None
    if story.model0 is not None and (doc is None or reg_png is None or cmp_png is None):
        say("report: simulating the linear model on every run")
        ev0 = lr.compare(story.runs, story.model0, through=None)
        if doc is None:
            wr = ev0.worst_regime()
            story.regimes = Regimes(
                **ev0.regimes, noise=ev0.metrics["noise"],
                worst=None if wr is None else {"channel": wr[0], "regime": wr[1],
                                               "rmse_over_noise": wr[2]})
            story.sources["failures"] = (f"computed by this report (simulation of "
                                         f"{story.model0_source})")
        if reg_png is None:
            reg_png = fig_bytes(lrf.regimes_figure(ev0.regimes,
                                                   title="Where the linear model fails"))
        if cmp_png is None:
            rr = ev0.worst_run()
            worst = rr["name"]
            cmp_png = fig_bytes(lrf.run_figure(rr, title=f"{worst}: linear model vs "
                                                         "measurement"))
    elif story.model0 is None and doc is None:
        story.missing["failures"] = (f"labrig identify {story.data_dir} -o model0.json, then "
                                     f"labrig diagnose {story.data_dir} --model model0.json "
                                     "--json > diagnosis.json")
    story.worst_run = worst
    figs = []
    if reg_png:
        figs.append(Figure("Error by regime", reg_png,
                           "rmse/noise of the linear model in each regime (1.0 = noise floor), "
                           "with the share of time spent there."))
    if cmp_png:
        figs.append(Figure(f"The worst run{': ' + worst if worst else ''}", cmp_png,
                           "Measured against simulated, the residual in noise units with the "
                           "stretches that leave the noise band, the +-1 quantum lines (a "
                           "quantised reading's staircase stays inside them), and the "
                           "whiteness tests."))
    story.figures["failures"] = figs
    return ev0


def _diagnosis(story: Story, seed, say):
    """diagnosis.json, else diagnose() unless quick. Returns the live result if computed."""
    if story.diagnosis is not None:
        story.sources["diagnosis"] = str(story.work / "diagnosis.json")
        return None
    if story.quick:
        story.missing["diagnosis"] = (
            f"skipped (--quick). Run `labrig report {story.data_dir}` without --quick, or "
            f"`labrig diagnose {story.data_dir} --model model0.json --json > diagnosis.json` "
            "in the work folder")
        return None
    if story.model0 is None:
        story.missing["diagnosis"] = (f"labrig diagnose {story.data_dir} --json > diagnosis.json "
                                      "(no model to diagnose here)")
        return None
    say("report: diagnosing the linear model (tries every catalogue effect, ~30 s)")
    story.diagnosis = lr.diagnose(story.runs, story.model0, seed=seed, through=None)
    story.sources["diagnosis"] = f"computed by this report (labrig.diagnosis.loop.diagnose, seed {seed})"
    return story.diagnosis


def _ladder(story: Story, diag_live, ev0, say, seed=1) -> None:
    w = story.work
    doc = _artefact(story, "ladder.json", Ladder)
    ladder = doc if doc is not None and doc.steps else None
    png = None
    if ladder is not None:
        story.sources["ladder"] = str(w / "ladder.json")
        png = _work_png(story, "ladder.png")
    elif story.quick:
        story.missing["ladder"] = (
            f"skipped (--quick). Run `labrig ladder {story.data_dir} --models "
            "model0.json,model1.json --json > ladder.json` in the work folder, or the report "
            "without --quick")
    elif w and (w / "model0.json").is_file() and (w / "model1.json").is_file():
        say("report: evaluating the error ladder")
        ladder = lr.ladder(story.runs, [str(w / "model0.json"), str(w / "model1.json")],
                           through=None)
        story.sources["ladder"] = f"computed by this report from {w / 'model0.json'} and model1.json"
    elif story.diagnosis is not None and story.model0 is not None:
        ladder = _ladder_from_diagnosis(story, diag_live, ev0)
    else:
        story.missing["ladder"] = (f"labrig ladder {story.data_dir} --models "
                                   "model0.json,model1.json --json > ladder.json")
    story.ladder = ladder
    if ladder is not None:
        story.figures["ladder"] = [Figure("The error ladder", png or fig_bytes(ladder.plot()),
                                          "rmse/noise after each added effect; the dotted line "
                                          "is the noise floor.", wide=False)]
        story.figures["ladder"] += _corrected(story, diag_live, ev0, say, seed)


def _corrected(story: Story, diag_live, ev0, say, seed) -> list:
    """The corrected model on the worst run, below the linear model on the same run: the
    error falling, seen on the data (the work folder's figures when it has them)."""
    w, rec = story.work, story.diagnosis.recommendation if story.diagnosis else None
    name = story.worst_run or (ev0.worst_run()["name"] if ev0 is not None else None)
    if name is None or not rec:
        return []
    label = f"linear + {rec}"
    has_m1 = bool(w) and (w / "model1.json").is_file()
    before = _work_png(story, f"compare_{name}_model0.png")
    after = _work_png(story, f"compare_{name}.png") if has_m1 else None
    if before is None and ev0 is not None:
        rr = next((r for r in ev0.per_run if r["name"] == name), None)
        before = rr and fig_bytes(lrf.run_figure(rr, title=f"{name}: linear model vs "
                                                           "measurement"))
    if after is None:
        ev1 = None
        if diag_live is not None and diag_live.candidate(rec).evaluation is not None:
            ev1 = diag_live.candidate(rec).evaluation
        elif has_m1 and not story.quick:
            say("report: simulating the corrected model (model1.json)")
            ev1 = lr.compare(story.runs, w / "model1.json", through=None)
        elif story.model0 is not None and not story.quick:
            say(f"report: fitting the linear model + {rec} (warm start from the linear model)")
            res1 = lr.add_effect(story.runs, story.model0, rec, seed=seed, through=None,
                                 starts=1)
            ev1 = lr.compare(story.runs, res1.model(), through=None)
        rr = ev1 and next((r for r in ev1.per_run if r["name"] == name), None)
        after = rr and fig_bytes(lrf.run_figure(rr, title=f"{name}: {label} vs "
                                                         "measurement"))
    if not (before and after):
        return []
    return [Figure(f"{name}: the linear model", before,
                   "Before: the linear model's residual leaves the noise band."),
            Figure(f"{name}: {label}", after,
                   "After: with the missing effect the residual stays in the noise band.")]

def _ladder_from_diagnosis(story: Story, diag_live, ev0):
    """Linear model, then + the recommended effect as fitted by the diagnosis."""
    d = story.diagnosis
    rec = d.recommendation
    if ev0 is not None:
        m = ev0.metrics
        first = LadderStep("linear model", [], m["rmse_over_noise"], m["fit_percent"],
                           m["fitness"])
    else:
        b = d.baseline
        first = LadderStep("linear model", [], dict(b.get("rmse_over_noise") or {}),
                           dict(b.get("fit_percent") or {}), b.get("fitness"))
    if first.rmse_over_noise.get("overall") is None:
        return None
    ladder = Ladder([first])
    if rec and diag_live is not None and diag_live.candidate(rec).evaluation is not None:
        m = diag_live.candidate(rec).evaluation.metrics  # evaluated by the diagnosis
        ladder.steps.append(LadderStep(f"+ {rec}", [rec], m["rmse_over_noise"],
                                       m["fit_percent"], m["fitness"]))
    elif rec and (c := next((c for c in d.ranking if c.effect == rec), None)) is not None:
        ladder.steps.append(LadderStep(f"+ {rec}", [rec], {"overall": c.rmse_over_noise},
                                       dict(c.fit_percent), c.rmse_over_noise))
    story.sources["ladder"] = ("computed by this report from the diagnosis (the linear model and "
                               "the recommended effect as the diagnosis fitted it)")
    return ladder
