"""``labrig report``: the whole story of a data set in one self-contained HTML page.

The page has six sections -- the sweep, the first-order analysis, the identified
models side by side, where the model fails, the diagnosis and the error ladder --
plus a header with the key numbers and a footer saying where everything came from.
Figures are embedded as base64 PNG, the CSS is inline and there is no script, so
the file can be mailed, opened in any browser and printed (each section starts on
a new page).

Artefacts written by the earlier stages (``analysis.json``, ``identify_all.json``,
``model0.json``, ``diagnosis.json``, ``model1.json``, ``ladder.json``, ``figures/``;
see ``labrig demo``) are read from a work folder when they exist; what is missing is
computed here through the Python APIs: the analysis always, identification with CO
only, where-the-model-fails by simulating the model, the diagnosis (about 30 s) and
the ladder unless ``quick``. A section that cannot be filled says which command fills
it.

>>> build_report("demo_out/runs", "report.html", work="demo_out")   # doctest: +SKIP
"""
from __future__ import annotations

import base64
import html
import io
import json
import math
import sys
import tempfile
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .. import __version__  # noqa: E402
from ..errors import UserError  # noqa: E402

#: files that mark a folder as a work folder of the earlier stages
ARTEFACTS = ("analysis.json", "identify_all.json", "model0.json", "diagnosis.json",
             "model1.json", "ladder.json")

SECTIONS = (("sweep", "1. The sweep"),
            ("analysis", "2. First-order analysis"),
            ("models", "3. Identified models"),
            ("failures", "4. Where the model fails"),
            ("diagnosis", "5. Diagnosis: what is missing"),
            ("ladder", "6. The error ladder"))


# -- small helpers -------------------------------------------------------------------

def esc(x) -> str:
    """Escape any value for HTML text or attributes."""
    return html.escape("" if x is None else str(x), quote=True)


def num(x, fmt=".4g", unit="", dash="–") -> str:
    """A number formatted and escaped; None/NaN/inf become a dash."""
    if x is None or isinstance(x, bool):
        return dash if x is None else esc(x)
    try:
        v = float(x)
    except (TypeError, ValueError):
        return esc(x)
    if not math.isfinite(v):
        return dash
    if fmt.endswith("d"):
        v = int(round(v))
    return esc(format(v, fmt) + (f" {unit}" if unit else ""))


def pct(x, fmt=".1f") -> str:
    def f(v):
        t = format(100 * v, fmt)
        return (t[1:] if t.startswith("-") and float(t) == 0 else t) + " %"
    return dash_or(x, f)


def dash_or(x, f) -> str:
    try:
        if x is None or not math.isfinite(float(x)):
            return "–"
        return esc(f(float(x)))
    except (TypeError, ValueError):
        return esc(x)


