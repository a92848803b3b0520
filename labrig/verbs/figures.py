"""The figures and tables of results that the front ends lay out (the command line's
PNGs, the report's sections): drawn by the library's own plotting, not again by each
front end."""
from __future__ import annotations


def runs_figure(runs):
    """Every run: the measured response over what the bridge applied."""
    from labrig.analysis.run_plots import plot_overview

    return plot_overview(runs)


def convergence_figure(results, ax=None):
    """Best fitness against iteration of one or several fits (or their records)."""
    from labrig.identification.plots import plot_convergence

    return plot_convergence(results, ax=ax)


def run_figure(per_run: dict, ax=None, title: str = ""):
    """A model against one run's measurement (an entry of ``Evaluation.per_run``), with
    the residual in noise units, its noise band and the regimes that leave it."""
    from labrig.diagnosis.results.plots import plot_run_comparison

    return plot_run_comparison(per_run, ax=ax, title=title)


def regimes_figure(regimes: dict, ax=None, title: str = "Where the model fails"):
    """rmse/noise by regime and channel (``Evaluation.regimes``), with the share of time."""
    from labrig.diagnosis.results.plots import plot_regimes

    return plot_regimes(regimes, ax=ax, title=title)


def fits_table(results, best: str | None = None):
    """Fits side by side, one column per method (the paper's Table 2)."""
    from labrig.identification.table import comparison_table

    return comparison_table(results, best)


def fits_text(results) -> str:
    """Fits as ``labrig identify`` prints them (one, or side by side)."""
    from labrig.identification.table import format_identification

    return format_identification(results)


def fits_warnings(results) -> list:
    """Every fit's bound and fit warnings, each once."""
    from labrig.identification.table import all_warnings

    return all_warnings(results)


def save_figures(figures, folder, dpi: int | None = None) -> dict:
    """Save each of ``figures`` (``{name: figure}``, drawn on access) as ``folder/name``,
    one in memory at a time; returns ``{name: path}``."""
    from labrig.analysis.plots import save_figures as _save

    return _save(figures, folder) if dpi is None else _save(figures, folder, dpi)


def run_view(per_run: dict, **size):
    """One run's model against measurement as interactive Bokeh figures (linked time
    axes, hover, the residual's noise band): a
    :class:`~labrig.diagnosis.results.interactive.RunView`; ``show(per_run)`` redraws it."""
    from labrig.diagnosis.results.interactive import run_view as _view

    return _view(per_run, **size)


def drawn_channels(per_run: dict) -> tuple:
    """The channels :func:`run_view` draws for a run: its own, and the measured current
    beside them where the run has one."""
    from labrig.diagnosis.results.interactive import drawn_channels as _channels

    return _channels(per_run)


def pair_view(evaluations: dict, run: str | None = None, **size):
    """Two explanations of a pair on one run, as interactive Bokeh figures
    (``evaluations``: ``{effect: Evaluation}`` of the same runs, from :func:`compare`)."""
    from labrig.diagnosis.results.interactive import pair_view as _view

    return _view(evaluations, run, **size)


def ladder_view(steps, **size):
    """The error ladder (a Ladder's ``to_json()["steps"]``) as an interactive Bokeh figure."""
    from labrig.diagnosis.results.interactive import ladder_figure

    return ladder_figure(steps, **size)


def ranking_view(rows, **size):
    """A diagnosis' ranking (its candidates, or the lab's rows) as an interactive Bokeh
    figure."""
    from labrig.diagnosis.results.interactive import ranking_figure

    return ranking_figure(rows, **size)
