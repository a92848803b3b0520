"""Figures of the identification: convergence of each method."""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_convergence(results, path):
    """Best fitness against iteration for each method (log scale), with the noise floor."""
    fig, ax = plt.subplots(figsize=(7, 4))
    for r in results:
        h = r.result.history
        if len(h) > 1:
            ax.semilogy(range(1, len(h) + 1), h, label=f"{r.method}: {r.fitness:.3g}")
        else:
            ax.axhline(r.fitness, ls="--", label=f"{r.method} (local): {r.fitness:.3g}")
    ax.axhline(1.0, color="k", lw=0.8, ls=":", label="noise floor (1.0)")
    ax.set_xlabel("iteration (CO: start)")
    ax.set_ylabel("fitness = rmse / noise")
    ax.set_title("Convergence of the identifiers")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
