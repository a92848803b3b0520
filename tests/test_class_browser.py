"""A class on one server in real browsers: two students and an instructor, each logged in
from a headless Chromium context of their own (their own cookies, as at three PCs),
against `labrig class serve` on simulated benches and on the emulated board.

Seats, isolation (tried by guessing addresses and names and by editing the page's own
requests), the instructor's live view, Stop and grading. Screenshots are kept in
tests/artefacts/ to look at.
"""
from __future__ import annotations

import csv
import io
import re
import time

import numpy as np
import pytest
import requests

from class_room import PASSWORDS, ClassProc, write_class
from lab_page import Page

pytestmark = [pytest.mark.slow, pytest.mark.browser]

#: a Bokeh widget of the page found by its css class, made clickable again in the browser
#: (as an edited request would): the server must refuse what it asks, not the button
ENABLE = r"""cls => { let n = 0;
  for (const d of Bokeh.documents) for (const m of d.all_models)
    if (m.css_classes && m.css_classes.includes(cls)) { m.disabled = false; n++; }
  return n; }"""


#: ana's sweep (2 periods at 0.25 Hz each)
SWEEP_V = ("1.00", "1.25", "1.50", "1.75", "2.00", "2.25", "2.50")


def _as(browser, server, who: str) -> Page:
    return Page(browser, server.url + "/", login=(who, PASSWORDS[who]),
                ready=".lab-class-header")


def _runs(folder) -> list[str]:
    return sorted(p.name for p in folder.glob("*.csv")) if folder.is_dir() else []