def png_uri(data: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def fig_bytes(fig, dpi=110) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()


def _say(log, text):
    if log:
        log(text)


def _read_json(path: Path, notes: list) -> dict | None:
    if not path.exists():
        return None
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        notes.append(f"{path} was ignored: not valid JSON ({exc}).")
        return None
    if not isinstance(d, dict):
        notes.append(f"{path} was ignored: not a JSON object.")
        return None
    return d


def find_work(data_dir) -> Path | None:
    """The default work folder: the parent of the data folder when it holds artefacts."""
    parent = Path(data_dir).resolve().parent
    if any((parent / a).is_file() for a in ARTEFACTS) or (parent / "figures").is_dir():
        return parent
    return None


@dataclass
class Figure:
    title: str
    data: bytes
    caption: str = ""
    wide: bool = True


@dataclass
class Story:
    """Everything the page shows, gathered from files or computed."""

    data_dir: Path
    work: Path | None
    runs: list
    quick: bool
    sources: dict = field(default_factory=dict)      # section -> where its content came from
    notes: list = field(default_factory=list)        # page-level notes (ignored files, ...)
    figures: dict = field(default_factory=dict)      # section -> [Figure]
    analysis: dict | None = None
    analysis_error: str | None = None
    ident: list = field(default_factory=list)        # per-method to_dict()s
    ident_best: str | None = None
    model0: dict | None = None
    model0_source: str = ""
    regimes: dict | None = None
    worst_run: str | None = None
    diagnosis: dict | None = None
    ladder: list | None = None
    missing: dict = field(default_factory=dict)      # section -> what to run


# -- gathering -----------------------------------------------------------------------

def _work_figure(story: Story, name: str) -> bytes | None:
    if story.work is None:
        return None
    p = story.work / "figures" / name
    try:
        return p.read_bytes() if p.is_file() else None
    except OSError:
        return None


def _figure_from(tmp: Path, plot, *args, name="fig.png", **kw) -> bytes:
    from .compare_plots import save

    path = tmp / name
    save(plot(*args, **kw), path)
    return path.read_bytes()


def _run_names_match(names, story: Story) -> bool:
    have = {r.name for r in story.runs}
    names = set(names or ())
    return not names or names == have


def gather(data_dir, work=None, quick=False, seed=1, log=None) -> Story:
    from ..runs import read_dataset

    data_dir = Path(data_dir)
    runs = read_dataset(data_dir)
    story = Story(data_dir=data_dir, work=Path(work) if work else None, runs=runs, quick=quick)
    with tempfile.TemporaryDirectory(prefix="labrig-report-") as tmp:
        tmp = Path(tmp)
        _gather_sweep(story)
        _gather_analysis(story, tmp, log)
        ident_objs = _gather_models(story, tmp, seed, log)
        _gather_model0(story, ident_objs)
        ev0 = _gather_failures(story, tmp, log)
        diag_live = _gather_diagnosis(story, seed, log)
        _gather_ladder(story, tmp, diag_live, ev0, log)
    return story


def _gather_sweep(story: Story):
    story.sources["sweep"] = str(story.data_dir)
    story.figures["sweep"] = [Figure("Measured runs", plot_overview(story.runs),
                                     "Every run of the data set: the measured response (top) "
                                     "and what the bridge applied (bottom).")]


def _gather_analysis(story: Story, tmp: Path, log):
    from ..analyse import analyse

    w = story.work
    d = _read_json(w / "analysis.json", story.notes) if w else None
    if d is not None and not _run_names_match([r.get("name") for r in d.get("runs", [])
                                               if isinstance(r, dict)], story):
        story.notes.append(f"{w / 'analysis.json'} describes other runs than {story.data_dir}; "
                           "the analysis was recomputed.")
        d = None
    figs = {}
    if w:
        for name in ("speed_vs_voltage.png", "km_vs_amplitude.png"):
            b = _work_figure(story, name)
            if b:
                figs[name] = b
        for p in sorted((w / "figures").glob("edges_*.png")) if (w / "figures").is_dir() else []:
            if p.stem[len("edges_"):] in {r.name for r in story.runs}:
                figs[p.name] = p.read_bytes()
    if d is None or not figs:
        _say(log, "report: analysing the runs")
        try:
            res = analyse([story.data_dir])
        except Exception as exc:  # a data set analyse cannot read (e.g. closed loop only)
            story.analysis_error = f"{type(exc).__name__}: {exc}" if not str(exc) else str(exc)
            res = None
        if res is not None:
            if d is None:
                d = res.to_dict()
                story.sources["analysis"] = "computed by this report (labrig.analyse)"
            if not figs:
                # drawn one at a time; fig_bytes closes each
                for name, fig in res.figures().items():
                    figs[name] = fig_bytes(fig)
    if d is not None and "analysis" not in story.sources:
        story.sources["analysis"] = str(w / "analysis.json")
    story.analysis = d
    if d is None:
        story.missing["analysis"] = (f"labrig analyse {story.data_dir} --json > analysis.json "
                                     f"(it failed here: {story.analysis_error})")
    out = []
    for name, title in (("speed_vs_voltage.png", "Steady speed against input voltage"),
                        ("km_vs_amplitude.png", "Km = w/V against amplitude")):
        if name in figs:
            out.append(Figure(title, figs.pop(name), wide=False))
    for name, b in sorted(figs.items()):
        out.append(Figure(f"Edges of {name[len('edges_'):-4]}", b,
                          "Each edge with its first-order fit and the 63 % point.", wide=True))
    story.figures["analysis"] = out


def _gather_models(story: Story, tmp: Path, seed, log):
    """The identified models: identify_all.json, else CO now. Returns live objects."""
    from types import SimpleNamespace

    from ..report.identify_plots import plot_convergence

    w = story.work
    d = _read_json(w / "identify_all.json", story.notes) if w else None
    live = []
    if d is not None:
        if isinstance(d.get("results"), dict) and d["results"]:
            story.ident = [dict(v, method=v.get("method", k)) for k, v in d["results"].items()]
            story.ident_best = d.get("best")
        elif "params" in d:
            story.ident = [d]
            story.ident_best = d.get("method")
        if story.ident:
            names = [n for r in story.ident for n in (r.get("per_run") or {})]
            if not _run_names_match(set(names), story):
                story.notes.append(f"{w / 'identify_all.json'} was fitted on other runs than "
                                   f"{story.data_dir}; the model was re-identified.")
                story.ident = []
            else:
                story.sources["models"] = str(w / "identify_all.json")
    if not story.ident and w and (w / "model0.json").is_file():
        m = _read_json(w / "model0.json", story.notes)
        names = ((m or {}).get("dataset") or {}).get("runs")
        if m and isinstance(m.get("params"), dict) and _run_names_match(names, story):
            story.ident = [dict(m, method=m.get("method", "?"))]
            story.ident_best = story.ident[0]["method"]
            story.sources["models"] = (f"{w / 'model0.json'} (run `labrig identify "
                                       f"{story.data_dir} --method all --json > "
                                       "identify_all.json` for JFO, PSO and CO side by side)")
    if not story.ident:
        from ..identify.engine import identify

        _say(log, "report: identifying the linear model with CO (a few seconds)")
        res = identify(story.runs, "co", [], seed=seed, starts=4,
                       dataset={"paths": [str(story.data_dir)],
                                "runs": [r.name for r in story.runs]})
        live = [res]
        story.ident = [res.to_dict()]
        story.ident_best = res.method
        story.sources["models"] = (f"computed by this report (CO, seed {seed}); run "
                                   f"`labrig identify {story.data_dir} --method all --json` "
                                   "for JFO and PSO side by side")
    if story.ident_best is None:
        story.ident_best = min(story.ident, key=lambda r: _f(r.get("fitness"))).get("method")
    # drawn from the histories rather than taken from figures/: a local method (CO)
    # records its multi-starts' mean squares, not the fitness, so it gets a flat line
    fake = [SimpleNamespace(method=r.get("method", "?"), fitness=_f(r.get("fitness")),
                            result=SimpleNamespace(history=[] if str(r.get("method", "")).startswith("co")
                                                   else [h for h in r.get("history") or []
                                                         if h is not None]))
            for r in story.ident]
    conv = _figure_from(tmp, plot_convergence, fake, name="convergence.png")
    story.figures["models"] = [Figure("Convergence of the identifiers", conv,
                                      "Best fitness (rmse/noise) against iteration; 1.0 is the "
                                      "noise floor.", wide=False)]
    return live


def _f(x, default=math.inf) -> float:
    try:
        v = float(x)
        return v if math.isfinite(v) else default
    except (TypeError, ValueError):
        return default


def _gather_model0(story: Story, live):
    """The linear model the later sections judge: model0.json, else the best fit."""
    from ..model.model import Model

    w = story.work
    if w and (w / "model0.json").is_file():
        try:
            story.model0 = Model.load(w / "model0.json")
            story.model0_source = str(w / "model0.json")
            return
        except UserError as exc:
            story.notes.append(f"{w / 'model0.json'} was ignored: {exc}")
    try:
        if live:
            m = live[0].model()
        else:
            best = next((r for r in story.ident if r.get("method") == story.ident_best),
                        story.ident[0])
            m = Model.from_json({"params": best["params"], "effects": best.get("effects", []),
                                 "effect_params": best.get("effect_params", {})},
                                "identify_all.json")
    except UserError as exc:  # e.g. a user effect that is not trusted (or not here)
        story.notes.append(f"the identified model's effects could not be loaded ({exc})")
        return
    story.model0 = m
    story.model0_source = f"the {story.ident_best} fit of section 3"


def _gather_failures(story: Story, tmp: Path, log):
    """Regime table, regimes.png and the worst run's comparison. Returns the live
    evaluation of the linear model when it had to be computed (else None)."""
    from ..report.compare_plots import plot_regimes, plot_run_comparison

    w = story.work
    diag = _read_json(w / "diagnosis.json", story.notes) if w else None
    if diag is not None and not isinstance(diag.get("regimes"), dict):
        story.notes.append(f"{w / 'diagnosis.json'} was ignored: no 'regimes' key.")
        diag = None
    story.diagnosis = diag
    reg_png = _work_figure(story, "regimes.png")
    cmp_png, worst = None, None
    if w and (w / "figures").is_dir():
        names = {r.name for r in story.runs}
        for p in sorted((w / "figures").glob("compare_*_model0.png")):
            n = p.name[len("compare_"):-len("_model0.png")]
            if n in names:
                cmp_png, worst = p.read_bytes(), n
                break
    ev0 = None
    if diag is not None:
        story.regimes = diag["regimes"]
        story.sources["failures"] = str(w / "diagnosis.json")
    if story.model0 is not None and (diag is None or reg_png is None or cmp_png is None):
        from ..evaluation import evaluate
        from ..residuals import worst_regime

        _say(log, "report: simulating the linear model on every run")
        ev0 = evaluate(story.runs, story.model0)
        if diag is None:
            table = ev0.regimes
            wr = worst_regime(table)
            story.regimes = {"by_regime": table["by_regime"], "by_amplitude": table["by_amplitude"],
                             "worst": None if wr is None else {"channel": wr[0], "regime": wr[1],
                                                               "rmse_over_noise": wr[2]},
                             "noise": ev0.metrics["noise"]}
            story.sources["failures"] = (f"computed by this report (simulation of "
                                         f"{story.model0_source})")
        if reg_png is None:
            reg_png = _figure_from(tmp, plot_regimes, ev0.regimes, name="regimes.png",
                                   title="Where the linear model fails")
        if cmp_png is None:
            from ..residuals import worst_run

            rr = worst_run(ev0.per_run)
            worst = rr["name"]
            cmp_png = _figure_from(tmp, plot_run_comparison, rr, name="compare.png",
                                   title=f"{worst}: linear model vs measurement")
    elif story.model0 is None and diag is None:
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
                           "stretches that leave the noise band, and the whiteness tests."))
    story.figures["failures"] = figs
    return ev0


