"""The test suite's time, stage by stage and test by test.

``make test`` runs each of its stages through ``stage``, which times it and keeps pytest's
JUnit record of it in ``.suite/`` (``SUITE_DIR`` moves it); ``.ci/run`` times its install
steps the same way and ends with ``summary``: each stage's wall time and the total against
CI's 90-minute limit. ``record`` turns the folder into ``benchmarks/results_suite.json``
(per stage, per file, the 40 slowest tests with what each proves) and ``--markdown`` prints
the README's record of it. No test asserts on a time: this is where the time is kept.

    python benchmarks/bench_suite.py stage NAME -- pytest ARGS...   # one stage, timed
    python benchmarks/bench_suite.py summary                         # the stages so far
    python benchmarks/bench_suite.py record [--note TEXT]            # .suite/ -> results_suite.json
    python benchmarks/bench_suite.py --markdown                      # the README's record
    python benchmarks/bench_suite.py untouched coverage.json         # modules no test ran

Only the standard library: ``.ci/run`` times the install before any virtualenv exists.
"""
from __future__ import annotations

import argparse
import ast
import fcntl
import json
import os
import platform
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).resolve().parent / "results_suite.json"
#: CI's wall: a run of .ci/run that has not finished by then does not land
CI_LIMIT_S = 90 * 60
#: the target of the suite's own issue: .ci/run from a fresh clone within half an hour
TARGET_S = 30 * 60
SLOWEST = 40


def suite_dir() -> Path:
    return Path(os.environ.get("SUITE_DIR", ROOT / ".suite"))


def _stages_file() -> Path:
    return suite_dir() / "stages.json"


def _read_stages() -> list[dict]:
    f = _stages_file()
    return json.loads(f.read_text()) if f.is_file() else []


