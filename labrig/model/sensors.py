"""What a sensor reads of the simulated motion: the model's outputs as the rig's channels
see them."""
from __future__ import annotations

import numpy as np


def windowed_speed(w: np.ndarray, window: int, dt: float) -> np.ndarray:
    """The speed a moving window of ``window`` samples reads: the travel over the last
    ``window`` sample periods (the trapezoid integral of ``w``) over ``window * dt``, the
    shaft at rest before the run. It reads half a window late, and smooth."""
    w = np.asarray(w, float)
    travel = np.zeros(w.shape)
    travel[..., 1:] = np.cumsum(0.5 * (w[..., 1:] + w[..., :-1]), axis=-1) * dt
    before = np.zeros(w.shape)
    before[..., window:] = travel[..., :-window]
    return (travel - before) / (window * dt)
