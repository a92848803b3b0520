"""``labrig report``: one self-contained HTML page, readable in a browser and printable.

The page is rendered with headless Chromium (Debian's ``chromium`` package; CI installs
it) and the screenshot and the PDF print are checked. Without Chromium those two tests
are skipped; the HTML checks run anyway.
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from labrig.core.version import __version__
from labrig.io.experiment import Experiment

from conftest import labrig, make_rig, sim_dataset, square_plan

HEADINGS = ("1. The sweep", "2. Where the model fails", "3. Diagnosis: what is missing",
            "4. The error ladder", "5. First-order analysis", "6. Identified models")
HOSTILE = '<script>alert("x")</script> & friends'


def _chromium() -> str | None:
    for name in ("chromium", "/usr/bin/chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return None


CHROMIUM = _chromium()
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="headless Chromium not installed (Debian: apt-get install chromium)")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three short open-loop square waves and one closed-loop step at 500 Hz, with the
    default rig's Coulomb friction: a story with something for the diagnosis to find."""
    tmp = tmp_path_factory.mktemp("report")
    rig = make_rig(effects={"coulomb_friction": {"tc_v": 0.13}})
    plan = square_plan(amps=(1.2, 2.0, 2.5), rate=500.0, periods=1) + [
        Experiment(name="cl_0.50V", loop="closed", amplitude_v=0.5, frequency_hz=0.25,
                   periods=1, lead_in_s=0.5, sample_rate_hz=500.0, position_gain=2.0,
                   velocity_gain=0.15)]
    return sim_dataset(tmp, rig, plan, name="runs", seed=3)


def _fake_identification(method, runs, fitness, rig):
    """What `labrig identify --json` prints, small and by hand (no optimiser in the test)."""
    p = rig.plant
    return {"method": method, "effects": [], "effect_params": {}, "fixed": [],
            "params": {"R": p.R, "L": p.L, "J": p.J, "B": p.B, "K": p.K},
            "fitness": fitness,
            "rmse_over_noise": {"speed": fitness * 0.8, "position": fitness * 1.2, "overall": fitness},
            "fit_percent": {"speed": 97.5, "position": 96.1},
            "identifiable": {
                "km": {"value": 90.0, "unit": "rad/s per V", "identifiable": True,
                       "interval95": [89.9, 90.1]},
                "tau_m_s": {"value": 0.153, "unit": "s", "identifiable": True,
                            "interval95": [0.152, 0.154]},
                "tau_e_s": {"value": 1e-3, "unit": "s", "identifiable": False, "interval95": None},
                "parameters": {"R": {"value": p.R, "identifiable": False},
                               "K": {"value": p.K, "identifiable": True}},
                "warnings": ["structurally unidentifiable: R, L, J, B, K are one member of a "
                             "family"]},
            "nfev": 1234, "nit": 10, "seconds": 12.5, "seed": 7,
            "history": [3 * fitness, 2 * fitness, fitness],
            "step_info": {"rise_time_s": 0.7, "settling_time_s": 1.3, "overshoot_percent": 0.0},
            "noise": {"speed_rad_s": 0.45, "position_rad": 0.011},
            "per_run": {r: {"speed": fitness, "position": fitness} for r in runs}}


