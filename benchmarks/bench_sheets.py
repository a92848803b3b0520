"""Benchmark: every command a student types, timed as the student meets it.

    python benchmarks/bench_sheets.py             # measure (about 5 min), write results_sheets.json
    python benchmarks/bench_sheets.py --markdown  # the README rows of the recorded result

In ONE run, on this machine, warm (the numba cache filled, one warm-up command first):

* every exercise sheet runs as ``tests/test_exercises.py`` runs it: a fresh folder with
  copies of ``data/`` and ``configs/``, its ```bash commands in order, each a whole process
  (``python -m labrig ...``), then the commands of its checked figures that the sheet did
  not run itself (the sheet's and its instructor notes');
* the README's loop: every command its checked figures name, in one folder, in order;
* ``make demo`` (``labrig demo -o DIR``, whole process);
* ``labrig analyse data/sweep_default -o DIR`` against the same without ``-o``: what the
  figures cost.

Every command's wall time is recorded; the README shows the slowest ten and how many
commands miss the 10 s target, and the named figures against their own targets:
``diagnose --auto`` on the README's five-run case <= 15 s, one ``diagnose`` round
<= 8 s, the figures of ``analyse -o`` <= 3 s, ``make demo`` <= 30 s.
"""
from __future__ import annotations

import os
import shlex
import sys
import tempfile
import time
from pathlib import Path

from whole_process import machine, main

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / "tests"))
import quoted  # noqa: E402
import test_exercises as ex  # noqa: E402

RESULTS = HERE / "results_sheets.json"
TARGET_S = 10.0
NAMED = {"auto": 15.0, "round": 8.0, "figures": 3.0, "demo": 30.0}


def _record(where: str, line: str, seconds: float, rc: int) -> dict:
    return {"where": where, "command": line, "seconds": round(seconds, 2), "rc": rc}


def _checks(docs, workdir: Path, where: str, done: set) -> list[dict]:
    """The commands of ``docs``' checked figures not run yet, timed, in order."""
    out = []
    for doc in docs:
        for c in quoted.parse(doc):
            for line in c.after + [c.command]:
                argv = shlex.split(line)
                key = " ".join(argv)
                if key in done:
                    continue
                proc, dt = ex.run_command(argv, workdir)
                done.add(key)
                out.append(_record(where, line, dt, proc.returncode))
    return out


def sheets(tmp: Path) -> list[dict]:
    out = []
    for sheet in ex.SHEETS:
        wd = tmp / sheet.stem
        recs = ex.run_sheet(sheet, wd)
        out += [_record(sheet.name, r["line"], r["seconds"], r["rc"]) for r in recs]
        done = {" ".join(shlex.split(r["line"], comments=True)) for r in recs}
        out += _checks(ex._docs_of(sheet), wd, sheet.name, done)
    return out


def readme(tmp: Path) -> list[dict]:
    wd = tmp / "readme"
    ex.setup_workdir(wd)
    # (the loop's story moved from the README to the site's guide; its records keep the name)
    return _checks(ex.GUIDE, wd, "README.md", set())


def timed(argv: list[str], workdir: Path) -> float:
    proc, dt = ex.run_command(argv, workdir)
    if proc.returncode != 0:
        raise SystemExit(f"`{' '.join(argv)}` exited {proc.returncode}: {proc.stderr[-500:]}")
    return dt


def measure() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ex.setup_workdir(tmp / "warm")
        timed(["labrig", "analyse", "data/sweep_default"], tmp / "warm")   # warm-up
        load = os.getloadavg()[0]
        t0 = time.monotonic()
        commands = sheets(tmp) + readme(tmp)
        demo = timed(["labrig", "demo", "-o", str(tmp / "demo")], tmp / "warm")
        bare = timed(["labrig", "analyse", "data/sweep_default"], tmp / "warm")
        figs = timed(["labrig", "analyse", "data/sweep_default", "-o", str(tmp / "figs")],
                     tmp / "warm")
        total = time.monotonic() - t0
    readme_cmds = [c for c in commands if c["where"] == "README.md"]
    auto = max((c for c in readme_cmds if " --auto" in c["command"] and "--ask-rig" not in
                c["command"]), key=lambda c: c["seconds"])
    rounds = [c for c in readme_cmds if c["command"].startswith("labrig diagnose")
              and "--auto" not in c["command"]]
    slow = sorted(commands, key=lambda c: -c["seconds"])
    return {"commands": commands, "slowest": slow[:10], "count": len(commands),
            "over_target": sum(c["seconds"] > TARGET_S for c in commands),
            "target_s": TARGET_S, "failed": [c for c in commands if c["rc"] not in (0, 1, 2)],
            "named": {
                "auto": {"command": auto["command"], "seconds": auto["seconds"]},
                "round": {"command": max(rounds, key=lambda c: c["seconds"])["command"],
                          "seconds": max(c["seconds"] for c in rounds)},
                "figures": {"command": "labrig analyse data/sweep_default -o DIR, minus the "
                            "same without -o", "seconds": round(figs - bare, 2),
                            "with": round(figs, 2), "without": round(bare, 2)},
                "demo": {"command": "labrig demo -o DIR (make demo, warm)",
                         "seconds": round(demo, 2)}},
            "named_targets_s": NAMED, "total_s": round(total, 1), **machine(load)}


def markdown(res: dict) -> str:
    rows = [f"Every command of the five exercise sheets and of the README's loop "
            f"(`python benchmarks/bench_sheets.py`, {res['when']}, load {res['loadavg_before']} "
            f"at the start, {res['count']} commands, whole process each, warm): "
            f"**{res['over_target']}** over the {res['target_s']:.0f} s target. The slowest ten:",
            "", "| where | command | seconds | target |", "|---|---|---|---|"]
    for c in res["slowest"]:
        mark = "MISS" if c["seconds"] > res["target_s"] else "PASS"
        rows.append(f"| {c['where']} | `{c['command']}` | {c['seconds']:.1f} | "
                    f"{mark} ({res['target_s']:.0f} s) |")
    names = {"auto": "`diagnose --auto`, README five-run case", "round": "one `diagnose` round "
             "(README step 2)", "figures": "figures of `analyse -o` (with - without)",
             "demo": "`make demo`, warm"}
    rows += ["", "| figure | command | seconds | target |", "|---|---|---|---|"]
    for k, label in names.items():
        v, t = res["named"][k], res["named_targets_s"][k]
        rows.append(f"| {label} | `{v['command']}` | **{v['seconds']:.1f}** | "
                    f"{'PASS' if v['seconds'] <= t else 'MISS'} ({t:.0f} s) |")
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main(__doc__, RESULTS, measure, markdown))
