"""Benchmark: the fused fitness path against this machine's measured floating-point limit.

    python benchmarks/bench_kernel.py              # measure (about 1 min), write results_kernel.json
    python benchmarks/bench_kernel.py --markdown   # the README table of the recorded result

One core (numba and BLAS both held to one thread, so the figure is per core):

* the limit: the best of 5 double-precision matrix products (2000 x 2000, OpenBLAS),
  2 n^3 flops each: the floating-point rate this core reaches on the friendliest code;
  taken in each of 5 rounds, before the round's paths, and the best of all kept (as every
  path's best over the rounds is);
* the kernel: ``Simulator.sse`` (what JFO and PSO call: simulate and sum the squared
  residuals, no trajectories stored) on the default simulated sweep, a population of 50
  candidates within a factor 2 of the default rig, best of 15 calls (as the peak is the
  best of 5), for the linear
  model and with each catalogue effect;
* flops per sample per candidate, counted in the kernel's source for each path (the
  exact zero-order-hold update of the three states plus the residuals; see
  benchmarks/README.md, "The kernel and the limit"); the path's limit is peak / flops and
  its share of it is candidate-samples per second / limit.
"""
from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"   # before numpy loads its BLAS
os.environ["NUMBA_NUM_THREADS"] = "1"

import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from whole_process import labrig, machine, main  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results_kernel.json"
TARGET_SHARE = 0.35
#: closed-loop runs with an effect in the loop (issue: "closed loops in lanes")
TARGET_CLOSED_SHARE = 0.25
POP = 50
#: rounds of (peak, every path), the best of each kept
ROUNDS = 5
TRUTH = np.array([8.0, 0.0085, 5.2245e-5, 1.0e-5, 0.05])
# flops per sample per candidate, counted in labrig/simulation/kernels.py (_sweep, _input_map):
# the update i, w, theta of the linear model: 3 + 3 + 3 multiplications, 2 + 2 + 3
# additions (16); the residuals: theta / N, two differences, two scalings, two squares
# and two additions into the sum (9)
LINEAR = 16 + 9
FLOPS = {"linear": LINEAR,
         "coulomb_friction": LINEAR + 6 + 1,      # + gf Tf on three states, nw * w
         "stiction": LINEAR + 6 + 1,
         "delay": LINEAR + 6,                     # + g_old s_old on three states
         "backlash": LINEAR + 3,                  # play: x = theta / N, x - a, x + a
         "deadband": LINEAR + 3,                  # |v| - d, sign * max, Ka v
         "offset": LINEAR + 2,                    # v + u0, Ka v
         "asymmetry": LINEAR + 3,                 # 1 + k, v (1 + k), Ka v
         "saturation": LINEAR + 1,                # Ka v (the clip is two comparisons)
         "asymmetric_deadband": LINEAR + 2}       # v - dpos or v + dneg, Ka v
#: the open loop's input maps run only where the shared input changes (kernels._block: a
#: steady input leaves the lanes' mapped inputs as they were): their flops on those samples
MAP_FLOPS = {"deadband": 3, "offset": 2, "asymmetry": 3, "saturation": 1,
             "asymmetric_deadband": 2}
#: a closed loop with its input map inside (labrig/simulation/loop_kernel.py, _sweep_loop; the
#: table is in benchmarks/README.md), as (a sample in full, a steady input's sample),
#: counted in the source and the same in the machine code of the build each case runs
#: (vector multiplications, additions, subtractions and the division per eight lanes,
#: numba's inspect_asm, 2026-11-26). In full (where the input changed, and after a lane was
#: redone alone): the residuals (8), the loop's error (6), its piece (5), the piece's
#: constant drive (9), the update with feedback (22), theta/N, the error and its piece
#: after the step (1 + 6 + 5): 62. A steady input's sample starts in the piece the last one
#: ended in: the residuals, the update and the check after the step (the piece's 1 +- k
#: formed once): 41. Backlash alone (no dead zone or asymmetry, a gap in every lane: the
#: builds without them): 54 in full (the gap's ends x -+ a before and after, the piece
#: only Ka |e|, its drive Ka (kp (s - Kpot sc) + u0)) and 42 steady.
LOOP_FLOPS = {"deadband": (62, 41), "offset": (62, 41), "asymmetry": (62, 41),
              "saturation": (62, 41), "asymmetric_deadband": (62, 41), "backlash": (54, 42)}
