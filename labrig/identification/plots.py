"""Figures of the identification: convergence of each method."""
from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from labrig.core.figures import legend_outside, tight_layout


def plot_convergence(results, ax=None):
    """Best fitness against iteration for each method (log scale), with the noise floor.

    ``results``: one :class:`labrig.identification.fit.Identification` or a list of them.
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
    tight_layout(fig)
    return fig


def plot_fit(ident, runs, ax=None, max_runs: int = 4):
    """The identified model on the data it was fitted to: measured and simulated speed
    (position for a run without speed), one panel per run (at most ``max_runs``).

    With ``ax``: the first run only, on that axes. Returns the figure.
    """
    # the simulator brings numba (~0.11 s more to import); plot_convergence needs none of it
    from labrig.model.simulate import RunData

    runs = list(runs)[:max_runs] if ax is None else list(runs)[:1]
    sims = ident.model().simulate(runs)
    if ax is None:
        fig, axes = plt.subplots(len(runs), 1, figsize=(8.5, 2.4 * len(runs) + 0.6),
                                 squeeze=False, sharex=False)
        axes = axes[:, 0]
    else:
        fig, axes = ax.figure, [ax]
    for a, run, sim in zip(axes, runs, sims):
        rd = RunData.from_run(run)
        t = np.arange(len(rd.u)) * rd.dt
        pos_u, speed_u = run.units
        if rd.w is not None:
            y, yhat, label = rd.w, sim["w"], f"speed ({speed_u})"
        else:
            y, yhat, label = rd.theta, sim["theta"], f"position ({pos_u})"
        a.plot(t, y, color="0.6", lw=2.4, label="measured")
        a.plot(t, yhat, color="tab:blue", lw=0.9, label="model")
        a.set_ylabel(label, fontsize=8)
        a.set_title(run.name, fontsize=9, loc="left")
        a.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    legend_outside(axes[0], "right")
    m = ident.metrics
    fig.suptitle(f"{ident.method}: {', '.join(ident.effects.names) or 'linear model'} — "
                 f"rmse/noise {m['rmse_over_noise']['overall']:.2f}", fontsize=10)
    tight_layout(fig)
    return fig
