"""Benchmark: the loop's answer on a long axis record against the seed and the BLAS kernel.

`labrig diagnose DIR --auto --seed S --json` for seeds 0-4, each as a whole process, under
this machine's OpenBLAS kernel and under its Nehalem kernel (``OPENBLAS_CORETYPE``: SSE
only, no FMA: the last digits of every product differ, as on another CPU), on

* **the EMPS-shaped twin** (``tests/twin.py``'s ``emps_like_axis``: a 95 kg carriage under
  a PD position loop, viscous and Coulomb friction and a force offset hidden, 24,800
  samples at 1 kHz), always;
* **the real EMPS record** (Janot et al. 2019, ``DATA_EMPS.mat`` of
  github:forgi86/sysid-neural-continuous, examples/EMPS/data: it ships no licence, so it
  is not in this repository), where ``LABRIG_EMPS_MAT`` names the file.

Each is imported as the README's force-axis example does (``--axis linear --drive force
--input-gain 35.15065 --pos-unit m``). Recorded per record: the effects each of the ten
runs ends with, M, Fv and Fc (the friction level, Coulomb's or stiction's kinetic one)
with their spread over the runs (largest minus smallest, over the seed-0 value), and
over the cross-validation's folds of the seed-0 model (each fold's training fit, what one
odd stretch of the record can move). The target: the same effects in all ten and every
parameter within 2 % of seed 0's. And the step-by-step loop, as a student runs it (one
`labrig diagnose` process a round, each round's saved model the next one's ``--model``),
with the same seeds and kernels: the same effects as ``--auto`` and every parameter
within 2 % of its seed 0's.

    python benchmarks/bench_seeds.py              # measure and record (about 25 minutes with the real record)
    python benchmarks/bench_seeds.py --markdown   # the README's rows of the record
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))

from whole_process import labrig, machine, main  # noqa: E402

RESULTS = HERE / "results_seeds.json"
SEEDS = (0, 1, 2, 3, 4)
KERNELS = ("", "Nehalem")   # "" is the machine's own
TOLERANCE = 0.02
IMPORT = ("--map", "t=t,u=vir,pos=qm", "--axis", "linear", "--drive", "force",
          "--input-gain", "35.15065", "--pos-unit", "m")


def _auto(folder: Path, out: Path, seed: int, kernel: str) -> dict:
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel} if kernel else dict(os.environ)
    p = subprocess.run([sys.executable, "-m", "labrig", "diagnose", str(folder), "--auto",
                        "--seed", str(seed), "--json", "-o", str(out)],
                       capture_output=True, text=True, check=True, env=env)
    doc = json.loads(p.stdout)
    return {"seed": seed, "kernel": kernel or "own", "effects": doc["effects"],
            **_params(doc["final_model"]),
            "rmse_over_noise": doc["ladder"][-1]["rmse_over_noise"]["overall"]}


def _params(m: dict) -> dict:
    """M, Fv and Fc (the friction level, Coulomb's or stiction's kinetic one) of a saved model."""
    fp = m["effect_params"]
    friction = fp.get("coulomb_friction") or fp.get("stiction") or {}
    return {"M": m["params"]["M"], "Fv": m["params"]["Fv"], "Fc": friction.get("tc_n")}


def _steps(folder: Path, out: Path, seed: int, kernel: str) -> dict:
    """The step-by-step loop as a student runs it: `labrig diagnose DIR [--model MODEL] -o
    NEXT --json`, each round a whole process, until a round recommends nothing (its model
    then is the one it saved, re-fitted, or else the one it was given)."""
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel} if kernel else dict(os.environ)
    out.mkdir(parents=True, exist_ok=True)
    model, recs = None, []
    for k in range(1, 9):
        nxt = out / f"step{k}.json"
        p = subprocess.run([sys.executable, "-m", "labrig", "diagnose", str(folder), "--seed",
                            str(seed), "--json", "-o", str(nxt)]
                           + (["--model", str(model)] if model else []),
                           capture_output=True, text=True, check=True, env=env)
        rec = json.loads(p.stdout)["recommendation"]
        if nxt.exists():
            model = nxt
        if not rec:
            break
        recs.append(rec)
    m = json.loads(model.read_text())
    return {"seed": seed, "kernel": kernel or "own", "effects": m["effects"], "moves": recs,
            **_params(m)}


def _folds(folder: Path, model_file: Path) -> list[dict]:
    """M, Fv and Fc of each cross-validation fold's training fit of ``model_file``."""
    from labrig.analysis.noise import Weights
    from labrig.diagnosis.evidence.crossval import cross_validate, make_folds
    from labrig.io.runs import read_dataset
    from labrig.model.model import Model

    runs = read_dataset(folder)
    model = Model.load(model_file)
    cv = cross_validate(runs, model, make_folds(runs), sigmas=(1.0, 1.0), weights=Weights())
    out = []
    ka = model.constants.get("Ka", 1.0)   # (a level is fitted in input volts: N = V * Ka)
    for p in cv.fold_params:
        fc = p.get("coulomb_friction.tc_v", p.get("stiction.tc_v"))
        out.append({"M": p["M"], "Fv": p["Fv"], "Fc": None if fc is None else fc * ka})
    return out


