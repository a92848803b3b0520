"""A class's stations taking turns for the server's cores."""
from __future__ import annotations

import collections
import threading


class Turns:
    """Stations taking turns for the server's cores, first come first served: at most
    ``slots`` jobs run at once, the others wait in the order they were asked (a class's
    fits queued fairly: no student's click waits behind another's next one).

    Parameters
    ----------
    slots : int
        Jobs run at once (the server's cores).
    """

    def __init__(self, slots: int):
        self.slots = max(1, int(slots))
        self._running: list = []
        self._waiting: collections.deque = collections.deque()
        self._lock = threading.Lock()

    def ask(self, station) -> None:
        """``station`` has a job waiting: its turn now if a core is free, else later."""
        with self._lock:
            if station not in self._waiting:
                self._waiting.append(station)
        self.tick()

    def tick(self) -> None:
        """Free the turns of finished jobs and start the next waiting ones (the server's
        timer and the pages call this; cheap)."""
        with self._lock:
            self._running = [s for s in self._running if s.worker.busy]
            while len(self._running) < self.slots and self._waiting:
                st = self._waiting.popleft()
                if st.start_waiting():
                    self._running.append(st)

    def ahead(self, station) -> int:
        """Jobs before ``station``'s: the running ones and those waiting before it."""
        with self._lock:
            waiting = list(self._waiting)
            k = waiting.index(station) if station in waiting else 0
            return len(self._running) + k

    def forget(self, station) -> None:
        with self._lock:
            if station in self._waiting:
                self._waiting.remove(station)