def _gather_diagnosis(story: Story, seed, log):
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
    from ..diagnose import diagnose

    _say(log, "report: diagnosing the linear model (tries every catalogue effect, ~30 s)")
    res = diagnose(story.runs, story.model0, seed=seed)
    story.diagnosis = res.to_json()
    story.sources["diagnosis"] = f"computed by this report (labrig.diagnose, seed {seed})"
    return res


def _gather_ladder(story: Story, tmp: Path, diag_live, ev0, log):
    from ..report.compare_plots import plot_ladder

    w = story.work
    d = _read_json(w / "ladder.json", story.notes) if w else None
    steps = d.get("steps") if d else None
    if steps is not None and (not isinstance(steps, list) or not all(
            isinstance(s, dict) and isinstance(s.get("rmse_over_noise"), dict) for s in steps)):
        story.notes.append(f"{w / 'ladder.json'} was ignored: 'steps' is not a list of steps.")
        steps = None
    if steps:
        story.sources["ladder"] = str(w / "ladder.json")
    elif story.quick:
        story.missing["ladder"] = (
            f"skipped (--quick). Run `labrig ladder {story.data_dir} --models "
            "model0.json,model1.json --json > ladder.json` in the work folder, or the report "
            "without --quick")
    elif w and (w / "model0.json").is_file() and (w / "model1.json").is_file():
        from ..ladder import evaluate_ladder

        _say(log, "report: evaluating the error ladder")
        steps = evaluate_ladder(story.runs, [str(w / "model0.json"),
                                             str(w / "model1.json")]).to_json()["steps"]
        story.sources["ladder"] = f"computed by this report from {w / 'model0.json'} and model1.json"
    elif story.diagnosis is not None and story.model0 is not None:
        steps = _ladder_from_diagnosis(story, diag_live, ev0)
    else:
        story.missing["ladder"] = (f"labrig ladder {story.data_dir} --models "
                                   "model0.json,model1.json --json > ladder.json")
    story.ladder = steps or None
    if steps:
        png = _work_figure(story, "ladder.png") if w and story.sources["ladder"] == \
            str(w / "ladder.json") else None
        if png is None:
            png = _figure_from(tmp, plot_ladder, steps, name="ladder.png")
        story.figures["ladder"] = [Figure("The error ladder", png,
                                          "rmse/noise after each added effect; the dotted line "
                                          "is the noise floor.", wide=False)]


def _ladder_from_diagnosis(story: Story, diag_live, ev0) -> list:
    """Linear model, then + the recommended effect as fitted by the diagnosis."""
    from ..evaluation import evaluate

    d = story.diagnosis
    rec = d.get("recommendation")
    base = d.get("baseline", {})

    def step(label, effects, rmse, fit, fitness):
        return {"label": label, "effects": effects, "rmse_over_noise": rmse,
                "fit_percent": fit, "fitness": fitness, "model": None}

    if ev0 is not None:
        m = ev0.metrics
        steps = [step("linear model", [], m["rmse_over_noise"], m["fit_percent"], m["fitness"])]
    else:
        steps = [step("linear model", [], base.get("rmse_over_noise", {}),
                      base.get("fit_percent", {}), base.get("fitness"))]
    if rec:
        if diag_live is not None and rec in diag_live.states:
            m = evaluate(story.runs, diag_live.states[rec]).metrics
            steps.append(step(f"+ {rec}", [rec], m["rmse_over_noise"], m["fit_percent"],
                              m["fitness"]))
        else:
            e = next((e for e in d.get("ranking", []) if e.get("effect") == rec), None)
            if e is not None:
                steps.append(step(f"+ {rec}", [rec], {"overall": e.get("rmse_over_noise")},
                                  e.get("fit_percent", {}), e.get("rmse_over_noise")))
    if not isinstance(steps[0]["rmse_over_noise"], dict) or \
            steps[0]["rmse_over_noise"].get("overall") is None:
        return []
    story.sources["ladder"] = ("computed by this report from the diagnosis (the linear model and "
                               "the recommended effect as the diagnosis fitted it)")
    return steps


# -- figures made here ---------------------------------------------------------------

