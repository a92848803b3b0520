"""The lab station without a browser: bad input ends as one line, the rig untouched."""
from __future__ import annotations

import time
from pathlib import Path

import pytest

pytest.importorskip("panel")


def test_an_unplugged_board_is_one_line_and_the_sweep_ends(tmp_path):
    from labrig.io.config import load_plan
    from labrig.lab.serve import make_station

    st = make_station(tmp_path, port=str(tmp_path / "ttyNONE"))
    try:
        st.start_sweep(load_plan(None, st.rig)[:1])
        t0 = time.monotonic()
        while st.sweeping and time.monotonic() - t0 < 30:
            time.sleep(0.1)
        assert not st.sweeping
        assert st.sweep_note.startswith("error: cannot open") and "\n" not in st.sweep_note
        assert not list(tmp_path.glob("*.csv"))
    finally:
        st.close()


def test_the_plan_form_says_what_is_wrong_beside_its_field(tmp_path):
    from labrig.io.config import load_rig
    from labrig.lab.plan_form import PlanForm

    form = PlanForm(load_rig())
    for value, field, words in (("1.2, nan", "amplitudes", "finite number"),
                                ("3.0", "amplitudes", "exceeds the output limit"),
                                ("abc", "amplitudes", "not a list of numbers")):
        form.w["amplitudes"].value = value
        assert form.plan() is None
        shown = [k for k, m in form.msg.items() if m.visible]
        assert shown == [field] and words in form.msg[field].object
    form.w["amplitudes"].value = "1.2"
    form.w["frequency"].value = 5000.0
    assert form.plan() is None and form.msg["frequency"].visible


def test_a_proposal_that_separates_nothing_is_not_played(tmp_path):
    """When no input within the budget separates the pair, the proposal has no plan: the
    station refuses to play it, in one line, and no run is started."""
    from labrig.core.errors import LabrigError
    from labrig.lab.serve import make_station

    st = make_station(tmp_path, port=str(tmp_path / "ttyNONE"))
    try:
        st.proposal = {"plan": None, "text": "nothing within 20 s ... separates them"}
        st.predict("deadband", "it coasts")
        with pytest.raises(LabrigError, match="nothing to play"):
            st.play_proposal()
        assert not st.sweeping and not (tmp_path / "asked").exists()
    finally:
        st.close()


def _poll_until(st, cond, timeout=300):
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout, "the station's jobs did not finish"
        st.poll()
        time.sleep(0.02)


@pytest.mark.slow
def test_a_fit_shows_the_worst_run_first_and_a_click_overtakes_the_rest(tmp_path, rig):
    """Fit the linear model: the rung comes back with the model on its worst run only (each
    overlay costs about half a second to draw); the diagnosis and the ladder come next,
    then the model on the other runs, one run per job, in the background. A click while
    they are drawn waits for one figure, not for all of them."""
    from conftest import sim_dataset, square_plan
    from labrig.lab.serve import make_station

    folder = sim_dataset(tmp_path, rig, square_plan(amps=(1.2, 1.6, 2.0), periods=1), seed=1)
    st = make_station(folder, port=str(tmp_path / "ttyNONE"))
    try:
        st.fit_linear()
        _poll_until(st, lambda: bool(st.rungs))
        r = st.rungs[0]
        assert list(r["overlays"]) == [r["worst"]] and len(r["runs"]) == 3
        st.wanted = [n for n in r["runs"] if n != r["worst"]][-1]   # the page shows this one
        assert st.diagnosis is None and st.worker.name == "diagnose"
        _poll_until(st, lambda: st.ladder is not None)
        assert st.diagnosis is not None
        assert st.drawing() and not st.busy()      # the buttons are free while it draws
        st.add("coulomb_friction")
        assert st.busy() and st.drawing()          # queued behind the figure in hand
        _poll_until(st, lambda: len(st.rungs) == 2)
        assert sorted(st.rungs[0]["overlays"]) == sorted([r["worst"], st.wanted])  # + in hand
        assert st.rungs[1]["effects"] == ["coulomb_friction"]
        _poll_until(st, st.idle)
        r = st.rungs[1]
        assert sorted(r["overlays"]) == sorted(r["runs"])
        assert all(png[:8] == b"\x89PNG\r\n\x1a\n" for png in r["overlays"].values())
    finally:
        st.close()


