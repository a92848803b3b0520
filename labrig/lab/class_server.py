"""A class on one server: the room's benches, the seats on them, a station per booking.

The state behind the class pages, with no page in it. Each bench is reached as
``labrig lab`` reaches its rig (:func:`labrig.verbs.open_bridge`: the simulated rig, the
emulated board, or a board on this PC, its port held by this process for as long as the
server runs); a student's booking gets a :class:`~labrig.lab.station.Station` on the
bench whose folder is the student's own (``<class folder>/<student>/<bench>/``). Ending a
booking (released, expired, or ended by an instructor) stops the rig as Ctrl-C does
(STOP, ZERO; the finished runs kept) and closes the station.
"""
from __future__ import annotations

import os
import shutil
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
import time
from dataclasses import dataclass, field
from pathlib import Path

import labrig.verbs as lr
from labrig.classroom.batch import run_batch
from labrig.classroom.certs import security
from labrig.classroom.remote import RemoteBench, Scheduler
from labrig.classroom.roster import ClassRoom
from labrig.classroom.seats import Booking, Seats
from labrig.lab.station import Station
from labrig.lab.turns import Turns


def server_log(line: str) -> None:
    """One line in the server's log (its standard error), stamped with the time."""
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S')} labrig class: {line}", file=sys.stderr,
          flush=True)


@dataclass
class Bench:
    """One bench of the room: how to reach its rig, and the station of its booking."""

    name: str
    kind: str
    rig: object
    make_bridge: object
    rig_name: str
    close: object
    station: Station | None = None
    booking: Booking | None = None
    #: how the bench's last booking ended: (student, what ended it and what was kept)
    ended: tuple = ()
    watchers: set = field(default_factory=set)
    #: a bench on another PC (its sweeps played there, through the class's scheduler)
    remote: RemoteBench | None = None

    @property
    def note(self) -> str:
        """How its last booking ended, in words (the instructor's table)."""
        return ": ".join(self.ended)


