"""Benchmark: what a user waits for, whole process, against the python-control reference.

    python benchmarks/bench_user.py              # measure (about 10 min), write results_user.json
    python benchmarks/bench_user.py --markdown   # the README rows of the recorded result

In ONE run, on this machine:

* the data: the default simulated sweep (`labrig sweep --sim`: 4 open-loop square waves of
  8500 samples and 2 closed-loop runs of 4500 at 1 kHz) from a linear rig (its hidden
  Coulomb friction removed) and from the default rig (0.13 V of Coulomb friction);
* the reference a typical user writes with python-control, per candidate (one parameter
  set on all 6 runs), timed on 3 candidates near the default rig, one before each of
  labrig's timed runs (round robin: the reference and the run it is divided by see the
  host in the same state; its speed drifts by tens of per cent within minutes here):
  - linear: build the model (`ServoParams(...).open_loop()` / `.closed_loop(kp, kv)`)
    and call `control.forced_response` per run;
  - Coulomb friction: a discrete-time `control.nlsys` (one forward-Euler step per sample,
    `Tc sign(w)`, the loop closed inside) and `control.input_output_response` per run;
    the bare Python loop of the same update is timed too (a lower bound on any
    reference; its ratio is recorded beside);
* labrig as a user runs it: `labrig identify DIR --method jfo|co [--effects
  coulomb_friction] --seed 1 -o M.json --json` as a subprocess (interpreter start,
  imports, numba cache load, the fit, identifiability, step metrics, the file written),
  median of 3 after one warm-up; the phase marks (`LABRIG_LAUNCHED_AT`) say when fitting
  started and ended. The ratio is (candidates the fit simulated, `nfev`, times the
  median of the reference's seconds per candidate taken beside that case's runs) /
  labrig's whole-process seconds;
* `labrig diagnose --auto` on a five-run sweep with two hidden effects and `labrig
  propose` on one confusable step (as benchmarks/bench_auto.py and bench_propose.py);
* the first run after installation: `python -m labrig.simulation.warm` with an empty numba
  cache (the compile `make` does at install), and the same with the cache filled.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import bench_auto
import bench_propose
from whole_process import machine, main

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results_user.json"
TARGETS = {"jfo_linear": 1000.0, "jfo_coulomb": 500.0}
LINEAR_RIG = "[effects]\n"   # the default rig without its hidden friction
TC_V = 0.13                  # the default rig's hidden Coulomb friction (bridge volts)
REF_CANDIDATES = 3


def run(*args, env=None) -> tuple[float, subprocess.CompletedProcess, dict]:
    """``labrig ARGS`` as a subprocess: (wall seconds, process, phase marks)."""
    env = dict(os.environ, **(env or {}))
    t0 = time.time()
    env["LABRIG_LAUNCHED_AT"] = repr(t0)
    p = subprocess.run([sys.executable, "-m", "labrig", *map(str, args)], capture_output=True,
                       text=True, env=env, check=True)
    wall = time.time() - t0
    marks = {}
    for line in p.stderr.splitlines():
        if line.startswith("labrig-timing "):
            _, phase, s = line.split()
            marks.setdefault(phase, round(float(s), 3))
    return wall, p, marks


# -- the references ---------------------------------------------------------------------
def reference_linear(rd, cand) -> None:
    import control

    from labrig.model.servo import ServoParams

    for r in rd:
        sp = ServoParams(*cand, Ka=r.Ka, N=r.N, Kt=r.Kt, Kpot=r.Kpot)
        sys_ = sp.closed_loop(r.kp, r.kv) if r.loop == "closed" else sp.open_loop()
        T = np.arange(len(r.u)) * r.dt
        control.forced_response(sys_, T=T, U=r.u, X0=[0.0, 0.0, r.theta0 * r.N])


def _euler_update(r, cand, tc_v):
    R, L, J, B, K = cand
    Tc = tc_v * r.Ka * K / R

    def upd(t, x, u, params=None):
        i, w, th = x
        if r.loop == "closed":
            v = r.Ka * (r.kp * (u[0] - r.Kpot * th / r.N) - r.kv * r.Kt * w)
        else:
            v = r.Ka * u[0]
        return [i + r.dt * (v - R * i - K * w) / L,
                w + r.dt * (K * i - B * w - Tc * np.sign(w)) / J, th + r.dt * w]
    return upd


def reference_coulomb(rd, cand, tc_v=TC_V) -> None:
    """python-control's way for a nonlinear model: a discrete-time nlsys per run."""
    import control

    for r in rd:
        sys_ = control.nlsys(_euler_update(r, cand, tc_v), lambda t, x, u, p: [x[1], x[2] / r.N],
                             inputs=1, outputs=2, states=3, dt=r.dt)
        T = np.arange(len(r.u)) * r.dt
        with np.errstate(all="ignore"):
            control.input_output_response(sys_, T, r.u, X0=[0.0, 0.0, r.theta0 * r.N])


def reference_loop(rd, cand, tc_v=TC_V) -> None:
    """The bare Python loop of the same update (no python-control): a lower bound."""
    for r in rd:
        upd = _euler_update(r, cand, tc_v)
        x = [0.0, 0.0, r.theta0 * r.N]
        with np.errstate(all="ignore"):
            for k in range(len(r.u)):
                x = upd(0.0, x, (r.u[k],))


def timed(fn, rd, cand) -> float:
    t0 = time.perf_counter()
    fn(rd, cand)
    return time.perf_counter() - t0


REFERENCES = {"linear": reference_linear, "coulomb": reference_coulomb, "loop": reference_loop}


