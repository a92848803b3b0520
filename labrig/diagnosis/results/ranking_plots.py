"""The figure of a diagnosis: the ranking of candidate effects with its evidence, beside
where the model fails."""
from __future__ import annotations

import matplotlib.pyplot as plt

from labrig.diagnosis.results.plots import plot_regimes
from labrig.core.figures import tight_layout


def plot_ranking(diag, ax=None):
    """Each candidate's rmse/noise in-sample (bar) and cross-validated (dot), against the
    model as it is and the noise floor (removals and replacements by their labels); supported candidates in colour, dBIC and the
    folds that improved written beside each bar.

    Without ``ax``: a figure with the ranking and where the model fails (the first
    channel's regimes). Returns the figure.
    """
    if ax is None:
        fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 0.45 * max(len(diag.ranking), 4) + 1.6),
                                      gridspec_kw={"width_ratios": [3, 2]})
        plot_regimes(diag.regimes, ax=ax2, title="")
        ax2.set_title("where the model fails (" + next(iter(diag.regimes["by_regime"])) + ")",
                      fontsize=9)
        for label in ax2.get_xticklabels():
            label.set_horizontalalignment("right")
    else:
        fig = ax.figure
    ranking = diag.ranking
    names = [c.label for c in ranking][::-1]   # "- X" removes, "X -> Y" replaces
    vals = [c.rmse_over_noise for c in ranking][::-1]
    colours = ["tab:green" if c.supported else "0.7" for c in ranking][::-1]
    y = range(len(names))
    ax.barh(list(y), vals, color=colours)
    for i, c in zip(y, ranking[::-1]):
        cv = c.cross_validated
        if cv:
            ax.plot(cv["with_effect"], i, "o", color="k", ms=4)
        note = f"dBIC {c.delta_bic:.0f}" + (f", {cv['folds_improved']}/{cv['folds']} folds"
                                             if cv else "")
        ax.annotate(note, (max(vals[i], cv["with_effect"] if cv else 0.0), i), xytext=(6, 0),
                    textcoords="offset points",
                    va="center", fontsize=7)
    base = diag.baseline["rmse_over_noise"]["overall"]
    ax.axvline(base, color="tab:red", ls="--", lw=1, label=f"the model as it is: {base:.2f}")
    ax.axvline(1.0, color="k", ls=":", lw=1, label="noise floor (1.0)")
    ax.set_yticks(list(y))
    ax.set_yticklabels(names, fontsize=8)
    ax.set_xlabel("rmse / noise (bar: in-sample; dot: cross-validated)")
    top = max(vals + [base]) if vals else base
    if top > 30 * max(min(vals + [base]), 1.0):
        # a removal that costs a hundredfold would squash every other bar: log scale
        ax.set_xscale("log")
        ax.set_xlim(0.8, top * 3)
    else:
        ax.set_xlim(0, top * 1.35)
    ax.set_title("candidates, best first (green: supported)", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    tight_layout(fig)
    return fig
