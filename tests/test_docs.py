"""The project documents itself: every pointer into the documentation resolves inside the
repository (no notes outside it, no missing files, no missing sections)."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: where users and readers of the code look; nothing here may point outside the repository
SCANNED = [ROOT / "README.md", ROOT / "labrig", ROOT / "configs", ROOT / "data", ROOT / "docs",
           ROOT / "CHANGELOG.md", ROOT / "CONTRIBUTING.md"]
FORBIDDEN = ("../shared", "shared/design.md", "shared/physics.md")
#: "docs/physics.md, 'Jellyfish Search'" (the section may wrap onto the next line)
SECTION_REF = re.compile(r"docs/([\w-]+\.md)`?,\s+['\"]([^'\"]+)['\"]")
DOC_PATH = re.compile(r"docs/[\w./-]+?\.md")
MD_LINK = re.compile(r"\]\(([^)\s]+?\.md)(#[\w-]+)?\)")


def _files(roots):
    for root in roots:
        paths = [root] if root.is_file() else sorted(root.rglob("*"))
        for p in paths:
            if p.is_file() and "__pycache__" not in p.parts:
                yield p


def _text_files(roots, suffixes=(".py", ".md", ".toml")):
    return [p for p in _files(roots) if p.suffix in suffixes]


def _headings(md: Path) -> list[str]:
    return [line.lstrip("#").strip() for line in md.read_text(encoding="utf-8").splitlines()
            if line.startswith("#")]


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to '-'."""
    return re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-")


def _norm(text: str) -> str:
    return " ".join(text.split()).lower()


def test_nothing_points_outside_the_repository():
    bad = []
    for p in _files(SCANNED):
        data = p.read_bytes()
        bad += [f"{p.relative_to(ROOT)}: {s}" for s in FORBIDDEN if s.encode() in data]
    assert not bad, "pointers to notes outside the repository:\n" + "\n".join(bad)


def test_every_docs_path_in_readme_and_code_exists():
    missing = []
    for p in _text_files([ROOT / "README.md", ROOT / "labrig", ROOT / "CHANGELOG.md",
                          ROOT / "CONTRIBUTING.md"]):
        for ref in sorted(set(DOC_PATH.findall(p.read_text(encoding="utf-8")))):
            if not (ROOT / ref).is_file():
                missing.append(f"{p.relative_to(ROOT)}: {ref}")
    assert not missing, "documents named but missing:\n" + "\n".join(missing)


@pytest.mark.parametrize("doc", ["design.md", "physics.md"])
def test_the_reference_documents_exist(doc):
    assert (ROOT / "docs" / doc).is_file()


def test_the_project_files_a_university_asks_for_agree_with_the_package():
    """LICENSE is the licence pyproject declares; CITATION.cff cites this version and the
    seed paper (its schema checked with `cffconvert --validate` when it was written);
    CHANGELOG.md lists the firmware this labrig ships; CONTRIBUTING.md says how to run
    the suites."""
    import tomllib

    from labrig.bridge.flash import FIRMWARE_VERSION
    from labrig.core.version import __version__

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert (ROOT / "LICENSE").read_text().startswith(f"{project['license']} License")
    cff = (ROOT / "CITATION.cff").read_text()
    assert re.search(rf"^version: {re.escape(__version__)}$", cff, re.M)
    assert project["version"] == __version__
    assert f"license: {project['license']}" in cff and "Nyong-Bassey" in cff
    changes = (ROOT / "CHANGELOG.md").read_text()
    assert f"**{FIRMWARE_VERSION}**" in changes and f"labrig {__version__}" in changes
    contributing = (ROOT / "CONTRIBUTING.md").read_text()
    assert all(f"make {t}" in contributing for t in ("test-quick", "test", "demo"))


def test_every_named_section_exists():
    """A section named after a docs path in code, configs, docs and tests is a heading of
    that document."""
    missing = []
    for p in _text_files(SCANNED + [ROOT / "tests"]):
        if p == Path(__file__).resolve():
            continue
        for doc, section in SECTION_REF.findall(p.read_text(encoding="utf-8")):
            md = ROOT / "docs" / doc
            if not md.is_file():
                missing.append(f"{p.relative_to(ROOT)}: docs/{doc} does not exist")
            elif _norm(section) not in {_norm(h) for h in _headings(md)}:
                missing.append(f"{p.relative_to(ROOT)}: docs/{doc} has no section "
                               f"'{' '.join(section.split())}'")
    assert not missing, "\n".join(missing)


