#!/usr/bin/env python
"""Identification performance of labrig on the default simulated sweep.

Usage::

    python benchmarks/bench_identify.py [--quick] [-o results.json]

Everything is measured in ONE process, on the sweep that ``labrig sweep --sim``
writes with the default rig (4 open-loop square waves of 8500 samples + 2
closed-loop runs of 4500 samples at 1 kHz; the rig hides a Coulomb friction of
0.13 V):

1. the reference a typical user writes, per candidate and per run:
   - linear: build the python-control model (``ServoParams.open_loop()`` for an
     open-loop run, ``.closed_loop(kp, kv)`` for a closed-loop run) and call
     ``control.forced_response`` once;
   - with Coulomb friction: a fixed-step pure-python loop, one forward-Euler step
     per sample with ``Tc * np.sign(w)`` friction (the cheapest loop a user would
     write: any sub-stepping or ``solve_ivp`` is slower, so the ratio against it
     is a lower bound);
   only a few candidates are timed and the time per candidate is extrapolated;
2. labrig's ``Simulator`` on a population of 50 candidates (warm: the first call,
   numba compile or cache load, is timed separately; a cold compile is also timed
   in a subprocess with an empty numba cache), linear and with coulomb_friction,
   through ``simulate`` (trajectories, like the reference) and ``sse`` (the fused
   hot path of the identifiers);
3. candidate simulations per second (one candidate on all 6 runs) and the ratios;
4. JFO 50 x 200 through ``identify`` (wall time), linear and with coulomb_friction;
5. CO multi-start (default starts=8) through ``identify``, linear and with friction;
6. ``labrig diagnose`` on the sweep, if the command exists;
7. machine load (os.getloadavg) around every section, CPU count, versions.

It prints a table and writes JSON (default benchmarks/results.json).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TARGETS = {
    "ratio_linear": (">=", 500.0),
    "ratio_coulomb": (">=", 200.0),
    "jfo_linear_s": ("<=", 2.0),
    "jfo_coulomb_s": ("<=", 5.0),
    "co_linear_s": ("<=", 1.0),
    "co_coulomb_s": ("<=", 1.0),
    "diagnose_s": ("<", 60.0),
}
#: default rig plant (configs/rig_default.toml) and its hidden friction
TRUTH = np.array([8.0, 0.0085, 5.2245e-5, 1.0e-5, 0.05])
TRUTH_TC_V = 0.13
POP = 50
SEED = 1


def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def verdict(key: str, value) -> str:
    if value is None:
        return "not measured"
    op, target = TARGETS[key]
    ok = value >= target if op == ">=" else (value <= target if op == "<=" else value < target)
    return "PASS" if ok else "MISS"


# -- the data --------------------------------------------------------------------------
def make_sweep(folder: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "labrig", "sweep", "--sim", "-o", str(folder)],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def population(P: int, seed: int = 0):
    """P candidates within a factor 2 of the default rig (log-uniform), and tc_v."""
    rng = np.random.default_rng(seed)
    plant = TRUTH * 10.0 ** rng.uniform(-0.3, 0.3, (P, 5))
    tc_v = rng.uniform(0.05, 0.3, P)
    return plant, tc_v


# -- the references ------------------------------------------------------------------------
def reference_linear(rd, cand, keep=None) -> tuple[float, float]:
    """One candidate on every run, the python-control way. Returns (build s, forced_response s);
    the speed trajectories are appended to ``keep`` when given."""
    import control

    from labrig.model.servo import ServoParams

    t_build = t_fr = 0.0
    for r in rd:
        t0 = time.perf_counter()
        sp = ServoParams(*cand, Ka=r.Ka, N=r.N, Kt=r.Kt, Kpot=r.Kpot)
        sys_ = sp.closed_loop(r.kp, r.kv) if r.loop == "closed" else sp.open_loop()
        T = np.arange(len(r.u)) * r.dt
        t1 = time.perf_counter()
        out = control.forced_response(sys_, T=T, U=r.u, X0=[0.0, 0.0, r.theta0 * r.N])
        t2 = time.perf_counter()
        if keep is not None:
            keep.append(np.asarray(out.outputs)[0])
        t_build += t1 - t0
        t_fr += t2 - t1
    return t_build, t_fr


def user_loop(R, L, J, B, K, tc_v, u, dt, loop, Ka, N, Kt, Kpot, kp, kv, theta0):
    """What a typical user writes for the nonlinear model: fixed step (one forward-Euler
    step per sample), Coulomb friction Tc*sign(w), the loop closed by hand."""
    Tc = tc_v * Ka * K / R
    n = len(u)
    w_out = np.empty(n)
    th_out = np.empty(n)
    i = w = 0.0
    th = theta0 * N
    for k in range(n):
        w_out[k] = w
        th_out[k] = th / N
        if loop == "closed":
            v = Ka * (kp * (u[k] - Kpot * th / N) - kv * Kt * w)
        else:
            v = Ka * u[k]
        di = (v - R * i - K * w) / L
        dw = (K * i - B * w - Tc * np.sign(w)) / J
        i = i + dt * di
        w = w + dt * dw
        th = th + dt * w
    return w_out, th_out


def reference_coulomb(rd, cand, tc_v, keep=None) -> float:
    t0 = time.perf_counter()
    for r in rd:
        with np.errstate(all="ignore"):  # forward Euler diverges for candidates with L/R < dt/2
            w, _ = user_loop(*cand, tc_v, r.u, r.dt, r.loop, r.Ka, r.N, r.Kt, r.Kpot, r.kp, r.kv,
                         r.theta0)
        if keep is not None:
            keep.append(w)
    return time.perf_counter() - t0


def user_ivp(R, L, J, B, K, tc_v, u, dt, Ka, N, theta0):
    """The other thing a user writes: scipy solve_ivp (RK45, max_step = dt), open loop."""
    from scipy.integrate import solve_ivp

    Tc = tc_v * Ka * K / R
    n = len(u)

    def f(t, x):
        i, w, th = x
        v = Ka * u[min(int(t / dt), n - 1)]
        return [(v - R * i - K * w) / L, (K * i - B * w - Tc * np.sign(w)) / J, w]

    T = np.arange(n) * dt
    return solve_ivp(f, (0.0, T[-1]), [0.0, 0.0, theta0 * N], t_eval=T, max_step=dt).y[1]


def rms_over_noise(refs, sims, sigma_w) -> float:
    """RMS speed difference reference - labrig over all runs, in units of the speed noise."""
    d = np.concatenate([a - b for a, b in zip(refs, sims)])
    return float(np.sqrt(np.mean(d ** 2)) / sigma_w)


# -- labrig ------------------------------------------------------------------------------------
COLD_SNIPPET = r"""
import json, sys, time, numpy as np
from labrig.io.runs import read_dataset
from labrig.model.simulate import Simulator
from labrig.model.effects import get_effect
runs = read_dataset(sys.argv[1])
plant = np.array([[8.0, 0.0085, 5.2245e-5, 1.0e-5, 0.05]] * 50)
out = {}
t0 = time.perf_counter(); Simulator(runs).simulate(plant); out["simulate_linear"] = time.perf_counter() - t0
sim = Simulator(runs, [get_effect("coulomb_friction")])
ep = {"coulomb_friction": {"tc_v": 0.13}}
t0 = time.perf_counter(); sim.simulate(plant, ep); out["simulate_coulomb"] = time.perf_counter() - t0
print(json.dumps(out))
"""


def cold_compile(folder: Path) -> dict:
    """First calls in a fresh interpreter with an empty numba cache (true compile time)."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        p = subprocess.run([sys.executable, "-c", COLD_SNIPPET, str(folder)], env=env,
                           capture_output=True, text=True, check=True)
    return {k: round(v, 3) for k, v in json.loads(p.stdout.strip().splitlines()[-1]).items()}


