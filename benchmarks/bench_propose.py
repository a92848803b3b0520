"""Benchmark: `labrig propose` on one confusable run (whole process).

    python benchmarks/bench_propose.py                # measure, print JSON, write results_propose.json
    python benchmarks/bench_propose.py --markdown     # the README row from results_propose.json

The data: one 1.5 V step of 3 s at 1 kHz on the default rig with its hidden Coulomb
friction replaced by a 0.3 V one (`configs/rig_default.toml` hides 0.13 V): a dead zone and
Coulomb friction fit it equally well. The model: `labrig identify RUNS --effects deadband`.
Timed: `labrig propose RUNS --model M.json -o plan.toml --json` as a subprocess (interpreter
start, imports, numba cache load, both fits, the plausible variants, every candidate
simulated, the rivals re-fitted, plan and figure written), after one warm-up run so the
numba cache exists. Target: < 30 s on this 2-core machine.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from whole_process import labrig, machine, main, timed_json, timed_row

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results_propose.json"
TARGET_S = 30.0
RIG = "[effects.coulomb_friction]\ntc_v = 0.3\n"
PLAN = ('[[experiment]]\nname = "step"\nwaveform = "step"\namplitude_v = 1.5\n'
        'duration_s = 3.0\n')


def measure() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "rig.toml").write_text(RIG)
        (tmp / "plan.toml").write_text(PLAN)
        labrig("sweep", "--sim", "--rig", tmp / "rig.toml", "--plan", tmp / "plan.toml",
               "-o", tmp / "runs")
        labrig("identify", tmp / "runs", "--effects", "deadband", "--seed", "1",
               "-o", tmp / "m.json")
        labrig("propose", tmp / "runs", "--model", tmp / "m.json", "-o", tmp / "warm.toml")
        seconds, doc, load = timed_json("propose", tmp / "runs", "--model", tmp / "m.json",
                                        "-o", tmp / "p.toml", "--json")
    return {"command": "labrig propose RUNS --model M.json -o PLAN --json (subprocess, "
                       "whole process)",
            "seconds": round(seconds, 1), "target_s": TARGET_S, "pass": seconds < TARGET_S,
            "between": doc["between"], "proposed": doc["proposed"]["label"],
            **machine(load)}


def markdown(res: dict) -> str:
    return timed_row("`labrig propose`, one confusable step, dead zone or Coulomb friction "
                     "(subprocess, whole process)", res, f"proposed {res['proposed']}", "<")


if __name__ == "__main__":
    sys.exit(main(__doc__, RESULTS, measure, markdown))