@pytest.mark.slow
def test_the_ranking_forms_on_the_page_as_the_candidates_come_back(tmp_path, rig):
    """While the diagnosis runs, each candidate arrives as its re-fit is done and again
    with its held-out error: the page's ranking forms before the job ends, and ends with
    the numbers of the finished diagnosis."""
    from conftest import sim_dataset, square_plan
    from labrig.lab.words import forming_html
    from labrig.lab.serve import make_station

    folder = sim_dataset(tmp_path, rig, square_plan(amps=(1.2, 1.6, 2.0), periods=1), seed=1)
    st = make_station(folder, port=str(tmp_path / "ttyNONE"))
    try:
        st.fit_linear()
        _poll_until(st, lambda: bool(st.rungs))
        during = []
        while st.diagnosis is None:
            st.poll()
            if st.worker.name == "diagnose" and st.worker.busy:
                during.append(len(st.stream))
            time.sleep(0.05)
        name, seen = st.streamed
        assert name == "diagnose"
        kinds = [e["kind"] for e in seen]
        assert any(0 < n < len(seen) for n in during)     # it grew while the job ran
        # every row's re-fit arrived (again when a family member's re-fit took its place:
        # the last one is what the ranking keeps)
        assert {e["label"] for e in seen if e["kind"] == "fitted"} == \
            {r["label"] for r in st.diagnosis["rows"]}
        assert kinds.count("validated") == sum(r["cross_validated"] is not None
                                               for r in st.diagnosis["rows"])
        for row in st.diagnosis["rows"]:
            last = [e for e in seen if e["label"] == row["label"]][-1]
            assert last["rmse_over_noise"] == pytest.approx(row["rmse_over_noise"], rel=1e-12)
            if row["cross_validated"] is not None:
                assert last["cross_validated"] == pytest.approx(row["cross_validated"],
                                                                rel=1e-12)
        assert "the ranking as it forms" in forming_html(seen)
    finally:
        st.close()


def test_the_hand_view_in_a_notebook_is_the_library(tmp_path):
    """``hand_view`` (the page's *Try it by hand* as a notebook component): a slider's
    move gives ``lr.compare``'s rmse/noise for the model with that value; an effect tried
    unfitted; *Fit from here* takes the error to the floor."""
    import labrig.verbs as lr
    from labrig.lab.explore import hand_view

    data = str(Path(__file__).resolve().parent.parent / "data" / "sweep_default")
    m0 = lr.model_of(lr.identify(data, seed=0))
    ex = hand_view(data, m0)
    assert ex.ev.metrics == lr.compare(data, m0).metrics
    slider = next(s for s in ex.sliders.objects if "lab-param-J" in s.css_classes)
    slider.value = slider.value * 1.5
    moved = m0.with_value("J", ex.model.params["J"])
    assert ex.model.params["J"] == pytest.approx(1.5 * m0.params["J"], rel=1e-9)
    shown = float(ex.number.object.split()[2])
    assert shown == pytest.approx(
        lr.compare(data, moved).metrics["rmse_over_noise"]["overall"], abs=0.005)
    assert "set by hand" in ex.number.object
    ex.try_pick.value = "coulomb_friction"
    ex.try_btn.clicks += 1
    assert ex.model.names == ["coulomb_friction"] and "lab-param-coulomb-friction-tc-v" in \
        " ".join(c for s in ex.sliders.objects for c in s.css_classes)
    ex.fit_btn.clicks += 1
    assert ex.ev.metrics["rmse_over_noise"]["overall"] < 1.1 and ex.model is ex.fitted