def plot_overview(runs) -> bytes:
    """One figure of the whole sweep: response on top, input below; open-loop runs on
    the left (motor speed), closed-loop runs on the right (output angle and reference)."""
    groups = [("open", [r for r in runs if r.loop != "closed"]),
              ("closed", [r for r in runs if r.loop == "closed"])]
    groups = [g for g in groups if g[1]]
    fig, axes = plt.subplots(2, len(groups), figsize=(6.2 * len(groups) if len(groups) > 1 else 11, 5.6),
                             squeeze=False, sharex="col", gridspec_kw={"height_ratios": [3, 1.4]})
    for col, (loop, rs) in enumerate(groups):
        top, bot = axes[0, col], axes[1, col]
        cmap = plt.get_cmap("viridis")
        for i, r in enumerate(sorted(rs, key=lambda r: (r.amplitude, r.name))):
            c = cmap(0.1 + 0.8 * i / max(len(rs) - 1, 1))
            t = r.t - r.t[0]
            if loop == "open":
                y = r.speed if r.has_tacho else None
                if y is None and r.has_pos:
                    y = np.gradient(r.position * r.gear_ratio, r.dt)
                top.plot(t, y, color=c, lw=0.8, label=r.name)
            else:
                y = r.position
                if y is None:
                    y = np.cumsum(r.speed) * r.dt / r.gear_ratio
                top.plot(t, y, color=c, lw=1.0, label=r.name)
                if r.ref is not None:
                    # the loop compares the reference with the pot's volts without its
                    # offset (truth.py): reference angle = ref / Kpot
                    top.plot(t, r.ref / r.kpot, color=c, lw=0.8, ls="--")
            bot.plot(t, r.u, color=c, lw=0.8)
        if loop == "open":
            top.set_title("open loop: motor speed", fontsize=10)
            top.set_ylabel("speed (rad/s, motor)")
            bot.set_ylabel("u (V)")
        else:
            top.set_title("closed loop: output angle (dashed: reference)", fontsize=10)
            top.set_ylabel("angle (rad, output)")
            bot.set_ylabel("reference (V)")
        bot.set_xlabel("time (s)")
        for ax in (top, bot):
            ax.grid(alpha=0.3)
        top.legend(fontsize=7, loc="upper right", ncol=2 if len(rs) > 4 else 1)
    fig.tight_layout()
    return fig_bytes(fig)


# -- rendering -----------------------------------------------------------------------

CSS = """
:root { --ink:#1d2330; --muted:#5b6473; --line:#d8dde6; --accent:#1f5fa8; --soft:#f3f6fa;
        --good:#1b7a3a; --warn:#a65e00; --bad:#b3261e; }
* { box-sizing: border-box; }
html { background: #eef1f5; }
body { margin: 0; color: var(--ink); font: 15px/1.5 "DejaVu Sans", "Segoe UI", Helvetica, Arial, sans-serif; }
.page { max-width: 1160px; margin: 0 auto; background: #fff; padding: 28px 44px 36px;
        box-shadow: 0 0 0 1px var(--line); }
header h1 { font-size: 28px; margin: 0 0 2px; letter-spacing: -0.3px; }
header .sub { color: var(--muted); margin: 0 0 18px; }
h2 { font-size: 22px; margin: 0 0 10px; padding-bottom: 6px; border-bottom: 3px solid var(--accent); }
h3 { font-size: 16px; margin: 22px 0 8px; color: #2b3445; }
section { margin-top: 34px; }
p { margin: 8px 0; }
.muted { color: var(--muted); }
.small { font-size: 12.5px; }
code { font: 13px "DejaVu Sans Mono", Consolas, monospace; background: var(--soft);
       padding: 1px 4px; border-radius: 3px; }
.cards { display: grid; grid-template-columns: repeat(auto-fit, minmax(165px, 1fr)); gap: 10px;
         margin: 10px 0 16px; }
.card { border: 1px solid var(--line); border-radius: 8px; padding: 10px 12px; background: var(--soft); }
.card .k { font-size: 12px; color: var(--muted); text-transform: uppercase; letter-spacing: .4px; }
.card .v { font-size: 20px; font-weight: 700; margin-top: 2px; overflow-wrap: anywhere; }
.card .v.txt { font-size: 16px; line-height: 1.6; }
.card .d { font-size: 12px; color: var(--muted); }
nav.toc { border: 1px solid var(--line); border-radius: 8px; padding: 8px 14px; font-size: 14px; }
nav.toc ol { margin: 4px 0; padding-left: 0; list-style: none; columns: 2; }
nav.toc a { color: var(--accent); text-decoration: none; }
table { border-collapse: collapse; margin: 8px 0 12px; font-size: 13.5px; }
th, td { padding: 4px 10px; border-bottom: 1px solid var(--line); text-align: right; vertical-align: top; }
th { background: #e9eef5; font-weight: 600; }
th:first-child, td:first-child { text-align: left; }
td.l, th.l { text-align: left; }
tbody tr:nth-child(even) td { background: #fafbfd; }
tr.group td { background: #fff !important; font-weight: 700; color: var(--accent);
              padding-top: 10px; border-bottom: 1px solid var(--accent); text-align: left; }
td.best, th.best { background: #eaf4ec !important; }
tr.hl td { background: #fff4e0 !important; }
.yes { color: var(--good); font-weight: 600; }
.no { color: var(--muted); }
.q { color: var(--warn); font-weight: 700; }
.verdict { border-left: 5px solid var(--accent); background: var(--soft); padding: 10px 14px;
           margin: 12px 0; border-radius: 0 6px 6px 0; }
.verdict.good { border-color: var(--good); }
.verdict.warn { border-color: var(--warn); }
.missing { border: 2px dashed var(--warn); border-radius: 8px; padding: 12px 16px; color: #5a3b00;
           background: #fffaf0; }
.missing code { background: #fff; }
ul.warn { margin: 6px 0; padding-left: 20px; font-size: 13px; color: #5a3b00; }
figure { margin: 14px 0; break-inside: avoid; page-break-inside: avoid; }
figure img { max-width: 100%; height: auto; display: block; margin: 0 auto;
             border: 1px solid var(--line); border-radius: 4px; }
figcaption { font-size: 12.5px; color: var(--muted); margin-top: 4px; text-align: center; }
.grid2 { display: grid; grid-template-columns: 1fr 1fr; gap: 14px; align-items: start; }
.src { font-size: 12px; color: var(--muted); margin-top: -4px; }
footer { margin-top: 40px; padding-top: 10px; border-top: 1px solid var(--line); font-size: 12px;
         color: var(--muted); }
footer table { font-size: 12px; }
footer td { border: none; padding: 1px 10px 1px 0; text-align: left; }
@page { size: A4; margin: 14mm 12mm; }
@media print {
  html, body { background: #fff !important; }
  body { font-size: 11pt; }
  .page { max-width: none; padding: 0; box-shadow: none; }
  nav.toc { display: none; }
  section { break-before: page; page-break-before: always; margin-top: 0; }
  h2, h3 { break-after: avoid; page-break-after: avoid; }
  table, figure, .verdict, .missing, .cards { break-inside: avoid; page-break-inside: avoid; }
  th, .card, .verdict, code, tbody tr:nth-child(even) td, .missing { background: #fff !important; }
  figure img { max-height: 240mm; border: none; }
  a { color: inherit; text-decoration: none; }
}
"""


