"""Turn a :class:`~labrig.report.story.Story` into the page's sections and header cards.

Tables the CLI also prints are the result objects' own ``table_rows()``
(``AnalysisResult``, ``Diagnosis``, ``Ladder``); the report adds a column where it shows
a little more. Tables only the page has (the sweep, the error by regime) are built here
as :class:`labrig.core.tables.Table` too, so the template draws every table one way.
"""
from __future__ import annotations

import math

from labrig.verbs.types import REGIME_TEXT
from labrig.core.tables import Table
from labrig.report.blocks import Card, Figures, Heading, Section, TableBlock, Text, Verdict, dash_or, markup, num, pct, with_column, without_empty_columns
from labrig.report.model_table import models_section
from labrig.report.story import SECTIONS, Story


def sections(story: Story) -> list[Section]:
    """The six sections, in page order."""
    build = {"sweep": _sweep, "analysis": _analysis, "models": models_section,
             "failures": _failures, "diagnosis": _diagnosis, "ladder": _ladder}
    return [build[key](story, key, title) for key, title in SECTIONS]


def _source(story: Story, key: str) -> list:
    s = story.sources.get(key)
    return [Text(f"Source: {s}", "src")] if s else []


def _figures(story: Story, key: str) -> list:
    return [Figures(story.figures.get(key, []))]


# 1 --------------------------------------------------------------------------------------

def sweep_table(runs) -> Table:
    """One row per run: what was applied, how long, how fast, from where, with what."""
    rows = []
    for r in runs:
        exp = r.experiment
        br = r.meta.get("bridge", {}) or {}
        drop, crc = br.get("dropped_samples"), br.get("crc_errors")
        dropped = "–" if drop is None else str(drop)
        if crc:
            dropped = markup('{} <span class="q">({} CRC)</span>', dropped, crc)
        if drop:
            dropped = markup('<span class="q">{}</span>', dropped)
        rows.append([r.name, r.loop, exp.get("waveform", "–"),
                     num(exp.get("amplitude_v", r.amplitude), ".3g", "V"),
                     num(exp.get("frequency_hz"), ".3g", "Hz"), str(len(r)),
                     num(len(r) / r.fs, ".3g", "s"), num(r.fs, "g", "Hz"),
                     r.meta.get("source", "–"),
                     _sensors(r), dropped])
    return Table("runs", ["run", "loop", "waveform", "amplitude", "frequency", "samples",
                          "length", "rate", "source", "sensors", "dropped"], rows,
                 numeric=(3, 4, 5, 6, 7, 10))


def _sensors(run) -> str:
    """What a run measured: a tacho, a speed imported in physical units, a pot."""
    return ", ".join(s for s, ok in (("tacho", run.has_tacho),
                                     ("speed (imported)", run.has_speed and not run.has_tacho),
                                     ("pot", run.has_pos)) if ok)


def _sweep(story: Story, key, title) -> Section:
    runs = story.runs
    n_open = sum(r.loop != "closed" for r in runs)
    rig = (runs[0].meta.get("rig", {}) or {}) if runs else {}
    intro = markup("{} runs in <code>{}</code>: {} open-loop, {} closed-loop",
                   len(runs), story.data_dir, n_open, len(runs) - n_open)
    if rig.get("name"):
        intro += markup(", rig <b>{}</b>", rig["name"])
    if rig.get("gear_ratio"):
        intro += markup(" (gear ratio {}, amplifier gain {})", num(rig.get("gear_ratio"), "g"),
                        num(rig.get("amplifier_gain"), "g"))
    return Section(key, title, [Text(intro + "."), *_source(story, key),
                                TableBlock(sweep_table(runs), heading=""),
                                *_figures(story, key)])


# 2 --------------------------------------------------------------------------------------

