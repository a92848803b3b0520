"""Seats: who holds which bench, and until when.

A student takes a free bench (or the first free one), holds it until they release it or
the booking's time ends; one bench per student, one student per bench. Pure bookkeeping
(no rig, no page), safe to call from the server's callbacks and its timer at once.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from labrig.core.errors import UserError


class SeatTaken(UserError):
    """The bench asked for is held by someone else, or none is free."""


@dataclass(frozen=True)
class Booking:
    """A student's hold on a bench: from ``start`` to ``until`` (seconds, the clock's)."""

    student: str
    bench: str
    start: float
    until: float

    def left_s(self, now: float) -> float:
        return max(0.0, self.until - now)


class Seats:
    """The class's bookings.

    Parameters
    ----------
    benches : list of str
        The benches' names, in the order a free one is given.
    minutes : float
        How long a booking lasts.
    clock : callable, optional
        Seconds now (default :func:`time.time`; a test passes its own).

    Examples
    --------
    >>> t = [0.0]
    >>> seats = Seats(["b1", "b2"], minutes=45, clock=lambda: t[0])
    >>> seats.take("ana").bench
    'b1'
    >>> seats.take("ben", "b1")
    Traceback (most recent call last):
    ...
    labrig.classroom.seats.SeatTaken: b1 is taken; choose a free bench (b2)
    >>> t[0] = 45 * 60
    >>> [b.student for b in seats.expired()]
    ['ana']
    """

    def __init__(self, benches, minutes: float, clock=time.time):
        self.benches = list(benches)
        self.minutes = float(minutes)
        self.clock = clock
        self._by_bench: dict[str, Booking] = {}
        self._lock = threading.Lock()

    def free(self) -> list[str]:
        with self._lock:
            return [b for b in self.benches if b not in self._by_bench]

    def holder(self, bench: str) -> Booking | None:
        with self._lock:
            return self._by_bench.get(bench)

    def of(self, student: str) -> Booking | None:
        """The student's booking, if they hold a bench."""
        with self._lock:
            return next((b for b in self._by_bench.values() if b.student == student), None)

    def take(self, student: str, bench: str | None = None) -> Booking:
        """Book ``bench`` (default the first free one) for ``student``.

        Raises
        ------
        SeatTaken
            ``bench`` is held by another student, ``student`` holds another bench, or
            no bench is free.
        KeyError
            No bench of that name.
        """
        with self._lock:
            if bench is not None and bench not in self.benches:
                raise KeyError(bench)
            mine = next((b for b in self._by_bench.values() if b.student == student), None)
            if mine is not None:
                if bench in (None, mine.bench):
                    return mine
                raise SeatTaken(f"you hold {mine.bench}; release it before taking {bench}")
            free = [b for b in self.benches if b not in self._by_bench]
            if bench is None:
                if not free:
                    raise SeatTaken("every bench is taken; wait for one to be released")
                bench = free[0]
            elif bench not in free:
                raise SeatTaken(f"{bench} is taken; choose a free bench "
                                f"({', '.join(free) or 'none is free now'})")
            now = self.clock()
            booking = Booking(student, bench, now, now + 60 * self.minutes)
            self._by_bench[bench] = booking
            return booking

    def release(self, student: str) -> Booking | None:
        """End ``student``'s booking; the booking ended, or None if they held nothing."""
        with self._lock:
            for bench, b in list(self._by_bench.items()):
                if b.student == student:
                    return self._by_bench.pop(bench)
        return None

    def expired(self) -> list[Booking]:
        """End and return the bookings whose time is up."""
        now = self.clock()
        with self._lock:
            ended = [b for b in self._by_bench.values() if now >= b.until]
            for b in ended:
                del self._by_bench[b.bench]
        return ended