@pytest.mark.slow
def test_asking_until_sure_stopped_mid_step_keeps_what_was_finished(tmp_path):
    """Ask until sure on the station, its page closed while the first step plays on the
    rig (in real time): the rig is stopped, the step ends without a run (a run on disk is
    never half-written), the asking's job is answered at once and ends saying where it was
    stopped, and the folders the loop fits are the station's own, unchanged."""
    from conftest import labrig
    from labrig.lab.serve import make_station

    folder = tmp_path / "runs"
    labrig("sweep", "--sim", "--plan", Path(__file__).resolve().parent.parent / "configs" /
           "plan_two_steps.toml", "-o", folder, check=0)
    st = make_station(folder)
    try:
        st.fit_linear()
        _poll_until(st, st.idle)
        pair = ",".join(st.diagnosis["pairs"][0]["pair"])
        st.claim("page")
        st.ask_until_sure(pair)
        _poll_until(st, lambda: st.sweeping)     # the first step plays
        time.sleep(1.0)
        st.release("page")                       # the page closed
        assert not st.sweeping and st._rig_request is None
        _poll_until(st, lambda: st.asking is not None)
        assert "the rig was stopped during step 1" in st.asking["text"]
        assert not st.asking["json"]["steps"] and not st.asking["json"]["sure"]
        assert not list((folder / "asked" / "step1").glob("*.csv"))
        assert st.folders() == [folder]
    finally:
        st.close()


@pytest.mark.slow
def test_the_hand_view_waits_for_the_diagnosis_and_a_cancel_still_builds_it(tmp_path, rig):
    """A new rung's sliders are built once its diagnosis and ladder are in (built beside
    the diagnosis they took a core from it); when the student cancels the diagnosis, the
    hand view is built from the rung all the same."""
    from conftest import sim_dataset, square_plan
    from labrig.lab.page import LabPage
    from labrig.lab.serve import make_station

    folder = sim_dataset(tmp_path, rig, square_plan(amps=(1.2, 1.6), periods=1), seed=1)
    st = make_station(folder, port=str(tmp_path / "ttyNONE"))
    try:
        page = LabPage(st, "local")
        st.fit_linear()
        t0 = time.monotonic()
        while not (st.rungs and st.worker.name == "diagnose" and st.worker.busy):
            assert time.monotonic() - t0 < 300, "the fit did not come back"
            page.refresh()
            time.sleep(0.02)
        page.refresh()
        assert page.explore.model is None          # the diagnosis has the cores
        assert "rmse/noise" in page.now.object     # the rung's number is shown at once
        st.cancel()
        page.refresh()
        assert page.explore.model is not None
        assert page.explore.model.params == st.rungs[-1]["model"]["params"]
    finally:
        st.close()


@pytest.mark.slow
def test_a_diagnosis_that_places_the_model_better_offers_that_model_as_the_next_rung(tmp_path):
    """Nothing left to add, but the candidates' re-fits found better values of the model's
    own parameters (the EMPS-shaped twin, its search's model with M 10 % heavier): the
    station offers the model ``labrig diagnose -o`` writes, and taking it makes it the
    next rung as it stands, with the error lower than the model it replaces."""
    from dataclasses import replace

    from conftest import labrig
    from twin import emps_like_axis

    import labrig as lr
    from labrig.diagnosis.loop.search import search
    from labrig.io.runs import read_dataset
    from labrig.lab import jobs
    from labrig.lab.page import LabPage
    from labrig.lab.serve import make_station

    src = emps_like_axis(tmp_path / "export")
    folder = tmp_path / "runs"
    labrig("import", src, "-o", folder, "--map", "t=t,u=vir,pos=qm", "--axis", "linear",
           "--drive", "force", "--input-gain", "35.15065", "--pos-unit", "m", check=0)
    runs = read_dataset(folder)
    auto = search(runs).model
    bent = replace(auto, params={**auto.params, "M": 1.1 * auto.params["M"]})
    st = make_station(folder, port=str(tmp_path / "ttyNONE"))
    try:
        with pytest.raises(lr.LabrigError, match="no better values"):
            st.take_refined()                          # no diagnosis yet
        st.submit("fit", jobs.take, [folder], bent.to_json())
        _poll_until(st, lambda: st.diagnosis is not None)
        d = st.diagnosis
        assert d["recommendation"] is None and d["refined"] is not None, d["verdict"]
        assert "re-fitted to better values" in d["verdict"]
        cli = lr.diagnose(runs, bent).recommended_model()     # what diagnose -o writes
        assert st.rungs[0]["model"]["params"]["M"] == pytest.approx(bent.params["M"])
        page = LabPage(st, "s1")     # the page's own components: its button offers it
        page.refresh()
        assert page.refined_btn.visible and not page.refined_btn.disabled
        watcher = LabPage(st, "s2", may_drive=False)
        watcher.refined_btn.clicks += 1                # a watcher's click: refused
        assert st.idle() and len(st.rungs) == 1
        page.refined_btn.clicks += 1
        _poll_until(st, lambda: len(st.rungs) == 2)
        taken = st.rungs[1]
        for k in ("M", "Fv"):
            assert taken["model"]["params"][k] == pytest.approx(cli.params[k], rel=1e-9), k
            assert taken["model"]["params"][k] == pytest.approx(auto.params[k], rel=0.02), k
        assert taken["fit"] is None and sorted(taken["effects"]) == sorted(auto.names)
        before, after = (r["rmse_over_noise"]["overall"] for r in st.rungs)
        assert after < before
        _poll_until(st, st.idle)
        page.refresh()
        assert page.refined_btn.visible == (st.diagnosis["refined"] is not None)
    finally:
        st.close()


