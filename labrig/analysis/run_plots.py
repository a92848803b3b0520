"""Figure of the whole sweep: every run's response and input on one page."""
from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from labrig.core.figures import legend_outside, tight_layout


def plot_overview(runs):
    """One figure of the whole sweep: response on top, input below; open-loop runs on
    the left (motor speed), closed-loop runs on the right (output angle and reference).

    Parameters
    ----------
    runs : list of labrig.io.runs.Run

    Returns
    -------
    matplotlib.figure.Figure
        Not saved: the caller saves (and closes) it.
    """
    groups = [("open", [r for r in runs if r.loop != "closed"]),
              ("closed", [r for r in runs if r.loop == "closed"])]
    groups = [g for g in groups if g[1]]
    # each column's legend sits right of its plot (inside it would cover traces)
    fig, axes = plt.subplots(2, len(groups), figsize=(7.6 * len(groups) if len(groups) > 1 else 12.4, 5.6),
                             squeeze=False, sharex="col", gridspec_kw={"height_ratios": [3, 1.4]})
    for col, (loop, rs) in enumerate(groups):
        top, bot = axes[0, col], axes[1, col]
        cmap = plt.get_cmap("viridis")
        for i, r in enumerate(sorted(rs, key=lambda r: (r.amplitude, r.name))):
            c = cmap(0.1 + 0.8 * i / max(len(rs) - 1, 1))
            t = r.t - r.t[0]
            if loop == "open":
                y = r.speed if r.has_speed else None
                if y is None and r.has_pos:
                    y = np.gradient(r.position * r.gear_ratio, r.dt)
                top.plot(t, y, color=c, lw=0.8, label=r.name)
            else:
                y = r.position
                if y is None:
                    y = np.cumsum(r.speed) * r.dt / r.gear_ratio
                top.plot(t, y, color=c, lw=1.0, label=r.name)
                if r.ref is not None:
                    # the loop compares the reference with the pot's volts without its
                    # offset (truth.py): reference angle = ref / Kpot
                    top.plot(t, r.ref / r.kpot, color=c, lw=0.8, ls="--")
            bot.plot(t, r.u, color=c, lw=0.8)
        if loop == "open":
            top.set_title("open loop: motor speed", fontsize=10)
            top.set_ylabel("speed (m/s)" if runs[0].axis == "linear" else "speed (rad/s, motor)")
            bot.set_ylabel("u (V)")
        else:
            top.set_title("closed loop: output angle (dashed: reference)", fontsize=10)
            top.set_ylabel("position (m)" if runs[0].axis == "linear" else "angle (rad, output)")
            bot.set_ylabel("reference (V)")
        bot.set_xlabel("time (s)")
        for ax in (top, bot):
            ax.grid(alpha=0.3)
        legend_outside(top, "right", fontsize=7, ncol=2 if len(rs) > 8 else 1)
    tight_layout(fig)
    return fig
