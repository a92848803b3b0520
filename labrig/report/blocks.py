"""The building blocks of a report section, and the small formatters they share.

A section is a list of blocks (paragraph, heading, table, verdict, list, figures); the
template draws each kind one way. Text is plain ``str`` and is escaped when the page is
rendered; the few fragments with markup (subscripts, bold numbers) are
:class:`markupsafe.Markup` built by :func:`markup`, which escapes every value put into
them, so a run name or a verdict from a file can never become markup.
"""
from __future__ import annotations

import html
import math
from dataclasses import dataclass, field
from typing import ClassVar

from markupsafe import Markup

from labrig.core.tables import Table
from labrig.report.story import Figure


def esc(x) -> Markup:
    """``x`` as escaped text (quotes too, as ``html.escape`` does); None is empty."""
    if hasattr(x, "__html__"):
        return Markup(x)
    return Markup(html.escape("" if x is None else str(x), quote=True))


def markup(fmt: str, *args, **kwargs) -> Markup:
    """``fmt`` (trusted markup) with every argument escaped into it."""
    return Markup(fmt).format(*map(esc, args), **{k: esc(v) for k, v in kwargs.items()})


def num(x, fmt: str = ".4g", unit: str = "", dash: str = "–") -> str:
    """A number formatted; None, NaN and inf become a dash, a non-number stays as is."""
    if isinstance(x, bool):
        return str(x)

    def f(v):
        if fmt.endswith("d"):
            v = int(round(v))
        return format(v, fmt) + (f" {unit}" if unit else "")
    return dash_or(x, f, dash)


def pct(x, fmt: str = ".1f") -> str:
    """A fraction as a percentage (``-0 %`` shown as ``0 %``); missing: a dash."""
    def f(v):
        t = format(100 * v, fmt)
        return (t[1:] if t.startswith("-") and float(t) == 0 else t) + " %"
    return dash_or(x, f)


def dash_or(x, f, dash: str = "–") -> str:
    """``f(x)`` for a finite number, ``dash`` for a missing one; a non-number as is."""
    try:
        if x is None or not math.isfinite(float(x)):
            return dash
        return f(float(x))
    except (TypeError, ValueError):
        return str(x)


# -- blocks ------------------------------------------------------------------------------

@dataclass
class Text:
    """A paragraph (``cls``: ``src``, ``small``, ``muted``, ...)."""

    kind: ClassVar[str] = "text"
    html: str
    cls: str = ""


@dataclass
class Heading:
    kind: ClassVar[str] = "heading"
    text: str


@dataclass
class Verdict:
    """A boxed conclusion; ``cls`` is ``good`` or ``warn`` (or empty)."""

    kind: ClassVar[str] = "verdict"
    html: str
    cls: str = ""


@dataclass
class Bullets:
    kind: ClassVar[str] = "bullets"
    items: list
    cls: str = ""


@dataclass
class Cell:
    text: str
    cls: str = ""


@dataclass
class Row:
    cells: list = field(default_factory=list)
    cls: str = ""
    group: str | None = None      # a group row spans the table and shows only this


@dataclass
class TableBlock:
    """A :class:`labrig.core.tables.Table` as the page shows it.

    The table is drawn as it is -- title (or ``heading``), columns, rows and notes --
    so the page and the CLI show the same cells. A row ``["-- label", "", ...]`` is a
    group row (the CLI's convention), ``yes``/``no`` cells are coloured, and the
    non-numeric columns are left-aligned.

    Attributes
    ----------
    table : Table
    heading : str or None
        Shown above the table instead of its title; ``""``: no heading.
    best_cols : set of int
        Columns to shade (the best method).
    hl_rows : set of int
        Rows to highlight (the worst regime, the recommended effect).
    """

    kind: ClassVar[str] = "table"
    table: Table
    heading: str | None = None
    best_cols: set = field(default_factory=set)
    hl_rows: set = field(default_factory=set)

    @property
    def title(self) -> str:
        return self.table.title if self.heading is None else self.heading

    def _cls(self, i: int) -> str:
        c = [] if i == 0 or i in self.table.numeric else ["l"]
        return " ".join(c + (["best"] if i in self.best_cols else []))

    @property
    def head(self) -> list:
        return [Cell(c, self._cls(i)) for i, c in enumerate(self.table.columns)]

    @property
    def body(self) -> list:
        rows = []
        for k, r in enumerate(self.table.rows):
            first = str(r[0]) if r else ""
            if first.startswith("-- ") and not any(str(c) for c in r[1:]):
                rows.append(Row(group=first[3:]))
                continue
            cells = [Cell(markup('<span class="{}">{}</span>', c, c) if c in ("yes", "no")
                          else c, self._cls(i)) for i, c in enumerate(r)]
            rows.append(Row(cells, "hl" if k in self.hl_rows else ""))
        return rows


@dataclass
class Figures:
    """Figures in page order: a wide one alone, narrow ones two to a row."""

    kind: ClassVar[str] = "figures"
    figures: list[Figure]

    @property
    def rows(self) -> list[list[Figure]]:
        out, pair = [], []
        for f in self.figures:
            if f.wide:
                if pair:
                    out.append(pair)
                    pair = []
                out.append([f])
            else:
                pair.append(f)
                if len(pair) == 2:
                    out.append(pair)
                    pair = []
        if pair:
            out.append(pair)
        return out


@dataclass
class Card:
    """A key number in the page header."""

    key: str
    value: str
    detail: str = ""
    text: bool = False


@dataclass
class Section:
    """One numbered section: its blocks, or the command that would fill it."""

    key: str
    title: str
    blocks: list = field(default_factory=list)
    missing: str | None = None


def with_column(table: Table, at: int, name: str, cells: list, numeric: bool = False) -> Table:
    """A copy of ``table`` with a column inserted at ``at``: the report shows a little
    more than the CLI (the effects of a ladder step, a candidate's parameters) next to
    the very cells the CLI prints."""
    numeric = tuple(i + (i >= at) for i in table.numeric) + ((at,) if numeric else ())
    rows = [list(r[:at]) + [c] + list(r[at:]) for r, c in zip(table.rows, cells)]
    return Table(table.title, table.columns[:at] + [name] + table.columns[at:], rows,
                 list(table.notes), numeric)


def without_empty_columns(table: Table, empty: str = "-") -> Table:
    """A copy of ``table`` without the columns that are ``empty`` in every row (a value
    the source did not record, e.g. the tacho volts, which analysis.json does not keep)."""
    if not table.rows:
        return table
    keep = [i for i in range(len(table.columns)) if any(str(r[i]) != empty for r in table.rows)]
    if len(keep) == len(table.columns):
        return table
    return Table(table.title, [table.columns[i] for i in keep],
                 [[r[i] for i in keep] for r in table.rows], list(table.notes),
                 tuple(keep.index(i) for i in table.numeric if i in keep))