def _fig_html(f: Figure) -> str:
    cap = f"<figcaption><b>{esc(f.title)}.</b> {esc(f.caption)}</figcaption>"
    return f'<figure><img src="{png_uri(f.data)}" alt="{esc(f.title)}">{cap}</figure>'


def _figs_html(figs) -> str:
    out, pair = [], []
    for f in figs:
        if f.wide:
            if pair:
                out.append(_pair(pair))
                pair = []
            out.append(_fig_html(f))
        else:
            pair.append(f)
            if len(pair) == 2:
                out.append(_pair(pair))
                pair = []
    if pair:
        out.append(_pair(pair))
    return "\n".join(out)


def _pair(figs) -> str:
    if len(figs) == 1:
        return f'<div style="max-width:720px;margin:0 auto">{_fig_html(figs[0])}</div>'
    return '<div class="grid2">' + "".join(_fig_html(f) for f in figs) + "</div>"


def _table(head, rows, cls_head=None, row_cls=None) -> str:
    """head: list of (already escaped) header cells; rows: list of lists of escaped cells,
    or ("group", text) for a group row."""
    ncol = len(head)
    h = "".join(f'<th class="{(cls_head or {}).get(i, "")}">{c}</th>' for i, c in enumerate(head))
    body = []
    for k, r in enumerate(rows):
        if isinstance(r, tuple) and r and r[0] == "group":
            body.append(f'<tr class="group"><td colspan="{ncol}">{esc(r[1])}</td></tr>')
            continue
        rc = (row_cls or {}).get(k, "")
        cells = "".join(f'<td class="{(cls_head or {}).get(i, "")}">{c}</td>' for i, c in enumerate(r))
        body.append(f'<tr class="{rc}">{cells}</tr>')
    return f"<table><thead><tr>{h}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _missing(what: str) -> str:
    cmd = esc(what)
    return ('<div class="missing"><b>Not in this report.</b> To fill this section: '
            f"<code>{cmd}</code></div>")


def _source(story: Story, key: str) -> str:
    s = story.sources.get(key)
    return f'<p class="src">Source: {esc(s)}</p>' if s else ""


def _section(key, title, body) -> str:
    return f'<section id="{esc(key)}"><h2>{esc(title)}</h2>\n{body}\n</section>'


# section 1 -------------------------------------------------------------------------

def _sweep_html(story: Story) -> str:
    rows = []
    for r in story.runs:
        exp = r.experiment
        br = r.meta.get("bridge", {}) or {}
        sensors = ", ".join(s for s, ok in (("tacho", r.has_tacho), ("pot", r.has_pos)) if ok)
        drop = br.get("dropped_samples")
        crc = br.get("crc_errors")
        drop_txt = "–" if drop is None else esc(drop)
        if crc:
            drop_txt += f' <span class="q">({esc(crc)} CRC)</span>'
        if drop:
            drop_txt = f'<span class="q">{drop_txt}</span>'
        rows.append([esc(r.name), esc(r.loop), esc(exp.get("waveform", "–")),
                     num(exp.get("amplitude_v", r.amplitude), ".3g", "V"),
                     num(exp.get("frequency_hz"), ".3g", "Hz"), esc(len(r)),
                     num(len(r) / r.fs, ".3g", "s"), num(r.fs, "g", "Hz"),
                     esc(r.meta.get("source", "–")), esc(sensors), drop_txt])
    n_open = sum(r.loop != "closed" for r in story.runs)
    rig = (story.runs[0].meta.get("rig", {}) or {}) if story.runs else {}
    intro = (f"<p>{len(story.runs)} runs in <code>{esc(story.data_dir)}</code>: {n_open} open-loop, "
             f"{len(story.runs) - n_open} closed-loop"
             + (f", rig <b>{esc(rig.get('name'))}</b>" if rig.get("name") else "")
             + (f" (gear ratio {num(rig.get('gear_ratio'), 'g')}, amplifier gain "
                f"{num(rig.get('amplifier_gain'), 'g')})" if rig.get("gear_ratio") else "")
             + ".</p>")
    head = ["run", "loop", "waveform", "amplitude", "frequency", "samples", "length", "rate",
            "source", "sensors", "dropped"]
    cls = {1: "l", 2: "l", 8: "l", 9: "l"}
    return (intro + _source(story, "sweep") + _table(head, rows, cls)
            + _figs_html(story.figures.get("sweep", [])))


# section 2 -------------------------------------------------------------------------