def test_two_students_and_an_instructor_share_a_class(browser, tmp_path):
    f = write_class(tmp_path)
    server = ClassProc(f)
    runs = tmp_path / "class_runs"
    pages = []
    try:
        # ana takes the first free bench and plays two runs
        ana = _as(browser, server, "ana")
        pages.append(ana)
        ana.click(".lab-take")
        ana.page.wait_for_selector(".lab-start", timeout=60000)
        ana.wait(lambda: "You hold bench1" in ana.text(".lab-seat"), 30, "ana's seat")
        # seven runs of 8.5 s: the instructor's Stop below lands mid-sweep however slow
        # the machine is between ana's start and kim's click (13 s here; CI's slower
        # machine once took longer than two runs)
        ana.page.locator(".lab-amplitudes input").fill(", ".join(SWEEP_V))
        ana.page.locator(".lab-periods input").first.fill("2")
        ana.click(".lab-start")
        ana.wait(lambda: "running" in ana.text(".lab-counters"), 60, "ana's sweep")

        # ben: bench1 is not offered; he watches it, read-only
        ben = _as(browser, server, "ben")
        pages.append(ben)
        ben.wait(lambda: "You hold no bench" in ben.text(".lab-seat"), 30, "ben's seat text")
        offered = ben.page.locator(".lab-bench-pick select option").all_inner_texts()
        assert "bench1" not in offered and "bench2" in offered, offered
        ben.wait(lambda: ben.page.locator(".lab-watch-pick select option").count() == 1, 30,
                 "bench1 offered to watch")
        ben.click(".lab-watch")
        ben.page.wait_for_selector(".lab-start", timeout=60000)
        ben.wait(lambda: "watching (read-only)" in ben.text(".lab-watch-area"), 30,
                 "the read-only banner")
        assert ben.page.locator(".lab-start button").first.is_disabled()
        # ben edits his page: the Stop and Save buttons he may not press (Save would write
        # into ana's folder), enabled and pressed
        enabled = ben.page.evaluate(ENABLE, "lab-stop") + ben.page.evaluate(ENABLE, "lab-save")
        assert enabled == 2
        time.sleep(0.5)
        ben.page.locator(".lab-stop button").first.click(force=True)
        ben.page.get_by_text("The loop", exact=True).first.click()
        ben.page.locator(".lab-save button").first.click(force=True)
        time.sleep(1.5)
        assert "running" in ana.text(".lab-counters")        # ana's sweep plays on
        ben.shot("class_watching")

        # ben guesses addresses: nothing but his own page, no file of ana's
        cookies = {c["name"]: c["value"] for c in ben._context.cookies()}
        for path in ("/bench1", "/class_runs/ana/bench1/sq_1.00V.csv", "/?bench=bench1",
                     "/static/../class_runs/ana/bench1/sq_1.00V.csv", "/admin", "/ana"):
            r = requests.get(server.url + path, cookies=cookies, allow_redirects=False,
                             timeout=30)
            assert r.status_code in (200, 404) and "sq_1.00V" not in r.text, (path, r.status_code)
            assert "time,u" not in r.text, path

        # the instructor sees both benches live
        kim = _as(browser, server, "kim")
        pages.append(kim)
        kim.wait(lambda: re.search(r"bench1 .*ana .*playing sq_\d\.\d\dV",
                                   kim.text(".lab-class-table")), 60, "bench1 playing")
        row = kim.text(".lab-class-table")
        assert re.search(r"bench2 .* free", row), row
        # ben takes bench2 (a free one, by name) and plays a run of his own
        ben.page.locator(".lab-bench-pick select").select_option("bench2")
        ben.click(".lab-take")
        ben.wait(lambda: "You hold bench2" in ben.text(".lab-seat"), 30, "ben's bench")
        kim.wait(lambda: re.search(r"bench2 .*ben", kim.text(".lab-class-table")), 30,
                 "bench2 held by ben")
        # kim watches bench1 read-only, then stops it: ana's sweep ends at 0 V
        kim.page.locator(".lab-bench-pick select").select_option("bench1")
        kim.click(".lab-watch")
        kim.page.wait_for_selector(".lab-start", timeout=60000)
        assert kim.page.locator(".lab-start button").first.is_disabled()
        ana.wait(lambda: "sq_1.00V" in ana.text(".lab-runs"), 60, "ana's first run")
        kim.shot("class_instructor_watching")
        kim.click(".lab-bench-stop")
        ana.wait(lambda: "stopped" in ana.text(".lab-sweep-note"), 30, "the stop")
        assert "output is at 0 V" in ana.text(".lab-sweep-note")
        kim.wait(lambda: re.search(r"bench1 .*ana .*idle", kim.text(".lab-class-table")), 30,
                 "bench1 idle")
        ana.shot("class_student_stopped")

        # ana closes the loop once: the instructor's table shows her rung
        ana.fit_the_linear_model()
        ana.wait(lambda: "rmse" in ana.text(".lab-rmse"), 300, "ana's fit")
        kim.wait(lambda: re.search(r"bench1 .*linear model \d", kim.text(".lab-class-table")),
                 60, "ana's rung in the instructor's table")

        # grading: the batch over every student's folder that holds runs
        kim.click(".lab-grade")
        kim.wait(lambda: "ana bench1 ok" in kim.text(".lab-grades"), 600, "the grading")
        assert "1 ok, 0 failed" in kim.text(".lab-grade-note")
        assert " ok " in kim.text(".lab-grades")
        with kim.page.expect_download() as dl:
            kim.page.locator(".lab-grades-csv a, .lab-grades-csv button").first.click()
        rows = list(csv.DictReader(io.StringIO(open(dl.value.path()).read())))
        assert [(r["student"], r["bench"], r["status"]) for r in rows] == [
            ("ana", "bench1", "ok")], rows
        assert float(rows[0]["rmse_over_noise"]) < 3 and rows[0]["effects"], rows
        kim.shot("class_instructor")
        # ana releases her bench: it is free again
        ana.click(".lab-release")
        kim.wait(lambda: re.search(r"bench1 .*free", kim.text(".lab-class-table")), 30,
                 "bench1 free again")
        for p in pages:
            p.close()
    finally:
        server.stop()
    # each student's runs in their own folder, whole; nothing of one in the other's
    # the runs finished before the Stop, whole; the one it ended is not kept
    kept = _runs(runs / "ana" / "bench1")
    sweep = [f"sq_{v}V.csv" for v in SWEEP_V]
    assert kept and kept == sweep[:len(kept)] and len(kept) < len(sweep), kept
    assert _runs(runs / "ben" / "bench2") == [] and not (runs / "ben" / "bench1").exists()
    log = server.log.read_text()
    refused = [line for line in log.splitlines() if "refused: ben" in line]
    assert any("asked to stop" in line for line in refused), refused
    assert any("asked to save" in line for line in refused), refused
    assert "kim stopped bench1 (rig at 0 V)" in log
    assert "ana's booking of bench1 ended: released (rig at 0 V)" in log
    assert all(pw not in log for pw in PASSWORDS.values())


