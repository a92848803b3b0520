"""A model simulated on runs: the numbers every command judges it by.

:func:`evaluate` returns an :class:`Evaluation`: fitness, rmse/noise and fit % (overall,
per channel, per run), the residuals of every run with their regimes, the regime table,
and the residuals' sum of squares and lag-1 correlation for the BIC.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any

from pydantic import computed_field

import numpy as np
import pandas as pd

from labrig.identification.objective import adequacy
from labrig.identification.problem import Problem
from labrig.model.model import Model
from labrig.analysis.noise import Weights
from labrig.diagnosis.evidence.residuals import (autocorr, current_residual, regime_table, run_residuals,
                                        worst_regime, worst_run)
from labrig.core.tables import Table, fmt
from labrig.core.display import Displayable
from labrig.core.record import Live, Record
from labrig.identification.result import fit_warnings




@dataclass(repr=False)
class Evaluation(Displayable, Record):
    """How well a model explains runs.

    Attributes
    ----------
    metrics : dict
        ``fitness``, ``rmse_over_noise`` and ``fit_percent`` (overall and per channel),
        ``per_run`` and ``noise`` (the keys of ``labrig identify --json``).
    per_run : list of dict
        Residuals per run (``labrig.diagnosis.evidence.residuals.run_residuals``).
    regimes : dict
        The regime table (``by_regime``, ``by_amplitude``).
    sse, n : float, int
        Sum of squared normalised residuals and their count.
    sigmas : tuple
        The noise levels (speed rad/s, position rad) the residuals are divided by.
    rho1 : float
        Mean lag-1 autocorrelation of the residuals (the colour the BIC corrects for).
    floors : dict
        The channels' :class:`labrig.analysis.noise.NoiseFloor` (how the noise was measured).
    weights : Weights
        The channel weights of ``fitness``.

    Examples
    --------
    >>> import labrig as lr
    >>> m = lr.identify("data/sweep_default").model()  # doctest: +SKIP
    >>> ev = lr.compare("data/sweep_default", m)  # doctest: +SKIP
    >>> round(ev.rmse), round(ev.metrics["fit_percent"]["speed"])  # doctest: +SKIP
    (8, 98)
    >>> ev.plot()  # doctest: +SKIP
    <Figure size ... with 6 Axes>
    """

    readable = False   # (a summary of live objects: not read back)

    # (its JSON: the metrics' fitness, rmse/noise, fit % and noise, and the regimes)
    metrics: Annotated[dict, Live]
    per_run: Annotated[list, Live]
    regimes: dict[str, Any]
    sse: Annotated[float, Live]
    n: Annotated[int, Live]
    sigmas: Annotated[tuple, Live]
    rho1: Annotated[float, Live]
    floors: Annotated[dict, Live] = field(default_factory=dict, repr=False)
    weights: Annotated[Weights, Live] = Weights()

    def headline(self) -> str:
        """The first line of the ``repr``: the overall rmse/noise and how many runs.

        Returns
        -------
        str
        """
        return (f"Evaluation: rmse/noise {self.metrics['rmse_over_noise']['overall']:.2f} "
                f"on {len(self.per_run)} run(s)")

    @property
    def rmse(self) -> float:
        """Overall rmse/noise (1.0 is the noise floor)."""
        return self.metrics["rmse_over_noise"]["overall"]

    @computed_field(alias="rmse_over_noise")
    @property
    def _rmse_over_noise(self) -> dict[str, Any]:
        return self.metrics["rmse_over_noise"]

    @computed_field(alias="fit_percent")
    @property
    def _fit_percent(self) -> dict[str, Any]:
        return self.metrics["fit_percent"]

    @computed_field(alias="noise")
    @property
    def _noise(self) -> dict[str, Any]:
        return self.metrics["noise"]

    @computed_field
    @property
    def fitness(self) -> float:
        """The weighted rmse/noise the fits minimise (equal to ``rmse`` at p = q = 1)."""
        return self.metrics["fitness"]

    @property
    def wsse(self) -> float:
        """Weighted sum of squared normalised residuals (for the BIC)."""
        return self.fitness ** 2 * self.n

    @property
    def n_effective(self) -> float:
        """The residuals' count corrected for their colour, ``n (1 - rho) / (1 + rho)``
        with the lag-1 autocorrelation held in [0, 0.995], at least 10 (the BIC's N:
        simulation residuals are coloured even for a right model)."""
        rho = min(max(self.rho1, 0.0), 0.995)
        return max(self.n * (1 - rho) / (1 + rho), 10.0)

    def worst_regime(self):
        """Where the error is most over-represented: the regime with the largest
        rmse/noise (regimes under 0.5 % of the time left out).

        Returns
        -------
        tuple of (str, str, float) or None
            ``(channel, regime, rmse/noise)``; None when no regime qualifies.
        """
        return worst_regime(self.regimes)

    def worst_run(self) -> dict:
        """The run whose worst channel is furthest from the noise floor.

        Returns
        -------
        dict
            Its entry of :attr:`per_run` (``name``, ``t``, ``channels``, ...).
        """
        return worst_run(self.per_run)

    def runs(self) -> list[dict]:
        """Per run: fit % and rmse/noise per channel and the worst stretch outside the
        noise band (the ``runs`` of ``labrig compare --json``, without figures).

        Returns
        -------
        list of dict
            ``{"run", "fit_percent": {channel: %}, "rmse_over_noise": {channel: x},
            "worst_stretch": {"regime", "t_s", "rms_over_noise"} or None}``, one per
            run (``worst_stretch`` None for an evaluation without detail).
        """
        out = []
        for rr in self.per_run:
            ch = rr["channels"]
            # (an evaluation without detail has no stretches)
            st = sorted((s for c in ch.values() for s in c.get("stretches", ())),
                        key=lambda s: -s["rms"])
            out.append({"run": rr["name"],
                        "fit_percent": {k: c["fit_percent"] for k, c in ch.items()},
                        "rmse_over_noise": {k: c["rmse_over_noise"] for k, c in ch.items()},
                        "worst_stretch": {"regime": st[0]["regime"],
                                          "t_s": float(rr["t"][st[0]["start"]]),
                                          "rms_over_noise": st[0]["rms"]} if st else None})
        return out

    def to_pandas(self):
        """Per run and channel: fit % and rmse/noise, one row each.

        Returns
        -------
        pandas.DataFrame
            Columns ``run``, ``channel``, ``fit_percent``, ``rmse_over_noise``.
        """
        return pd.DataFrame([{"run": r["run"], "channel": ch, "fit_percent": r["fit_percent"][ch],
                              "rmse_over_noise": r["rmse_over_noise"][ch]}
                             for r in self.runs() for ch in r["fit_percent"]])

    def warnings(self) -> list[str]:
        """A run whose fit % is below zero (the model is worse than a constant).

        Returns
        -------
        list of str
            One sentence per run and channel whose fit % is below zero or not a number;
            empty when none.
        """
        return [w for r in self.runs() for w in fit_warnings(r["fit_percent"], f"run '{r['run']}'")]

    def table_rows(self) -> Table:
        """Per run: fit % and rmse/noise of each channel, and the worst stretch.

        Returns
        -------
        Table
            One row per run (:meth:`runs`).
        """
        rows = []
        for r in self.runs():
            f, e, st = r["fit_percent"], r["rmse_over_noise"], r["worst_stretch"]
            worst = (f"{st['regime']} at {st['t_s']:.2f} s ({st['rms_over_noise']:.1f} x noise)"
                     if st else "-")
            rows.append([r["run"], fmt(f.get("speed"), ".1f"), fmt(f.get("position"), ".1f"),
                         fmt(e.get("speed"), ".2f"), fmt(e.get("position"), ".2f"), worst])
        return Table("model against measurement", ["run", "fit % speed", "fit % pos",
                                                   "rmse/noise w", "rmse/noise th",
                                                   "worst stretch"], rows,
                     numeric=(1, 2, 3, 4))

    def plot(self, ax=None, kind: str = "overlay", run: str | None = None):
        """One run's model against measurement, or the error by regime.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Draw here (the overlay's first channel only, or the first channel's
            regimes); by default on a new figure.
        kind : {"overlay", "regimes"}
            ``"overlay"``: one run measured against simulated, with the residual in
            noise units, its noise band and the stretches outside it shaded by regime
            (``labrig compare``'s figure); ``"regimes"``: rmse/noise by regime. Any
            other value draws the overlay.
        run : str, optional
            The overlay's run by name; None: the worst run (:meth:`worst_run`).

        Returns
        -------
        matplotlib.figure.Figure
            Not saved: the caller saves (and closes) it.

        Raises
        ------
        KeyError
            ``run`` names no run of this evaluation.
        """
        # matplotlib: ~0.27 s more to import, only for a figure
        from labrig.diagnosis.results.plots import plot_regimes, plot_run_comparison

        if kind == "regimes":
            return plot_regimes(self.regimes, ax=ax)
        return plot_run_comparison(self.run(run), ax=ax)

    def run(self, name: str | None = None) -> dict:
        """The entry of :attr:`per_run` named ``name`` (default: the worst run).

        Parameters
        ----------
        name : str, optional
            The run's name (its file name without ``.csv``); None: the worst run
            (:meth:`worst_run`).

        Returns
        -------
        dict
            The run's residuals: ``name``, ``t`` (s), ``channels`` (per channel
            ``measured``, ``simulated``, ``residual`` in noise units, fit %,
            rmse/noise, ...) and each sample's regime (``labels``).

        Raises
        ------
        KeyError
            ``name`` is not one of the evaluated runs.
        """
        if name is None:
            return self.worst_run()
        rr = next((r for r in self.per_run if r["name"] == name), None)
        if rr is None:
            raise KeyError(f"run {name!r} is not one of {[r['name'] for r in self.per_run]}")
        return rr

    def view(self, run: str | None = None, **size):
        """The same as :meth:`plot` as interactive Bokeh figures on linked time axes
        (zoom, pan, hover: time, measured, model, residual), what the lab page shows;
        a notebook displays it with ``bokeh.io.show`` or ``panel.pane.Bokeh``.

        Parameters
        ----------
        run : str, optional
            The run by name; None: the worst run (:meth:`worst_run`).
        **size
            ``width`` and ``height`` of each channel's figure in pixels (default: the
            container's width, 190).

        Returns
        -------
        labrig.diagnosis.results.interactive.RunView
            Its ``layout`` is the figure.

        Raises
        ------
        KeyError
            ``run`` names no run of this evaluation.
        """
        from labrig.diagnosis.results.interactive import run_view  # bokeh: ~0.3 s more to import

        return run_view(self.run(run), **size)


def evaluate(runs, model: Model, sigmas=None, weights: Weights | None = None,
             detail: bool = True) -> Evaluation:
    """Simulate ``model`` on ``runs``; ``sigmas`` fixes the noise levels (to compare
    candidates on equal terms), else they are measured from the runs
    (:mod:`labrig.analysis.noise`); ``weights`` are the channel weights of the fitness;
    ``detail=False``: the residuals and every rmse/noise and fit %, without the regimes,
    stretches and correlations (``regimes`` empty, ``rho1`` nan): a slider's move."""
    weights = weights or Weights()
    problem = Problem.of(runs, model, weights=weights)
    obj = problem.objective
    if sigmas is not None:
        obj.sigma_w, obj.sigma_theta = sigmas
    sims = problem.simulate(model)
    metrics = adequacy(obj.runs, sims, obj.sigma_w, obj.sigma_theta, weights.p, weights.q)
    quanta = {ch: f.q for ch, f in obj.floors.items()}
    counted = bool(getattr(obj.floors.get("speed"), "counted", False))
    per_run = [run_residuals(rd, {"w": s["w"][0], "theta": s["theta"][0]}, obj.sigma_w,
                             obj.sigma_theta, quanta, detail, counted)
               for rd, s in zip(obj.runs, sims)]
    if obj.use_i:   # a measured current: drawn beside the channels, not in their numbers
        for rr, rd, s in zip(per_run, obj.runs, sims):
            rr["current"] = current_residual(rd, s["i"][0], obj.sigma_i)
    for rr in per_run:   # the fitted start of a run that starts in motion (its figure marks it)
        st = model.starts.get(rr["name"])
        rr["start"] = {**st, "moving": "w0" in st} if st else None
    kept = [(rr["channels"], slice(None) if rr["lost"] is None else ~rr["lost"])
            for rr in per_run]  # a sample the link lost is not counted
    r = np.concatenate([c["residual"][k] for chans, k in kept for c in chans.values()])
    metrics["counts"] = {ch: sum(len(chans[ch]["residual"][k]) for chans, k in kept
                                 if ch in chans) for ch in ("speed", "position")}
    rho1 = float(np.mean([autocorr(c["residual"], 1)[0] for rr in per_run
                          for c in rr["channels"].values()])) if detail else float("nan")
    return Evaluation(metrics=metrics, per_run=per_run,
                      regimes=regime_table(per_run) if detail else {},
                      sse=float(np.sum(r ** 2)), n=int(len(r)),
                      sigmas=(obj.sigma_w, obj.sigma_theta), rho1=rho1, floors=obj.floors,
                      weights=weights)
