"""Section 3: the identified models side by side (the paper's Table 2, done right).

The table is :func:`labrig.verbs.figures.fits_table` of the identification
records, the same builder the CLI prints, whether the fits were read or computed.
"""
from __future__ import annotations

from labrig.core.tables import Table
from labrig.verbs.figures import fits_table
from labrig.verbs.types import IdentRecord
from labrig.report.blocks import Bullets, Figures, Heading, Section, TableBlock, Text, markup
from labrig.report.story import Story

def comparison(records: list[IdentRecord], best: str | None) -> Table:
    """Table 2 exactly as ``labrig identify --method all`` prints it (one builder)."""
    return fits_table(records, best)


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