def _analysis_html(story: Story) -> str:
    a = story.analysis
    if a is None:
        return _missing(story.missing.get("analysis", f"labrig analyse {story.data_dir} --json"))
    out = [_source(story, "analysis")]
    # Table 1: one row per moving input level
    rows = []
    skipped = []
    for r in a.get("runs", []):
        if not isinstance(r, dict):
            continue
        if r.get("skipped"):
            skipped.append((r.get("name"), r["skipped"]))
            continue
        for lv in r.get("levels", []):
            v = lv.get("v")
            if v is None or abs(_f(v, 0.0)) < 1e-6:
                continue
            w = lv.get("speed_rad_s")
            note = "" if lv.get("moving") is not False else "at rest"
            if not lv.get("settled"):
                note = "not settled"
            rows.append([esc(r.get("name")), num(v, "+.3f"),
                         dash_or(w, lambda x: f"{x * 30 / math.pi:.0f}"), num(w, ".2f"),
                         num(lv.get("spread_rad_s"), ".2f"), num(lv.get("km_paper"), ".2f"),
                         dash_or(lv.get("tau_s"), lambda x: f"{1e3 * x:.1f}"), esc(note)])
    out.append("<h3>Table 1: steady speed per input level</h3>")
    if rows:
        out.append(_table(["run", "V<sub>m</sub> (V)", "n (rpm)", "&omega; (rad/s)", "spread (rad/s)",
                           "K<sub>m</sub> = &omega;/V", "&tau; (ms)", "note"], rows, {7: "l"}))
    else:
        out.append('<p class="muted">No settled open-loop levels (the analysis uses open-loop runs).</p>')
    if skipped:
        out.append('<p class="small muted">Not analysed: '
                   + "; ".join(f"{esc(n)} ({esc(s)})" for n, s in skipped) + ".</p>")
    kmp = a.get("km_paper") or {}
    if kmp:
        cells = sorted(((_f(k, 0), v) for k, v in kmp.items()), key=lambda x: x[0])
        out.append('<p class="small">K<sub>m</sub> = &omega;/V by amplitude: '
                   + ", ".join(f"{num(k, '.3g')} V: <b>{num(v, '.2f')}</b>" for k, v in cells)
                   + " rad/s per V.</p>")
    # the summary
    out.append("<h3>Summary</h3>")
    fwd, rev = a.get("forward") or {}, a.get("reverse") or {}
    tr = a.get("trend") or {}
    srows = [["k<sub>m</sub> (incremental gain)", num(a.get("km"), ".4g", "rad/s per V"),
              esc(f"forward {num(fwd.get('km'), '.4g')}, reverse {num(rev.get('km'), '.4g')}")
              if fwd.get("km") is not None else ""],
             ["&tau;<sub>m</sub> (median edge)", dash_or(a.get("tau_s"), lambda x: f"{1e3 * x:.1f} ms"), ""],
             ["deadband", num(a.get("deadband_v"), ".3f", "V"),
              esc(f"forward {num(fwd.get('deadband_v'), '.3f')}, reverse "
                  f"{num(rev.get('deadband_v'), '.3f')} V") if fwd.get("deadband_v") is not None else ""],
             ["k<sub>t</sub> (tacho)", num(a.get("kt"), ".4g", "V per rad/s"),
              (f"configured {num(a.get('kt_configured'), '.4g')}"
               + (' <span class="q">MISMATCH</span>' if a.get("kt_mismatch") else ""))
              if a.get("kt_configured") is not None else ""],
             ["gain trend", f"<b>{esc(a.get('gain_trend', '–'))}</b>",
              esc(f"w/V changes by {100 * tr['relative_change']:+.1f} % over the amplitude range "
                  f"(tolerance {100 * _f(a.get('tolerance'), 0):.0f} %)")
              if tr.get("relative_change") is not None else ""]]
    if a.get("breakaway_v") is not None:
        srows.insert(3, ["breakaway (stiction)", num(a.get("breakaway_v"), ".3f", "V"), ""])
    out.append(_table(["quantity", "value", "detail"], srows, {1: "l", 2: "l"}))
    if a.get("verdict"):
        out.append(f'<div class="verdict"><b>Verdict.</b> {esc(a["verdict"])}</div>')
    out.append(_figs_html(story.figures.get("analysis", [])))
    return "\n".join(out)


# section 3 -------------------------------------------------------------------------

COMBOS = (("km", "K<sub>m</sub> (rad/s per V)"), ("tau_m_s", "&tau;<sub>m</sub> (s)"),
          ("tau_e_s", "&tau;<sub>e</sub> (s)"))
PLANT = (("R", "ohm"), ("L", "H"), ("J", "kg m²"), ("B", "N m s/rad"), ("K", "N m/A"))


def _interval(c) -> str:
    if not isinstance(c, dict):
        return "–"
    v = num(c.get("value"), ".4g")
    iv = c.get("interval95")
    if c.get("identifiable") is False or not iv:
        return f'{v} <span class="q" title="not identifiable">?</span>'
    return f'{v}<br><span class="small muted">[{num(iv[0], ".4g")}, {num(iv[1], ".4g")}]</span>'


def _models_html(story: Story) -> str:
    res = story.ident
    if not res:
        return _missing(f"labrig identify {story.data_dir} --method all --json > identify_all.json")
    best = story.ident_best
    head = [""] + [esc(r.get("method", "?").upper()) + (" (best)" if r.get("method") == best else "")
                   for r in res]
    bi = {i + 1: ("best" if r.get("method") == best else "") for i, r in enumerate(res)}
    rows = [("group", "identifiable combinations (95 % intervals)")]
    for key, label in COMBOS:
        rows.append([label] + [_interval((r.get("identifiable") or {}).get(key)) for r in res])
    rows.append(("group", "physical parameters (one member of the family the data allow)"))
    for n, unit in PLANT:
        cells = []
        for r in res:
            info = ((r.get("identifiable") or {}).get("parameters") or {}).get(n, {})
            v = num((r.get("params") or {}).get(n), ".4g")
            if info.get("fixed"):
                v += ' <span class="small muted">(fixed)</span>'
            elif info and info.get("identifiable") is False:
                v += ' <span class="q" title="not identifiable from these data">?</span>'
            cells.append(v)
        rows.append([f"{n} ({esc(unit)})"] + cells)
    eff_keys = []
    for r in res:
        for e, ps in (r.get("effect_params") or {}).items():
            for k in ps:
                if (e, k) not in eff_keys:
                    eff_keys.append((e, k))
    for e, k in eff_keys:
        rows.append([esc(f"{e}.{k}")] + [num(((r.get("effect_params") or {}).get(e) or {}).get(k), ".4g")
                                          for r in res])
    rows.append(("group", "fit"))
    rows.append(["fitness (eq. 26)"] + [num(r.get("fitness"), ".4g") for r in res])
    for ch in ("overall", "speed", "position"):
        rows.append([f"rmse/noise {ch}"] + [num((r.get("rmse_over_noise") or {}).get(ch), ".3g")
                                             for r in res])
    for ch in ("speed", "position"):
        rows.append([f"fit % {ch}"] + [num((r.get("fit_percent") or {}).get(ch), ".2f") for r in res])
    rows.append(("group", "closed-loop position step of the identified model"))
    for key, label in (("rise_time_s", "rise time (s)"), ("settling_time_s", "settling time (s)"),
                       ("overshoot_percent", "overshoot (%)")):
        rows.append([label] + [num((r.get("step_info") or {}).get(key), ".3g") for r in res])
    rows.append(("group", "cost"))
    rows.append(["evaluations (nfev)"] + [num(r.get("nfev"), "d") for r in res])
    rows.append(["seconds"] + [num(r.get("seconds"), ".1f") for r in res])
    rows.append(["seed"] + [esc(r.get("seed", "–")) for r in res])
    out = [_source(story, "models"),
           "<p>Only three combinations of R, L, J, B, K shape the response from u to the "
           "speed and the angle, so the identifiable combinations come first; "
           '<span class="q">?</span> marks a value the data cannot pin down on its own.</p>',
           _table(head, rows, {**bi}, None)]
    warns = []
    for r in res:
        for wtxt in (r.get("identifiable") or {}).get("warnings", []) or []:
            if wtxt not in warns:
                warns.append(wtxt)
    if warns:
        out.append("<h3>Identifiability warnings</h3><ul class=\"warn\">"
                   + "".join(f"<li>{esc(wt)}</li>" for wt in warns) + "</ul>")
    out.append(_figs_html(story.figures.get("models", [])))
    return "\n".join(out)


