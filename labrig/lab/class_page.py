"""The class pages: a student's seat and bench, and the instructor's view of every bench.

Thin views over :class:`~labrig.lab.class_server.ClassServer`: a student takes a bench
and drives it on the lab page (:class:`~labrig.lab.page.LabPage`, the same components as
``labrig lab``), watches another bench read-only when the class allows it, and releases
the bench; an instructor sees every bench live, watches any one read-only, stops it or
ends its booking, and grades the class's folders with the batch. Every action is checked
here, on the server, against who is logged in (a page's requests can be edited); every
refusal is one line in the server's log.
"""
from __future__ import annotations

import io
import time

import panel as pn

from labrig.classroom.seats import SeatTaken
from labrig.core.tables import Table, table_html
from labrig.lab.page import LabPage
from labrig.lab.words import esc, set_text

#: the seat's and the overview's words are redrawn every this many page refreshes
SLOW_EVERY = 5
ANY_BENCH = "the first free bench"


class _ClassView:
    """What both pages share: the header, one error line, a watched bench, the expiry."""

    def __init__(self, server, user: str, session: str, alive, stop_refresh=lambda: None):
        self.srv, self.user, self.session, self._alive = server, user, session, alive
        self.watched: LabPage | None = None
        self._tick = 0
        #: the login grew too old: the page has stopped for good (:meth:`expire`)
        self.expired = False
        #: ends the page's periodic refresh (given by the server that added it)
        self.stop_refresh = stop_refresh
        self.error = pn.pane.Alert("", alert_type="danger", visible=False,
                                   css_classes=["lab-class-error"])
        self.area = pn.Column(sizing_mode="stretch_width")
        self.watch_area = pn.Column(sizing_mode="stretch_width", css_classes=["lab-watch-area"])
        room = server.room
        self.header = pn.pane.Markdown(
            f"## {esc(room.name)}\nlogged in as **{user}** ({room.role(user)}) · "
            f"[log out](/logout)", css_classes=["lab-class-header"])

    def refused(self, what: str) -> None:
        self.srv.log(f"refused: {self.user} asked to {what} ({self.session[:8]})")

    def _may_act(self, what: str) -> bool:
        """False (refused, logged) once the login has expired: an action's message can
        still come from a page that no longer shows its button."""
        if self.expired or not self._alive():
            self.refused(f"{what} after the login expired")
            return False
        return True

    def _say(self, text: str) -> None:
        self.error.object, self.error.visible = text, bool(text)

    def watch(self, bench: str | None) -> None:
        """Open ``bench``'s lab page below, read-only (its actions refused and logged)."""
        if not self._may_act("watch a bench"):
            return
        b = self.srv.benches.get(bench or "")
        if b is None or b.station is None:
            return self._say(f"{bench}: no one is on that bench now")
        self._unwatch()
        self.watched = LabPage(b.station, self.session, may_drive=False, refused=self.refused)
        b.watchers.add(self.session)
        self.watch_area.objects = [pn.pane.Markdown(f"### Watching {b.name} "
                                                    f"({b.booking.student}), read-only"),
                                   self.watched.view]

    def _unwatch(self) -> None:
        if self.watched is not None:
            for b in self.srv.benches.values():
                b.watchers.discard(self.session)
            self.watched = None
            self.watch_area.objects = []

    def refresh(self) -> None:
        if self.expired:
            return
        self._tick += 1
        if self._tick % SLOW_EVERY == 1 and not self._alive():
            return self.expire()
        if self.watched is not None:
            if not any(b.station is self.watched.st for b in self.srv.benches.values()):
                self._unwatch()     # the booking watched has ended
            else:
                self.watched.refresh()

    def expire(self) -> None:
        """The login is too old: the page stops for good -- its refresh ended, its actions
        refused, a rig it drove stopped at 0 V and let go, never claimed again from it."""
        if self.expired:
            return
        self.expired = True
        self.stop_refresh()
        self.srv.log(f"{self.user}'s login expired; the page is closed ({self.session[:8]})")
        self.closed()
        self.view.objects = [pn.pane.Alert("Your login has expired: [log in again](/login).",
                                           alert_type="warning")]

    def closed(self) -> None:
        self._unwatch()