# -- measure ----------------------------------------------------------------------------
def identify_rows(lin: Path, coul: Path, tmp: Path, rd, cands) -> tuple[dict, dict]:
    """labrig's four identify cases, each run 3 times after a warm-up; before each timed
    run, the case's references on one candidate (round robin over ``cands``), so a
    reference and the labrig run it is divided by see the host in the same state (it
    drifts by tens of per cent within minutes here). Returns the rows and every
    reference's timings."""
    cases = {"jfo_linear": (lin, "jfo", []), "jfo_coulomb": (coul, "jfo", ["coulomb_friction"]),
             "co_linear": (lin, "co", []), "co_coulomb": (coul, "co", ["coulomb_friction"])}
    for fn in REFERENCES.values():
        fn(rd, cands[0])  # imports and caches
    ref_times: dict = {k: [] for k in REFERENCES}
    out = {}
    for key, (data, method, effects) in cases.items():
        args = ["identify", data, "--method", method, "--seed", "1", "-o", tmp / f"{key}.json",
                "--force", "--json"] + (["--effects", ",".join(effects)] if effects else [])
        kinds = ["coulomb", "loop"] if effects else ["linear"]
        run(*args)  # warm-up: the numba cache loaded once from disk before timing
        rows, refs = [], {k: [] for k in kinds}
        for j in range(3):
            for k in kinds:
                refs[k].append(timed(REFERENCES[k], rd, cands[j % len(cands)]))
            rows.append(run(*args))
        for k in kinds:
            ref_times[k] += refs[k]
        walls = [w for w, _, _ in rows]
        wall, p, marks = sorted(rows, key=lambda r: r[0])[1]
        doc = json.loads(p.stdout)
        ref = statistics.median(refs[kinds[0]])
        nfev = int(doc["nfev"])
        out[key] = {"seconds": round(statistics.median(walls), 2),
                    "all_seconds": [round(w, 2) for w in walls], "marks": marks,
                    "fit_seconds_reported": round(doc["seconds"], 2), "nfev": nfev,
                    "reference_per_candidate_s": [round(t, 4) for t in refs[kinds[0]]],
                    "reference_s": round(nfev * ref, 1),
                    "ratio": round(nfev * ref / statistics.median(walls)),
                    "fitness": round(doc["fitness"], 4)}
        if effects:
            out[key]["ratio_vs_bare_loop"] = round(
                nfev * statistics.median(refs["loop"]) / statistics.median(walls))
    return out, ref_times


def first_run() -> dict:
    """The install step's compile (empty numba cache), then the same with the cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        cmd = [str(Path(sys.executable).with_name("labrig-warm"))]  # as make runs it
        t0 = time.perf_counter()
        subprocess.run(cmd, env=env, check=True, capture_output=True)
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        subprocess.run(cmd, env=env, check=True, capture_output=True)
        warm = time.perf_counter() - t0
    return {"compile_s": round(cold, 1), "cached_s": round(warm, 1),
            "command": "labrig-warm (whole process; every kernel and mode)"}


def measure() -> dict:
    from labrig.model.simulate import prepare
    from labrig.io.runs import read_dataset

    load = os.getloadavg()[0]
    res: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "linear.toml").write_text(LINEAR_RIG)
        run("sweep", "--sim", "--rig", tmp / "linear.toml", "-o", tmp / "lin")
        run("sweep", "--sim", "-o", tmp / "coul")
        rd = prepare(read_dataset(tmp / "coul"))
        rng = np.random.default_rng(1)
        truth = np.array([8.0, 0.0085, 5.2245e-5, 1.0e-5, 0.05])
        cands = [truth * 10.0 ** rng.uniform(-0.2, 0.2, 5) for _ in range(REF_CANDIDATES)]
        res["identify"], times = identify_rows(tmp / "lin", tmp / "coul", tmp, rd, cands)
        res["reference_per_candidate_s"] = {k: round(statistics.median(v), 4)
                                            for k, v in times.items()}
        res["reference_range_s"] = {k: [round(min(v), 4), round(max(v), 4)]
                                    for k, v in times.items()}
        res["samples"] = int(sum(len(r.u) for r in rd))
    res["diagnose_auto"] = bench_auto.measure()
    res["propose"] = bench_propose.measure()
    res["first_run"] = first_run()
    return {**res, **machine(load)}


def markdown(res: dict) -> str:
    rows = []
    names = {"jfo_linear": "`labrig identify --method jfo` (50 x 200), linear",
             "jfo_coulomb": "`labrig identify --method jfo --effects coulomb_friction`",
             "co_linear": "`labrig identify --method co` (8 starts), linear",
             "co_coulomb": "`labrig identify --method co --effects coulomb_friction`"}
    for key, label in names.items():
        r = res["identify"][key]
        target = TARGETS.get(key)
        verdict = ("PASS" if r["ratio"] >= target else "MISS") if target else "-"
        extra = (f"; {r['ratio_vs_bare_loop']}x against a bare Python loop"
                 if "ratio_vs_bare_loop" in r else "")
        rows.append(f"| {label}, whole process | **{r['seconds']:.2f} s** for {r['nfev']} "
                    f"candidates = **{r['ratio']}x** the python-control reference "
                    f"({r['reference_s']:.0f} s){extra}; fitting starts at "
                    f"{r['marks'].get('fit-start', float('nan')):.2f} s | "
                    f"{'>= %dx' % target if target else '-'} | {verdict} |")
    rows.append(bench_auto.markdown(res["diagnose_auto"]))
    rows.append(bench_propose.markdown(res["propose"]))
    f = res["first_run"]
    rows.append(f"| first run after installation: the kernels compiled once (`make` does it "
                f"at install) / loaded from the cache | **{f['compile_s']:.0f} s** / "
                f"{f['cached_s']:.1f} s | - | - |")
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main(__doc__, RESULTS, measure, markdown))