# section 4 -------------------------------------------------------------------------

def _regime_name(reg):
    from ..residuals import REGIME_TEXT

    return REGIME_TEXT.get(reg, reg)


def _failures_html(story: Story) -> str:
    t = story.regimes
    if t is None:
        return _missing(story.missing.get("failures", f"labrig diagnose {story.data_dir} --json"))
    out = [_source(story, "failures")]
    model = story.model0_source or "the linear model"
    out.append(f"<p>The linear model ({esc(model)}) simulated on every run; its error is split "
               "by what the motor was doing. rmse/noise = 1 means the model explains all that "
               "the sensor noise allows.</p>")
    worst = t.get("worst") or {}
    if worst:
        out.append(f'<div class="verdict warn"><b>Worst:</b> the {esc(_regime_name(worst.get("regime")))} '
                   f"stretches of the {esc(worst.get('channel'))} (rmse/noise "
                   f"{num(worst.get('rmse_over_noise'), '.2f')})"
                   + (f"; worst run: <b>{esc(story.worst_run)}</b>" if story.worst_run else "")
                   + ".</div>")
    by = t.get("by_regime") or {}
    chans = list(by)
    regs = []
    for ch in chans:
        for reg in by[ch]:
            if reg not in regs:
                regs.append(reg)
    head = ["regime"]
    for ch in chans:
        head += [f"{esc(ch)}<br>rmse/noise", "share of<br>time", "share of<br>error"]
    rows, hl = [], {}
    for k, reg in enumerate(regs):
        row = [esc(_regime_name(reg))]
        for ch in chans:
            v = by[ch].get(reg) or {}
            row += [num(v.get("rmse_over_noise"), ".2f"), pct(v.get("share_of_time"), ".0f"),
                    pct(v.get("share_of_error"), ".0f")]
        if reg == worst.get("regime"):
            hl[k] = "hl"
        rows.append(row)
    if rows:
        out.append("<h3>Error by regime</h3>" + _table(head, rows, row_cls=hl))
    ba = t.get("by_amplitude") or {}
    if ba:
        keys = []
        for ch in ba:
            for k in ba[ch]:
                if k not in keys:
                    keys.append(k)
        rows = [[esc(k)] + [num(ba[ch].get(k), ".2f") for ch in ba] for k in keys]
        out.append("<h3>Error by run amplitude</h3>"
                   + _table(["runs"] + [f"{esc(ch)} rmse/noise" for ch in ba], rows))
    noise = t.get("noise") or {}
    if noise:
        out.append('<p class="small muted">Noise levels used: '
                   + ", ".join(f"{esc(k)} {num(v, '.3g')}" for k, v in noise.items()) + ".</p>")
    out.append(_figs_html(story.figures.get("failures", [])))
    return "\n".join(out)


# section 5 -------------------------------------------------------------------------

def _diagnosis_html(story: Story) -> str:
    d = story.diagnosis
    if d is None:
        return _missing(story.missing.get("diagnosis", "labrig diagnose DIR --json"))
    out = [_source(story, "diagnosis")]
    base = d.get("baseline") or {}
    rec = d.get("recommendation")
    out.append(f"<p>Baseline: {esc(base.get('source', 'the model'))}"
               + (f" with {esc(', '.join(base['effects']))}" if base.get("effects") else "")
               + f"; rmse/noise {num((base.get('rmse_over_noise') or {}).get('overall'), '.2f')}. "
               "Each catalogue effect the model lacks was added and the model re-fitted; an effect "
               "is supported when it lowers the error by at least "
               f"{pct((d.get('criteria') or {}).get('min_improvement'), '.0f')}, with "
               f"&Delta;BIC below {num((d.get('criteria') or {}).get('max_delta_bic'), 'g')} "
               + (f"and on the held-out run {esc(', '.join(d['held_out']))}" if d.get("held_out")
                  else "(no held-out run)") + ".</p>")
    cls = "good" if rec else "warn"
    out.append(f'<div class="verdict {cls}"><b>Recommendation: {esc(rec or "none")}.</b> '
               f"{esc(d.get('verdict', ''))}</div>")
    rows, hl = [], {}
    for k, e in enumerate(d.get("ranking") or []):
        ho = e.get("held_out") or {}
        params = ", ".join(f"{esc(p)} = {num(v, '.3g')}" for p, v in (e.get("params") or {}).items())
        sup = '<span class="yes">yes</span>' if e.get("supported") else '<span class="no">no</span>'
        rows.append([f"{k + 1}. {esc(e.get('effect'))}", num(e.get("rmse_over_noise"), ".2f"),
                     pct(e.get("improvement"), ".0f"), num(e.get("delta_bic"), ".0f"),
                     pct(ho.get("improvement"), ".0f") if ho else "–", sup, params])
        if e.get("effect") == rec:
            hl[k] = "hl"
    if rows:
        out.append("<h3>Ranking of the candidate effects</h3>")
        out.append(_table(["effect", "rmse/noise", "improvement", "&Delta;BIC", "held-out<br>improvement",
                           "supported", "fitted parameters"], rows, {6: "l"}, hl))
    top = next((e for e in d.get("ranking") or [] if e.get("effect") == rec), None)
    if top is None and d.get("ranking"):
        top = d["ranking"][0]
        if top.get("explanation"):
            out.append(f"<h3>The best candidate, {esc(top.get('effect'))}, and why it is not "
                       f"enough</h3><p>{esc(top['explanation'])}</p>")
    elif top is not None and top.get("explanation") and top["explanation"] not in d.get("verdict", ""):
        out.append(f"<h3>Why {esc(rec)}</h3><p>{esc(top['explanation'])}</p>")
    if d.get("seconds") is not None:
        out.append(f'<p class="small muted">The diagnosis took {num(d["seconds"], ".0f")} s.</p>')
    return "\n".join(out)


# section 6 -------------------------------------------------------------------------

