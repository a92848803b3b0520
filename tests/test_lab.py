"""The lab station in a real browser: headless Chromium (Debian's, driven by Playwright)
against `labrig lab` served on 127.0.0.1.

Every page here fails its test on any request that leaves the machine (a script, style,
font or icon from a CDN). Screenshots are kept in tests/artefacts/ to look at.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import labrig
from lab_page import ARTEFACTS, DRAWN, DRAWN_READY, WORDS, Page, free_port, stop_process

ROOT = Path(__file__).resolve().parent.parent

pytestmark = [pytest.mark.slow, pytest.mark.browser]

class Server:
    """`labrig lab` in a subprocess; ended with Ctrl-C (SIGINT) by its PID."""

    def __init__(self, folder: Path, *flags, cwd: Path = ROOT):
        self.port = free_port()
        env = {**__import__("os").environ, "PYTHONPATH": str(ROOT)}
        # the server's own log (a page callback's error lands there), kept to look at
        ARTEFACTS.mkdir(exist_ok=True)
        self.log = ARTEFACTS / f"lab_server_{self.port}.log"
        self._err = open(self.log, "w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "labrig", "lab", str(folder), "--no-browser",
             "--http-port", str(self.port), *flags],
            stdout=subprocess.PIPE, stderr=self._err, text=True, cwd=cwd, env=env)
        line = self.proc.stdout.readline()
        assert "http://127.0.0.1" in line, line + self.log.read_text()
        self.url = re.search(r"http://\S+/", line).group(0)

    def stop(self) -> int:
        return stop_process(self.proc)


def test_a_run_streams_in_and_stop_keeps_every_finished_run(browser, tmp_path):
    folder = tmp_path / "bench"
    server = Server(folder)            # the simulated rig, paced to real time
    try:
        page = Page(browser, server.url)
        page.page.locator(".lab-amplitudes input").fill("1.2, 1.5, 2.0")
        page.click(".lab-start")
        # the run comes in while it plays, not at its end (how often the view refreshes is
        # measured by benchmarks/bench_lab.py, not asserted here)
        page.wait(lambda: "running" in page.text(".lab-counters"), 60, "the sweep to start")
        # watched for as long as the first run plays (4.5 s of rig time, longer on a slow
        # machine), not for a fixed time: a machine three times slower refreshes as often
        # per run, not per second
        seen, t0 = set(), time.monotonic()
        while "sq_1.20V" not in page.text(".lab-runs") and time.monotonic() - t0 < 60:
            seen.add(int(re.search(r"samples (\d+)/", page.text(".lab-counters")).group(1)))
            time.sleep(0.05)
        assert len({n for n in seen if 0 < n < 4500}) >= 3, seen
        page.wait(lambda: "sq_1.20V" in page.text(".lab-runs"), 60, "the first run on disk")
        page.shot("streaming")
        page.click(".lab-stop")
        page.wait(lambda: "stopped" in page.text(".lab-sweep-note"), 30, "the stop")
        note = page.text(".lab-sweep-note")
        assert "output is at 0 V" in note
        # Ctrl-C on the server in the middle of a run: it ends, the run is not written
        page.page.locator(".lab-amplitudes input").fill("2.5")
        page.click(".lab-start")
        page.wait(lambda: "running" in page.text(".lab-counters"), 60, "the second sweep")
        page.close()
    finally:
        assert server.stop() in (0, 130)
    written = sorted(p.name for p in folder.iterdir())
    assert "sq_1.20V.csv" in written and "sq_2.00V.csv" not in written
    assert "sq_2.50V.csv" not in written and "sq_2.50V.json" not in written
    assert not [n for n in written if n.endswith(".tmp")]
    from labrig.io.runs import read_run

    for csv in folder.glob("*.csv"):     # every run on disk is whole
        run = read_run(csv)
        assert len(run) == 4500 and "gap" not in run.data


def test_the_loop_on_one_page_agrees_with_the_cli(browser, tmp_path):
    folder = tmp_path / "runs"
    labrig("sweep", "--sim", "-o", folder, check=0)
    server = Server(folder, "--fast")
    try:
        page = Page(browser, server.url)
        watcher = Page(browser, server.url)     # a second page watches, read-only
        assert "read-only" in watcher.text(".bk-panel-models-markup-HTML") or \
            watcher.page.locator(".lab-start button").first.is_disabled()
        page.fit_the_linear_model()
        linear = page.number(".lab-rmse", r"rmse/noise ([\d.]+)")
        page.shot("linear")
        # the fit drew the model on the worst run; the others came after the diagnosis
        other = page.page.locator(".lab-run-pick select").first
        names = other.evaluate("s => Array.from(s.options).map(o => o.value)")
        assert len(names) == 6
        shown = other.evaluate("s => s.value")
        other.select_option(next(n for n in names if n != shown))
        page.wait(lambda: "drawing" not in page.text(".lab-compare-figure")
                  and page.page.locator(".lab-compare-figure img").count() == 1, 30, "the overlay")
        rec = re.search(r"recommendation: (\w+)", page.text(".lab-evidence")).group(1)
        # the same numbers from the command line, same data and seed
        m0 = tmp_path / "m0.json"
        cli = json.loads(labrig("identify", folder, "--seed", "0", "-o", m0, "--json",
                                check=0).stdout)
        assert linear == pytest.approx(cli["rmse_over_noise"]["overall"], abs=0.006)
        diag = json.loads(labrig("diagnose", folder, "--model", m0, "--json", check=0).stdout)
        assert rec == diag["recommendation"] == "coulomb_friction"
        top = diag["ranking"][0]
        ev = page.text(".lab-evidence")
        assert re.search(rf"{top['effect']}\s*{top['rmse_over_noise']:.2f}", ev)
        # the candidates the command line screens out, the page marks the same way
        screened = [c for c in diag["ranking"] if "screened_after_iterations" in c]
        assert screened and ev.count("screened out") == len(screened)
        page.click(".lab-add")                  # the recommended effect is selected
        page.idle()
        after = page.number(".lab-rmse", r"rmse/noise ([\d.]+)")
        assert "coulomb_friction" in page.text(".lab-rmse")
        assert after < 1.3 < linear
        # the ladder is the chain's last job (fit, diagnosis, ladder): wait for it, as
        # the quiet looks of idle() can fall between two of them on a busy machine
        page.wait(lambda: "+ coulomb_friction" in page.text(".lab-ladder"), 60, "the ladder")
        # the run on screen is drawn first once the new rung's diagnosis is in
        page.wait(lambda: page.page.locator(".lab-compare-figure img").count() == 1, 30, "the overlay")
        page.shot("loop")
        watcher.close()
        page.close()
    finally:
        server.stop()


def test_the_loop_by_hand_sliders_an_effect_tried_and_a_fit_from_there(browser, tmp_path):
    """The hand view of the loop: the fitted model's rmse/noise is the library's; a
    parameter's slider moved redraws the curves and the number (set by hand); an effect
    tried at a hand-set size, unfitted, then *Fit from here* takes the error to the floor.
    The page is served on a folder with a plain name, as the README's figure shows it."""
    labrig("sweep", "--sim", "-o", tmp_path / "runs", check=0)
    server = Server(Path("runs"), "--fast", cwd=tmp_path)
    try:
        page = Page(browser, server.url)
        assert "folder: runs" in page.page.locator("body").evaluate(WORDS)
        page.fit_the_linear_model()
        page.wait(lambda: "rmse/noise" in page.text(".lab-try-rmse"), 120, "the hand view")
        fitted = page.number(".lab-try-rmse", r"rmse/noise ([\d.]+)")
        assert fitted == page.number(".lab-rmse", r"rmse/noise ([\d.]+)")
        assert page.page.locator(".lab-param").count() == 5    # R, L, J, B, K
        handle = page.page.locator(".lab-param-J .noUi-handle").first
        # the hand view's figure reaches the browser after its numbers: wait for it, not
        # for a time (a loaded machine takes longer)
        page.wait(lambda: page.page.evaluate(DRAWN_READY), 60, "the hand view's figure")
        curve = page.page.evaluate(DRAWN)[4]
        handle.focus()
        for _ in range(20):
            handle.press("ArrowRight")
        page.wait(lambda: "by hand" in page.text(".lab-try-rmse"), 30, "the slider's move")
        shown = []   # every move drawn: the number stays put for a second
        page.wait(lambda: shown.append(page.text(".lab-try-rmse")) or
                  (len(shown) > 4 and len(set(shown[-5:])) == 1), 30, "the moves to settle")
        moved = page.number(".lab-try-rmse", r"rmse/noise ([\d.]+)")
        assert moved != fitted
        assert abs(page.page.evaluate(DRAWN)[4] - curve) > 1e-3 * abs(curve)   # the curve too
        # zoom into the overlay (the wheel over the speed figure): the time in view
        # narrows, and every sample in it is drawn (the whole run is drawn decimated)
        start, end, n, dt, _ = page.page.evaluate(DRAWN)
        assert end - start > 8.0 and dt == pytest.approx(0.009)   # 8.5 s at 1 kHz, 1 in 9
        canvas = page.page.locator(".lab-overlay canvas").first
        canvas.scroll_into_view_if_needed()
        box = canvas.bounding_box()
        page.page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        for _ in range(20):   # a reversal's second or so
            page.page.mouse.wheel(0, -100)
            page.page.wait_for_timeout(150)
            start, end, n, dt, _ = page.page.evaluate(DRAWN)
            if end - start < 1.0:
                break
        page.wait(lambda: page.page.evaluate(DRAWN)[3] < 0.0015, 30, "the samples zoomed into")
        start, end, n, dt, _ = page.page.evaluate(DRAWN)
        assert 0.2 < end - start < 1.0 and dt == pytest.approx(0.001)
        assert n >= (end - start) / dt   # the time in view, at every sample
        page.shot("zoomed")
        # the toolbar's reset: the whole run again, drawn one sample in nine
        page.page.locator(".lab-overlay .bk-tool-icon-reset").first.click()
        page.wait(lambda: page.page.evaluate(DRAWN)[3] > 0.005, 30, "the whole run again")
        start, end, n, dt, _ = page.page.evaluate(DRAWN)
        assert end - start > 8.0 and dt == pytest.approx(0.009)
        page.click(".lab-try-reset")
        page.wait(lambda: "by hand" not in page.text(".lab-try-rmse"), 30, "back to the fit")
        assert page.number(".lab-try-rmse", r"rmse/noise ([\d.]+)") == fitted
        page.page.locator(".lab-try-pick select").first.select_option("coulomb_friction")
        page.click(".lab-try-add")
        page.wait(lambda: "coulomb_friction" in page.text(".lab-try-rmse"), 30, "the tried effect")
        assert page.page.locator(".lab-param").count() == 6
        tried = page.number(".lab-try-rmse", r"rmse/noise ([\d.]+)")
        assert tried != fitted
        page.shot("by_hand")
        page.click(".lab-try-fit")
        page.idle()
        after = page.number(".lab-rmse", r"rmse/noise ([\d.]+)")
        assert "coulomb_friction" in page.text(".lab-rmse") and after < 1.3 < fitted
        page.wait(lambda: "coulomb_friction" in page.text(".lab-try-rmse")
                  and "by hand" not in page.text(".lab-try-rmse"), 60, "the new rung by hand")
        assert page.number(".lab-try-rmse", r"rmse/noise ([\d.]+)") == after
        page.shot("loop_readme")
        # at the floor nothing is confusable: Propose cannot act, looks it, and says why
        page.wait(lambda: "recommendation: none" in page.text(".lab-evidence"), 120,
                  "the new rung's diagnosis")
        # a click on a candidate's row of the ranking draws it on the runs
        canvas = page.page.locator(".lab-ranking-plot canvas").first
        # (the page redraws the ranking when its state changes: find it again if it went)
        for _ in range(10):
            try:
                canvas = page.page.locator(".lab-ranking-plot canvas").first
                canvas.scroll_into_view_if_needed(timeout=3000)
                box = canvas.bounding_box()
                break
            except Exception:
                page.page.wait_for_timeout(500)
        for y in range(40, int(box["height"]) - 30, 13):
            page.page.mouse.click(box["x"] + box["width"] * 0.6, box["y"] + y)
            page.page.wait_for_timeout(200)
            if "as the diagnosis re-fitted it" in page.text(".lab-try-rmse"):
                break
        page.wait(lambda: "as the diagnosis re-fitted it" in page.text(".lab-try-rmse"), 30,
                  "the clicked candidate's curves")
        tapped = page.page.locator(".lab-show-pick select").first.evaluate("s => s.value")
        assert tapped and tapped in page.text(".lab-try-rmse")
        # a candidate of the ranking, as the diagnosis re-fitted it, drawn on the runs
        pick = page.page.locator(".lab-show-pick select").first
        options = pick.evaluate("s => Array.from(s.options).map(o => o.value)")
        assert "- coulomb_friction" in options
        pick.select_option("- coulomb_friction")
        page.click(".lab-show")
        # (the clicked row above may be another candidate: wait for this one by name)
        page.wait(lambda: "- coulomb_friction, as the diagnosis re-fitted it"
                  in page.text(".lab-try-rmse"), 30, "the candidate's curves")
        assert page.number(".lab-try-rmse", r"rmse/noise ([\d.]+)") > 3.0   # friction gone
        assert page.page.locator(".lab-ladder-plot canvas").count() >= 1
        assert page.page.locator(".lab-ranking-plot canvas").count() >= 1
        page.page.get_by_text("Ask the rig", exact=True).click()
        page.wait(lambda: "nothing to ask" in page.text(".lab-ask-note"), 30, "the reason")
        assert page.page.locator(".lab-propose button").first.is_disabled()
        assert "--between" not in page.page.locator("body").evaluate(WORDS)
        page.close()
    finally:
        server.stop()


