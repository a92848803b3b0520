"""The exact zero-order hold of the servo's linear part, per candidate: the state matrix
(states i, w, theta), its voltage and friction-torque columns, and their discretisation
over one sample whose input switches at a fractional delay."""
from __future__ import annotations

import numpy as np

from labrig.simulation.expm import zoh_batch
from labrig.simulation.layout import C_KE


def plant_matrices(prm):
    """The open-loop state matrix of every candidate, the voltage's and the friction
    torque's input columns (states i, w, theta)."""
    P = prm.shape[0]
    R, L, J, B, K = (prm[:, i] for i in range(5))
    A = np.zeros((P, 3, 3))
    A[:, 0, 0], A[:, 0, 1] = -R / L, -prm[:, C_KE] / L
    A[:, 1, 0], A[:, 1, 1] = K / J, -B / J
    A[:, 2, 1] = 1.0
    bs = np.zeros((P, 3))
    bs[:, 0] = 1.0 / L
    bf = np.zeros((P, 3))
    bf[:, 1] = -1.0 / J
    return A, bs, bf


def zoh(A, bs, bf, frac, h):
    """Exact ZOH of x' = A x + bs s + bf Tf over one sample whose input switches from
    s_old to s_new at ``frac`` of it (a fractional delay): Ad, g_old, g_new, g_f."""
    return zoh_batch(np.ascontiguousarray(A), np.ascontiguousarray(bs),
                     np.ascontiguousarray(bf), np.ascontiguousarray(frac, dtype=float), float(h))


def discretise(prm, run, frac):
    """Exact ZOH of the linear part per candidate, with the delay's split sample.

    Inputs of the continuous model: s (armature volts in open loop, reference volts
    in closed loop) and the friction torque Tf.
    """
    A, bs, bf = plant_matrices(prm)
    L = prm[:, 1]
    if run.loop == "closed" and run.pd is None:   # (a board's loop drives the plant open)
        # e = kp r - kv Kt w - kp Kpot theta_m / N ; v = Ka e
        A[:, 0, 1] -= run.Ka * run.kv * run.Kt / L
        A[:, 0, 2] -= run.Ka * run.kp * run.Kpot / run.N / L
        bs = bs * run.Ka * run.kp
    return zoh(A, bs, bf, frac, run.dt)
