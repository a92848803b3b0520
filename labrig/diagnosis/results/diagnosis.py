"""The result of ``labrig diagnose``: typed, with its JSON, its tables and its figure.

:func:`labrig.diagnosis.loop.diagnose.diagnose` computes a :class:`Diagnosis`; the CLI prints
:meth:`Diagnosis.to_text`, ``--json`` prints :meth:`Diagnosis.to_json` and the report
renders :meth:`Diagnosis.table_rows`, so nothing is formatted twice.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Annotated, Any, Optional

import pandas as pd
from pydantic import Field

from labrig.diagnosis.evidence.evaluation import Evaluation
from labrig.model.model import Model
from labrig.diagnosis.evidence.residuals import REGIME_TEXT
from labrig.core.tables import Table, fmt
from labrig.core.display import Displayable
from labrig.core.record import Num, Record, empty
from labrig.diagnosis.results.candidate import Baseline, Candidate, Criteria, Regimes
# how the diagnosis ranks and picks candidates, for the table's notes
from labrig.diagnosis.evidence.criteria import (CV_CANDIDATES, CV_REACH, PARSIMONY, SCREEN_AFTER, SCREEN_GAIN,
                                       SCREEN_STALL, SIMPLER_MARGIN, SWAP_GAIN)


@dataclass(repr=False)
class Diagnosis(Displayable, Record):
    """Where the model fails and which effect is missing, with the evidence.

    Attributes
    ----------
    baseline : dict
        The diagnosed model's rmse/noise and fit % per channel.
    regimes : dict
        Its error by regime (start from rest, reversal, steady, ...), worst first.
    ranking : list of Candidate
        Each catalogue effect re-fitted, best first: rmse/noise, BIC, held-out error
        by fold, the evidence by regime, whether it is supported, and the words.
    recommendation : str or None
        The effect to add, or None when none earns its parameters.
    verdict : str
        The recommendation in a sentence.
    cross_validation : dict or None
        How the held-out folds were cut and the base model's held-out error.

    ``to_json()`` gives the keys of ``labrig diagnose --json``: baseline, regimes,
    ranking, recommendation, verdict, cross_validation, noise, weights, criteria, seconds;
    ``recommended_model()`` the re-fitted model with the recommended effect (or, with
    none, the given model re-fitted where its candidates found better values).

    Examples
    --------
    >>> import labrig as lr
    >>> diag = lr.diagnose("data/sweep_default")  # doctest: +SKIP
    >>> [c.effect for c in diag.ranking[:2]]  # doctest: +SKIP
    ['coulomb_friction', 'stiction']
    """

    # (a record read back may lack what it can do without: pydantic defaults)
    baseline: Annotated[Baseline, Field(default_factory=dict)]
    regimes: Regimes
    ranking: Annotated[list[Candidate], Field(default_factory=list)]
    recommendation: Annotated[Optional[str], Field(default=None)]
    verdict: Annotated[str, Field(default="")]
    cross_validation: Annotated[Optional[dict], Field(default=None)]
    criteria: Annotated[Criteria, Field(default_factory=dict)]
    seconds: Annotated[Num, Field(default=None)]
    #: each channel's noise floor and how it was measured; the channel weights
    noise: dict = field(default_factory=dict)
    weights: dict = field(default_factory=dict)
    #: candidates not ranked because every start of their re-fit diverged
    diverged: Annotated[list[str], Field(exclude_if=empty)] = field(default_factory=list)
    #: live, not in the JSON: the diagnosed model, its evaluation, the rig constants and
    #: run names, the folds and the base model's cross-validation
    base: Annotated[Optional[Model], Field(exclude=True)] = field(default=None, repr=False)
    evaluation: Annotated[Optional[Evaluation], Field(exclude=True)] = field(default=None,
                                                                             repr=False)
    constants: Annotated[dict, Field(exclude=True)] = field(default_factory=dict, repr=False)
    dataset: Annotated[list, Field(exclude=True)] = field(default_factory=list, repr=False)
    folds: Annotated[Any, Field(exclude=True)] = field(default=None, repr=False)
    cv_baseline: Annotated[Any, Field(exclude=True)] = field(default=None, repr=False)
    #: the given model was re-fitted here: its candidates found better values of its own
    #: parameters, and ``base`` holds them (``baseline['source']`` says by how much)
    refined: Annotated[bool, Field(exclude=True)] = field(default=False, repr=False)

    def headline(self) -> str:
        """The first line of the ``repr``: the model's rmse/noise, its effects and the
        recommendation.

        Returns
        -------
        str
        """
        r = self.baseline["rmse_over_noise"]["overall"]
        return (f"Diagnosis: rmse/noise {r:.2f} with effects "
                f"{', '.join(self.baseline['effects']) or 'none'}; recommendation: "
                f"{self.recommendation or 'none'}")

    def candidate(self, label: str) -> Candidate:
        """The candidate of a ranking label (an added effect is its own name).

        Parameters
        ----------
        label : str
            A label of :attr:`ranking`: ``"deadband"`` (added), ``"- deadband"``
            (removed) or ``"X -> Y"`` (replaced).

        Returns
        -------
        Candidate

        Raises
        ------
        KeyError
            No candidate of the ranking has that label (the message lists them).
        """
        for c in self.ranking:
            if c.label == label:
                return c
        # (a lookup by key, as a mapping's: the command line never asks for a missing one)
        raise KeyError(f"'{label}' is not a move of the ranking; its moves: "
                       + (", ".join(c.label for c in self.ranking) or "none"))

    def recommended_model(self) -> Model | None:
        """The model this round leaves: the re-fitted model with the recommended effect,
        ready to save; with no effect to add, the diagnosed model itself where its
        candidates' re-fits found better values of its own parameters (``refined``: the
        same effects, better placed, as ``--auto``'s search goes on from); else None.

        Returns
        -------
        Model or None
            With the rig's constants and a record of the re-fit in ``info``.
        """
        if self.recommendation:
            return self.model_with(self.recommendation)
        if not self.refined:
            return None
        return self._to_save(self.base, self.evaluation.rmse, "co (diagnose re-fit, refined)")

    def model_with(self, label: str) -> Model:
        """The re-fitted model of a candidate (by its ranking label).

        Parameters
        ----------
        label : str
            A label of :attr:`ranking` (:meth:`candidate`'s).

        Returns
        -------
        Model
            The candidate's re-fitted model with the rig's constants and a record of the
            re-fit in ``info``, ready to save.

        Raises
        ------
        KeyError
            No candidate of the ranking has that label (:meth:`candidate`).
        """
        c = self.candidate(label)
        return self._to_save(c.model, c.rmse_over_noise, "co (diagnose re-fit)")

    def _to_save(self, model: Model, rmse: float, method: str) -> Model:
        """``model`` with the rig's constants and the record of how it was fitted."""
        return replace(model, constants=dict(self.constants),
                       info={"method": method, "rmse_over_noise": {"overall": rmse},
                             "dataset": {"runs": list(self.dataset)}})

    def to_pandas(self):
        """The ranking as a DataFrame, one row per candidate effect.

        Returns
        -------
        pandas.DataFrame
            Best first; columns ``effect``, ``move`` (the label), ``rmse_over_noise``,
            ``improvement`` (a fraction), ``delta_bic``, ``cross_validated`` (held-out
            rmse/noise with the move, None if not cross-validated) and ``supported``.
        """
        return pd.DataFrame([{"effect": c.effect, "move": c.label, "rmse_over_noise": c.rmse_over_noise,
                              "improvement": c.improvement, "delta_bic": c.delta_bic,
                              "cross_validated": (c.cross_validated or {}).get("with_effect"),
                              "supported": c.supported} for c in self.ranking])

    # -- presentation ---------------------------------------------------------------------
    def table_rows(self) -> list[Table]:
        """Where it fails (by regime), and the ranking of candidates.

        Returns
        -------
        list of Table
            The rmse/noise by channel and regime, then the ranking with its rules,
            cross-validation, noise floors and weights as notes.
        """
        regimes = Table("where it fails (rmse/noise by regime; share of time)",
                        ["channel", "regime", "rmse/noise", "share of time"], numeric=(2, 3))
        for ch, regs in self.regimes["by_regime"].items():
            for r, v in sorted(regs.items(), key=lambda kv: -kv[1]["rmse_over_noise"]):
                regimes.rows.append([ch, REGIME_TEXT[r], fmt(v["rmse_over_noise"], ".2f"),
                                     f"{100 * v['share_of_time']:.0f} %"])
        for ch, amps in self.regimes["by_amplitude"].items():
            regimes.notes.append(f"{ch} by run amplitude: "
                                 + ", ".join(f"{k} {v:.2f}" for k, v in amps.items()))
        ranking = Table("candidates (re-fitted: each effect the model lacks added, each it "
                        "has removed or replaced)",
                        ["rank", "effect", "rmse/noise", "gain", "dBIC", "cross-validated",
                         "folds", "supported"], numeric=(0, 2, 3, 4))
        for i, c in enumerate(self.ranking, 1):
            cv = c.cross_validated
            ranking.rows.append([str(i), c.label, fmt(c.rmse_over_noise, ".2f"),
                                 f"{fmt(100 * c.improvement, '.0f')} %", fmt(c.delta_bic, ".0f"),
                                 f"{cv['baseline']:.2f} -> {cv['with_effect']:.2f}" if cv else "-",
                                 f"{cv['folds_improved']}/{cv['folds']}" if cv else "-",
                                 ("yes" if c.supported else "no")
                                 + (" (screened out)" if c.screened is not None else "")
                                 + (" (out of reach)" if c.out_of_reach is not None else "")
                                 + (" (size not resolved)" if c.unresolved else "")
                                 + (" (at bound)" if c.at_bound else "")])
        ranking.notes += self._ranking_rules()
        cvd = self.cross_validation
        if cvd:
            ranking.notes.append(f"cross-validation: {cvd['folds']} folds, {cvd['kind']}; "
                                 "gain is in the weighted error the fits minimise")
        if self.noise:
            ranking.notes.append("noise floors: " + "; ".join(v["method"] for v in self.noise.values()))
        if self.weights:
            ranking.notes.append(f"channel weights: speed {self.weights['speed']:.3g}, position "
                                 f"{self.weights['position']:.3g} (each channel's squared error "
                                 "over its own at the starting model; --weights overrides)"
                                 + (f"; {self.weights['why']}" if self.weights.get("why") else ""))
        return [regimes, ranking]

    def _ranking_rules(self) -> list[str]:
        """The ranking table's notes: what it is ordered by and when an effect is
        supported, with the thresholds this diagnosis used (its ``criteria``)."""
        crit = self.criteria or {}
        gain = crit.get("min_improvement")
        dbic = crit.get("max_delta_bic")
        gain = "the minimum gain" if gain is None else f"{100 * gain:g} %"
        dbic = "the BIC threshold" if dbic is None else f"{dbic:g}"
        return [
            "ordered by: the cross-validated rmse/noise after the move, raised "
            f"{100 * PARSIMONY:g} % per parameter it adds beyond one and lowered as much per "
            "parameter it takes away (a simpler model that predicts held-out data about as "
            "well ranks first); candidates that were not cross-validated come last, by dBIC",
            f"supported (add) = yes only when all four hold: dBIC below {dbic}, gain of at "
            f"least {gain}, the cross-validated error falls by at least {gain}, and more "
            "than half of the counted folds improved; so a strongly negative dBIC alone is not "
            "enough. And the effect's size must be resolved: above one step of the input, "
            "a delay above a quarter sample, and more than 3 standard errors (from the folds' "
            "fits) from zero (docs/physics.md, 'Diagnosis')",
            f"'- X' removes X: supported when the model without it predicts held-out data "
            f"within {gain} of the model with it (the mirror of adding); 'X -> Y' replaces X "
            f"by Y: by the add rule, with a {100 * SWAP_GAIN:g} % gain for an effect with as "
            f"many parameters, or as good within {100 * SIMPLER_MARGIN:g} % for a simpler one",
            f"cross-validated '-': not cross-validated (of the effects added, only the "
            f"{CV_CANDIDATES} largest gains of at least {gain} are; of the revisions, every "
            f"removal and each replacement that gains {100 * SWAP_GAIN:g} % or, simpler, fits "
            f"within {100 * SIMPLER_MARGIN:g} %), hence not supported; '(out of reach)': an "
            f"effect whose error on all runs is already more than {100 * CV_REACH:g} % above "
            "what the best supported candidate predicts held out (a fit predicts held-out "
            "data no better than it fits them), so it is not cross-validated; a fold whose training "
            "data do not "
            "pin the new threshold is not counted; '(at bound)': a fitted parameter ended at a "
            "bound of its search range (a warning: it does not enter the decision)",
        ] + ([f"'(screened out)': the re-fit was ended after {SCREEN_AFTER} iterations, "
              f"having gained under {100 * SCREEN_GAIN:g} % and stalled (its last iteration "
              f"gained under {100 * SCREEN_STALL:g} % of the error): its numbers are where it "
              "stood then, and a move that gains under "
              f"{gain} is never supported (--full re-fits every candidate to the end)"]
             if any(c.screened is not None for c in self.ranking) else [])

    def _tables(self) -> list[Table]:
        regimes, ranking = self.table_rows()
        return [ranking, regimes]   # in a notebook, the ranking first: it is the answer

    def to_text(self) -> str:
        """What ``labrig diagnose`` prints: the baseline, the tables, the recommendation
        (with each fold's evidence), the verdict and the next command.

        Returns
        -------
        str
        """
        b = self.baseline
        r = b["rmse_over_noise"]
        out = [f"baseline ({b['source']}; effects: {', '.join(b['effects']) or 'none'}): "
               f"rmse/noise {r['overall']:.2f} (speed {fmt(r.get('speed'), '.2f')}, "
               f"position {fmt(r.get('position'), '.2f')}); 1.0 is the noise floor", ""]
        out += [t.to_text() + "\n" for t in self.table_rows()]
        out += [f"recommendation: {self.recommendation or 'none'}"]
        folds = (self.candidate(self.recommendation).cross_validated or {}).get("per_fold") \
            if self.recommendation else None
        if folds:   # every fold's own evidence: one fold cannot hide in the pooled number
            out.append("per fold (held-out rmse/noise, now -> with it): " + "; ".join(
                f"{f['fold']}: {f['baseline']:.2f} -> {f['with_effect']:.2f}"
                + ("" if f["counted"] else " (not counted)") for f in folds))
        out += ["", self.verdict]
        if self.recommendation:
            c = self.candidate(self.recommendation)
            out.append(f"\nnext: labrig identify DATA --model MODEL.json --effects "
                       f"{self.recommendation} -o next.json" if c.move == "add" else
                       f"\nnext: labrig diagnose DATA --model MODEL.json -o next.json saves "
                       f"the model with this change ({c.label}), re-fitted")
        return "\n".join(out)

    def view(self, **size):
        """The ranking as an interactive Bokeh figure (hover for each move's numbers),
        what the lab page shows beside the table.

        Parameters
        ----------
        **size
            ``width`` in pixels; by default the figure stretches to its container.

        Returns
        -------
        bokeh.plotting.figure
            Show it with ``bokeh.io.show`` (or ``panel.pane.Bokeh``).
        """
        from labrig.diagnosis.results.interactive import ranking_figure  # bokeh: ~0.3 s more to import

        return ranking_figure(self.ranking, **size)

    def plot(self, ax=None, kind: str = "ranking"):
        """The candidates' evidence, or where the model fails.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Draw here (the ranking alone, or the first channel's regimes); by default
            on a new figure.
        kind : {"ranking", "regimes"}
            ``"ranking"``: the candidates with their evidence (in-sample and
            cross-validated rmse/noise, dBIC, folds) beside where the model fails;
            ``"regimes"``: rmse/noise by regime for every channel. Any other value
            draws the ranking.

        Returns
        -------
        matplotlib.figure.Figure
            Not saved: the caller saves (and closes) it.
        """
        if kind == "regimes":
            from labrig.diagnosis.results.plots import plot_regimes  # matplotlib: ~0.27 s to import

            return plot_regimes(self.regimes, ax=ax)
        from labrig.diagnosis.results.ranking_plots import plot_ranking  # matplotlib: ~0.27 s to import

        return plot_ranking(self, ax=ax)