def time_calls(fn, repeats: int) -> dict:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return {"median_s": statistics.median(ts), "min_s": min(ts), "max_s": max(ts),
            "repeats": repeats}


def bench_identify(runs, method, effects, repeats, **kw) -> dict:
    from labrig.identification.engine import identify

    rows = []
    for k in range(repeats):
        t0 = time.perf_counter()
        ident = identify(runs, method, effects, seed=SEED + k, **kw)
        wall = time.perf_counter() - t0
        rows.append({"wall_s": round(wall, 3), "seconds": round(ident.seconds, 3),
                     "nfev": int(ident.result.nfev), "fitness": round(ident.fitness, 4),
                     "seed": SEED + k,
                     "params": {n: float(f"{v:.4g}") for n, v in ident.params.items()}})
    walls = [r["wall_s"] for r in rows]
    return {"median_s": statistics.median(walls), "min_s": min(walls), "max_s": max(walls),
            "options": kw, "runs": rows}


def diagnose_available() -> bool:
    p = subprocess.run([sys.executable, "-m", "labrig", "--help"], capture_output=True, text=True)
    return any(line.strip().startswith("diagnose") for line in p.stdout.splitlines())


def bench_diagnose(folder: Path) -> dict:
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "labrig", "diagnose", str(folder), "--seed", str(SEED)],
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    return {"seconds": round(wall, 2), "returncode": p.returncode,
            "command": f"labrig diagnose SWEEP --seed {SEED} (subprocess: includes interpreter start)",
            "stderr_tail": p.stderr.strip().splitlines()[-3:] if p.returncode else []}