#: a linear closed loop adds the feedback a02 theta, a12 theta, (a22 - 1) theta
FEEDBACK = 6
VALUES = {"coulomb_friction": {"tc_v": (0.05, 0.3)},
          "stiction": {"tc_v": (0.05, 0.3), "excess": (0.1, 1.0)},
          "delay": {"td_s": (0.0005, 0.01)}, "backlash": {"a_rad": (0.005, 0.05)},
          "deadband": {"d_v": (0.05, 0.4)}, "offset": {"u0_v": (-0.1, 0.1)},
          "asymmetry": {"k": (-0.2, 0.2)}, "saturation": {"vmax_v": (5.0, 12.0)},
          "asymmetric_deadband": {"dpos_v": (0.05, 0.3), "dneg_v": (0.05, 0.3)}}


def peak_gflops(n: int = 2000) -> float:
    a = np.random.default_rng(0).random((n, n))
    a @ a
    best = min(_timed(lambda: a @ a) for _ in range(5))
    return 2.0 * n ** 3 / best / 1e9


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def kernel_rates(folder: Path, rounds: int = ROUNDS) -> tuple[float, dict]:
    """The peak and every path's rate, best over ``rounds`` rounds that each measure the
    peak and then every path: this host's speed drifts by tens of per cent over minutes,
    and a share must compare the kernel and the peak at the host's same best."""
    from labrig.model.effects import CATALOGUE
    from labrig.model.simulate import Simulator
    from labrig.io.runs import read_dataset

    runs = read_dataset(folder)
    openl = [r for r in runs if r.loop == "open"]
    closed = [r for r in runs if r.loop == "closed"]
    rng = np.random.default_rng(1)
    plant = TRUTH * 10.0 ** rng.uniform(-0.3, 0.3, (POP, 5))
    cases, changed = [], {}
    for subset, rr in (("open", openl), ("closed", closed), ("all", runs)):
        # the samples where the input changed (and the first): the only ones an open
        # loop's input map and a closed loop's piece search run on
        changed[subset] = sum(1 + int(np.count_nonzero(np.diff(r.u))) for r in rr) \
            / sum(len(r.u) for r in rr)
    for name in FLOPS:
        effects = [] if name == "linear" else [CATALOGUE[name]()]
        ep = {name: {k: rng.uniform(lo, hi, POP) for k, (lo, hi) in VALUES[name].items()}} \
            if effects else {}
        for subset, rr in (("open", openl), ("closed", closed), ("all", runs)):
            sim = Simulator(rr, effects)
            w = [(r.speed, 1.0, r.position, 30.0, None, 0.0) for r in rr]
            sim.sse(plant, ep, w)
            cases.append((f"{name}/{subset}", sim, ep, w, sum(len(r.u) for r in rr)))
    peak, best = 0.0, {}
    for _ in range(rounds):
        peak = max(peak, peak_gflops())
        for key, sim, ep, w, n in cases:
            t = min(_timed(lambda: sim.sse(plant, ep, w)) for _ in range(15))  # as the peak: best
            best[key] = min(best.get(key, t), t)
    out = {key: {"ms": round(best[key] * 1e3, 3), "samples": n,
                 "cand_samples_per_s": POP * n / best[key]} for key, _, _, _, n in cases}
    return peak, out, changed