class StudentPage(_ClassView):
    """A student's page: take a bench, drive it, release it; watch another (if allowed)."""

    def __init__(self, server, user, session, alive=lambda: True):
        super().__init__(server, user, session, alive)
        self.lab: LabPage | None = None
        self.seat = pn.pane.Markdown("", css_classes=["lab-seat"])
        self.bench_pick = pn.widgets.Select(name="bench", options=[ANY_BENCH], width=200,
                                            css_classes=["lab-bench-pick"])
        self.take_btn = pn.widgets.Button(name="Take the bench", button_type="primary",
                                          css_classes=["lab-take"])
        self.release_btn = pn.widgets.Button(name="Release it", css_classes=["lab-release"])
        self.take_btn.on_click(lambda e: self._take(self.bench_pick.value))
        self.release_btn.on_click(lambda e: self._release())
        controls = [self.bench_pick, self.take_btn, self.release_btn]
        self.watch_pick = pn.widgets.Select(name="watch a bench (read-only)", options=[],
                                            width=200, css_classes=["lab-watch-pick"],
                                            visible=server.room.watch)
        self.watch_btn = pn.widgets.Button(name="Watch", css_classes=["lab-watch"],
                                           visible=server.room.watch)
        self.watch_btn.on_click(lambda e: self.watch(self.watch_pick.value))
        controls += [self.watch_pick, self.watch_btn]
        self.view = pn.Column(self.header, self.error, pn.Row(*controls), self.seat,
                              self.area, self.watch_area, sizing_mode="stretch_width")
        if server.station_of(user) is not None:   # a page opened again keeps the bench
            self._open(server.station_of(user))
        self._paint_seat()

    def _take(self, bench) -> None:
        if not self._may_act("take a bench"):
            return
        self._say("")
        try:
            st = self.srv.take(self.user, None if bench in (None, ANY_BENCH) else bench)
        except SeatTaken as exc:
            self.refused(f"take {bench}: {exc}")
            return self._say(str(exc))
        except KeyError:
            self.refused(f"take a bench that does not exist ({str(bench)[:40]!r})")
            return self._say(f"no bench called {str(bench)[:40]}")
        self._open(st)

    def _open(self, station) -> None:
        if self.lab is not None and self.lab.st is station:
            return
        self.lab = LabPage(station, self.session, refused=self.refused)
        self.area.objects = [self.lab.view]

    def _release(self) -> None:
        if not self._may_act("release the bench") or self.srv.seats.of(self.user) is None:
            return
        self.srv.later(self.srv.release, self.user)   # (a station's stop: off the loop)

    def watch(self, bench) -> None:
        if not self.srv.room.watch:
            return self.refused(f"watch {str(bench)[:40]} (this class does not allow it)")
        mine = self.srv.seats.of(self.user)
        if mine is not None and mine.bench == bench:
            return
        super().watch(bench)

    def _paint_seat(self) -> None:
        mine = self.srv.seats.of(self.user)
        free = self.srv.seats.free()
        if mine is None:
            text = ("You hold no bench: take one. " if free else
                    "Every bench is taken; one frees when its booking ends. ")
        else:
            left = mine.left_s(self.srv.seats.clock()) / 60
            until = time.strftime("%H:%M", time.localtime(mine.until))
            text = (f"You hold **{mine.bench}** until {until} ({left:.0f} min left). Your "
                    f"runs: `{self.srv.room.seat_folder(self.user, mine.bench)}`. ")
        set_text(self.seat, text + self._ended_note())
        options = [ANY_BENCH, *free]
        if self.bench_pick.options != options:
            self.bench_pick.options = options
        held = [name for name, bench in self.srv.benches.items() if bench.station is not None
                and (mine is None or name != mine.bench)]
        if self.watch_pick.options != held:
            self.watch_pick.options = held
        self.take_btn.disabled = mine is not None or not free
        self.release_btn.disabled = mine is None

    def _ended_note(self) -> str:
        if self.lab is None:
            return ""
        for b in self.srv.benches.values():
            if b.ended and b.ended[0] == self.user:
                return f"Your last booking ended ({b.name}: {b.ended[1]})."
        return ""

    def refresh(self) -> None:
        super().refresh()
        if self.expired:   # (never opens, so never claims, the bench again)
            return
        st = self.srv.station_of(self.user)
        if self.lab is not None and self.lab.st is not st:   # the booking ended
            self.lab = None
            self.area.objects = []
        if self.lab is None and st is not None:
            self._open(st)
        if self.lab is not None:
            self.lab.refresh()
        if self._tick % SLOW_EVERY == 1:
            self._paint_seat()

    def closed(self) -> None:
        super().closed()
        if self.lab is not None:   # the page that drove the rig is gone: stop at 0 V
            self.lab.may_drive = False    # and never claims it again from this page
            self.lab.set_owner(False)
            self.srv.later(self.lab.st.release, self.session)