def test_the_station_says_what_its_folder_holds_and_plays_only_its_own_rig_into_it(tmp_path):
    """A folder of imported recordings (a sketch's u,count log at 200 Hz): the page heads
    itself with the runs' source file, drive and sensor, apart from the rig that would play;
    a sweep into that folder is refused in one line before the rig moves (the folder's fit
    would be of two systems), and nothing is written. A folder of this rig's own sweeps
    plays on."""
    import numpy as np

    from conftest import labrig
    from labrig.io.config import load_plan
    from labrig.core.errors import UserError
    from labrig.lab.page import LabPage
    from labrig.lab.serve import make_station

    folder = tmp_path / "imported"
    log = tmp_path / "log.csv"
    counts = np.cumsum(np.r_[np.zeros(40), np.full(360, 4)]).astype(int)
    log.write_text("u,count\n" + "".join(f"{0 if k < 40 else 6.0},{c}\n"
                                         for k, c in enumerate(counts)))
    labrig("import", log, "--map", "u=u,pos=count", "--pos-unit", "counts:1320",
           "--gear-ratio", "30", "--rate", "200", "-o", folder, check=0)
    st = make_station(folder, realtime=False)
    try:
        said = st.holds()
        assert said == ("1 run imported from log.csv (voltage drive, rotary; encoder, "
                        "1320 counts per turn)"), said
        why = st.foreign()
        assert str(folder) in why and "another folder" in why and st.rig.name in why
        with pytest.raises(UserError, match="holds runs this rig did not play"):
            st.start_sweep(load_plan(None, st.rig)[:1])
        assert not st.sweeping and sorted(p.name for p in folder.glob("*.csv")) == ["log.csv"]
        page = LabPage(st, "s-1")
        assert "imported from log.csv" in page.heading.object
        assert f"rig that plays: {st.rig_name}" in page.heading.object
        assert page.sweep_note.object == why
        page._on_start(None)   # the button: the same line on the page, nothing played
        assert "holds runs this rig did not play" in page._page_error and not st.sweeping
    finally:
        st.close()
    own, plan = tmp_path / "own", tmp_path / "one.toml"
    plan.write_text('[[experiment]]\nloop = "open"\nwaveform = "step"\namplitude_v = 1.5\n'
                    'duration_s = 1.0\nsample_rate_hz = 200.0\n')
    labrig("sweep", "--sim", "-o", own, "--plan", plan, check=0)
    st = make_station(own, realtime=False)
    try:
        assert st.holds() == f"1 run swept on '{st.rig.name}'" and st.foreign() == ""
    finally:
        st.close()
