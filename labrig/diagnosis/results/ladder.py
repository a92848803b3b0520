"""The error ladder: the model's error after each added effect, against the noise floor.

:func:`evaluate_ladder` judges a chain of saved models;
:func:`labrig.diagnosis.loop.search.auto_ladder` builds the chain itself. Both return a :class:`Ladder`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Optional

import pandas as pd
from pydantic import Field
from typing_extensions import NotRequired, TypedDict

from labrig.diagnosis.evidence.evaluation import Evaluation, evaluate
from labrig.model.model import Model
from labrig.core.tables import Table, fmt
from labrig.core.display import Displayable
from labrig.core.record import Num, Record, keeps_extra_keys



@keeps_extra_keys
class RungError(TypedDict):
    """A rung's rmse/noise: ``overall`` (the weighted sum) and per channel."""

    overall: Num
    speed: NotRequired[Num]
    position: NotRequired[Num]


@dataclass
class LadderStep(Record):
    """One rung: the model's label, its effects and how well it explains the runs."""

    # (a record read back may lack what it can do without: pydantic defaults)
    label: Annotated[str, Field(default="")]
    effects: Annotated[list[str], Field(default_factory=list)]
    rmse_over_noise: RungError
    fit_percent: Annotated[dict[str, Num], Field(default_factory=dict)]
    fitness: Annotated[Num, Field(default=None)]
    #: the model file the rung was read from (None: built by the search)
    model: Optional[str] = None
    #: weighted rmse/noise on held-out data (``diagnose --auto``); None: not validated
    cross_validated: Num = None

    @classmethod
    def of(cls, label: str, model: Model, ev: Evaluation, path=None,
           cv: float | None = None) -> "LadderStep":
        return cls(label=label, effects=list(model.names),
                   rmse_over_noise=ev.metrics["rmse_over_noise"],
                   fit_percent=ev.metrics["fit_percent"], fitness=ev.metrics["fitness"],
                   model=str(path) if path else None, cross_validated=cv)


@dataclass(repr=False)
class Ladder(Displayable, Record):
    """The error after each step; ``to_json()`` is ``labrig ladder --json``.

    Attributes
    ----------
    steps : list of LadderStep
        One rung a model, simplest first: its label, effects, rmse/noise and fit % per
        channel, and its held-out error where the search validated it.

    ``plot()`` draws the rungs against the noise floor; ``to_pandas()`` is the table.

    Examples
    --------
    >>> import labrig as lr
    >>> lad = lr.ladder("data/sweep_default", ["m0.json", "m1.json"])  # doctest: +SKIP
    >>> list(lad.to_pandas()["step"])  # doctest: +SKIP
    ['linear model', '+ coulomb_friction']
    """

    steps: list[LadderStep] = field(default_factory=list)

    def headline(self) -> str:
        """The first line of the ``repr``: how many rungs.

        Returns
        -------
        str
        """
        return f"Ladder: {len(self.steps)} rung(s)"

    def to_pandas(self):
        """The ladder as a DataFrame, one row per rung, simplest first.

        Returns
        -------
        pandas.DataFrame
            Columns ``step`` (the rung's label), ``rmse/noise <channel>`` (``overall``,
            ``speed``, ``position``) and ``fit % <channel>``.
        """
        return pd.DataFrame([{"step": s.label,
                              **{f"rmse/noise {k}": v for k, v in s.rmse_over_noise.items()},
                              **{f"fit % {k}": v for k, v in s.fit_percent.items()}}
                             for s in self.steps])

    def table_rows(self) -> Table:
        """The error ladder as a table.

        Returns
        -------
        Table
            One row per rung: rmse/noise overall and per channel, cross-validated (where
            the search validated it) and fit % per channel.
        """
        t = Table("the error ladder (rmse/noise; 1.00 is the noise floor)",
                  ["step", "rmse/noise", "speed", "position", "cross-validated", "fit % w",
                   "fit % th"], numeric=(1, 2, 3, 4, 5, 6))
        for s in self.steps:
            r, f = s.rmse_over_noise, s.fit_percent
            t.rows.append([s.label, fmt(r.get("overall"), ".2f"), fmt(r.get("speed"), ".2f"),
                           fmt(r.get("position"), ".2f"), fmt(s.cross_validated, ".2f"),
                           fmt(f.get("speed"), ".2f"), fmt(f.get("position"), ".2f")])
        if any(s.cross_validated is not None for s in self.steps):
            t.notes.append("cross-validated: the weighted error on data each fit did not see")
        return t

    def plot(self, ax=None):
        """The rungs' rmse/noise (overall, per channel and cross-validated) against the
        noise floor, on a log scale.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Draw here; by default on a new figure.

        Returns
        -------
        matplotlib.figure.Figure
            Not saved: the caller saves (and closes) it.
        """
        from labrig.diagnosis.results.plots import plot_ladder  # matplotlib: ~0.27 s more to import

        return plot_ladder(self, ax=ax)

    def view(self, **size):
        """The ladder as an interactive Bokeh figure (hover for each rung's numbers), what
        the lab page shows.

        Parameters
        ----------
        **size
            ``width`` and ``height`` in pixels (default: the container's width, 260).

        Returns
        -------
        bokeh.plotting.figure
            Show it with ``bokeh.io.show`` (or ``panel.pane.Bokeh``).
        """
        from labrig.diagnosis.results.interactive import ladder_figure  # bokeh: ~0.3 s more to import

        return ladder_figure(self.steps, **size)


def rung_label(names, previous) -> str:
    """A rung's label that names exactly the effects of its model.

    ``"+ new"`` only when the model keeps every effect of the rung before it; a model
    that dropped one is named by its whole effect set, e.g. ``"deadband (without
    offset)"`` (a chain m0, m_offset, m1 with m1 = deadband alone is not "+ deadband").

    Parameters
    ----------
    names : list of str
        The effects of this rung's model.
    previous : list of str
        The effects of the rung before (empty for the first).
    """
    names, previous = list(names), list(previous)
    if not names:
        return "linear model" if not previous else f"linear model (without {', '.join(previous)})"
    new = [n for n in names if n not in previous]
    dropped = [n for n in previous if n not in names]
    if not dropped:
        return "+ " + ", ".join(new) if new else ", ".join(names) + " (same effects)"
    return f"{', '.join(names)} (without {', '.join(dropped)})"


def evaluate_ladder(runs, model_paths) -> Ladder:
    """Evaluate saved models (paths, or Models already loaded) in order (``labrig ladder
    --models m0.json,m1.json``)."""
    ladder, prev = Ladder(), []
    for path in model_paths:
        model, path = (path, None) if isinstance(path, Model) else (Model.load(path), path)
        ladder.steps.append(LadderStep.of(rung_label(model.names, prev), model,
                                          evaluate(runs, model), path))
        prev = model.names
    return ladder