def test_the_search_shows_itself_as_it_climbs(browser, tmp_path):
    """Auto on the page: the rungs of the search appear while it runs, each one's model
    drawn on the runs by the hand view as it comes, the error falling before the job
    ends."""
    folder = tmp_path / "runs"
    labrig("sweep", "--sim", "-o", folder, check=0)
    server = Server(folder, "--fast")
    try:
        page = Page(browser, server.url)
        page.page.get_by_text("The loop", exact=True).click()
        page.click(".lab-auto")
        # the first round's candidates come in one by one, each with its error
        counts = set()
        page.wait(lambda: counts.add(int((re.findall(r"as it forms \((\d+) re-fitted",
                                                     page.text(".lab-forming")) or [0])[0]))
                  or len(counts - {0}) >= 2, 300, "the ranking growing while the search runs")
        assert "working" in page.text(".lab-status")
        page.wait(lambda: "the search so far" in page.text(".lab-forming"), 300,
                  "the first rung while the search runs")
        assert "working" in page.text(".lab-status")
        page.wait(lambda: "rmse/noise" in page.text(".lab-try-rmse"), 60, "the rung drawn")
        page.wait(lambda: page.text(".lab-forming").count("rung") >= 3, 300, "the second rung")
        rows = re.findall(r"rung (\d+): ([a-z_+ ]+?) ([\d.]+)", page.text(".lab-forming"))
        page.shot("search_climbing")
        # the error falling as the student watches: the linear rung above the floor, the
        # last one near it, and the hand view drawing the newest rung
        assert rows[0][1].strip() == "linear" and float(rows[0][2]) > 1.3 > float(rows[-1][2])
        page.wait(lambda: rows[-1][1].strip().split(" + ")[-1] in page.text(".lab-try-rmse"),
                  30, "the newest rung drawn")
        page.idle()
        assert page.number(".lab-rmse", r"rmse/noise ([\d.]+)") < 1.3
        page.close()
    finally:
        server.stop()