def _analysis(story: Story, key, title) -> Section:
    res = story.analysis
    if res is None:
        return Section(key, title, missing=story.missing.get(
            "analysis", f"labrig analyse {story.data_dir} --json"))
    levels, summary = res.table_rows()
    levels = without_empty_columns(levels)
    blocks = _source(story, key)
    if levels.rows:
        blocks.append(TableBlock(levels, heading="Table 1: steady speed per input level"))
    else:
        blocks += [Heading("Table 1: steady speed per input level"),
                   Text("No settled open-loop levels (the analysis uses open-loop runs).",
                        "muted"), *(Text(n, "small muted") for n in levels.notes)]
    by_amp = [(a, k) for a, k in res.trend.get("km_by_amplitude", [])]
    if by_amp:
        cells = markup(", ").join(markup("{} V: <b>{}</b>", num(a, ".3g"), num(k, ".2f"))
                                  for a, k in sorted(by_amp, key=lambda x: x[0]))
        blocks.append(Text(markup("K<sub>m</sub> = &omega;/V by amplitude: {} {} per V.",
                                  cells, res.speed_unit), "small"))
    blocks.append(TableBlock(summary))
    if res.verdict:
        blocks.append(Verdict(markup("<b>Verdict.</b> {}", res.verdict)))
    return Section(key, title, blocks + _figures(story, key))


# 4 --------------------------------------------------------------------------------------

def regime_tables(regimes) -> tuple[Table, int | None, Table | None]:
    """Error by regime (each channel's rmse/noise with its share of time and of error)
    with the worst regime's row, and error by run amplitude (None when absent)."""
    by = regimes["by_regime"]
    chans = list(by)
    regs = list(dict.fromkeys(reg for ch in chans for reg in by[ch]))
    worst = regimes["worst"]["regime"] if regimes.get("worst") else None
    cols = ["regime"]
    for ch in chans:
        cols += [markup("{}<br>rmse/noise", ch), markup("share of<br>time"),
                 markup("share of<br>error")]
    rows = []
    for reg in regs:
        row = [REGIME_TEXT.get(reg, reg)]
        for ch in chans:
            v = by[ch].get(reg)
            row += ["–", "–", "–"] if v is None else [
                num(v["rmse_over_noise"], ".2f"), pct(v["share_of_time"], ".0f"),
                pct(v.get("share_of_error"), ".0f")]
        rows.append(row)
    table = Table("Error by regime", cols, rows, numeric=tuple(range(1, len(cols))))
    hl = regs.index(worst) if worst in regs else None
    ba = regimes.get("by_amplitude")
    if not ba:
        return table, hl, None
    keys = list(dict.fromkeys(k for ch in ba for k in ba[ch]))
    amp = Table("Error by run amplitude", ["runs"] + [f"{ch} rmse/noise" for ch in ba],
                [[k] + [num(ba[ch].get(k), ".2f") for ch in ba] for k in keys],
                numeric=tuple(range(1, len(ba) + 1)))
    return table, hl, amp


def _failures(story: Story, key, title) -> Section:
    t = story.regimes
    if t is None:
        return Section(key, title, missing=story.missing.get(
            "failures", f"labrig diagnose {story.data_dir} --json"))
    blocks = _source(story, key)
    blocks.append(Text(markup(
        "The linear model ({}) simulated on every run; its error is split by what the motor "
        "was doing. rmse/noise = 1 means the model explains all that the sensor noise allows.",
        story.model0_source or "the linear model")))
    worst = t.get("worst")
    if worst is not None:
        text = markup("<b>Worst:</b> the {} stretches of the {} (rmse/noise {})",
                      REGIME_TEXT.get(worst["regime"], worst["regime"]), worst["channel"],
                      num(worst.get("rmse_over_noise"), ".2f"))
        if story.worst_run:
            text += markup("; worst run: <b>{}</b>", story.worst_run)
        blocks.append(Verdict(text + ".", "warn"))
    table, hl, amp = regime_tables(t)
    if table.rows:
        blocks.append(TableBlock(table, hl_rows={hl} if hl is not None else set()))
    if amp is not None:
        blocks.append(TableBlock(amp))
    if t.get("noise"):
        blocks.append(Text("Noise levels used: " + ", ".join(
            f"{k} {num(v, '.3g')}" for k, v in t["noise"].items()) + ".", "small muted"))
    return Section(key, title, blocks + _figures(story, key))


# 5 --------------------------------------------------------------------------------------