def test_links_between_documents_resolve():
    broken = []
    for p in _text_files([ROOT / "README.md", ROOT / "docs"], suffixes=(".md",)):
        for target, anchor in MD_LINK.findall(p.read_text(encoding="utf-8")):
            if "://" in target:
                continue
            md = (p.parent / target).resolve()
            if not md.is_file():
                broken.append(f"{p.relative_to(ROOT)}: {target}")
            elif anchor and anchor[1:] not in {_slug(h) for h in _headings(md)}:
                broken.append(f"{p.relative_to(ROOT)}: {target}{anchor}")
    assert not broken, "broken links:\n" + "\n".join(broken)


#: where the benchmarks' records are quoted: the site's performance and test-suite pages
RECORDS = [ROOT / "docs" / "project" / "performance.md", ROOT / "docs" / "project" / "tests.md",
           ROOT / "docs" / "start" / "install.md"]


def _records() -> str:
    return "\n".join(p.read_text() for p in RECORDS)


def _markdown(script: str) -> str:
    import subprocess
    import sys

    return subprocess.run([sys.executable, str(ROOT / "benchmarks" / script), "--markdown"],
                          capture_output=True, text=True, check=True).stdout.strip()


def test_readme_quotes_the_recorded_whole_process_benchmark():
    """The README's performance rows are the ones benchmarks/bench_user.py writes from its
    recorded run (benchmarks/results_user.json), with that run's load average and the
    reference's seconds per candidate."""
    import json

    readme = _records()
    for row in _markdown("bench_user.py").splitlines():
        assert row in readme, row
    rec = json.loads((ROOT / "benchmarks" / "results_user.json").read_text())
    assert f"load average {rec['loadavg_before']:.1f} at the start" in readme
    ref = rec["reference_per_candidate_s"]
    for key in ("linear", "coulomb", "loop"):
        assert f"{ref[key]:.3f} s per candidate" in readme, key
    jfo = rec["identify"]["jfo_linear"]
    prose = " ".join(readme.split())  # the figures in the text, whatever the line breaks
    marks = jfo["marks"]
    assert (f"fitting starts {marks['fit-start']:.2f} s after launch, the fit ends at "
            f"{marks['fit-end']:.2f} s, identifiability at {marks['identifiability-end']:.2f} s, "
            f"and the process ends at {marks['exit']:.2f} s") in prose
    assert (f"from {marks['helper-start']:.2f} s to {marks['helper-ready']:.2f} s after launch"
            in prose)
    assert f"under {jfo['reference_s'] / 1000:.2f} s at this case's reference" in prose
    rng = rec["reference_range_s"]["linear"]
    assert f"the linear reference took {rng[0]:.2f}-{rng[1]:.2f} s per" in prose
    from labrig.simulation.warm import COMPILE_S

    assert f"compiling the simulator once (about {COMPILE_S} s on a 2-core machine" in prose


def test_readme_quotes_the_recorded_kernel_benchmark():
    """The kernel-against-the-limit table (with its closed-loop sentence), the measured peak
    and the run's date are those of benchmarks/results_kernel.json."""
    import json

    readme = _records()
    assert _markdown("bench_kernel.py") in readme
    rec = json.loads((ROOT / "benchmarks" / "results_kernel.json").read_text())
    assert f"{rec['peak_gflops_one_core']:.1f} GFLOP/s" in readme
    share = rec["paths"]["linear/open"]["share"]
    prose = " ".join(readme.split())
    assert f"**{100 * share:.0f} %** on the open-loop runs" in prose
    assert f"(`benchmarks/results_kernel.json`, {rec['when']}, one core)" in prose


def test_readme_quotes_the_recorded_startup_benchmark():
    """The start-up paragraph (fitting's start against the floor numba sets) is the one
    benchmarks/bench_startup.py writes from benchmarks/results_startup.json."""
    prose = " ".join(_records().split())
    assert " ".join(_markdown("bench_startup.py").split()) in prose


def test_readme_quotes_the_recorded_lab_benchmark():
    """The lab page's table is the one benchmarks/bench_lab.py writes from
    benchmarks/results_lab.json."""
    assert _markdown("bench_lab.py") in _records()


def test_readme_quotes_the_recorded_class_benchmark():
    """The class server's load table is the one benchmarks/bench_class.py writes from
    benchmarks/results_class.json, misses included."""
    assert _markdown("bench_class.py") in _records()


