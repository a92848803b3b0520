"""What ``labrig propose`` returns: the explanations it weighed, the candidate inputs it
judged, and the proposal (or the plain statement that nothing within the limits separates
the pair), with its text, tables, plan file and figure. The search is
:mod:`labrig.design.propose`; the words are those of docs/physics.md, 'Experiments that
decide'.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any

from pydantic import Field, PlainSerializer, computed_field

from labrig.core.display import Displayable
from labrig.core.record import Live, NoneIfEmpty, Record, TupleOf
from labrig.core.errors import UserError
from labrig.core.tables import Table
from labrig.io.runs import Run
from labrig.design.inputs import MAX_POINTS, why
from labrig.design.hypotheses import Hypothesis, Judged, after_number
from labrig.design.synthetic import LEAD_IN_S, loop_keys, synthetic_run

#: what the naive ranking uses, in the words every text line uses
DIFFERENCE = "sum of squared differences of the two predictions, in noise units"
#: what a proposal is judged by: the decision's own measure (labrig.design.decide)
SEPARATION = "worse rmse/noise over better, minus one"
#: a proposal is made when the rival, re-fitted, is predicted to stay at least this far
#: behind for every plausible truth: its rmse/noise at least twice the truth's
DECISIVE = 1.0

@dataclass(repr=False)
class Proposal(Displayable, Record):
    """The proposed experiment, why it separates the pair and by how much; or, when no
    input within the limits separates it (``separates`` False), the best found and what
    would help instead.

    Attributes
    ----------
    pair : tuple of str
        The two explanations.
    chosen : Judged
        The input proposed, with its predicted separation against the noise.
    judged : list of Judged
        Every input tried, best first.
    budget_s : float
        The rig seconds it was allowed.
    amax : float
        The input limit it kept to (V).
    separates : bool
        Whether the chosen input separates the pair beyond the noise.
    advice : str
        What would help when it does not.

    ``to_toml()`` is the plan ``labrig sweep --plan`` plays; ``plot()`` draws both
    explanations' predictions.

    Examples
    --------
    >>> import labrig as lr
    >>> p = lr.propose("runs", "m1.json", "deadband,coulomb_friction")  # doctest: +SKIP
    >>> p.separates  # doctest: +SKIP
    True
    """

    readable = False   # (a summary of live objects: not read back)

    pair: Annotated[TupleOf, Field(alias="between")]
    hypotheses: list[Hypothesis]
    judged: Annotated[list[Judged], Field(alias="candidates")]
    # (written as "proposed")
    chosen: Annotated[Judged, Live]
    sigmas: Annotated[dict[str, float], Field(alias="noise")]
    template: Annotated[Run, Live]
    budget_s: float
    amax: Annotated[float, Field(alias="amax_v")]
    seconds: Annotated[float, PlainSerializer(lambda v: round(v, 2))] = 0.0
    # plausible models per hypothesis
    plausible: Annotated[list, Live] = field(default_factory=list)
    separates: bool = True
    advice: Annotated[str, NoneIfEmpty] = ""
    #: per explanation judged across sizes the data cannot narrow: the smallest size the
    #: proposed input separates (:func:`labrig.design.separation.smallest_separable`)
    smallest: Annotated[list[dict[str, Any]], Field(alias="smallest_separable"),
                        NoneIfEmpty] = field(default_factory=list)
    #: [(truth label, best separation any leading input reached)]: the smallest sizes no
    #: input within the budget separates (the noise hides them), set aside from the worst
    #: case; the smallest size the input separates is then stated
    unseen: Annotated[list, Field(alias="not_separable"),
                      PlainSerializer(lambda v: [{"truth": lab, "best_separation": best}
                                                 for lab, best in v] or None)] \
        = field(default_factory=list)

    @computed_field
    @property
    def proposed(self) -> dict[str, Any]:
        """The chosen input: its kind, label, length (s), why it separates the pair, its
        breakpoints and its predicted separation."""
        c = self.chosen
        return {"kind": c.candidate.kind, "label": c.candidate.label,
                "duration_s": c.candidate.duration, "why": self.why,
                "points": c.candidate.points,
                "separation": {"naive": c.naive, "after_refit": dict(c.refit),
                               "worst_after_refit": c.worst}}

    def smallest_text(self) -> str:
        """'it separates them for any deadband d_v above 0.08 V ...', one clause each.

        Returns
        -------
        str
            One clause per explanation whose size the data cannot narrow (the smallest
            size the proposed input separates), then the sizes no input within the
            budget separates; "" when there are none.
        """
        out = []
        for s in self.smallest:
            u = after_number(s["unit"])
            if s["every_plausible_size"]:
                out.append(f"for every {s['effect']} {s['key']} the data allow (down to "
                           f"{s['plausible_from']:.3g}{u})")
            else:
                out.append(f"for any {s['effect']} {s['key']} above {s['size']:.3g}{u} "
                           f"(the data allow {s['plausible_from']:.3g}{u} and up; smaller, "
                           "the two explanations differ on this input by less than the noise "
                           "lets the decision see)")
        text = ("it separates them " + "; and ".join(out)) if out else ""
        if self.unseen:
            text += ("\nnot separated by any input within the budget: " + ", ".join(
                f"{lab} (the best reaches {best:.2f})" for lab, best in self.unseen)
                + ": at that size the two explanations differ by less than the noise lets "
                "the decision see; asking until sure (--ask-rig --step-s) lets the rig "
                "answer for the size it has")
        return text

    def headline(self) -> str:
        """The first line of the ``repr``: the pair and the proposed input, or that
        nothing within the budget separates them.

        Returns
        -------
        str
        """
        if not self.separates:
            return (f"No proposal between {self.pair[0]} and {self.pair[1]}: nothing within "
                    f"{self.budget_s:g} s separates them")
        return (f"Proposal between {self.pair[0]} and {self.pair[1]}: "
                f"{self.chosen.candidate.label} ({self.chosen.candidate.duration:.1f} s)")

    @property
    def why(self) -> str:
        """Why the chosen kind of input separates the pair, in plain words."""
        return why(self.chosen.candidate.kind, self.pair)

    @computed_field
    @property
    def limits(self) -> dict[str, Any]:
        """The board's limits the proposed input respects, and what it uses of them:
        ``budget_s``, ``duration_s`` (s), ``max_points``, ``points``, ``amax_v``,
        ``peak_v`` (V; rad for a reference of the board's own loop)."""
        c = self.chosen.candidate
        return {"budget_s": self.budget_s, "duration_s": c.duration,
                "max_points": MAX_POINTS, "points": len(c.points),
                "amax_v": self.amax, "peak_v": max(abs(u) for _, u in c.points)}

    def experiment(self, name: str = "proposed") -> dict:
        """The plan's ``[[experiment]]`` table.

        Parameters
        ----------
        name : str, default "proposed"
            The experiment's name (the run file's stem when the rig plays it).

        Returns
        -------
        dict
            ``name``, ``loop``, ``waveform`` ("pwl"), ``lead_in_s``, ``sample_rate_hz``
            (the template run's), a closed loop's gains, ``points`` (``[t_s, u]``
            breakpoints) and ``between`` (the pair).
        """
        c = self.chosen.candidate
        return {"name": name, "loop": c.loop, "waveform": "pwl", "lead_in_s": LEAD_IN_S,
                "sample_rate_hz": float(self.template.fs), **loop_keys(c),
                "points": [[float(t), float(u)] for t, u in c.points],
                "between": list(self.pair)}

    def to_toml(self, name: str = "proposed", step: bool = False) -> str:
        """The plan file: an ordinary plan with one ``pwl`` experiment named ``name``.

        Parameters
        ----------
        name : str, default "proposed"
            The experiment's name (:meth:`experiment`).
        step : bool, default False
            A step of a sequence (:mod:`labrig.design.ask`): written even when it is
            not predicted to decide alone (the evidence adds up), provided its rival
            re-fits were judged.

        Returns
        -------
        str
            TOML for ``labrig sweep --plan``, with comments saying why the input
            separates the pair, by how much, and the limits it keeps to.

        Raises
        ------
        UserError
            No input within the budget separates the pair (the message gives the
            advice), unless ``step`` and the chosen input was judged after re-fits.
        """
        if not self.separates and not (step and self.chosen.refit):
            raise UserError(f"no input within {self.budget_s:g} s separates {self.pair[0]} "
                            f"and {self.pair[1]}; {self.advice}")
        e = self.experiment(name)
        a, b = self.pair
        lim = self.limits
        # a board's loop plays references in rad from the start, its output within the rig's
        peak = (f"references within +-{lim['peak_v']:.2f} rad of the start, the board's output "
                f"within +-{lim['amax_v']:.2f} V." if "board" in (self.chosen.candidate.gains or {})
                else f"|u| <= {lim['peak_v']:.2f} V within +-{lim['amax_v']:.2f} V.")
        lines = [f"# Proposed by `labrig propose`: the experiment that best tells {a} and {b} "
                 "apart.", f"# {self.chosen.candidate.label}: {self.why}.",
                 f"# Predicted difference ({DIFFERENCE}): {self.chosen.naive:.0f} "
                 "for the best fits.",
                 f"# Predicted separation ({SEPARATION}) after the rival re-fits: "
                 f"{self.chosen.worst:.2f} at worst (>= {DECISIVE:g} is decisive).",
                 f"# Limits respected: {lim['duration_s']:.2f} s of the {lim['budget_s']:g} s "
                 f"budget, {lim['points']} of at most {lim['max_points']} breakpoints, "
                 + peak, "",
                 "[[experiment]]"]
        for k in ("name", "loop", "waveform", "lead_in_s", "sample_rate_hz", "position_gain",
                  "velocity_gain"):
            if k not in e:
                continue
            v = e[k]
            lines.append(f"{k} = {v!r}".replace("'", '"') if isinstance(v, str) else f"{k} = {v}")
        lines.append("between = [" + ", ".join(f'"{x}"' for x in e["between"]) + "]")
        lines.append("points = [" + ", ".join(f"[{t:g}, {u:g}]" for t, u in e["points"]) + "]")
        return "\n".join(lines) + "\n"

    def _leaders(self) -> list:
        lead = sorted((j for j in self.judged if j.refit), key=lambda j: -j.worst)
        rest = sorted((j for j in self.judged if not j.refit), key=lambda j: -j.robust)
        return lead + rest[:max(0, 8 - len(lead))]

    def to_text(self) -> str:
        """What ``labrig propose`` prints: the explanations' fits, the candidate inputs
        with their predicted differences and separations, and the proposal with why (or
        that nothing separates the pair, and what would).

        Returns
        -------
        str
        """
        c = self.chosen
        a, b = self.pair
        fits = "; ".join(f"with {h.effect}: rmse/noise {h.rmse_over_noise:.2f}"
                         + (f", {h.describe_size()}" if h.key else "") for h in self.hypotheses)
        judged = []
        for h in self.hypotheses:
            if h.skipped:
                judged.append(f"{h.effect} is not judged as the truth: {h.skipped}")
            else:
                judged.append(f"judged true as {', '.join(lab for lab, _ in h.truths())}")
        rows = self._leaders()
        w = max([45] + [len(j.candidate.label) for j in rows])   # labels whole, aligned
        body = "\n".join(
            f"  {j.candidate.label:<{w}} {j.naive:12.0f} {j.robust:12.0f} "
            + (f"{('<= ' if j.stopped else '') + format(j.worst, '.2f'):>12}" if j.refit
               else f"{'-':>12}") for j in rows)
        text = (f"between {a} and {b} ({fits})\n" + "\n".join(judged) + "\n\n"
                f"candidate inputs (at most {self.budget_s:g} s, within +-{self.amax:.2f} V, at "
                f"most {MAX_POINTS} breakpoints): the predicted difference ({DIFFERENCE}) of the "
                "best fits and the worst over the models the data cannot exclude "
                f"({' and '.join(map(str, self.plausible))}); for the leaders, the predicted "
                f"separation ({SEPARATION}) after the rival re-fits, the worst over the "
                "plausible truths:\n"
                f"  {'input':<{w}} {'best fits':>12} {'worst case':>12} {'separation':>12}\n"
                f"{body}\n\n")
        after = ", ".join(f"{v:.2f} with {k} true" for k, v in c.refit.items())
        if not self.separates:
            return text + (f"nothing within {self.budget_s:g} s and +-{self.amax:.2f} V is "
                           f"predicted to separate them: the best, {c.candidate.label}, reaches "
                           f"a separation of {(c.worst or 0.0):.2f} after the rival re-fits "
                           f"({after or 'no truth to judge'}; {DECISIVE:g} needed). No plan "
                           f"is written.\nwhat would: {self.advice}")
        return text + (f"proposed: {c.candidate.label} ({c.candidate.duration:.1f} s, "
                       f"{len(c.candidate.points)} breakpoints)\n"
                       f"why: {self.why}.\n"
                       f"predicted separation ({SEPARATION}) after the rival re-fits: {after} "
                       f"({DECISIVE:g} or more is decisive: the wrong one's rmse/noise at "
                       "least twice the right one's)"
                       + (f"\n{self.smallest_text()}" if self.smallest or self.unseen else ""))

    def table_rows(self) -> list[Table]:
        """The explanations' fits, and the candidate inputs by predicted separation.

        Returns
        -------
        list of Table
            One row per explanation (rmse/noise, size, judged true), then the leading
            inputs (predicted difference of the best fits, worst case, separation after
            the rival re-fits).
        """
        fits = Table(f"between {self.pair[0]} and {self.pair[1]}",
                     ["explanation", "rmse/noise", "size", "judged true"], numeric=(1,))
        fits.rows = [[h.effect, f"{h.rmse_over_noise:.2f}", h.describe_size() or "-",
                      "yes" if not h.skipped else f"no: {h.skipped}"] for h in self.hypotheses]
        inputs = Table(f"candidate inputs (at most {self.budget_s:g} s, within "
                       f"+-{self.amax:.2f} V)", ["input", "best fits", "worst case",
                                                 "separation"], numeric=(1, 2, 3))
        inputs.rows = [[j.candidate.label, f"{j.naive:.0f}", f"{j.robust:.0f}",
                        (("<= " if j.stopped else "") + f"{j.worst:.2f}") if j.refit else "-"]
                       for j in self._leaders()]
        inputs.notes.append(f"predicted difference ({DIFFERENCE}); predicted separation "
                            f"({SEPARATION}) after the rival re-fits; "
                            + (f"proposed: {self.chosen.candidate.label}" if self.separates
                               else "nothing separates them: no plan"))
        return [fits, inputs]

    def predicted(self):
        """The proposed run as the template's rig would record it, and the two predictions
        of it (``w``, ``theta``) in the pair's order, with their labels: the hardest
        plausible truth judged and the rival as re-fitted to it (what the predicted
        separation measures), else the two best fits.

        Returns
        -------
        tuple of (Run, list of dict, list of str)
            The synthetic run; per explanation ``{"w", "theta", "i"}`` as
            :meth:`Model.simulate` gives them; their labels.
        """
        run = synthetic_run(self.template, self.chosen.candidate, "proposed")
        hard = self.chosen.hardest
        if hard is None:
            return run, [h.model.simulate([run])[0] for h in self.hypotheses], \
                [f"with {h.effect} (best fit)" for h in self.hypotheses]
        ti, label, truth, rival = hard
        pair = [None, None]
        pair[ti] = (truth.simulate([run])[0], f"{label}, as the truth")
        pair[1 - ti] = (rival.simulate([run])[0],
                        f"{self.pair[1 - ti]}, re-fitted to it")
        return run, [p for p, _ in pair], [lab for _, lab in pair]

    def plot(self, ax=None):
        """Both explanations' predicted responses to the proposed input, with the noise band.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Draw the speed (or, without a speed channel, the position) only, here; by
            default a new figure with each channel and the input.

        Returns
        -------
        matplotlib.figure.Figure
            Not saved: the caller saves (and closes) it.
        """
        from labrig.design.plots import plot_proposal  # matplotlib: ~0.25 s to import

        return plot_proposal(self, ax=ax)