def _two_steps_on_the_ask_tab(browser, tmp_path):
    """The README's two steps from rest served, the linear model fitted, the Ask tab
    open: (folder, server, page)."""
    folder = tmp_path / "steps"
    labrig("sweep", "--sim", "--plan", ROOT / "configs" / "plan_two_steps.toml", "-o", folder,
           check=0)
    server = Server(folder, "--fast")
    try:
        page = Page(browser, server.url)
        page.fit_the_linear_model()
        page.page.get_by_text("Ask the rig", exact=True).click()
    except BaseException:
        server.stop()
        raise
    return folder, server, page


def test_ask_the_rig_from_the_page(browser, tmp_path):
    folder, server, page = _two_steps_on_the_ask_tab(browser, tmp_path)
    try:
        page.click(".lab-propose")
        page.idle()
        assert "proposed:" in page.text(".lab-proposal")
        page.page.locator(".lab-proposal img").first.wait_for()
        first = page.page.locator(".lab-which button").first
        first.click()
        page.page.locator(".lab-why input").fill("a dead zone lets it coast; friction brakes")
        page.click(".lab-predict")
        page.wait(lambda: "your prediction" in page.text(".lab-prediction"), 10, "prediction")
        page.wait(lambda: not page.page.locator(".lab-play button").first.is_disabled(), 10,
                  "Play to be enabled")
        page.click(".lab-play")
        page.wait(lambda: "the rig says" in page.text(".lab-decision"), 600, "the decision")
        assert "explains the data better" in page.text(".lab-decision")
        page.shot("ask_the_rig")
        page.close()
    finally:
        server.stop()
    assert list((folder / "asked").glob("proposed_1.csv"))