class ClassServer:
    """The benches, seats and stations of one class.

    Parameters
    ----------
    room : ClassRoom
        The class file, read (:func:`labrig.classroom.roster.read_class`).
    realtime : bool
        Pace the simulated benches to real time (as on the bench).
    log : callable
        Where the server's lines go (refusals, bookings, stops).
    """

    def __init__(self, room: ClassRoom, *, realtime: bool = True, log=server_log,
                 clock=time.time):
        self.room = room
        self.log = log
        self.realtime = realtime
        self.seats = Seats([b.name for b in room.benches], room.booking_minutes, clock=clock)
        self.benches: dict[str, Bench] = {}
        self._lock = threading.RLock()
        #: the cores the stations' fits and the grading share, first come first served
        self.cores = room.server.cores or os.cpu_count() or 1
        self.turns = Turns(self.cores)
        self.grading = False
        self.graded = None          # the last BatchResult
        self.grade_note = ""
        self.scheduler = None
        self._closing = threading.Event()
        self._timer: threading.Thread | None = None
        #: the changes pages ask for that stop a station (up to a dead link's timeouts):
        #: one thread, in the order asked, never the pages' event loop (:meth:`later`)
        self._changes = ThreadPoolExecutor(1, thread_name_prefix="labrig-class-change")
        try:
            if any(spec.rig == "remote" for spec in room.benches):
                self.scheduler = _scheduler(room)
            for spec in room.benches:
                rig = lr.load_rig(room.resolve(spec.rig_file))
                if spec.rig == "remote":
                    self.benches[spec.name] = Bench(
                        spec.name, spec.rig, rig, None, f"bench PC ({spec.name})",
                        lambda: None, remote=RemoteBench(self.scheduler, spec.name))
                    continue
                make, name, close = lr.open_bridge(rig, port=spec.port,
                                                   emulate=spec.rig == "emulate",
                                                   board_id=spec.board_id)
                self.benches[spec.name] = Bench(spec.name, spec.rig, rig, make, name, close)
        except BaseException:   # a board that cannot be held: the others are let go
            self.close()
            raise
        room.folder.mkdir(parents=True, exist_ok=True)

    # -- seats -----------------------------------------------------------------------
    def take(self, student: str, bench: str | None = None) -> Station:
        """Book a bench (the first free one by default) for ``student``: its station,
        on the student's folder."""
        with self._lock:
            booking = self.seats.take(student, bench)
            b = self.benches[booking.bench]
            if b.station is None or b.booking != booking:
                folder = self.room.seat_folder(student, b.name)
                folder.mkdir(parents=True, exist_ok=True)
                rig_file = self.room.resolve(self.room.bench(b.name).rig_file)
                if rig_file is not None and rig_file.suffix == ".mystery" \
                        and not (folder / rig_file.name).exists():
                    # a hand-in holds its mystery file (what `batch check` scores against)
                    shutil.copyfile(rig_file, folder / rig_file.name)
                b.station = Station(folder, b.rig, b.make_bridge, rig_name=b.rig_name,
                                    realtime=self.realtime and b.kind == "sim",
                                    remote=b.remote, threads=1)   # one core a booking
                b.station.cores = self.turns   # the class's fits take turns
                b.booking, b.ended = booking, ()
                self.log(f"{student} took {b.name} until "
                         f"{time.strftime('%H:%M', time.localtime(booking.until))}")
            return b.station

    def station_of(self, student: str) -> Station | None:
        booking = self.seats.of(student)
        return None if booking is None else self.benches[booking.bench].station

    def release(self, student: str, why: str = "released") -> None:
        """End ``student``'s booking: the rig stopped at 0 V, the finished runs kept."""
        with self._lock:
            booking = self.seats.release(student)
            if booking is not None:
                self._end(booking, why)

    def expire(self) -> None:
        """End the bookings whose time is up (the server's timer calls this), and pass
        on the turns of fits whose page is gone. Under the server's lock from taking the
        bookings out of the seats to their stations closed: no page takes a bench between."""
        self.turns.tick()
        with self._lock:
            for booking in self.seats.expired():
                self._end(booking, "the booking's time ended")

    def start_timer(self, period_s: float = 1.0) -> None:
        """Every ``period_s``, in a thread of its own: the bookings' expiry (stopping a
        station takes up to seconds, which the pages' event loop must not wait) and the
        benches on other PCs asked of the scheduler (:meth:`online` only reads the
        answer). Ended by :meth:`close`."""
        def tick():
            while not self._closing.wait(period_s):
                try:
                    self.expire()
                    self._ask_online()
                except Exception as exc:   # a tick's failure is said; the next one runs
                    self.log(f"the server's timer: {type(exc).__name__}: {exc}")

        self._timer = threading.Thread(target=tick, name="labrig-class-timer", daemon=True)
        self._timer.start()

    def _end(self, booking: Booking, why: str) -> None:
        b = self.benches[booking.bench]
        st, b.station, b.booking = b.station, None, None
        if st is not None:
            self.turns.forget(st)
            st.stop()           # STOP and ZERO; a run in progress is not written
            kept = len(st.runs_on_disk())
            st.close()
            b.ended = (booking.student, f"{why}; {kept} run(s) kept")
        self.log(f"{booking.student}'s booking of {b.name} ended: {why} (rig at 0 V)")

    def stop_bench(self, bench: str, by: str) -> None:
        """An instructor's Stop: the bench's sweep stops at 0 V (the booking stays)."""
        b = self.benches[bench]
        if b.station is not None:
            b.station.stop()
        self.log(f"{by} stopped {bench} (rig at 0 V)")

    # -- the instructor's view -------------------------------------------------------
    def overview(self) -> list[dict]:
        """A row per bench: who holds it, until when, what plays, the last rung."""
        now = self.seats.clock()
        online = self.online()
        rows = []
        for b in self.benches.values():
            st, bk = b.station, b.booking
            row = {"bench": b.name, "rig": b.rig_name, "student": bk.student if bk else "",
                   "minutes_left": round(bk.left_s(now) / 60, 1) if bk else None,
                   "state": ("not connected" if b.remote is not None and b.name not in online
                             else "free" if st is None else _state(st)),
                   "rung": "",
                   "rmse_over_noise": None, "note": b.note, "watchers": len(b.watchers)}
            if st is not None and st.rungs:
                r = st.rungs[-1]
                row["rung"] = ", ".join(r["effects"]) or "linear model"
                row["rmse_over_noise"] = r["rmse_over_noise"]["overall"]
            rows.append(row)
        return rows

    _online: tuple = (0.0, set())

    def online(self) -> set:
        """The benches on other PCs connected now, as the scheduler last said (asked once
        a second by the server's timer, :meth:`start_timer`; without one, asked here at
        most once a second)."""
        if self.scheduler is None:
            return set()
        if self._timer is None and time.monotonic() - self._online[0] > 1.0:
            self._ask_online()
        return self._online[1]

    def _ask_online(self) -> None:
        if self.scheduler is None:
            return
        try:
            self._online = (time.monotonic(), self.scheduler.benches_online())
        except Exception:   # the scheduler busy or closing: the last answer stands
            pass

    def hand_ins(self) -> list:
        """Every student's bench folder that holds runs: what the grading reads."""
        out = []
        for s in self.room.students:
            for b in self.room.benches:
                f = self.room.seat_folder(s, b.name)
                if f.is_dir() and any(f.glob("*.csv")):
                    out.append(f)
        return out

    def grade(self, task: str = "diagnose", by: str = "") -> None:
        """The class's folders through the batch (``labrig batch diagnose``, or
        ``check`` for mystery rigs), in the background: two processes (joblib) of one
        thread each, taking their turn for two of the class's cores like the benches'
        fits, so the pages keep their pace. The result lands on :attr:`graded`."""
        with self._lock:
            if self.grading:
                return
            self.grading, self.grade_note = True, f"grading ({task}): waiting for its cores"
        folders = self.hand_ins()
        self.log(f"{by} graded {len(folders)} folder(s) with batch {task}")
        jobs = min(2, self.cores)

        def work():
            try:
                if not folders:
                    self.graded, self.grade_note = None, "no runs in any student's folder yet"
                    return
                self.grade_note = f"grading ({task})"
                self.graded = run_batch(task, folders, options={"seed": 0}, jobs=jobs,
                                        threads=1)
                self.grade_note = (f"{task}: {self.graded.folders - self.graded.failed} ok, "
                                   f"{self.graded.failed} failed")
            except Exception as exc:   # one line on the page, like any error of the batch
                self.graded, self.grade_note = None, f"error: {str(exc).splitlines()[0]}"
            finally:
                self.grading = False

        self.turns.ask(_Turn(work, jobs))

    def grades(self):
        """The last grading as a table (pandas): a row per student and bench, the
        batch's key figures, no paths of this machine."""
        df = self.graded.to_pandas().drop(columns=["name"])
        seat = [Path(f).relative_to(self.room.folder).parts for f in df["folder"]]
        df.insert(0, "student", [p[0] for p in seat])
        df.insert(1, "bench", [p[1] for p in seat])
        return df.drop(columns=["folder"])

    def later(self, fn, *args, **kw) -> None:
        """``fn(*args, **kw)`` on the server's change thread, after the changes asked
        before it: a page's Release, an instructor's Stop or End stops a station at 0 V,
        which must not hold the pages' event loop. A failure is one line in the log."""
        def change():
            try:
                fn(*args, **kw)
            except Exception as exc:
                self.log(f"{getattr(fn, '__name__', 'a change')} failed: "
                         f"{type(exc).__name__}: {exc}")

        self._changes.submit(change)

    def close(self) -> None:
        """Every station stopped at 0 V and closed; every bench let go (ports, emulators)."""
        self._closing.set()
        self._changes.shutdown(wait=True)   # (the changes asked before: done first)
        if self._timer is not None:
            self._timer.join(timeout=30)
        for b in self.benches.values():
            if b.station is not None:
                b.station.close()
                b.station = None
            b.close()
        if self.scheduler is not None:
            self.scheduler.close()


class _Turn:
    """A job of the server's own (the grading) in the class's turns for the cores: it
    holds ``cores_held`` while its thread runs (:class:`~labrig.lab.turns.Turns`)."""

    def __init__(self, work, cores: int):
        self.work, self.cores_held = work, cores
        self._thread: threading.Thread | None = None
        self.worker = self   # (the turns ask a job's worker whether it is busy)

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start_waiting(self) -> bool:
        self._thread = threading.Thread(target=self.work, name="labrig-grade", daemon=True)
        self._thread.start()
        return True


def _scheduler(room: ClassRoom):
    """The class's Dask scheduler for its bench PCs: TLS only, the class's certificates."""
    sec = security(room.resolve(room.server.certs), "server")   # its scheduler and client
    return Scheduler(room.server.host, room.server.dask_port, sec, sec)


def _state(st: Station) -> str:
    if st.sweeping:
        live = st.live
        return f"playing {live.name} ({live.samples}/{live.n_planned})"
    if st.worker.busy:
        return f"fitting ({st.worker.name})"
    return "idle"
