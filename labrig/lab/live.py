"""The run coming in, as the lab page shows it: decimated points per channel, the
bridge's counters, and the points a page has not shown yet."""
from __future__ import annotations

import collections
import itertools
import threading
from dataclasses import dataclass, field

import numpy as np

#: samples kept for the live view per channel (decimated for display only)
LIVE_POINTS = 4000


@dataclass
class Live:
    """The run coming in: decimated for the view; counters as the bridge reports them."""

    name: str = ""
    n_planned: int = 0
    t: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LIVE_POINTS))
    u: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LIVE_POINTS))
    speed: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LIVE_POINTS))
    pos: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LIVE_POINTS))
    samples: int = 0
    counters: dict = field(default_factory=dict)
    #: points appended so far (the deques keep the last LIVE_POINTS): a page sends only
    #: the points it has not shown (:meth:`since`)
    points: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def since(self, shown: int) -> tuple[dict, int]:
        """The points after the first ``shown`` (at most the last LIVE_POINTS), as
        arrays per channel, and the count now; taken under the lock the sweep appends
        under, so the channels stay the same length."""
        with self.lock:
            k = min(max(self.points - shown, 0), len(self.t))
            cols = {"t": _tail(self.t, k), "u": _tail(self.u, k)}
            for key in ("speed", "pos"):
                d = getattr(self, key)
                cols[key] = _tail(d, k) if d else np.zeros(k)
            return cols, self.points


def _tail(d: collections.deque, k: int) -> np.ndarray:
    """The last ``k`` items of ``d``."""
    return np.fromiter(itertools.islice(d, len(d) - k, None), float, k)
