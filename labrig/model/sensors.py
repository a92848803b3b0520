"""What a sensor reads of the simulated motion: the model's outputs as the rig's channels
see them."""
from __future__ import annotations

import numpy as np


def windowed_speed(w: np.ndarray, window: int, dt: float,
                   travel: np.ndarray | None = None) -> np.ndarray:
    """The speed a moving window of ``window`` samples reads (a count over the window, one
    sample's included): the travel over the last ``window`` sample periods over
    ``window * dt``, the shaft at rest before the run. It reads half a window late, and
    smooth. ``travel``: the shaft's angle at each sample as the simulation integrated it
    (the exact travel: a motor faster than the sample period bends within one), else the
    trapezoid integral of ``w``."""
    w = np.asarray(w, float)
    if travel is None:
        travel = np.zeros(w.shape)
        travel[..., 1:] = np.cumsum(0.5 * (w[..., 1:] + w[..., :-1]), axis=-1) * dt
    else:
        travel = np.asarray(travel, float) - np.asarray(travel, float)[..., :1]
    before = np.zeros(w.shape)
    before[..., window:] = travel[..., :-window]
    return (travel - before) / (window * dt)