def path_flops(name: str, subset: str, changed: dict) -> float:
    """Flops per sample per candidate the path performs on these runs: the full count where
    the input changed, the steady one elsewhere (the samples after a lane was redone alone,
    0.02-0.1 % of them, also run in full: left out, at most 0.02 flops a sample)."""
    if subset == "closed" and name in LOOP_FLOPS:
        full, steady = LOOP_FLOPS[name]
        return steady + changed["closed"] * (full - steady)
    if subset == "closed":
        return FLOPS[name] + FEEDBACK
    if name in MAP_FLOPS:
        return FLOPS[name] - MAP_FLOPS[name] * (1.0 - changed[subset])
    return FLOPS[name]


def measure() -> dict:
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        labrig("sweep", "--sim", "-o", Path(tmp) / "sweep")
        peak, rates, changed = kernel_rates(Path(tmp) / "sweep")
    paths = {}
    for key, r in rates.items():
        name, subset = key.split("/")
        flops = round(path_flops(name, subset, changed), 2)
        limit = peak * 1e9 / flops
        paths[key] = {**r, "flops": flops, "limit_cand_samples_per_s": limit,
                      "share": round(r["cand_samples_per_s"] / limit, 3)}
    return {"peak_gflops_one_core": round(peak, 1), "paths": paths,
            "input_changes": {k: round(v, 5) for k, v in changed.items()},
            "target_share": TARGET_SHARE, "target_closed_share": TARGET_CLOSED_SHARE,
            "threads": 1, **machine(load)}


def markdown(res: dict) -> str:
    rows = ["| fitness path (one core, P = 50) | candidate-samples/s | flops/sample | "
            "share of the limit |", "|---|---|---|---|"]
    for key, r in res["paths"].items():
        name, subset = key.split("/")
        what = {"open": "open-loop runs", "closed": "the 2 closed-loop runs",
                "all": "all 6 runs (2 closed-loop)"}[subset]
        rows.append(f"| {name}, {what} | {r['cand_samples_per_s'] / 1e6:.0f} M "
                    f"| {r['flops']:.3g} | **{100 * r['share']:.0f} %** |")
    return "\n".join(rows) + "\n\n" + closed_summary(res)


#: the effects a closed loop's drive map holds (labrig/simulation/loop_kernel.py) besides backlash
MAPPED = ("deadband", "offset", "asymmetry", "saturation", "asymmetric_deadband")


def closed_summary(res: dict) -> str:
    """The closed-loop rows against their own target, in a sentence (one decimal: the
    rows sit near the target, and a rounded 25 % may be 24.6 %)."""
    share = {k: 100 * v["share"] for k, v in res["paths"].items()}
    target = 100 * res["target_closed_share"]
    names = {"deadband": "dead zone", "offset": "offset", "asymmetry": "asymmetry",
             "saturation": "rail", "asymmetric_deadband": "asymmetric dead zone",
             "backlash": "backlash", "coulomb_friction": "Coulomb friction", "delay": "delay"}
    rows = {n: share[f"{n}/closed"] for n in names}
    mapped = [rows[n] for n in MAPPED]
    met = [names[n] for n in names if rows[n] >= target]
    missed = [f"{names[n]} ({rows[n]:.1f} %)" for n in names if rows[n] < target]
    verdict = ("met by every row" if not missed else
               f"met by {', '.join(met) or 'none'}; missed by {', '.join(missed)}")
    return (f"Closed loops with an effect in them (the rows \"the 2 closed-loop runs\"): a dead "
            f"zone, offset, asymmetry, rail or asymmetric dead zone in the loop "
            f"**{min(mapped):.1f}-{max(mapped):.1f} %** of the limit, backlash "
            f"**{rows['backlash']:.1f} %**, the linear loop's Coulomb friction "
            f"{rows['coulomb_friction']:.1f} % and delay {rows['delay']:.1f} %; the target for "
            f"these rows, {target:.0f} %, is {verdict}.")


if __name__ == "__main__":
    sys.exit(main(__doc__, RESULTS, measure, markdown))
