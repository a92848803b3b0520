"""Figures of the identification: convergence of each method."""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from .figures import legend_outside  # noqa: E402


def plot_convergence(results, ax=None):
    """Best fitness against iteration for each method (log scale), with the noise floor.

    ``results``: one :class:`labrig.identify.engine.Identification` or a list of them.
    Returns the figure; the caller saves it.
    """
    results = results if isinstance(results, (list, tuple)) else [results]
    fig, ax = plt.subplots(figsize=(8.5, 4)) if ax is None else (ax.figure, ax)
    for r in results:
        h = r.result.history
        # a local method's history is its starts' screening error on a subset of the
        # residuals, not the fitness: it gets a flat line at its fitness
        if len(h) > 1 and not str(r.method).startswith("co"):
            ax.semilogy(range(1, len(h) + 1), h, label=f"{r.method}: {r.fitness:.3g}")
        else:
            ax.axhline(r.fitness, ls="--", label=f"{r.method} (local): {r.fitness:.3g}")
    ax.axhline(1.0, color="k", lw=0.8, ls=":", label="noise floor (1.0)")
    ax.set_xlabel("iteration (CO: start)")
    ax.set_ylabel("fitness (weighted rmse / noise)")
    ax.set_title("Convergence of the identifiers")
    ax.grid(True, which="both", alpha=0.3)
    legend_outside(ax, "right")
    fig.tight_layout()
    return fig
