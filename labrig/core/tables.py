"""One table type for every result: the CLI prints it with rich, the HTML report renders
the same rows, so nothing is computed twice and columns never collide.

A result's ``table_rows()`` returns a :class:`Table` (or a list of them).
"""
from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from html import escape


@dataclass
class Table:
    """A titled table of already-formatted cells (strings), plus notes under it."""

    title: str
    columns: list[str]
    rows: list[list[str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: column indices to right-align (numbers)
    numeric: tuple[int, ...] = ()

    def to_text(self, width: int = 110, notes: bool = True) -> str:
        """The table as plain text, drawn by rich (no colour codes); ``notes`` below it."""
        # rich: ~0.02 s to import, for the text only (not the HTML, JSON or --help)
        from rich import box
        from rich.console import Console
        from rich.table import Table as RichTable

        t = RichTable(title=self.title or None, box=box.SIMPLE_HEAD, title_justify="left",
                      pad_edge=False, show_edge=False)
        for i, c in enumerate(self.columns):
            t.add_column(c, justify="right" if i in self.numeric else "left",
                         overflow="fold")
        for r in self.rows:
            t.add_row(*[str(x) for x in r])
        buf = io.StringIO()
        Console(file=buf, width=width, color_system=None, force_terminal=False,
                legacy_windows=False).print(t)
        text = "\n".join(line.rstrip() for line in buf.getvalue().rstrip().splitlines())
        if self.notes and notes:
            text += "\n" + "\n".join(self.notes)
        return text

    def to_dict(self) -> dict:
        return {"title": self.title, "columns": list(self.columns),
                "rows": [list(map(str, r)) for r in self.rows], "notes": list(self.notes)}


def fmt(x, spec: str = ".4g", none: str = "-") -> str:
    """A number for a table cell: ``none`` for missing or non-finite values."""
    if x is None:
        return none
    try:
        xf = float(x)
    except (TypeError, ValueError):
        return str(x)
    if not math.isfinite(xf):
        return none
    text = format(int(round(xf)), spec) if spec.endswith("d") else format(xf, spec)
    # a value that rounds to zero is "0", never "-0" (a -0.3 % gain is no gain)
    if text.startswith("-") and not any(ch in "123456789" for ch in text.split("e")[0]):
        text = text[1:]
    return text


def table_html(table: Table) -> str:
    """The table as an HTML fragment (cells escaped), for notebooks and the lab page."""
    right = set(table.numeric)
    head = "".join(f'<th style="text-align:{"right" if i in right else "left"}">{escape(c)}</th>'
                   for i, c in enumerate(table.columns))
    body = "".join("<tr>" + "".join(
        f'<td style="text-align:{"right" if i in right else "left"}">{escape(str(x))}</td>'
        for i, x in enumerate(r)) + "</tr>" for r in table.rows)
    notes = "".join(f"<div><small>{escape(n)}</small></div>" for n in table.notes)
    title = f"<caption style='text-align:left'><b>{escape(table.title)}</b></caption>" \
        if table.title else ""
    return f"<table>{title}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>{notes}"
