"""What the whole-process benchmarks share: the CLI as a subprocess, the machine's record,
and the command line (measure and record, or print the README row of the record)."""
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


def machine(load: float) -> dict:
    """The conditions of a measurement: load average before it, CPUs, versions, time."""
    return {"loadavg_before": round(load, 2), "cpus": os.cpu_count(),
            "python": platform.python_version(), "machine": platform.machine(),
            "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}


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
