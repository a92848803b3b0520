"""The exercise sheets (docs/exercises/*.md) run as written.

Conventions of a sheet (docs/instructor/README.md repeats them for authors):

- ```bash blocks: commands a student types, one per line, run in order. Only
  ``labrig ...`` (run as ``python -m labrig`` from this interpreter) and ``python ...``
  (this interpreter); no pipes, redirections or ``&&``. A line may end in
  ``# expect-exit: N`` when the sheet demonstrates an error; otherwise the exit code
  must be 0. ``#`` comment lines are skipped.
- ```python file=NAME / ```toml file=NAME blocks: files the sheet tells the student to
  create; they are written to disk when the runner reaches them.
- ```text blocks (real rig only, e.g. ``--port /dev/ttyACM0``, or sample output) and
  any other fences are not run.

Each sheet runs in a fresh temporary folder holding copies of the repository's
``data/`` and ``configs/``, so sheets use relative names like ``data/sweep_default``.

Run one sheet by hand, keeping its folder and printing every output and timing::

    python tests/test_exercises.py docs/exercises/03_mystery_rig.md
"""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import outputs_record  # noqa: E402
import quoted  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SHEETS = sorted((ROOT / "docs" / "exercises").glob("[0-9]*.md"))
FENCE = re.compile(r"^```\s*([A-Za-z0-9_+-]*)\s*(.*)$")
EXPECT = re.compile(r"#\s*expect-exit:\s*(\d+)\s*$")
#: the site's pages that tell the loop's story with checked figures (they were the
#: README's), and their sections whose every decimal figure and percentage a check must declare
GUIDE = [ROOT / "docs" / "guide" / "loop.md", ROOT / "docs" / "project" / "validation.md",
         ROOT / "docs" / "guide" / "your-rig.md"]
GUIDE_MEASURED = ("The missing-physics loop", "What the loop can and cannot see",
                  "Your rig is not an MS150")
FORBIDDEN = {"|", "||", "&&", ";", ">", ">>", "<", "&", "2>", "2>&1"}


def parse_sheet(path: Path) -> list[tuple]:
    """A sheet -> steps in order: ("run", argv, expected_rc, line_no, line) or
    ("file", name, text, line_no)."""
    steps, lines = [], path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i].strip())
        if not m:
            i += 1
            continue
        lang, info = m.group(1), m.group(2)
        start = i + 1
        j = start
        while j < len(lines) and lines[j].strip() != "```":
            j += 1
        if j >= len(lines):
            raise AssertionError(f"{path.name}:{i + 1}: unclosed ``` block")
        body = lines[start:j]
        fm = re.search(r"file=(\S+)", info)
        if lang == "bash":
            for k, line in enumerate(body, start + 1):
                s = line.strip()
                if not s or s.startswith("#"):
                    continue
                em = EXPECT.search(s)
                rc = int(em.group(1)) if em else 0
                argv = shlex.split(s, comments=True)
                bad = FORBIDDEN.intersection(argv) or (s.endswith("\\") and {"\\"})
                assert not bad, f"{path.name}:{k}: one plain command per line, no shell syntax ({bad})"
                assert argv[0] in ("labrig", "python", "python3"), \
                    f"{path.name}:{k}: sheets run only labrig and python commands, got {argv[0]!r}"
                steps.append(("run", argv, rc, k, s))
        elif fm:
            steps.append(("file", fm.group(1), "\n".join(body) + "\n", start))
        i = j + 1
    return steps


def setup_workdir(workdir: Path) -> None:
    for name in ("data", "configs"):
        shutil.copytree(ROOT / name, workdir / name,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env["MPLBACKEND"] = "Agg"
    # the sheets' checks read the numbers, not the pictures: draft figures, a third of a
    # command's time less (tests/test_figures.py draws and checks every kind in full)
    env["LABRIG_FIGURES"] = "draft"
    env.setdefault("PYTHONHASHSEED", "0")
    return env


def run_command(argv: list[str], workdir: Path) -> tuple[subprocess.CompletedProcess, float]:
    """One ``labrig ...`` or ``python ...`` line, run from this interpreter in ``workdir``."""
    cmd = ([sys.executable, "-m", "labrig"] if argv[0] == "labrig" else [sys.executable]) + argv[1:]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=workdir, env=_env(), capture_output=True, text=True,
                          timeout=600)
    if outputs_record.DIR:   # (the kernels' measurement only)
        outputs_record.record(proc.stdout.replace(str(workdir), "WORKDIR"))
    return proc, time.monotonic() - t0