def test_readme_quotes_the_recorded_sheet_and_peer_benchmarks():
    """The slowest commands of the sheets and the README's loop, the named targets, and
    the diagnose round against scipy are what benchmarks/bench_sheets.py and
    benchmarks/bench_peer.py write from their recorded runs."""
    readme = _records()
    assert _markdown("bench_sheets.py") in readme
    assert _markdown("bench_peer.py") in readme


def test_readme_quotes_the_recorded_click_benchmark():
    """The loop's speed targets (a round, --auto, closed against open loops) are what
    benchmarks/bench_click.py writes from benchmarks/results_click.json, misses included."""
    assert _markdown("bench_click.py") in _records()


def test_readme_quotes_the_recorded_long_record_benchmark():
    """`--auto` on long recordings against the README's default round is what
    benchmarks/bench_long.py writes from benchmarks/results_long.json, misses included."""
    assert _markdown("bench_long.py") in _records()


def test_readme_quotes_the_recorded_seed_benchmark():
    """The loop's answer on the long axis records against the seed and the BLAS kernel is
    what benchmarks/bench_seeds.py writes from benchmarks/results_seeds.json, misses
    included."""
    assert _markdown("bench_seeds.py") in _records()


def test_benchmarks_readme_quotes_the_recorded_walk():
    """The walk's table in benchmarks/README.md is results_walk.json's."""
    import json

    text = (ROOT / "benchmarks" / "README.md").read_text()
    rec = json.loads((ROOT / "benchmarks" / "results_walk.json").read_text())
    before, after = rec.values()
    for key in ("rooms", "folders", "hand_offs", "back_and_forth", "climbs", "form_changes"):
        assert f"| {key} | {before[key]} | {after[key]} |" in text, key
    parse = [f"{r['effectset_parse']['calls']} ({r['effectset_parse']['parsed']} parsing)"
             for r in (before, after)]
    assert f"| effectset_parse | {parse[0]} | {parse[1]} |" in text


def test_readme_quotes_the_recorded_suite_times():
    """The test suite's stage times and its slowest tests are what benchmarks/bench_suite.py
    writes from benchmarks/results_suite.json (the last full run of .ci/run), the miss of
    the 30-minute target included."""
    assert _markdown("bench_suite.py") in _records()


# -- the newcomer's page and the site ----------------------------------------------------

def test_the_readme_is_a_newcomers_page():
    """At most 150 lines (the rest lives in the site, docs/), with the two quick-start
    commands, the tested platform, the licence and how to cite."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150, len(text.splitlines())
    for must in ("make demo", "make test", "CPython 3.11", "LICENSE", "CITATION.cff"):
        assert must in text, must
    quick = text.split("## Quick start\n", 1)[1].split("\n## ", 1)[0]
    assert "make demo" in quick and "make test" in quick


def test_the_sites_screenshots_are_the_browser_tests():
    """Every screenshot of the lab page in docs/figures is one `make screenshots` copies
    from the browser tests' artefacts, and each is a shot a browser test takes."""
    import re

    make = (ROOT / "Makefile").read_text()
    recipe = make[make.index("\nscreenshots:"):].split("\n\n")[0]
    shots = set()
    for test in ("test_lab.py", "test_class_browser.py"):
        shots |= set(re.findall(r'\.shot\("(\w+)"\)', (ROOT / "tests" / test).read_text()))
    copied = re.findall(r"tests/artefacts/lab_(\w+)\.png", recipe)
    assert copied and set(copied) <= shots, (copied, shots)
    for png in (ROOT / "docs" / "figures").glob("lab_*.png"):
        assert png.name in recipe or f"lab_{png.stem[4:]}.png" in recipe, png.name


@pytest.mark.slow
def test_the_students_copy_of_the_site_has_no_instructor_notes(tmp_path):
    """`make docs-student` (Sphinx's -t student) builds the site without the instructor
    notes and without a warning; the notebook is not run here (`make docs` runs it, CI
    builds it)."""
    import subprocess
    import sys

    pytest.importorskip("sphinx")
    out = tmp_path / "site"
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q",
                           "-t", "student", "-D", "nb_execution_mode=off", "-b", "html",
                           "-d", str(tmp_path / "doctrees"), str(ROOT / "docs"), str(out)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (out / "index.html").is_file() and (out / "exercises" / "03_mystery_rig.html").is_file()
    assert not (out / "instructor").exists()
    assert "instructor/" not in (out / "index.html").read_text()