def test_a_proposal_through_the_rigs_own_loop_from_the_page(browser, tmp_path):
    """'through the loop' on the Ask tab: the proposal judges position steps played as
    the reference of the station's rig's analog loop (its rig file's gains: the two steps
    are open-loop runs), each named with its loop gain in the proposal's table."""
    folder, server, page = _two_steps_on_the_ask_tab(browser, tmp_path)
    try:
        page.page.locator(".lab-loop button", has_text="through the loop").click()
        page.click(".lab-propose")
        # the proposal's own text, not an idle status: on a machine 3x slower the job had
        # not started when the status was first read (a throttled run of the suite)
        page.wait(lambda: "position steps" in page.text(".lab-proposal"), 600, "the proposal")
        page.idle()
        text = page.text(".lab-proposal")
        assert "position steps" in text and "through the loop (kp 2)" in text, text
        assert "ramp through zero" not in text     # the open-loop inputs were not asked for
        page.shot("propose_through_the_loop")
        page.close()
    finally:
        server.stop()


def test_ask_until_sure_from_the_page(browser, tmp_path):
    """Ask the rig until sure on the page: the worker's job has the page's rig play each
    short experiment (streamed like a sweep) into asked/step<k>/, the verdict after each
    step shown as it comes, then the result: the friction the rig hides, in fewer rig
    seconds than the one-shot plan."""
    folder, server, page = _two_steps_on_the_ask_tab(browser, tmp_path)
    try:
        page.wait(lambda: not page.page.locator(".lab-ask-sure button").first.is_disabled(),
                  120, "Ask until sure to be enabled")
        page.click(".lab-ask-sure")
        seen = []
        page.wait(lambda: seen.append(page.text(".lab-asking")) or
                  "asked until sure" in seen[-1], 600, "the asking's result")
        assert any("the rig is playing it" in t for t in seen)   # each step streamed in
        text = page.text(".lab-asking")
        assert "sure: coulomb_friction explains the data" in text, text
        used, one = map(float, re.search(r"([\d.]+) s of rig time \(the one-shot plan: "
                                         r"([\d.]+) s\)", text).groups())
        assert used <= one
        # both explanations drawn on the step's run, their errors in the legend
        page.wait(lambda: page.page.locator(".lab-asking-plot canvas").count() >= 1, 30,
                  "both explanations drawn")
        page.shot("ask_until_sure")
        page.close()
    finally:
        server.stop()
    assert list((folder / "asked" / "step1").glob("step1.csv"))