def _ladder_html(story: Story) -> str:
    steps = story.ladder
    if not steps:
        return _missing(story.missing.get("ladder", "labrig ladder DIR --models a.json,b.json --json"))
    out = [_source(story, "ladder"),
           "<p>The model's error after each added effect, against the noise floor (1.0).</p>"]
    rows = []
    first = _f((steps[0].get("rmse_over_noise") or {}).get("overall"), None)
    for s in steps:
        r = s.get("rmse_over_noise") or {}
        fp = s.get("fit_percent") or {}
        ov = _f(r.get("overall"), None)
        rows.append([esc(s.get("label")), esc(", ".join(s.get("effects") or []) or "none"),
                     f"<b>{num(r.get('overall'), '.2f')}</b>", num(r.get("speed"), ".2f"),
                     num(r.get("position"), ".2f"), num(fp.get("speed"), ".2f"),
                     num(fp.get("position"), ".2f"),
                     "–" if first is None or ov is None or s is steps[0]
                     else esc(f"{100 * (1 - ov / first):.0f} %")])
    out.append(_table(["step", "effects", "rmse/noise<br>overall", "speed", "position",
                       "fit %<br>speed", "fit %<br>position", "error<br>removed"], rows, {1: "l"}))
    last = _f((steps[-1].get("rmse_over_noise") or {}).get("overall"), None)
    if last is not None:
        at = last <= 1.15
        out.append(f'<div class="verdict {"good" if at else "warn"}">'
                   + (f"The last model is at the noise floor (rmse/noise {last:.2f})."
                      if at else f"The last model is still {last:.2f} times the noise: something "
                      "is left to find (run the diagnosis again on the last model).")
                   + "</div>")
    out.append(_figs_html(story.figures.get("ladder", [])))
    return "\n".join(out)


# page ------------------------------------------------------------------------------

def _cards(story: Story) -> str:
    cards = []

    def card(k, v, d="", txt=False):
        cards.append(f'<div class="card"><div class="k">{esc(k)}</div>'
                     f'<div class="v{" txt" if txt else ""}">{v}</div>'
                     f'<div class="d">{esc(d)}</div></div>')
    card("runs", esc(len(story.runs)),
         f"{sum(r.loop != 'closed' for r in story.runs)} open, "
         f"{sum(r.loop == 'closed' for r in story.runs)} closed loop")
    a = story.analysis or {}
    if a:
        card("km (analysis)", num(a.get("km"), ".4g"), "rad/s per V")
        card("tau_m (analysis)", dash_or(a.get("tau_s"), lambda x: f"{1e3 * x:.0f} ms"),
             f"gain trend: {a.get('gain_trend', '–')}")
    if story.ident:
        b = next((r for r in story.ident if r.get("method") == story.ident_best), story.ident[0])
        card("linear model", num((b.get("rmse_over_noise") or {}).get("overall"), ".2f"),
             f"rmse/noise ({str(b.get('method', '')).upper()})")
    if story.diagnosis is not None:
        rec = story.diagnosis.get("recommendation")
        card("missing effect", esc((rec or "none").replace("_", " ")), "diagnosis", txt=True)
    if story.ladder:
        card("final model", num((story.ladder[-1].get("rmse_over_noise") or {}).get("overall"), ".2f"),
             f"rmse/noise: {story.ladder[-1].get('label', '')}")
    return '<div class="cards">' + "".join(cards) + "</div>"


def render(story: Story, created: datetime | None = None) -> str:
    created = created or datetime.now(timezone.utc)
    bodies = {"sweep": _sweep_html, "analysis": _analysis_html, "models": _models_html,
              "failures": _failures_html, "diagnosis": _diagnosis_html, "ladder": _ladder_html}
    sections = "\n".join(_section(k, t, bodies[k](story)) for k, t in SECTIONS)
    toc = "".join(f'<li><a href="#{esc(k)}">{esc(t)}</a></li>' for k, t in SECTIONS)
    rig = (story.runs[0].meta.get("rig", {}) or {}).get("name") if story.runs else None
    notes = ""
    if story.notes:
        notes = ('<div class="verdict warn small"><b>Notes.</b><ul>'
                 + "".join(f"<li>{esc(n)}</li>" for n in story.notes) + "</ul></div>")
    srcs = "".join(f"<tr><td>{esc(t)}</td><td>{esc(story.sources.get(k, 'not available'))}</td></tr>"
                   for k, t in SECTIONS)
    title = f"labrig report: {story.data_dir.name or story.data_dir}"
    work_txt = story.work.resolve() if story.work else "none (everything computed here)"
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="labrig {esc(__version__)}">
<title>{esc(title)}</title>
<style>{CSS}</style>
</head>
<body>
<div class="page">
<header>
<h1>DC-servo lab report</h1>
<p class="sub">Data set <code>{esc(story.data_dir)}</code>{(' &middot; rig ' + esc(rig)) if rig else ''}
 &middot; {esc(created.strftime('%Y-%m-%d %H:%M UTC'))}{' &middot; quick report' if story.quick else ''}</p>
{_cards(story)}
{notes}
<nav class="toc"><b>Contents</b><ol>{toc}</ol></nav>
</header>
{sections}
<footer>
<table>
<tr><td>labrig</td><td>{esc(__version__)}</td></tr>
<tr><td>created</td><td>{esc(created.isoformat(timespec='seconds'))}</td></tr>
<tr><td>data</td><td>{esc(story.data_dir.resolve())}</td></tr>
<tr><td>work folder</td><td>{esc(work_txt)}</td></tr>
{srcs}
</table>
</footer>
</div>
</body>
</html>
"""


def build_report(data_dir, output="report.html", work=None, *, quick=False, seed=1,
                 log=None) -> Path:
    """Write the report of ``data_dir`` to ``output``; returns its path.

    Parameters
    ----------
    data_dir : folder of runs
    output : the HTML file to write
    work : folder with the earlier stages' artefacts (analysis.json, ...); None: the
        parent of ``data_dir`` when it holds any; False: none, everything is computed here
    quick : skip the diagnosis and the ladder when their JSON files are absent
    seed : seed of what is identified or diagnosed here
    log : callable(str) for progress (e.g. print to stderr)
    """
    if log is None:
        def log(text):
            print(text, file=sys.stderr, flush=True)
    if work is None:
        work = find_work(data_dir)
    elif work is False:
        work = None
    elif not Path(work).is_dir():
        raise UserError(f"--work {work}: no such folder")
    story = gather(data_dir, work=work, quick=quick, seed=seed, log=log)
    page = render(story)
    from ..fileio import atomic_write

    out = Path(output)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out, page)
    try:  # a report is for sharing: the usual file mode, not mkstemp's 0600
        import os

        mask = os.umask(0)
        os.umask(mask)
        os.chmod(out, 0o666 & ~mask)
    except OSError:
        pass
    return out