@pytest.fixture(scope="module")
def work(dataset):
    """A work folder as `labrig demo` leaves it, with small hand-made artefacts for the
    slow stages (identify --method all, diagnose, ladder); analyse is left to the report."""
    w = dataset.parent
    rig = make_rig()
    runs = sorted(p.stem for p in dataset.glob("*.csv"))
    jfo = _fake_identification("jfo", runs, 9.5, rig)
    pso = _fake_identification("pso", runs, 9.8, rig)
    co = _fake_identification("co", runs, 9.3, rig)
    (w / "identify_all.json").write_text(json.dumps(
        {**co, "method": "all", "best": "co", "results": {"jfo": jfo, "pso": pso, "co": co}}))
    ranking = [{"effect": "coulomb_friction", "rmse_over_noise": 1.1, "improvement": 0.88,
                "delta_bic": -11000.0, "params": {"tc_v": 0.129}, "supported": True,
                "cross_validated": {"baseline": 2.7, "with_effect": 1.1, "improvement": 0.6,
                                    "folds_improved": 4, "folds": 4, "evidence": []},
                "explanation": "Dry friction of brushes and bearings. " + HOSTILE},
               {"effect": "delay", "rmse_over_noise": 9.3, "improvement": -0.0, "delta_bic": 8.0,
                "params": {"td_s": 1e-4}, "supported": False, "explanation": "A delay."}]
    diag = {"baseline": {"source": "the given model", "effects": [], "fitness": 9.3,
                         "rmse_over_noise": {"speed": 7.2, "position": 11.1, "overall": 9.3}},
            "regimes": {"by_regime": {"speed": {"steady": {"rmse_over_noise": 7.4,
                                                           "share_of_error": 0.76,
                                                           "share_of_time": 0.72},
                                                "reversal": {"rmse_over_noise": 8.7,
                                                             "share_of_error": 0.24,
                                                             "share_of_time": 0.28}}},
                        "by_amplitude": {"speed": {"open 1.20 V": 9.2, "open 2.50 V": 8.6}},
                        "worst": {"channel": "speed", "regime": "reversal",
                                  "rmse_over_noise": 8.7}},
            "ranking": ranking, "recommendation": "coulomb_friction",
            "verdict": "Add coulomb_friction: " + HOSTILE,
            "cross_validation": {"kind": "leave-one-run-out", "folds": 4, "baseline": 2.7},
            "criteria": {"min_improvement": 0.05, "max_delta_bic": -10.0, "floor": 1.15},
            "seconds": 31.0}
    (w / "diagnosis.json").write_text(json.dumps(diag))
    steps = [{"label": "linear model", "effects": [],
              "rmse_over_noise": {"overall": 9.3, "speed": 7.2, "position": 11.1},
              "fit_percent": {"speed": 97.6, "position": 96.7}, "fitness": 9.3},
             {"label": "+ coulomb_friction", "effects": ["coulomb_friction"],
              "rmse_over_noise": {"overall": 1.1, "speed": 0.98, "position": 1.2},
              "fit_percent": {"speed": 99.7, "position": 99.6}, "fitness": 1.1}]
    (w / "ladder.json").write_text(json.dumps({"steps": steps}))
    return w


@pytest.fixture(scope="module")
def full_report(dataset, work):
    out = work / "report.html"
    proc = labrig("report", dataset, "-o", out, check=0)  # --work defaults to the parent
    assert "reading artefacts from" in proc.stderr
    return out