def test_a_closed_page_stops_the_rig(browser, tmp_path):
    """The page that drives a sweep is closed mid-sweep: the server ends that session
    within ~6 s (checked every 1 s, kept 5 s) and the sweep stops (STOP, ZERO), keeping the
    finished runs; no more runs appear."""
    from labrig.lab.serve import CHECK_UNUSED_MS, UNUSED_LIFETIME_MS

    folder = tmp_path / "left"
    server = Server(folder)            # real time: six runs of 4.5 s would take 27 s
    try:
        page = Page(browser, server.url)
        page.page.locator(".lab-amplitudes input").fill("0.5, 0.7, 0.9, 1.1, 1.3, 1.5")
        page.page.locator(".lab-periods input").first.fill("1")
        page.click(".lab-start")
        page.wait(lambda: "running" in page.text(".lab-counters"), 60, "the sweep to start")
        page.close()
        time.sleep((CHECK_UNUSED_MS + UNUSED_LIFETIME_MS) / 1e3 + 2)   # the session ends
        first = sorted(p.name for p in folder.glob("*.csv"))
        time.sleep(9)                  # a sweep still running would write a run meanwhile
        assert sorted(p.name for p in folder.glob("*.csv")) == first
        assert len(first) < 4 and not list(folder.glob("*.tmp"))
    finally:
        server.stop()


def test_the_loop_on_runs_that_start_in_motion(browser, tmp_path):
    """A kit's recordings that start in motion (tests/twin.py), imported and opened in the
    lab: the page's fit and its added effect carry each run's fitted start, as the command
    line's do (the same rmse/noise), and the error falls to the floor."""
    from twin import kit_recordings

    folder = tmp_path / "runs"
    for src in kit_recordings(tmp_path / "logger"):
        labrig("import", src, "-o", folder, "--map", "t=t,u=u,speed=speed",
               "--waveform", "custom", check=0)
    server = Server(folder, "--fast")
    try:
        page = Page(browser, server.url)
        page.fit_the_linear_model()
        linear = page.number(".lab-rmse", r"rmse/noise ([\d.]+)")
        cli = json.loads(labrig("identify", folder, "--seed", "0", "--json", check=0).stdout)
        assert set(cli["starts"]) == {"prbs_2.5V", "prbs_3.5V", "prbs_4.5V", "step"}
        assert linear == pytest.approx(cli["rmse_over_noise"]["overall"], abs=0.006)
        page.click(".lab-add")                  # the recommended effect is selected
        page.idle()
        after = page.number(".lab-rmse", r"rmse/noise ([\d.]+)")
        assert after < 1.2 < linear
        page.wait(lambda: page.page.locator(".lab-compare-figure img").count() == 1, 30, "the overlay")
        page.shot("moving_start")
        page.close()
    finally:
        server.stop()
