"""A class's stations taking turns for the server's cores."""
from __future__ import annotations

import collections
import threading


class Turns:
    """Stations taking turns for the server's cores, first come first served: the jobs
    running hold at most ``slots`` cores, the others wait in the order they were asked (a
    class's fits queued fairly: no student's click waits behind another's next one). A
    job holds one core, or its ``cores_held`` (a grading's processes); the first waiting job
    starts only when its cores are free, and none behind it overtakes it.

    Parameters
    ----------
    slots : int
        Cores the jobs share (the class file's ``cores``, or the server's).
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
            used = sum(self._cores(s) for s in self._running)
            while self._waiting and used + self._cores(self._waiting[0]) <= self.slots:
                st = self._waiting.popleft()
                if st.start_waiting():
                    self._running.append(st)
                    used += self._cores(st)

    def _cores(self, job) -> int:
        return min(max(1, int(getattr(job, "cores_held", 1))), self.slots)

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