#: a sheet line that plays on the emulated board ends with this comment: the firmware
#: stage of the suite runs those lines (and the checks of what they write), the rest of
#: the suite runs the others
BOARD = "# emulated board"


def _on_board(line: str) -> bool:
    return line.rstrip().endswith(BOARD) or "--emulate" in shlex.split(line, comments=True)


def _board_outputs(sheet: Path) -> set[str]:
    """The folders the sheet's board lines write (``-o X``)."""
    out = set()
    for st in parse_sheet(sheet):
        if st[0] == "run" and _on_board(st[4]) and "-o" in st[1]:
            out.add(st[1][st[1].index("-o") + 1])
    return out


def _uses(argv: list[str], folders: set[str]) -> bool:
    return any(a in folders or any(a.startswith(f + "/") for f in folders) for a in argv)


def check_quoted(docs: list[Path], workdir: Path, records: list[dict], board: bool | None = None,
                 board_outputs: set[str] = frozenset()) -> list[str]:
    """Run each ``check`` of ``docs`` in ``workdir`` (a line the sheet ran is not run again)
    and list every quoted figure its command no longer gives. ``board`` False leaves out
    the checks of the emulated board's runs (``board_outputs``), True keeps only those,
    None keeps all."""
    ran = {" ".join(shlex.split(r["line"], comments=True)): r["stdout"] for r in records}
    problems = []
    for doc in docs:
        for c in quoted.parse(doc):
            lines = [shlex.split(x) for x in c.after + [c.command]]
            on_board = any(_uses(a, set(board_outputs)) or "--emulate" in a for a in lines)
            if board is not None and on_board != board:
                continue
            problems += quoted.problems_in_text(c)
            failed = None
            for line in c.after + [c.command]:
                argv = shlex.split(line)
                key = " ".join(argv)
                if key in ran:
                    continue
                proc, _ = run_command(argv, workdir)
                if proc.returncode != 0:
                    failed = (f"{doc.name}:{c.line_no}: `{line}` exited {proc.returncode}: "
                              f"{proc.stderr.strip()[-300:]}")
                    break
                ran[key] = proc.stdout
            if failed:
                problems.append(failed)
                continue
            problems += quoted.problems_in_output(c, ran[" ".join(c.argv)])
    return problems


def run_sheet(sheet: Path, workdir: Path, echo: bool = False, board: bool | None = None) -> list[dict]:
    """Run the steps of ``sheet`` in ``workdir``; returns one record per command. ``board``
    False leaves out the lines that play on the emulated board, True runs only those,
    None runs all."""
    setup_workdir(workdir)
    records = []
    for step in parse_sheet(sheet):
        if step[0] == "run" and board is not None and _on_board(step[4]) != board:
            continue
        if step[0] == "file":
            _, name, text, _ = step
            (workdir / name).parent.mkdir(parents=True, exist_ok=True)
            (workdir / name).write_text(text, encoding="utf-8")
            if echo:
                print(f"## wrote {name}", flush=True)
            continue
        _, argv, rc, line_no, line = step
        proc, dt = run_command(argv, workdir)
        rec = {"line": line, "line_no": line_no, "rc": proc.returncode, "expected": rc,
               "seconds": dt, "stdout": proc.stdout, "stderr": proc.stderr}
        records.append(rec)
        if echo:
            print(f"$ {line}    [{dt:.1f} s, exit {proc.returncode}]\n{proc.stdout}", flush=True)
            if proc.returncode != rc:
                print(proc.stderr[-3000:], flush=True)
        if proc.returncode != rc:
            raise AssertionError(
                f"{sheet.name}:{line_no}: `{line}` exited {proc.returncode}, expected {rc}\n"
                f"--- stdout (end)\n{proc.stdout[-2000:]}\n--- stderr (end)\n{proc.stderr[-2000:]}")
    return records


def test_there_are_five_sheets_with_instructor_notes():
    assert len(SHEETS) == 5, [s.name for s in SHEETS]
    notes = ROOT / "docs" / "instructor"
    for s in SHEETS:
        assert (notes / s.name).exists(), f"no instructor notes for {s.name}"
        steps = parse_sheet(s)
        assert any(st[0] == "run" for st in steps), f"{s.name} has no ```bash commands"
        text = s.read_text()
        for heading in ("## Objectives", "## Questions"):
            assert heading in text, f"{s.name}: missing '{heading}'"
        # the answers belong to the instructor, not to the student's copy
        assert "What good answers" not in text and "Model answers" not in text, s.name
        assert "## Model answers" in (notes / s.name).read_text(), s.name