class InstructorPage(_ClassView):
    """Every bench at a glance, live; watch, stop or end any booking; grade the class."""

    def __init__(self, server, user, session, alive=lambda: True):
        super().__init__(server, user, session, alive)
        names = list(server.benches)
        self.table = pn.pane.HTML("", sizing_mode="stretch_width",
                                  css_classes=["lab-class-table"])
        self.bench_pick = pn.widgets.Select(name="bench", options=names, width=160,
                                            css_classes=["lab-bench-pick"])
        self.watch_btn = pn.widgets.Button(name="Watch", css_classes=["lab-watch"])
        self.stop_btn = pn.widgets.Button(name="Stop the bench", button_type="danger",
                                          css_classes=["lab-bench-stop"])
        self.end_btn = pn.widgets.Button(name="End the booking", button_type="warning",
                                         css_classes=["lab-bench-end"])
        self.watch_btn.on_click(lambda e: self.watch(self.bench_pick.value))
        self.stop_btn.on_click(lambda e: self._stop(self.bench_pick.value))
        self.end_btn.on_click(lambda e: self._end(self.bench_pick.value))
        self.task = pn.widgets.RadioButtonGroup(
            name="grade with", options={"diagnose --auto": "diagnose",
                                        "mystery check": "check"},
            value="diagnose", button_type="light", css_classes=["lab-grade-task"])
        self.grade_btn = pn.widgets.Button(name="Grade the class", button_type="primary",
                                           css_classes=["lab-grade"])
        self.grade_btn.on_click(lambda e: self._grade())
        self.grade_note = pn.pane.Markdown("", css_classes=["lab-grade-note"])
        self.grades = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["lab-grades"])
        self.csv = pn.widgets.FileDownload(callback=self._csv, filename="grades.csv",
                                           label="Download the table (CSV)",
                                           css_classes=["lab-grades-csv"], visible=False)
        self._graded_shown = None
        self.view = pn.Column(
            self.header, self.error, pn.pane.Markdown("### The benches"), self.table,
            pn.Row(self.bench_pick, self.watch_btn, self.stop_btn, self.end_btn),
            pn.pane.Markdown("### Grade the class's folders"),
            pn.Row(self.task, self.grade_btn), self.grade_note, self.grades, self.csv,
            self.watch_area, sizing_mode="stretch_width")
        self._paint()

    def _bench(self, name):
        if name not in self.srv.benches:
            self.refused(f"act on a bench that does not exist ({str(name)[:40]!r})")
            return None
        return name

    def _stop(self, name) -> None:
        if self._may_act("stop a bench") and self._bench(name):
            self.srv.later(self.srv.stop_bench, name, by=self.user)

    def _end(self, name) -> None:
        if self._may_act("end a booking") and self._bench(name):
            booking = self.srv.seats.holder(name)
            if booking is not None:
                self.srv.later(self.srv.release, booking.student,
                               why=f"ended by {self.user}")

    def _grade(self) -> None:
        if not self._may_act("grade the class"):
            return
        task = self.task.value if self.task.value in ("diagnose", "check") else "diagnose"
        self.srv.grade(task, by=self.user)

    def _csv(self):
        return io.StringIO("" if self.srv.graded is None else
                           self.srv.grades().to_csv(index=False))

    def _paint(self) -> None:
        rows = self.srv.overview()
        t = Table("every bench, live", ["bench", "rig", "student", "min left", "now", "last rung", "rmse/noise",
                   "watching", "note"],
                  [[r["bench"], r["rig"], r["student"] or "-",
                    "-" if r["minutes_left"] is None else f"{r['minutes_left']:.0f}",
                    r["state"], r["rung"] or "-",
                    "-" if r["rmse_over_noise"] is None else f"{r['rmse_over_noise']:.2f}",
                    str(r["watchers"]), r["note"] or ""] for r in rows])
        html = table_html(t)
        if self.table.object != html:
            self.table.object = html
        set_text(self.grade_note, self.srv.grade_note)
        res = self.srv.graded
        if res is not None and res is not self._graded_shown:
            self._graded_shown = res
            self.grades.object = self.srv.grades().to_html(index=False, na_rep="-",
                                                           float_format="%.4g")
            self.csv.visible = True
        self.grade_btn.disabled = self.srv.grading

    def refresh(self) -> None:
        super().refresh()
        if not self.expired and self._tick % SLOW_EVERY == 1:
            self._paint()