def test_a_class_that_does_not_share_keeps_each_bench_to_its_student(browser, tmp_path):
    """``watch = false``: a student sees no other bench, and a watch asked for by an
    edited page is refused on the server."""
    server = ClassProc(write_class(tmp_path, watch=False))
    try:
        ana = _as(browser, server, "ana")
        ana.click(".lab-take")
        ana.page.wait_for_selector(".lab-start", timeout=60000)
        ben = _as(browser, server, "ben")
        assert not ben.page.locator(".lab-watch button").first.is_visible()
        ben.page.evaluate(r"""() => { for (const d of Bokeh.documents)
            for (const m of d.all_models) if (m.css_classes && m.css_classes.includes(
            "lab-watch")) { m.visible = true; m.disabled = false; } }""")
        time.sleep(0.5)
        ben.page.locator(".lab-watch button").first.click(force=True)
        time.sleep(1.5)
        assert ben.page.locator(".lab-start").count() == 0     # no bench on his page
        ana.close()
        ben.close()
    finally:
        server.stop()
    assert "refused: ben asked to watch" in server.log.read_text()


@pytest.mark.firmware
def test_a_student_on_the_emulated_board_in_a_class(browser, tmp_path):
    """A bench that is the real firmware in simavr: a student's run comes in live and
    lands whole in her folder; the instructor sees the bench play."""
    import shutil

    if not (shutil.which("avr-gcc") and shutil.which("simavr")):
        pytest.skip("needs avr-gcc and simavr (CI installs them)")
    server = ClassProc(write_class(tmp_path, benches=("emu",), kinds={"emu": "emulate"}))
    try:
        # (both pages open before the run: on this machine the browsers share the two
        # cores with the emulator, which must keep real time; in a room they are elsewhere)
        kim = _as(browser, server, "kim")
        ana = _as(browser, server, "ana")
        ana.click(".lab-take")
        ana.page.wait_for_selector(".lab-start", timeout=60000)
        ana.page.locator(".lab-amplitudes input").fill("1.5")
        # two periods (8.5 s): the instructor's table, refreshed twice a second, sees it
        # play however slow the machine
        ana.page.locator(".lab-periods input").first.fill("2")
        time.sleep(3)   # the bench's fitting process started with the booking
        ana.click(".lab-start")
        kim.wait(lambda: re.search(r"emu .*emulated board.*ana .*playing",
                                   kim.text(".lab-class-table")), 60, "the bench playing")
        ana.wait(lambda: "sq_1.50V" in ana.text(".lab-runs"), 120, "the run on disk")
        ana.shot("class_emulated")
        ana.close()
        kim.close()
    finally:
        server.stop()
    from labrig.io.runs import read_run

    run = read_run(tmp_path / "class_runs" / "ana" / "emu" / "sq_1.50V.csv")
    lost = np.flatnonzero(run.data["gap"].to_numpy()) if "gap" in run.data else []
    assert len(run) == 8500 and len(lost) == 0, (
        f"{len(lost)} samples lost, from {lost[0] if len(lost) else '-'}; the server said: "
        + server.log.read_text()[-1500:])
