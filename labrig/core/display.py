"""How a result shows itself: a one-screen ``repr`` in a terminal, its tables and its
figure in a notebook.

A result class mixes in :class:`Displayable` and has ``table_rows()`` (one
:class:`~labrig.core.tables.Table` or a list) and ``plot(ax=None)``; ``headline()``
gives the first line. Nothing here computes: it only presents what the result holds.
"""
from __future__ import annotations

import base64
from html import escape

from labrig.core.tables import Table, table_html

#: a repr longer than this many lines is cut, and says how to see the rest
REPR_LINES = 30
#: ... and at most this many characters (a screen of 100 columns holds about 2,000)
REPR_CHARS = 2000


class Displayable:
    """Mixin: ``__repr__`` (one screen of text) and ``_repr_html_`` (tables + figure)."""

    def headline(self) -> str:
        """The first line of the ``repr`` and the title of the notebook's view.

        Returns
        -------
        str
            Here the class's name; a result says more.
        """
        return type(self).__name__

    def _tables(self) -> list[Table]:
        rows = self.table_rows()
        return [rows] if isinstance(rows, Table) else list(rows)

    def __repr__(self) -> str:
        """One screen: the headline and the tables, without their notes, cut at
        :data:`REPR_LINES` lines or :data:`REPR_CHARS` characters, whichever comes first."""
        try:
            text = "\n\n".join(t.to_text(width=100, notes=False) for t in self._tables())
        except Exception as exc:  # a repr never raises: say what is missing instead
            text = f"(no table: {type(exc).__name__}: {exc})"
        lines = [f"<{self.headline()}>"] + text.splitlines()
        more = ".table_rows(), .to_pandas() or .to_json()"
        keep, size = [], 0
        for k, line in enumerate(lines):
            if k == REPR_LINES - 1 or size + len(line) + 1 > REPR_CHARS - 80:
                keep.append(f"... {len(lines) - k} more lines: {more}")
                break
            keep.append(line)
            size += len(line) + 1
        return "\n".join(keep)

    def _figure_for_html(self):
        return self.plot()

    def _repr_html_(self) -> str:
        parts = [f"<div><b>{escape(self.headline())}</b></div>"]
        parts += [table_html(t) for t in self._tables()]
        try:
            fig = self._figure_for_html()
        except Exception as exc:  # a table without a figure beats no output at all
            fig, parts = None, parts + [f"<div><small>(no figure: {escape(str(exc))})</small></div>"]
        if fig is not None:
            parts.append(figure_html(fig))
        return "\n".join(parts)


def figure_html(fig) -> str:
    """A matplotlib figure as an inline PNG ``<img>``; the figure is closed after."""
    from labrig.core.figures import png_bytes  # matplotlib: ~0.35 s to import

    return png_html(png_bytes(fig, dpi=80))


def png_html(png: bytes | None, max_width: int | None = None) -> str:
    """PNG bytes as an inline ``<img>`` (nothing fetched from anywhere); "" for none."""
    if not png:
        return ""
    style = f"max-width:{max_width}px;width:100%" if max_width else "max-width:100%"
    return f'<img src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}" ' \
           f'style="{style}"/>'
