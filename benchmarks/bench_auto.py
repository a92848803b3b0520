"""Benchmark: `labrig diagnose DIR --auto` on a five-run sweep with two hidden effects.

    python benchmarks/bench_auto.py                 # measure, print JSON, write results_auto.json
    python benchmarks/bench_auto.py --markdown      # the README row from results_auto.json

The sweep: `labrig sweep --sim --rig configs/rig_deadzone_rail.toml --plan
configs/plan_five.toml` (a 0.3 V dead zone in front of a 4 V armature rail; open-loop
square waves of 0.6, 0.9, 1.2, 1.8 and 2.5 V, 0.25 Hz, two periods, 1 kHz: 5 x 8500
samples). The whole process is timed (`labrig diagnose ... --auto` as a
subprocess: interpreter start, imports, numba cache load, every round, the files
written), after one warm-up run so the numba cache exists. Target: <= 15 s on this
2-core machine. Load average before the timed run, CPU count and versions are recorded.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from whole_process import labrig, machine, main, timed_json, timed_row

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results_auto.json"
TARGET_S = 15.0
RIG = HERE.parent / "configs" / "rig_deadzone_rail.toml"
PLAN = HERE.parent / "configs" / "plan_five.toml"


def measure() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        labrig("sweep", "--sim", "--rig", RIG, "--plan", PLAN, "-o", tmp / "runs")
        labrig("diagnose", tmp / "runs", "--auto", "--max-rounds", "1", "-o", tmp / "warm")
        seconds, doc, load = timed_json("diagnose", tmp / "runs", "--auto", "-o", tmp / "auto",
                                        "--json")
    return {"command": "labrig diagnose RUNS --auto -o OUT --json (subprocess, whole process)",
            "seconds": round(seconds, 1), "target_s": TARGET_S, "pass": seconds <= TARGET_S,
            "effects_found": doc["effects"],
            "final_rmse_over_noise": doc["ladder"][-1]["rmse_over_noise"],
            **machine(load)}


def markdown(res: dict) -> str:
    return timed_row("`labrig diagnose --auto`, five-run sweep, dead zone + rail hidden "
                     "(subprocess, whole process)", res,
                     f"found {' + '.join(res['effects_found'])}", "<=")


if __name__ == "__main__":
    sys.exit(main(__doc__, RESULTS, measure, markdown))
