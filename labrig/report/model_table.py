"""Section 3: the identified models side by side (the paper's Table 2, done right).

The table is built here from the identification records, not by
:func:`labrig.identify.table.comparison_table`: that one needs live ``Identification``
objects (search space, effect objects, rig constants) which ``identify_all.json`` does
not hold, and the page must look the same whether the fits were read or computed.
"""
from __future__ import annotations

from ..tables import Table
from .artefacts import Combination, IdentRecord
from .blocks import Bullets, Figures, Heading, Section, TableBlock, Text, markup, num
from .story import Story

COMBOS = (("km", "K<sub>m</sub> (rad/s per V)"), ("tau_m_s", "&tau;<sub>m</sub> (s)"),
          ("tau_e_s", "&tau;<sub>e</sub> (s)"))
PLANT = (("R", "ohm"), ("L", "H"), ("J", "kg m²"), ("B", "N m s/rad"), ("K", "N m/A"))
NOT_IDENTIFIABLE = '<span class="q" title="not identifiable">?</span>'


def interval(c: Combination | None) -> str:
    """A combination's value with its 95 % interval below it, or ``?`` when the data
    do not bound it."""
    if c is None:
        return "–"
    v = num(c.value, ".4g")
    if c.identifiable is False or not c.interval95:
        return markup("{} " + NOT_IDENTIFIABLE, v)
    lo, hi = (c.interval95 + [None, None])[:2]
    return markup('{}<br><span class="small muted">[{}, {}]</span>', v, num(lo, ".4g"),
                  num(hi, ".4g"))


def parameter(r: IdentRecord, name: str) -> str:
    """A plant parameter, marked fixed or not identifiable."""
    info = r.identifiable.parameters.get(name)
    v = num(r.params.get(name), ".4g")
    if info is not None and info.fixed:
        return markup('{} <span class="small muted">(fixed)</span>', v)
    if info is not None and info.identifiable is False:
        return markup('{} <span class="q" title="not identifiable from these data">?</span>', v)
    return v


def comparison(records: list[IdentRecord], best: str | None) -> Table:
    """Table 2: identifiable combinations, R..K and effect parameters, the fit, the
    identified model's closed-loop step and the cost, one column per method."""
    n = len(records)
    rows = []

    def group(label):
        rows.append([f"-- {label}"] + [""] * n)

    def row(label, cells):
        rows.append([label] + list(cells))

    group("identifiable combinations (95 % intervals)")
    for key, label in COMBOS:
        row(markup(label), [interval(getattr(r.identifiable, key)) for r in records])
    group("physical parameters (one member of the family the data allow)")
    for name, unit in PLANT:
        row(f"{name} ({unit})", [parameter(r, name) for r in records])
    keys = list(dict.fromkeys((e, k) for r in records for e, ps in r.effect_params.items()
                              for k in ps))
    for e, k in keys:
        row(f"{e}.{k}", [num(r.effect_params.get(e, {}).get(k), ".4g") for r in records])
    group("fit")
    row("fitness (eq. 26)", [num(r.fitness, ".4g") for r in records])
    for ch in ("overall", "speed", "position"):
        row(f"rmse/noise {ch}", [num(r.rmse_over_noise.get(ch), ".3g") for r in records])
    for ch in ("speed", "position"):
        row(f"fit % {ch}", [num(r.fit_percent.get(ch), ".2f") for r in records])
    group("closed-loop position step of the identified model")
    for key, label in (("rise_time_s", "rise time (s)"), ("settling_time_s", "settling time (s)"),
                       ("overshoot_percent", "overshoot (%)")):
        row(label, [num(r.step_info.get(key), ".3g") for r in records])
    group("cost")
    row("evaluations (nfev)", [num(r.nfev, "d") for r in records])
    row("seconds", [num(r.seconds, ".1f") for r in records])
    row("seed", [num(r.seed, "d") for r in records])
    heads = [r.method.upper() + (" (best)" if r.method == best else "") for r in records]
    return Table("identified models (Table 2)", [""] + heads, rows,
                 numeric=tuple(range(1, n + 1)))


def models_section(story: Story, key: str, title: str) -> Section:
    """Section 3: the table, the identifiability warnings and the convergence figure."""
    records = story.idents
    if not records:
        return Section(key, title, missing=(f"labrig identify {story.data_dir} --method all "
                                            "--json > identify_all.json"))
    blocks = [Text(f"Source: {story.sources['models']}", "src")] \
        if story.sources.get("models") else []
    blocks.append(Text(markup(
        "Only three combinations of R, L, J, B, K shape the response from u to the speed and "
        "the angle, so the identifiable combinations come first; <span class=\"q\">?</span> "
        "marks a value the data cannot pin down on its own.")))
    blocks.append(TableBlock(comparison(records, story.best), heading="",
                             best_cols={i + 1 for i, r in enumerate(records)
                                        if r.method == story.best}))
    warnings = list(dict.fromkeys(w for r in records for w in r.identifiable.warnings))
    if warnings:
        blocks += [Heading("Identifiability warnings"), Bullets(warnings, "warn")]
    blocks.append(Figures(story.figures.get("models", [])))
    return Section(key, title, blocks)