def _add_stage(entry: dict) -> None:
    # two stages may run side by side (make test-kernels): one writer at a time
    with open(suite_dir() / "stages.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        stages = [s for s in _read_stages() if s["name"] != entry["name"]] + [entry]
        tmp = _stages_file().with_suffix(".tmp")
        tmp.write_text(json.dumps(stages, indent=1) + "\n")
        tmp.replace(_stages_file())


def _wall(stages: list[dict]) -> float:
    """The wall time the stages took together: stages run side by side count once (the
    union of their intervals; a record without them is a sum)."""
    if not all("t0" in s for s in stages):
        return sum(s["seconds"] for s in stages)
    total, end = 0.0, float("-inf")
    for s in sorted(stages, key=lambda s: s["t0"]):
        t0, t1 = s["t0"], s["t0"] + s["seconds"]
        total += max(0.0, t1 - max(t0, end))
        end = max(end, t1)
    return total


def _beside(stages: list[dict]) -> list[list[dict]]:
    """The stages in the order they started, those that ran side by side grouped."""
    groups: list[list[dict]] = []
    end = float("-inf")
    for s in sorted(stages, key=lambda s: s.get("t0", 0.0)):
        if groups and "t0" in s and s["t0"] < end - 1.0:
            groups[-1].append(s)
        else:
            groups.append([s])
        end = max(end, s.get("t0", 0.0) + s["seconds"]) if "t0" in s else float("-inf")
    return groups


def _stages_text(stages: list[dict]) -> str:
    parts = []
    for g in _beside(stages):
        one = " beside ".join(f"{s['name']} {_mmss(s['seconds'])}" for s in g)
        parts.append(one if len(g) == 1 else f"({one})")
    return " + ".join(parts)


def stage(name: str, argv: list[str]) -> int:
    """Run ``argv`` (a pytest command: its JUnit record goes to ``.suite/NAME.xml``), time
    it and add it to the stages; returns its exit code."""
    d = suite_dir()
    d.mkdir(parents=True, exist_ok=True)
    if any("pytest" in a for a in argv[:3]):
        argv = [*argv, f"--junitxml={d / (name + '.xml')}", "-o", "junit_family=xunit1"]
    load = os.getloadavg()[0]
    wall0, t0 = time.time(), time.monotonic()
    rc = subprocess.call(argv)
    seconds = time.monotonic() - t0
    _add_stage({"name": name, "seconds": round(seconds, 1), "rc": rc, "load": round(load, 2),
                "t0": round(wall0, 1),
                "started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(wall0))})
    print(f"[suite] stage {name}: {_mmss(seconds)} (exit {rc})", flush=True)
    return rc


def _mmss(s: float) -> str:
    return f"{int(s) // 60}:{int(s) % 60:02d}"


def summary() -> int:
    """Each stage's wall time so far and the total against CI's limit."""
    stages = _read_stages()
    if not stages:
        print("[suite] no stage recorded")
        return 0
    total = _wall(stages)
    print("[suite] stage times (wall):")
    for g in _beside(stages):
        for k, s in enumerate(g):
            side = f", beside {g[0]['name']}" if k else ""
            print(f"[suite]   {s['name']:<16} {_mmss(s['seconds']):>6}  (exit {s['rc']}, "
                  f"load {s['load']} at its start{side})")
    print(f"[suite]   {'total':<14} {_mmss(total):>6}  = {100 * total / CI_LIMIT_S:.0f} % of CI's "
          f"90-minute limit (target {TARGET_S // 60} min)", flush=True)
    return 0


# -- the record --------------------------------------------------------------------------

def _docstring_line(nodeid: str, cache: dict) -> str:
    """What a test proves: the first sentence of its docstring (or of its module's, for a
    test without one), else its name in words."""
    path, _, rest = nodeid.partition("::")
    func = rest.split("[", 1)[0].split("::")[-1]
    if path not in cache:
        try:
            tree = ast.parse((ROOT / path).read_text(encoding="utf-8"))
        except (OSError, SyntaxError):
            tree = None
        cache[path] = tree
    tree = cache[path]
    doc = None
    if tree is not None:
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name == func:
                doc = ast.get_docstring(node)
                break
    if not doc:
        return func.removeprefix("test_").replace("_", " ")
    first = " ".join(doc.split("\n\n", 1)[0].split())
    for end in (". ", ": "):
        if end in first:
            first = first.split(end, 1)[0]
    return first.rstrip(".") if len(first) <= 110 else first[:107].rsplit(" ", 1)[0] + "..."


def _cases(xml: Path):
    for case in ET.parse(xml).getroot().iter("testcase"):
        cls, name = case.get("classname", ""), case.get("name", "")
        file = case.get("file") or cls.replace(".", "/") + ".py"
        # xunit1 gives the file; a class inside it is the last part of classname
        if not (ROOT / file).is_file() and "/" in file:
            file = file.rsplit("/", 1)[0] + ".py"
        outcome = "passed"
        for tag in ("failure", "error", "skipped"):
            if case.find(tag) is not None:
                outcome = {"failure": "failed", "error": "error", "skipped": "skipped"}[tag]
        yield {"nodeid": f"{file}::{name}", "file": file, "seconds": float(case.get("time", 0)),
               "outcome": outcome}


def record(note: str | None) -> dict:
    d = suite_dir()
    stages = _read_stages()
    out = {"when": stages[0]["started"] if stages else None, "cpus": os.cpu_count(),
           "python": platform.python_version(), "note": note, "stages": [], "files": {},
           "slowest": []}
    docs: dict = {}
    every = []
    for s in stages:
        entry = {k: s[k] for k in ("name", "seconds", "rc", "load", "t0") if k in s}
        xml = d / f"{s['name']}.xml"
        if xml.is_file():
            cases = list(_cases(xml))
            entry["tests"] = len(cases)
            entry["outcomes"] = {o: sum(c["outcome"] == o for c in cases)
                                 for o in ("passed", "failed", "error", "skipped")}
            entry["test_seconds"] = round(sum(c["seconds"] for c in cases), 1)
            by_file = defaultdict(float)
            for c in cases:
                by_file[c["file"]] += c["seconds"]
                every.append({**c, "stage": s["name"]})
            out["files"][s["name"]] = {f: round(t, 1) for f, t in
                                       sorted(by_file.items(), key=lambda kv: -kv[1])}
        out["stages"].append(entry)
    out["total_s"] = round(_wall(stages), 1)
    for c in sorted(every, key=lambda c: -c["seconds"])[:SLOWEST]:
        out["slowest"].append({"test": c["nodeid"], "stage": c["stage"],
                               "seconds": round(c["seconds"], 1),
                               "proves": _docstring_line(c["nodeid"], docs)})
    return out


def markdown(res: dict) -> str:
    stages = _stages_text(res["stages"])
    tests = sum(s.get("tests", 0) for s in res["stages"])
    outcomes = {o: sum(s.get("outcomes", {}).get(o, 0) for s in res["stages"])
                for o in ("passed", "failed", "error", "skipped")}
    said = ", ".join(f"{n} {o}" for o, n in outcomes.items() if n)
    lines = [f"The last recorded full run (`benchmarks/results_suite.json`, {res['when']}, "
             f"{res['cpus']} cores, load {res['stages'][0]['load']} at the start): {stages} = "
             f"**{_mmss(res['total_s'])}** ({100 * res['total_s'] / CI_LIMIT_S:.0f} % of "
             f"CI's 90 minutes; target {TARGET_S // 60} min: "
             f"{'PASS' if res['total_s'] <= TARGET_S else 'MISS'}), {tests} test runs ({said}).",
             ""]
    prev = res.get("previous")
    if prev:
        stages_p = _stages_text(prev["stages"])
        lines[-2:-1] = [lines[-2] + f" The run before it ({prev['when']}, load "
                        f"{prev['stages'][0]['load']} at the start): {stages_p} = "
                        f"{_mmss(prev['total_s'])}."]
    if res.get("note"):
        lines += [res["note"], ""]
    lines += [f"<details><summary>The {len(res['slowest'])} slowest tests of that run</summary>",
              "", "| test | stage | s | what it proves |", "|---|---|---|---|"]
    for t in res["slowest"]:
        lines.append(f"| `{t['test']}` | {t['stage']} | {t['seconds']:.0f} | {t['proves']} |")
    lines += ["", "</details>"]
    return "\n".join(lines)


def untouched(report: Path) -> int:
    """The modules of ``labrig/`` of which a coverage run (``coverage json``) ran no line;
    exit 1 if any, with the line coverage of the whole package."""
    doc = json.loads(report.read_text())
    files = {Path(f).resolve().relative_to(ROOT).as_posix(): v for f, v in doc["files"].items()
             if (ROOT / "labrig") in Path(f).resolve().parents}
    every = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "labrig").rglob("*.py"))
    missing = [f for f in every if f not in files or (
        files[f]["summary"]["covered_lines"] == 0 and files[f]["summary"]["num_statements"] > 0)]
    pct = doc["totals"]["percent_covered"]
    print(f"[suite] {len(every) - len(missing)} of {len(every)} modules of labrig/ touched, "
          f"{pct:.1f} % of its lines run")
    for f in missing:
        print(f"[suite]   not touched: {f}")
    return 1 if missing else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--markdown", action="store_true",
                    help="print the README's record of results_suite.json and exit")
    sub = ap.add_subparsers(dest="what")
    st = sub.add_parser("stage", help="run one stage of the suite, timed")
    st.add_argument("name")
    st.add_argument("argv", nargs=argparse.REMAINDER)
    sub.add_parser("summary", help="print the stages' times so far")
    rec = sub.add_parser("record", help="write results_suite.json from the suite folder")
    rec.add_argument("--note", help="one paragraph said under the record")
    rec.add_argument("-o", "--output", type=Path, default=RESULTS)
    un = sub.add_parser("untouched", help="the modules a coverage run did not touch")
    un.add_argument("report", type=Path, help="coverage's JSON report")
    args = ap.parse_args()
    if args.what == "untouched":
        return untouched(args.report)
    if args.markdown:
        print(markdown(json.loads(RESULTS.read_text())))
        return 0
    if args.what == "stage":
        argv = args.argv[1:] if args.argv[:1] == ["--"] else args.argv
        return stage(args.name, argv)
    if args.what == "summary":
        return summary()
    if args.what == "record":
        res = record(args.note)
        if args.output.is_file():   # the run before this one, in one line of the README
            old = json.loads(args.output.read_text())
            res["previous"] = {k: old[k] for k in ("when", "total_s")} | {
                "stages": [{k: s[k] for k in ("name", "seconds", "load", "t0") if k in s}
                           for s in old["stages"]]}
        args.output.write_text(json.dumps(res, indent=1) + "\n")
        print(markdown(res))
        return 0
    ap.print_help()
    return 2


if __name__ == "__main__":
    sys.exit(main())