def _spread(values) -> float | None:
    v = [x for x in values if x is not None]
    if len(v) < 2 or not v[0]:
        return None
    return (max(v) - min(v)) / abs(v[0])


def _agree(rows, effects, spread) -> bool:
    """Whether every row ends with ``effects`` and every parameter some row has spreads
    at most :data:`TOLERANCE` (Fc has no spread when no row ends with a friction level,
    and then it is not judged)."""
    return all(sorted(r["effects"]) == sorted(effects) for r in rows) and all(
        spread[p] is not None and spread[p] <= TOLERANCE
        for p in ("M", "Fv", "Fc") if any(r[p] is not None for r in rows))


def _record(folder: Path, tmp: Path) -> dict:
    runs = [_auto(folder, tmp / f"auto_{k or 'own'}_{s}", s, k) for k in KERNELS for s in SEEDS]
    first = runs[0]
    folds = _folds(folder, tmp / "auto_own_0" / "model.json")
    spread = {p: _spread([r[p] for r in runs]) for p in ("M", "Fv", "Fc")}
    fold_spread = {p: _spread([first[p]] + [f[p] for f in folds]) for p in ("M", "Fv", "Fc")}
    same = _agree(runs, first["effects"], spread)
    steps = [_steps(folder, tmp / f"steps_{k or 'own'}_{s}", s, k) for k in KERNELS for s in SEEDS]
    # the step-by-step loop against --auto's seed 0: the largest gap over its ten runs
    apart = {p: _spread([first[p]] + [x[p] for x in steps]) for p in ("M", "Fv", "Fc")}
    steps_same = _agree(steps, first["effects"], apart)
    return {"runs": runs, "folds": folds, "spread": spread, "fold_spread": fold_spread,
            "same": same, "steps": steps, "steps_apart": apart, "steps_same": steps_same}