@pytest.fixture(scope="module")
def quick_report(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("quick") / "quick.html"
    labrig("report", dataset, "-o", out, "--quick", "--no-work", check=0)
    return out


def _check_self_contained(page: str):
    # nothing fetched from elsewhere: no external src/href/url(), every image inline
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", page, re.I)
    assert not re.search(r"url\(\s*['\"]?\s*(https?:)?//", page, re.I)
    assert not re.search(r"<(script|link|iframe|object|embed)\b", page, re.I)
    imgs = re.findall(r"<img\b[^>]*\bsrc=\"([^\"]*)\"", page)
    assert imgs, "no figures embedded"
    assert all(s.startswith("data:image/png;base64,") for s in imgs)
    assert "@media print" in page


def test_report_quick_computes_what_it_needs(quick_report, dataset):
    page = quick_report.read_text(encoding="utf-8")
    _check_self_contained(page)
    for h in HEADINGS:
        assert f">{h}</h2>" in page
    # the sweep table names every run; the analysis and a CO model were computed here
    for name in ("sq_1.20V", "sq_2.00V", "sq_2.50V", "cl_0.50V"):
        assert name in page
    assert "Table 1" in page and "K<sub>m</sub> = &omega;/V" in page
    assert "computed by this report" in page
    assert ">CO (best)</th>" in page
    assert "rmse/noise" in page
    # diagnosis and ladder say how to fill them
    assert page.count("skipped (--quick)") == 2
    assert "labrig diagnose" in page and "labrig ladder" in page
    assert len(re.findall(r"<img\b", page)) >= 5  # overview, analysis, convergence, regimes, worst run


def test_report_reads_the_work_folder(full_report):
    page = full_report.read_text(encoding="utf-8")
    _check_self_contained(page)
    for h in HEADINGS:
        assert f">{h}</h2>" in page
    # the loop first: the diagnosis and the ladder before the analysis' edge figures, and
    # the corrected model on the data beside the linear one
    assert page.index(">3. Diagnosis: what is missing</h2>") < \
        page.index(">5. First-order analysis</h2>")
    ladder = page[page.index(">4. The error ladder</h2>"):
                  page.index(">5. First-order analysis</h2>")]
    assert ": the linear model" in ladder and ": linear + " in ladder
    assert "Not in this report" not in page
    # JFO, PSO and CO side by side, CO best; artefacts named as the source
    assert ">JFO</th>" in page and ">PSO</th>" in page and ">CO (best)</th>" in page
    assert "identify_all.json" in page and "diagnosis.json" in page and "ladder.json" in page
    assert "Recommendation: coulomb_friction" in page
    assert "89.9" in page and "1234" in page  # an interval bound and nfev
    # text from files is escaped, never markup
    assert HOSTILE not in page and "<script>" not in page
    assert html_escaped(HOSTILE) in page
    assert f"<td>{__version__}</td>" in page  # version in the footer


def html_escaped(text):
    import html

    return html.escape(text, quote=True)


def test_report_user_errors(dataset, tmp_path):
    p = labrig("report", dataset, "-o", tmp_path / "r.html", "--work", tmp_path / "nope")
    assert p.returncode == 2 and "--work" in p.stderr
    p = labrig("report", tmp_path / "missing", "-o", tmp_path / "r.html")
    assert p.returncode == 2
    assert not (tmp_path / "r.html").exists()


def _chrome(*args, tmp):
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", "--hide-scrollbars", f"--user-data-dir={tmp / 'profile'}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


@needs_chromium
@pytest.mark.parametrize("which", ["full_report", "quick_report"])
def test_report_renders_in_chromium(which, request, tmp_path):
    from PIL import Image

    page = request.getfixturevalue(which)
    png = tmp_path / "shot.png"
    proc = _chrome(f"--screenshot={png}", "--window-size=1280,2400", page.resolve().as_uri(),
                   tmp=tmp_path)
    assert png.exists(), proc.stderr[-2000:]
    img = Image.open(png)
    assert img.format == "PNG" and img.size == (1280, 2400)
    a = np.asarray(img.convert("L"), dtype=float)
    content = a[:, 100:1180]  # the page column
    assert content.std() > 20, "the screenshot is (almost) uniform: nothing rendered"
    nonwhite = float(np.mean(content < 245))
    dark = float(np.mean(content < 128))
    assert nonwhite > 0.05, f"only {nonwhite:.1%} non-white pixels"
    assert dark > 0.005, f"only {dark:.2%} dark pixels: no text?"
    assert len(np.unique(a.astype(np.uint8))) > 32  # text, tables and figures, not flat fill


@needs_chromium
def test_report_prints_to_pdf(full_report, tmp_path):
    pdf = tmp_path / "report.pdf"
    proc = _chrome(f"--print-to-pdf={pdf}", "--no-pdf-header-footer",
                   full_report.resolve().as_uri(), tmp=tmp_path)
    assert pdf.exists(), proc.stderr[-2000:]
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF-")
    pages = len(re.findall(rb"/Type\s*/Page(?![s\w])", data))
    assert pages > 1, f"{pages} page(s): the print CSS should break between sections"
    assert pages >= len(HEADINGS)  # one section per page at least


# -- the parts: artefacts validated once, tables shared with the CLI, escaping ---------

def _cells(page: str) -> list[str]:
    """Every table cell's text, tags stripped, in page order."""
    import html

    return [html.unescape(re.sub(r"<[^>]+>", "", c)).strip()
            for c in re.findall(r"<t[dh]\b[^>]*>(.*?)</t[dh]>", page, re.S)]


def _contains_row(cells: list[str], row: list[str]) -> bool:
    n = len(row)
    return any(cells[i:i + n] == row for i in range(len(cells) - n + 1))


def test_the_page_renders_the_cli_tables(full_report, work):
    """The ranking and the ladder on the page are Diagnosis.table_rows() and
    Ladder.table_rows() (the CLI's tables), cell for cell, with the page's extra columns
    beside them; Table 1 and the summary are AnalysisResult.table_rows()."""
    from labrig.verbs.types import Diagnosis, Ladder

    page = full_report.read_text(encoding="utf-8")
    cells = _cells(page)
    diag = Diagnosis.from_json(json.loads((work / "diagnosis.json").read_text()))
    ranking = diag.table_rows()[1]
    for row, cand in zip(ranking.rows, diag.ranking):
        params = ", ".join(f"{p} = {v:.3g}" for p, v in cand.params.items())
        assert _contains_row(cells, [*row, params]), row
    ladder = Ladder.from_json(json.loads((work / "ladder.json").read_text()))
    table = ladder.table_rows()
    for row, step in zip(table.rows, ladder.steps):
        assert _contains_row(cells, [row[0], ", ".join(step.effects) or "none", *row[1:]]), row
    assert _contains_row(cells, ["gain trend"])
    assert "Table 1: steady speed per input level" in page and "Summary</h3>" in page


def test_analysis_json_gives_the_same_tables_as_the_live_analysis(dataset):
    """analysis.json read back is the AnalysisResult it was written from: the same
    table cells, less the tacho volts the JSON does not keep."""
    from labrig.analysis import analyse
    from labrig.analysis.result import AnalysisResult
    from labrig.report.blocks import without_empty_columns

    live = analyse([dataset])
    read = AnalysisResult.from_json(json.loads(json.dumps(live.to_json())))
    live_levels, live_summary = live.table_rows()
    read_levels, read_summary = read.table_rows()
    assert read_summary.to_dict() == live_summary.to_dict()
    vt = live_levels.columns.index("Vt (V)")
    drop = [[c for i, c in enumerate(r) if i != vt] for r in live_levels.rows]
    assert without_empty_columns(read_levels).rows == drop
    assert read_levels.notes == live_levels.notes  # the skipped closed-loop run
    assert dict(read.trend["km_by_amplitude"]) == pytest.approx(
        {float(f"{a:g}"): k for a, k in live.trend["km_by_amplitude"]})


def test_artefacts_that_do_not_fit_are_ignored_with_a_note(tmp_path):
    from labrig.report.artefacts import read_artefact
    from labrig.verbs.types import AnalysisResult as AnalysisDoc, Diagnosis as DiagnosisDoc
    from labrig.verbs.types import IdentifyAllDoc, Ladder as LadderDoc

    notes = []
    cases = {"a.json": ("{not json", AnalysisDoc, "not valid JSON"),
             "b.json": ("[1, 2]", AnalysisDoc, "not a JSON object"),
             "c.json": ('{"steps": {"a": 1}}', LadderDoc, "'steps' is not a list of steps"),
             "d.json": ('{"ranking": []}', DiagnosisDoc, "no 'regimes' key"),
             "e.json": ('{"regimes": {"by_regime": {"speed": {"warp": {"rmse_over_noise": 1, '
                        '"share_of_time": 1}}}}}', DiagnosisDoc, "warp"),
             "f.json": ('{"results": {"co": {"params": {"R": "big"}}}}', IdentifyAllDoc,
                        "results.co.params.R")}
    for name, (text, schema, why) in cases.items():
        (tmp_path / name).write_text(text)
        assert read_artefact(tmp_path / name, schema, notes) is None
        assert why in notes[-1] and str(tmp_path / name) in notes[-1], notes[-1]
    assert read_artefact(tmp_path / "absent.json", LadderDoc, notes) is None
    assert len(notes) == len(cases)


def test_identify_all_records_and_the_best(work):
    from labrig.verbs.types import IdentifyAllDoc

    doc = IdentifyAllDoc.model_validate_json((work / "identify_all.json").read_text())
    records, best = doc.records()
    assert [r.method for r in records] == ["jfo", "pso", "co"] and best == "co"
    assert records[2].identifiable.km.interval95 == [89.9, 90.1]
    assert records[0].result.history == [28.5, 19.0, 9.5]  # what the convergence plot draws
    # a single method's JSON (identify --json) is one record, best by its own name
    single, best = IdentifyAllDoc.model_validate(records[1].model_dump()).records()
    assert [r.method for r in single] == ["pso"] and best == "pso"


def test_a_broken_artefact_is_named_on_the_page_and_recomputed(dataset, work, tmp_path):
    """A ladder.json of the wrong shape and a diagnosis.json without regimes: the page
    says so, and with --quick says how to fill the two sections."""
    import shutil

    from labrig.report.html import build_report

    w = tmp_path / "w"
    shutil.copytree(dataset, w / "runs")
    shutil.copy(work / "identify_all.json", w)
    (w / "ladder.json").write_text('{"steps": "none"}')
    (w / "diagnosis.json").write_text('{"verdict": "x"}')
    out = build_report(w / "runs", tmp_path / "r.html", work=w, quick=True, log=lambda t: None)
    page = out.read_text(encoding="utf-8")
    assert "ladder.json was ignored: &#x27;steps&#x27; is not a list of steps." in page
    assert "diagnosis.json was ignored: no &#x27;regimes&#x27; key." in page
    assert page.count("skipped (--quick)") == 2
    assert str(w / "identify_all.json") in page  # the good artefact is still used


def test_text_is_escaped_and_markup_only_where_made(tmp_path):
    """Autoescape with html.escape's quoting; markup() escapes what goes into it."""
    from markupsafe import Markup

    from labrig.report.blocks import TableBlock, markup
    from labrig.report.render import environment
    from labrig.core.tables import Table

    m = markup("<b>{}</b>", HOSTILE)
    assert isinstance(m, Markup) and m == f"<b>{html_escaped(HOSTILE)}</b>"
    tpl = environment().from_string("{{ a }}|{{ b }}|{{ c }}")
    assert tpl.render(a=HOSTILE, b=m, c=None) == f"{html_escaped(HOSTILE)}|{m}|"
    # a CLI table's conventions: a "-- label" row is a group row, yes/no are coloured,
    # text columns are left-aligned
    t = Table("t", ["", "a", "b"], [["-- fit", "", ""], ["x <y>", "yes", "1.0"]], numeric=(2,))
    block = TableBlock(t)
    assert block.body[0].group == "fit"
    assert [c.cls for c in block.body[1].cells] == ["", "l", ""]
    assert block.body[1].cells[1].text == '<span class="yes">yes</span>'


def test_the_template_ships_as_package_data():
    import tomllib
    from pathlib import Path

    import labrig.report.render as render

    root = Path(render.__file__).resolve().parents[2]
    conf = tomllib.loads((root / "pyproject.toml").read_text())
    assert "report/templates/*.j2" in conf["tool"]["setuptools"]["package-data"]["labrig"]
    assert (render.TEMPLATES / "report.html.j2").is_file()
