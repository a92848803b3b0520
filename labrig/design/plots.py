"""Figure of a proposed experiment: what each explanation predicts for it, with the noise
band, and the input the rig will play."""
from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from labrig.core.figures import legend_outside, tight_layout

COLOURS = ("tab:blue", "tab:red")


def plot_proposal(prop, ax=None):
    """Predicted speed and position for the proposed input, each with a +-1 noise band, and
    the input below: the hardest plausible truth judged and the rival as re-fitted to it
    (what the predicted separation measures). With ``ax``, the speed (or, without a
    speed channel, the position) only."""
    run, preds, labels = prop.predicted()
    t = run.t
    chans = [(ch, key) for ch, key in (("speed", "w"), ("position", "theta"))
             if ch in prop.sigmas and (run.has_speed if ch == "speed" else run.has_pos)]
    units = run.units
    if ax is not None:
        fig, axes = ax.figure, [ax]
        chans = chans[:1]
    else:
        fig, axes = plt.subplots(len(chans) + 2, 1, figsize=(11.5, 2.6 * (len(chans) + 2)),
                                 sharex=True, height_ratios=[3] * len(chans) + [2, 1.6])
        axes = list(np.atleast_1d(axes))
        # where the explanations part: their difference against the noise band
        ch, key = chans[0]
        s = prop.sigmas[ch]
        d = preds[0][key] - preds[1][key]
        axes[-2].plot(t, d, color="0.2", lw=1.1,
                      label=f"{prop.pair[0]} - {prop.pair[1]}")
        axes[-2].fill_between(t, -s, s, color="tab:green", alpha=0.25, lw=0,
                              label="+-1 noise: differences inside it cannot be seen")
        axes[-2].set_ylabel(f"difference\n({units[1] if ch == 'speed' else units[0]})")
        axes[-2].grid(alpha=0.3)
        legend_outside(axes[-2], "right", fontsize=8)
    for a, (ch, key) in zip(axes, chans):
        s = prop.sigmas[ch]
        for lab, p, c in zip(labels, preds, COLOURS):
            a.plot(t, p[key], color=c, lw=1.1, label=lab)
            a.fill_between(t, p[key] - s, p[key] + s, color=c, alpha=0.18, lw=0)
        unit = units[1] if ch == "speed" else units[0]
        a.set_ylabel(f"{ch} ({unit})")
        a.grid(alpha=0.3)
        legend_outside(a, "right", title="predicted (band: +-1 noise)", title_fontsize=8)
    if ax is None:
        axes[-1].plot(t, run.u, color="0.25", lw=1.0)
        # a closed-loop plan plays the position loop's reference, not the amplifier's input:
        # the MS150's in pot volts, a board's in the axis's units from the start
        board = "board" in (prop.chosen.candidate.gains or {})
        axes[-1].set_ylabel(f"reference ({units[0] if board else 'V'})" if run.loop == "closed"
                            else "u (V)")
        axes[-1].set_xlabel("time (s)")
        axes[-1].grid(alpha=0.3)
        c = prop.chosen
        what = "proposed" if prop.separates else "best found (does not separate them)"
        fig.suptitle(f"{prop.pair[0]} or {prop.pair[1]}? {what}: {c.candidate.label}\n"
                     f"predicted separation after the rival re-fits {c.worst or 0.0:.2f} "
                     "(worse rmse/noise over better, minus one)", fontsize=10)
        tight_layout(fig)
    return fig