def measure() -> dict:
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        from twin import emps_like_axis

        records = {"EMPS-shaped twin": emps_like_axis(tmp / "twin_export")}
        real = os.environ.get("LABRIG_EMPS_MAT")
        if real:
            records["the real EMPS record"] = Path(real)
        out = {}
        for k, (what, path) in enumerate(records.items()):
            folder = tmp / f"rec{k}"
            labrig("import", path, "-o", folder, *IMPORT)
            work = tmp / f"work{k}"
            work.mkdir()
            out[what] = _record(folder, work)
    return {"records": out, "seeds": list(SEEDS), "kernels": [k or "own" for k in KERNELS],
            "tolerance": TOLERANCE, **machine(load)}


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def markdown(res: dict) -> str:
    rows = [f"The loop's answer against the seed and the BLAS kernel (`python "
            f"benchmarks/bench_seeds.py`, {res['when']}; `diagnose --auto` with seeds "
            f"{', '.join(map(str, res['seeds']))} under the machine's own OpenBLAS kernel and "
            f"under Nehalem's, ten whole processes a record; spread = largest minus smallest "
            f"over seed 0's):", "",
            "| record | effects (seed 0) | M, Fv, Fc (seed 0) | all ten end with | spread over "
            "seeds and kernels (M / Fv / Fc) | over the folds | target | result |",
            "|---|---|---|---|---|---|---|---|"]
    for what, r in res["records"].items():
        first = r["runs"][0]
        ends = sorted({" + ".join(x["effects"]) for x in r["runs"]})
        fc = "no friction level" if first["Fc"] is None else f"{first['Fc']:.3g} N"
        sp, fs = r["spread"], r["fold_spread"]
        rows.append(
            f"| {what} | {' + '.join(first['effects'])} | {first['M']:.4g} kg, "
            f"{first['Fv']:.4g} N s/m, {fc} | {' / '.join(ends)} | "
            f"{_pct(sp['M'])} / {_pct(sp['Fv'])} / {_pct(sp['Fc'])} | "
            f"{_pct(fs['M'])} / {_pct(fs['Fv'])} / {_pct(fs['Fc'])} | same effects, "
            f"<= {100 * res['tolerance']:.0f} % | {'PASS' if r['same'] else 'MISS'} |")
    rows += ["", "The step-by-step loop (`labrig diagnose DIR [--model M] -o NEXT`, a whole "
             "process a round, until a round recommends nothing) with the same seeds and "
             "kernels, against `--auto`'s seed 0 (largest gap over the ten, over --auto's "
             "value):", "",
             "| record | the ten end with | moves (seed 0) | M, Fv, Fc (seed 0) | apart from "
             "`--auto` (M / Fv / Fc) | target | result |", "|---|---|---|---|---|---|---|"]
    for what, r in res["records"].items():
        if "steps" not in r:
            continue
        x, ap = r["steps"][0], r["steps_apart"]
        ends = sorted({" + ".join(sorted(y["effects"])) for y in r["steps"]})
        fc = "no friction level" if x["Fc"] is None else f"{x['Fc']:.3g} N"
        rows.append(f"| {what} | {' / '.join(ends)} | {'; '.join(x['moves'])} | "
                    f"{x['M']:.4g} kg, {x['Fv']:.4g} N s/m, {fc} | {_pct(ap['M'])} / "
                    f"{_pct(ap['Fv'])} / {_pct(ap['Fc'])} | --auto's effects, <= "
                    f"{100 * res['tolerance']:.0f} % | {'PASS' if r['steps_same'] else 'MISS'} |")
    for what, r in res["records"].items():
        ends: dict = {}
        for x in r["runs"]:
            ends.setdefault(" + ".join(x["effects"]), []).append(x)
        if len(ends) < 2:
            continue
        rows += ["", f"{what}, each ending (the runs that reach it; M, Fv, Fc and rmse/noise "
                 f"of the first of them):", ""]
        for name, xs in sorted(ends.items(), key=lambda kv: kv[1][0]["rmse_over_noise"]):
            x = xs[0]
            fc = "" if x["Fc"] is None else f", Fc {x['Fc']:.3g} N"
            who = ", ".join(f"{y['kernel']} {y['seed']}" for y in xs)
            rows.append(f"- {name}: {len(xs)} of {len(r['runs'])} ({who}); M {x['M']:.3g} kg, "
                        f"Fv {x['Fv']:.3g} N s/m{fc}; rmse/noise {x['rmse_over_noise']:.0f}")
    if len(res["records"]) < 2:
        rows += ["", "The real EMPS record was not measured in this run (no "
                 "`LABRIG_EMPS_MAT`)."]
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main(__doc__, RESULTS, measure, markdown))
