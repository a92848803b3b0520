"""What the whole-process benchmarks share: the CLI as a subprocess (and one such command
timed), the machine's record, a row of the README's table, and the command line
(measure and record, or print the README row of the record)."""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time


def labrig(*args) -> subprocess.CompletedProcess:
    """``labrig ARGS`` as a user runs it (a new interpreter, the numba cache loaded)."""
    return subprocess.run([sys.executable, "-m", "labrig", *map(str, args)],
                          capture_output=True, text=True, check=True)


def timed_json(*args) -> tuple[float, dict, float]:
    """``labrig ARGS`` (a command given ``--json``) timed as a whole process: its seconds,
    the JSON it printed and the load average just before it started."""
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    p = labrig(*args)
    seconds = time.perf_counter() - t0
    return seconds, json.loads(p.stdout), load


def machine(load: float) -> dict:
    """The conditions of a measurement: load average before it, CPUs, versions, time."""
    return {"loadavg_before": round(load, 2), "cpus": os.cpu_count(),
            "python": platform.python_version(), "machine": platform.machine(),
            "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}


def readme_row(what: str, measured: str, target: str, passed: bool) -> str:
    """A row of the README's table of whole-process results: what was timed, what was
    measured, the target, and PASS or MISS."""
    return f"| {what} | {measured} | {target} | {'PASS' if passed else 'MISS'} |"


def timed_row(what: str, res: dict, found: str, within: str) -> str:
    """The README row of a command timed against ``res["target_s"]``: its seconds and what
    it ``found``; ``within`` (``<`` or ``<=``) says how the target is met."""
    return readme_row(what, f"**{res['seconds']:.1f} s**, {found}",
                      f"{within} {res['target_s']:.0f} s", res["pass"])


def main(doc: str, results, measure, markdown) -> int:
    """Measure and write ``results`` (JSON), printing it and the README row; with
    ``--markdown`` only the README row of the recorded result."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--markdown", action="store_true", help="print the README row of the "
                    "recorded result and exit")
    args = ap.parse_args()
    if args.markdown:
        print(markdown(json.loads(results.read_text())))
        return 0
    res = measure()
    results.write_text(json.dumps(res, indent=2) + "\n")
    print(json.dumps(res, indent=2))
    print(markdown(res))
    return 0
