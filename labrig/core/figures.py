"""Saving figures: every labrig figure is drawn by a ``plot_x(obj, ax=None)`` that
returns it, and is saved (to a file or to PNG bytes) and closed here, one at a time, so
a command or report with many runs keeps one figure in memory."""
from __future__ import annotations

import io
import os
from pathlib import Path

import matplotlib.pyplot as plt

DPI = 110
#: the resolution of a draft figure (see :func:`draft`)
DRAFT_DPI = 40


def draft() -> bool:
    """Whether figures are drafts: ``LABRIG_FIGURES=draft`` in the environment.

    A draft is saved at ``DRAFT_DPI`` and laid out without ``tight_layout``, whose
    measuring of every text is most of a figure's cost (about a third of ``labrig
    compare``'s whole process). For runs whose pictures nobody looks at: the test suite's
    runs of the sheets, which check the numbers the commands print and write (those are
    the same either way); the figures themselves are checked drawn in full
    (tests/test_figures.py).
    """
    return os.environ.get("LABRIG_FIGURES", "").strip().lower() == "draft"


def tight_layout(fig, **kw) -> None:
    """``fig.tight_layout(**kw)``, left out for a draft (see :func:`draft`)."""
    if not draft():
        fig.tight_layout(**kw)


def save(fig, path, dpi: int = DPI):
    """Save ``fig`` to ``path`` and close it (at ``DRAFT_DPI`` for a draft); returns the
    path."""
    try:
        fig.savefig(path, dpi=DRAFT_DPI if draft() else dpi)
    finally:
        plt.close(fig)
    return path


def save_all(figs, figdir, dpi: int = DPI) -> dict:
    """Save each figure of ``figs`` (``{name: Figure}``, drawn on access) as
    ``figdir/name``; returns ``{name: path}``."""
    figdir = Path(figdir)
    figdir.mkdir(parents=True, exist_ok=True)
    return {name: save(fig, figdir / name, dpi) for name, fig in figs.items()}


def png_bytes(fig, dpi: int = DPI) -> bytes:
    """``fig`` as PNG bytes, drawn in memory; the figure is closed."""
    buf = io.BytesIO()
    save(fig, buf, dpi)
    return buf.getvalue()


def legend_outside(ax, where: str = "right", **kw):
    """A legend outside ``ax``, where it cannot cover data.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    where : {"right", "above"}
        Beside the axes, top-aligned (axes with a title), or in rows just above them
        (wide time series stacked in one figure).
    **kw
        Passed to ``ax.legend`` (``fontsize`` defaults to 8; ``ncol`` for "above" to as
        many entries as fit in one row, at most 4).

    Returns
    -------
    matplotlib.legend.Legend or None
        None when nothing is labelled. The figure's ``tight_layout`` makes room for it.
    """
    handles, _ = ax.get_legend_handles_labels()
    if not handles:
        return None
    kw.setdefault("fontsize", 8)
    if where == "above":
        kw.setdefault("ncol", min(len(handles), 4))
        return ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.01), borderaxespad=0.0,
                         frameon=False, **kw)
    return ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, **kw)