def _diagnosis(story: Story, key, title) -> Section:
    d = story.diagnosis
    if d is None:
        return Section(key, title, missing=story.missing.get("diagnosis",
                                                              "labrig diagnose DIR --json"))
    base, crit, rec = d.baseline, d.criteria or {}, d.recommendation
    text = markup("Baseline: {}", base.get("source", "the model"))
    if base.get("effects"):
        text += markup(" with {}", ", ".join(base["effects"]))
    text += markup(
        "; rmse/noise {}. Each catalogue effect the model lacks was added and the model "
        "re-fitted; an effect is supported when it lowers the error by at least {}, with "
        "&Delta;BIC below {} ", num((base.get("rmse_over_noise") or {}).get("overall"), ".2f"),
        pct(crit.get("min_improvement"), ".0f"), num(crit.get("max_delta_bic"), "g"))
    cv = d.cross_validation
    text += (markup("and on data the fits did not see ({} folds, {})", cv["folds"], cv["kind"])
             if cv else "(not cross-validated)") + "."
    blocks = _source(story, key) + [Text(text), Verdict(
        markup("<b>Recommendation: {}.</b> {}", rec or "none", d.verdict),
        "good" if rec else "warn")]
    if d.ranking:
        ranking = d.table_rows()[1]
        params = [", ".join(f"{p} = {num(v, '.3g')}" for p, v in c.params.items())
                  for c in d.ranking]
        blocks.append(TableBlock(with_column(ranking, len(ranking.columns), "fitted parameters",
                                             params),
                                 heading="Ranking of the candidate effects",
                                 hl_rows={k for k, c in enumerate(d.ranking) if c.effect == rec}))
    top = next((c for c in d.ranking if c.effect == rec), None)
    if top is None and d.ranking:
        top = d.ranking[0]
        if top.explanation:
            blocks += [Heading(f"The best candidate, {top.effect}, and why it is not enough"),
                       Text(top.explanation)]
    elif top is not None and top.explanation and top.explanation not in d.verdict:
        blocks += [Heading(f"Why {rec}"), Text(top.explanation)]
    if d.seconds is not None:
        blocks.append(Text(f"The diagnosis took {num(d.seconds, '.0f')} s.", "small muted"))
    return Section(key, title, blocks)


# 6 --------------------------------------------------------------------------------------

def _ladder(story: Story, key, title) -> Section:
    ladder = story.ladder
    if ladder is None or not ladder.steps:
        return Section(key, title, missing=story.missing.get(
            "ladder", "labrig ladder DIR --models a.json,b.json --json"))
    steps = ladder.steps
    overall = [_finite(s.rmse_over_noise.get("overall")) for s in steps]
    removed = ["–" if k == 0 or overall[0] is None or ov is None
               else f"{100 * (1 - ov / overall[0]):.0f} %" for k, ov in enumerate(overall)]
    table = with_column(ladder.table_rows(), 1, "effects",
                        [", ".join(s.effects) or "none" for s in steps])
    table = with_column(table, len(table.columns), "error removed", removed, numeric=True)
    blocks = _source(story, key) + [
        Text("The model's error after each added effect, against the noise floor (1.0)."),
        TableBlock(table, heading="")]
    last = overall[-1]
    if last is not None:
        at = last <= 1.15
        blocks.append(Verdict(
            f"The last model is at the noise floor (rmse/noise {last:.2f})." if at else
            f"The last model is still {last:.2f} times the noise: something is left to find "
            "(run the diagnosis again on the last model).", "good" if at else "warn"))
    return Section(key, title, blocks + _figures(story, key))


def _finite(x) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


# header ---------------------------------------------------------------------------------

def cards(story: Story) -> list[Card]:
    """The key numbers of the page header."""
    runs = story.runs
    out = [Card("runs", str(len(runs)), f"{sum(r.loop != 'closed' for r in runs)} open, "
                                        f"{sum(r.loop == 'closed' for r in runs)} closed loop")]
    a = story.analysis
    if a is not None:
        out.append(Card("km (analysis)", num(a.km, ".4g"), f"{a.speed_unit} per V"))
        out.append(Card("tau_m (analysis)", dash_or(a.tau_s, lambda x: f"{1e3 * x:.0f} ms"),
                        f"gain trend: {a.gain_trend or '–'}"))
    b = story.best_ident
    if b is not None:
        out.append(Card("linear model", num(b.rmse_over_noise.get("overall"), ".2f"),
                        f"rmse/noise ({b.method.upper()})"))
    if story.diagnosis is not None:
        rec = story.diagnosis.recommendation
        out.append(Card("missing effect", (rec or "none").replace("_", " "), "diagnosis",
                        text=True))
    if story.ladder is not None and story.ladder.steps:
        last = story.ladder.steps[-1]
        out.append(Card("final model", num(last.rmse_over_noise.get("overall"), ".2f"),
                        f"rmse/noise: {last.label}"))
    return out