# -- main --------------------------------------------------------------------------------------
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="fewer repeats and reference candidates (a smoke run, minutes less)")
    ap.add_argument("-o", "--output", default=str(Path(__file__).with_name("results.json")))
    ap.add_argument("--markdown", metavar="RESULTS_JSON",
                    help="only print the Markdown results table of a saved results file")
    args = ap.parse_args(argv)
    if args.markdown:
        print(markdown(json.loads(Path(args.markdown).read_text())))
        return 0

    n_ref_lin = 2 if args.quick else 5
    n_ref_nl = 1 if args.quick else 3
    rep_sim = 5 if args.quick else 20
    rep_ident = 1 if args.quick else 3

    import control
    import numba
    import scipy

    import labrig
    from labrig.model.effects import get_effect
    from labrig.model.simulate import Simulator, prepare
    from labrig.io.runs import read_dataset

    res: dict = {"quick": args.quick, "loadavg": {"start": load()},
                 "machine": {"cpu_count": os.cpu_count(),
                             "cpus_usable": len(os.sched_getaffinity(0)),
                             "numba_threads": numba.get_num_threads(),
                             "platform": platform.platform(), "python": platform.python_version(),
                             "versions": {"labrig": getattr(labrig, "__version__", "?"),
                                          "numpy": np.__version__, "scipy": scipy.__version__,
                                          "control": control.__version__,
                                          "numba": numba.__version__}},
                 "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "sweep"
        res["sweep"] = {"seconds": round(make_sweep(folder), 2)}
        runs = read_dataset(folder)
        rd = prepare(runs)
        res["sweep"].update(runs=[{"name": r.name, "loop": r.loop, "samples": len(r.u)} for r in rd],
                            samples_total=sum(len(r.u) for r in rd))
        plant, tc_v = population(POP)
        coulomb = get_effect("coulomb_friction")
        ep = {"coulomb_friction": {"tc_v": tc_v}}

        # -- labrig simulator ------------------------------------------------------------
        res["loadavg"]["before_simulator"] = load()
        sim_lin = Simulator(runs)
        sim_nl = Simulator(runs, [coulomb])
        t0 = time.perf_counter(); sim_lin.simulate(plant)
        first_lin = time.perf_counter() - t0
        t0 = time.perf_counter(); sim_nl.simulate(plant, ep)
        first_nl = time.perf_counter() - t0
        from labrig.identification.objective import Objective, build_space
        weights = {}
        for name, effs in (("linear", []), ("coulomb", [coulomb])):
            weights[name] = Objective(runs, effs, build_space(effs))._weights
        sim_lin.sse(plant, None, weights["linear"]); sim_nl.sse(plant, ep, weights["coulomb"])
        lab = {
            "linear": {"simulate": time_calls(lambda: sim_lin.simulate(plant), rep_sim),
                       "sse": time_calls(lambda: sim_lin.sse(plant, None, weights["linear"]), rep_sim)},
            "coulomb": {"simulate": time_calls(lambda: sim_nl.simulate(plant, ep), rep_sim),
                        "sse": time_calls(lambda: sim_nl.sse(plant, ep, weights["coulomb"]), rep_sim)},
        }
        for v in lab.values():
            for d in v.values():
                d["cand_per_s"] = POP / d["median_s"]
        res["simulator"] = {"population": POP, **lab,
                            "first_call_s": {"linear": round(first_lin, 3),
                                             "coulomb": round(first_nl, 3),
                                             "note": "in this process: numba compile, or a load "
                                                     "from labrig's on-disk numba cache"}}
        res["loadavg"]["before_cold_compile"] = load()
        res["simulator"]["cold_compile_s"] = cold_compile(folder)

        # -- references --------------------------------------------------------------------
        res["loadavg"]["before_reference"] = load()
        reference_linear(rd, plant[0])  # warm python-control's imports and caches
        lin = [reference_linear(rd, plant[c]) for c in range(n_ref_lin)]
        tot = [b + f for b, f in lin]
        ref_lin = {"what": "per candidate: ServoParams(...).open_loop() / .closed_loop(kp, kv) "
                           "+ one control.forced_response per run",
                   "candidates_timed": n_ref_lin,
                   "per_candidate_s": statistics.median(tot),
                   "build_per_candidate_s": statistics.median([b for b, _ in lin]),
                   "forced_response_per_candidate_s": statistics.median([f for _, f in lin])}
        ref_lin["cand_per_s"] = 1.0 / ref_lin["per_candidate_s"]
        nl = [reference_coulomb(rd, plant[c], tc_v[c]) for c in range(n_ref_nl)]
        ref_nl = {"what": "per candidate: pure-python fixed-step loop, one forward-Euler step per "
                          "sample, Tc*np.sign(w) friction, loop closed by hand",
                  "candidates_timed": n_ref_nl, "per_candidate_s": statistics.median(nl)}
        ref_nl["cand_per_s"] = 1.0 / ref_nl["per_candidate_s"]
        # how close each reference is to labrig's simulation (candidate 0), so the reader
        # sees both compute the same physics to within the measurement noise
        from labrig.identification.objective import noise_level
        sigma_w = float(np.median([noise_level(r.w) for r in rd]))
        keep: list = []
        reference_linear(rd, plant[0], keep)
        ref_lin["rms_speed_diff_over_noise"] = rms_over_noise(
            keep, [o["w"][0] for o in sim_lin.simulate(plant[:1])], sigma_w)
        keep = []
        reference_coulomb(rd, plant[0], tc_v[0], keep)
        labw = [o["w"][0] for o in sim_nl.simulate(plant[:1], {"coulomb_friction": {"tc_v": tc_v[:1]}})]
        ref_nl["rms_speed_diff_over_noise"] = rms_over_noise(keep, labw, sigma_w)
        # solve_ivp, on the first open-loop run only (on a closed-loop run the sign(w)
        # friction at rest makes RK45 crawl: minutes per run in a trial)
        k_open = next(k for k, r in enumerate(rd) if r.loop == "open")
        r = rd[k_open]
        t0 = time.perf_counter()
        w_ivp = user_ivp(*plant[0], tc_v[0], r.u, r.dt, r.Ka, r.N, r.theta0)
        t_ivp = time.perf_counter() - t0
        t0 = time.perf_counter()
        user_loop(*plant[0], tc_v[0], r.u, r.dt, r.loop, r.Ka, r.N, r.Kt, r.Kpot, r.kp, r.kv,
                  r.theta0)
        t_eul = time.perf_counter() - t0
        ref_ivp = {"what": "scipy solve_ivp RK45, max_step=dt, Tc*np.sign(w); one open-loop run "
                           "of one candidate (informative, not the reference of the ratio)",
                   "run": r.name, "seconds": t_ivp, "euler_loop_same_run_s": t_eul,
                   "slower_than_euler_loop": t_ivp / t_eul,
                   "rms_speed_diff_over_noise": rms_over_noise([w_ivp], [labw[k_open]], sigma_w)}
        res["reference"] = {"linear": ref_lin, "coulomb": ref_nl, "coulomb_solve_ivp": ref_ivp,
                            "sigma_w_rad_s": sigma_w}
        res["ratio"] = {
            "linear_simulate": lab["linear"]["simulate"]["cand_per_s"] / ref_lin["cand_per_s"],
            "linear_sse": lab["linear"]["sse"]["cand_per_s"] / ref_lin["cand_per_s"],
            "linear_simulate_vs_forced_response_only":
                lab["linear"]["simulate"]["cand_per_s"] * ref_lin["forced_response_per_candidate_s"],
            "coulomb_simulate": lab["coulomb"]["simulate"]["cand_per_s"] / ref_nl["cand_per_s"],
            "coulomb_sse": lab["coulomb"]["sse"]["cand_per_s"] / ref_nl["cand_per_s"],
        }

        # -- identification ---------------------------------------------------------------
        res["loadavg"]["before_identify"] = load()
        res["identify"] = {
            "jfo_linear": bench_identify(runs, "jfo", [], rep_ident, pop=50, iters=200),
            "jfo_coulomb": bench_identify(runs, "jfo", [coulomb], rep_ident, pop=50, iters=200),
            "co_linear": bench_identify(runs, "co", [], rep_ident),
            "co_coulomb": bench_identify(runs, "co", [coulomb], rep_ident),
            "note": "wall time of identify() (optimiser + metrics + identifiability), warm numba; "
                    "CO with the default starts=8",
        }
        res["loadavg"]["before_diagnose"] = load()
        res["diagnose"] = bench_diagnose(folder) if diagnose_available() else {
            "seconds": None, "note": "`labrig diagnose` does not exist in this build: not measured"}
    res["loadavg"]["end"] = load()
    res["total_s"] = round(time.perf_counter() - t_start, 1)

    figures = {"ratio_linear": res["ratio"]["linear_simulate"],
               "ratio_coulomb": res["ratio"]["coulomb_simulate"],
               "jfo_linear_s": res["identify"]["jfo_linear"]["median_s"],
               "jfo_coulomb_s": res["identify"]["jfo_coulomb"]["median_s"],
               "co_linear_s": res["identify"]["co_linear"]["median_s"],
               "co_coulomb_s": res["identify"]["co_coulomb"]["median_s"],
               "diagnose_s": res["diagnose"]["seconds"]}
    res["verdict"] = {k: {"value": v, "target": f"{TARGETS[k][0]} {TARGETS[k][1]:g}",
                          "result": verdict(k, v)} for k, v in figures.items()}

    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(json.dumps(res, indent=2, default=float) + "\n")
    print_table(res)
    print(f"\nwritten {args.output}")
    return 0


def print_table(res: dict) -> None:
    s, r, ref = res["simulator"], res["ratio"], res["reference"]
    print(f"machine: {res['machine']['cpu_count']} CPUs, numba threads "
          f"{res['machine']['numba_threads']}; load average (1, 5, 15 min): "
          + ", ".join(f"{k} {v}" for k, v in res["loadavg"].items()))
    print(f"sweep: {len(res['sweep']['runs'])} runs, {res['sweep']['samples_total']} samples")
    print(f"\n{'candidate simulations / s (one candidate on all runs)':<58}{'linear':>12}{'coulomb':>12}")
    print(f"{'reference (typical user)':<58}{ref['linear']['cand_per_s']:>12.2f}"
          f"{ref['coulomb']['cand_per_s']:>12.2f}")
    for k in ("simulate", "sse"):
        label = f"labrig Simulator.{k} (P={s['population']}, median)"
        print(f"{label:<58}"
              f"{s['linear'][k]['cand_per_s']:>12.0f}{s['coulomb'][k]['cand_per_s']:>12.0f}")
    print(f"{'ratio simulate / reference':<58}{r['linear_simulate']:>12.0f}{r['coulomb_simulate']:>12.0f}")
    print(f"{'ratio sse / reference':<58}{r['linear_sse']:>12.0f}{r['coulomb_sse']:>12.0f}")
    print(f"{'reference vs labrig speed, RMS / noise (candidate 0)':<58}"
          f"{ref['linear']['rms_speed_diff_over_noise']:>12.2f}"
          f"{ref['coulomb']['rms_speed_diff_over_noise']:>12.2f}")
    iv = ref["coulomb_solve_ivp"]
    print(f"solve_ivp on {iv['run']}: {iv['seconds']:.2f} s = {iv['slower_than_euler_loop']:.0f}x the "
          f"Euler loop on the same run")
    print(f"first call (this process) s: {s['first_call_s']['linear']} / {s['first_call_s']['coulomb']};"
          f" cold numba compile s: {s['cold_compile_s']}")
    print(f"\n{'figure':<26}{'measured':>12}  {'target':<10}result")
    for k, v in res["verdict"].items():
        val = "-" if v["value"] is None else (f"{v['value']:.0f}x" if k.startswith("ratio")
                                              else f"{v['value']:.2f} s")
        print(f"{k:<26}{val:>12}  {v['target']:<10}{v['result']}")


def markdown(res: dict) -> str:
    """The results table for the READMEs."""
    ref, s, r = res["reference"], res["simulator"], res["ratio"]
    v = res["verdict"]
    L, C = s["linear"]["simulate"]["cand_per_s"], s["coulomb"]["simulate"]["cand_per_s"]
    lines = [
        "| figure | measured | target | result |",
        "|---|---|---|---|",
        f"| candidate simulations/s, linear: labrig `Simulator.simulate` (P={s['population']}) vs "
        f"python-control reference | {L:.0f}/s vs {ref['linear']['cand_per_s']:.2f}/s = "
        f"**{r['linear_simulate']:.0f}x** | >= 500x | {v['ratio_linear']['result']} |",
        f"| candidate simulations/s, coulomb_friction: labrig vs python Euler loop | "
        f"{C:.0f}/s vs {ref['coulomb']['cand_per_s']:.2f}/s = **{r['coulomb_simulate']:.0f}x** "
        f"| >= 200x | {v['ratio_coulomb']['result']} |",
    ]
    for key, label in (("jfo_linear_s", "JFO 50 x 200, linear"),
                       ("jfo_coulomb_s", "JFO 50 x 200, + coulomb_friction"),
                       ("co_linear_s", "CO multi-start (starts=8), linear"),
                       ("co_coulomb_s", "CO multi-start (starts=8), + coulomb_friction"),
                       ("diagnose_s", "`labrig diagnose` on the sweep")):
        val = v[key]["value"]
        lines.append(f"| {label} | {'not measured' if val is None else f'**{val:.2f} s**'} | "
                     f"{v[key]['target']} s | {v[key]['result']} |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