def test_real_rig_commands_are_not_in_bash_blocks():
    for s in SHEETS:
        for st in parse_sheet(s):
            if st[0] == "run":
                assert "--port" not in st[1], f"{s.name}:{st[3]}: --port belongs in a ```text block"


def _docs_of(sheet: Path) -> list[Path]:
    return [sheet, ROOT / "docs" / "instructor" / sheet.name]


def test_quoted_figures_are_declared_beside_their_command():
    """Static: every check parses, its figures stand in the text beside it, and the
    measured sections quote no figure that no check declares."""
    problems = []
    for sheet in SHEETS:
        for doc in _docs_of(sheet):
            for c in quoted.parse(doc):
                assert c.argv[0] in ("labrig", "python"), f"{doc.name}:{c.line_no}: {c.command}"
                problems += quoted.problems_in_text(c)
            problems += quoted.unchecked_figures(doc)
        assert any(quoted.parse(d) for d in _docs_of(sheet)), f"{sheet.name}: no checked figures"
    assert not problems, "\n".join(problems)


@pytest.mark.slow
@pytest.mark.kernels
def test_readme_figures(tmp_path):
    """The loop's story in the guide (once the README's), and the README's one figure,
    quote what their commands give now."""
    setup_workdir(tmp_path)
    problems = [p for doc in GUIDE for p in quoted.unchecked_figures(doc, GUIDE_MEASURED)]
    problems += check_quoted(GUIDE + [ROOT / "README.md"], tmp_path, [], board=False)
    assert not problems, "the guide's figures out of date:\n" + "\n".join(problems)


@pytest.mark.firmware
def test_readme_figures_of_the_emulated_board(tmp_path):
    """The guide's figures from runs played on the real firmware under simavr."""
    from labrig.bridge.emulate import missing_tools

    if missing_tools():
        pytest.skip(f"firmware toolchain missing: {', '.join(missing_tools())}")
    setup_workdir(tmp_path)
    problems = check_quoted(GUIDE, tmp_path, [], board=True)
    assert not problems, "the guide's figures out of date:\n" + "\n".join(problems)


@pytest.mark.kernels
@pytest.mark.parametrize("sheet", SHEETS, ids=[s.stem for s in SHEETS])
def test_sheet_runs(sheet, tmp_path):
    """The sheet runs as written, and every figure it and its instructor notes quote is
    what the commands give now."""
    records = run_sheet(sheet, tmp_path, board=False)
    assert records
    for r in records:
        if r["expected"] != 0:  # a demonstrated error is one line, not a traceback
            assert "Traceback" not in r["stderr"] and r["stderr"].strip(), r["line"]
    problems = check_quoted(_docs_of(sheet), tmp_path, records, board=False,
                            board_outputs=_board_outputs(sheet))
    assert not problems, "quoted figures out of date:\n" + "\n".join(problems)


BOARD_SHEETS = [s for s in SHEETS if any(st[0] == "run" and _on_board(st[4]) for st in parse_sheet(s))]


@pytest.mark.firmware
@pytest.mark.parametrize("sheet", BOARD_SHEETS, ids=[s.stem for s in BOARD_SHEETS])
def test_sheet_plays_live_on_the_emulated_board(sheet, tmp_path):
    """The sheet's lines that play on the board run on the real firmware under simavr, and
    the figures the notes quote from those runs hold."""
    from labrig.bridge.emulate import missing_tools

    if missing_tools():
        pytest.skip(f"firmware toolchain missing: {', '.join(missing_tools())}")
    records = run_sheet(sheet, tmp_path, board=True)
    assert records
    problems = check_quoted(_docs_of(sheet), tmp_path, records, board=True,
                            board_outputs=_board_outputs(sheet))
    assert not problems, "quoted figures out of date:\n" + "\n".join(problems)


if __name__ == "__main__":  # run sheets by hand, printing outputs and times
    for arg in sys.argv[1:] or map(str, SHEETS):
        wd = Path(tempfile.mkdtemp(prefix=f"sheet_{Path(arg).stem}_"))
        print(f"#### {arg} in {wd}", flush=True)
        t0 = time.monotonic()
        recs = run_sheet(Path(arg), wd, echo=True)
        for line in check_quoted(_docs_of(Path(arg).resolve()), wd, recs) or ["quoted figures: all hold"]:
            print(line, flush=True)
        print(f"#### {arg}: {len(recs)} commands, {time.monotonic() - t0:.1f} s", flush=True)
