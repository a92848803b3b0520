"""The first-order fit of one edge, as :func:`labrig.analysis.edges.fit_edge` returns it."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class StepFit:
    """The outcome of :func:`labrig.analysis.edges.fit_edge` for one edge.

    Attributes
    ----------
    y0, y1 : float or None
        Initial and final speed (rad/s): fitted, or the guesses when nothing was fitted.
    tau, td : float or None
        Time constant and dead time of the fit (s); None when nothing was fitted.
    tau63 : float or None
        Time from the edge to 63 % of the change in the (smoothed) data (s).
    nrmse : float or None
        RMS residual relative to the speed change.
    seg_dur : float or None
        Time the input is held after the edge (s).
    s, w, model : ndarray or None
        Time from the edge (s), measured speed and fitted speed, for the figure.
    too_short, no_response : bool
        Nothing was fitted: fewer than six samples, or no speed change.
    error : str or None
        The optimiser's error message when it raised.
    not_settled, poor_fit : bool
        Conditions of a fit that ran (see :class:`~labrig.analysis.EdgeFit`).
    tau_bound : str
        The bound of the search tau sits at ("lower", "upper"), "" if none;
        ``tau_at_bound`` says whether it does.
    """

    y0: float | None = None
    y1: float | None = None
    tau: float | None = None
    td: float | None = None
    tau63: float | None = None
    nrmse: float | None = None
    seg_dur: float | None = None
    s: np.ndarray | None = field(default=None, repr=False)
    w: np.ndarray | None = field(default=None, repr=False)
    model: np.ndarray | None = field(default=None, repr=False)
    too_short: bool = False
    no_response: bool = False
    error: str | None = None
    not_settled: bool = False
    #: which bound tau sits at: "lower" (a quarter sample) or "upper" (20 segment
    #: lengths); "" if none
    tau_bound: str = ""
    poor_fit: bool = False

    @property
    def tau_at_bound(self) -> bool:
        return bool(self.tau_bound)

    @property
    def ran(self) -> bool:
        """A time constant was fitted (accepted or not)."""
        return self.tau is not None

    @property
    def accepted(self) -> bool:
        """Fitted, settled within the segment and not stuck at a bound."""
        return self.ran and not self.not_settled and not self.tau_at_bound
