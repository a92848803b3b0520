"""Benchmark: one `diagnose` round against the same round written the way a scipy user would.

    python benchmarks/bench_peer.py             # measure (about 10 min), write results_peer.json
    python benchmarks/bench_peer.py --markdown  # the README rows of the recorded result

In ONE run, on this machine:

* the data: the README's five-run case (`labrig sweep --sim --rig
  configs/rig_deadzone_rail.toml --plan configs/plan_five.toml`: five open-loop square
  waves, 5 x 8500 samples at 1 kHz, a dead zone and a rail hidden) and its linear model
  (`labrig identify RUNS -o m_lin.json`);
* **labrig**: `labrig diagnose RUNS --model m_lin.json --json` as a subprocess (the whole
  process: interpreter, imports, numba's cache, every candidate re-fitted from scanned
  starts in two basins, the cross-validation of the best four, the files written),
  median of 3 after a warm-up;
* **the peer**: the round a scipy user writes: every catalogue effect the model lacks,
  fitted from the *same* starts (labrig's own scan, `labrig.diagnosis.loop.starts.starts_for`) with
  `scipy.optimize.least_squares` (trf, the same bounds and coordinates, a 2-point
  Jacobian, the same evaluation limit), over a per-candidate simulation of the same
  model: `scipy.signal.lsim` of the servo's state space (`ServoParams.A_open/B_open/
  C_out`) fed the input through the effect's static map (dead zones, offset, asymmetry,
  rail; a delay shifts the input; backlash is a play loop over the output), and
  `scipy.integrate.solve_ivp` (RK45, one step per sample at most) for friction, which
  lsim cannot hold. The same objective (each channel over its noise floor, the same
  weights). No cross-validation: the peer's round is the candidates' fits only, so the
  ratio is conservative.

Honest extrapolation: two candidates (the dead zone and the rail) are fitted in full from
both starts, which gives the peer's evaluations per fit (its `nfev` plus `njev` times the
parameters, the Jacobian's own evaluations); every candidate's evaluation is timed
(median of 3); the peer's round = sum over candidates of starts x evaluations per fit x
seconds per evaluation. Target: labrig >= 100x the peer.
"""
from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from whole_process import labrig, machine, main, readme_row

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results_peer.json"
TARGET = 100.0
RIG = HERE.parent / "configs" / "rig_deadzone_rail.toml"
PLAN = HERE.parent / "configs" / "plan_five.toml"
FITTED = ("deadband", "saturation")
MAX_NFEV = 60        # labrig's re-fits' limit (labrig.diagnosis.loop.refit.fit)


class Peer:
    """The scipy user's simulation of one candidate structure on every run."""

    def __init__(self, runs, effects, space, weights):
        from labrig.identification.objective import Objective
        from labrig.model.simulate import prepare

        obj = Objective(runs, effects, space, p=weights.p, q=weights.q)
        self.runs = prepare(runs)
        self.effects = list(effects)
        self.space = space
        self.scale_w = np.sqrt(weights.q) / obj.sigma_w / np.sqrt(obj.m)
        self.scale_th = np.sqrt(weights.p) / obj.sigma_theta / np.sqrt(obj.m)
        self.evaluations = 0

    def simulate(self, phys: dict, run):
        from scipy import signal
        from scipy.integrate import solve_ivp

        from labrig.model.servo import ServoParams

        sp = ServoParams(phys["R"], phys["L"], phys["J"], phys["B"], phys["K"], Ka=run.Ka,
                         N=run.N, Kt=run.Kt, Kpot=run.Kpot)
        t = np.arange(len(run.u)) * run.dt
        u = run.u.astype(float)
        names = {e.name for e in self.effects}
        for e in self.effects:                       # static maps of the bridge input
            if e.stage == "input":
                u = e.apply(u, **{k: phys[f"{e.name}.{k}"] for k in e.param_names()})
        v = u * run.Ka
        for e in self.effects:                       # the armature rail
            if e.stage == "drive":
                v = e.apply(v, **{k: phys[f"{e.name}.{k}"] for k in e.param_names()})
        if "delay" in names:
            shift = int(round(phys["delay.td_s"] / run.dt))
            v = np.concatenate([np.zeros(shift), v[:len(v) - shift]])
        x0 = [0.0, 0.0, run.theta0 * run.N]
        A, B, C = sp.A_open(), sp.B_open() / run.Ka, sp.C_out()
        friction = [e for e in self.effects if e.stage == "friction"]
        if friction:
            # tc_v: the friction torque as the bridge volts that would hold it at stall
            e = friction[0]
            tc = phys[f"{e.name}.tc_v"] * run.Ka * phys["K"] / phys["R"]
            dt = run.dt

            def rhs(tt, x):
                k = min(int(tt / dt), len(v) - 1)
                dx = A @ x + B[:, 0] * v[k]
                dx[1] -= tc * np.sign(x[1]) / phys["J"]
                return dx

            sol = solve_ivp(rhs, (0.0, t[-1]), x0, t_eval=t, max_step=dt, rtol=1e-6)
            y = C @ sol.y
            w, th = y[0], y[1]
        else:
            _, y, _ = signal.lsim(signal.StateSpace(A, B, C, np.zeros((2, 1))), v, t, X0=x0,
                                  interp=False)   # the bridge holds each sample
            w, th = y[:, 0], y[:, 1]
        if "backlash" in names:                      # the play on the output shaft
            a = phys["backlash.a_rad"]
            out = np.empty_like(th)
            p = th[0]
            for k in range(len(th)):
                p = min(max(p, th[k] - a), th[k] + a)
                out[k] = p
            th = out
        return w, th

    def residuals(self, x):
        self.evaluations += 1
        phys = self.space.as_dict(self.space.to_physical(x)[0])
        parts = []
        for r in self.runs:
            w, th = self.simulate(phys, r)
            parts += [(r.w - w) * self.scale_w, (r.theta - th) * self.scale_th]
        return np.concatenate(parts)


def peer_round(runs_dir: Path, model_file: Path) -> dict:
    from scipy.optimize import least_squares

    import labrig as lr
    from labrig.identification.objective import build_space
    from labrig.diagnosis.loop.diagnose import balanced_weights, candidate_names
    from labrig.diagnosis.evidence.evaluation import evaluate
    from labrig.diagnosis.loop.starts import starts_for
    from labrig.model.effects import get_effect
    from labrig.model.plants import plant_of_runs
    from labrig.model.reach import Reach

    runs = lr.read_runs(runs_dir)
    base = lr.load_model(model_file)
    weights = balanced_weights(evaluate(runs, base))
    reach = Reach.of(runs, base)
    out = {}
    for name in candidate_names(base):
        eff = get_effect(name)
        effects = base.effects + [eff]
        starts = starts_for(runs, base.flat(), effects, eff, reach, {}, weights)
        space = build_space(effects, None, {}, reach=reach, plant=plant_of_runs(runs))
        peer = Peer(runs, effects, space, weights)
        x0 = space.to_search(starts[0])
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            peer.residuals(x0)
            times.append(time.perf_counter() - t0)
        rec = {"starts": len(starts), "seconds_per_evaluation": statistics.median(times),
               "parameters": len(x0)}
        if name in FITTED:
            evals, secs, costs = [], [], []
            lo, hi = space.search_bounds()
            for s in starts:
                peer.evaluations = 0
                t0 = time.perf_counter()
                res = least_squares(peer.residuals, space.to_search(s), bounds=(lo, hi),
                                    method="trf", max_nfev=MAX_NFEV)
                secs.append(time.perf_counter() - t0)
                evals.append(peer.evaluations)
                costs.append(float(np.sqrt(2 * res.cost)))
            rec.update({"fit_seconds": secs, "fit_evaluations": evals, "fitness": costs})
        out[name] = rec
        print(f"peer {name}: {rec}", file=sys.stderr, flush=True)
    per_fit = statistics.mean(e for r in out.values() for e in r.get("fit_evaluations", []))
    total = sum(r["starts"] * per_fit * r["seconds_per_evaluation"] for r in out.values())
    return {"candidates": out, "evaluations_per_fit": per_fit, "round_seconds": total}


def measure() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        labrig("sweep", "--sim", "--rig", RIG, "--plan", PLAN, "-o", tmp / "runs")
        labrig("identify", tmp / "runs", "-o", tmp / "m_lin.json")
        labrig("diagnose", tmp / "runs", "--model", tmp / "m_lin.json", "--json")   # warm-up
        load = os.getloadavg()[0]
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            p = labrig("diagnose", tmp / "runs", "--model", tmp / "m_lin.json", "--json")
            times.append(time.perf_counter() - t0)
        doc = json.loads(p.stdout)
        ours = statistics.median(times)
        peer = peer_round(tmp / "runs", tmp / "m_lin.json")
    ratio = peer["round_seconds"] / ours
    return {"labrig": {"command": "labrig diagnose RUNS --model m_lin.json --json (whole "
                       "process, median of 3)", "seconds": round(ours, 2),
                       "all": [round(t, 2) for t in times],
                       "recommendation": doc.get("recommendation"),
                       "candidates": [c["effect"] for c in doc["ranking"]]},
            "peer": peer, "ratio": round(ratio, 1), "target": TARGET, "pass": ratio >= TARGET,
            **machine(load)}


def markdown(res: dict) -> str:
    p = res["peer"]
    fitted = ", ".join(f"{n} {statistics.mean(c['fit_seconds']):.0f} s per fit"
                       for n, c in p["candidates"].items() if "fit_seconds" in c)
    return readme_row("one `diagnose` round (README five-run case, from the linear model) "
                      "against the same round in scipy (least_squares over lsim/solve_ivp per "
                      f"candidate, same starts; {len(p['candidates'])} candidates, "
                      f"{p['evaluations_per_fit']:.0f} evaluations per fit measured on {fitted})",
                      f"labrig **{res['labrig']['seconds']:.1f} s** whole process; the peer "
                      f"{p['round_seconds']:.0f} s = **{res['ratio']:.0f}x**",
                      f">= {res['target']:.0f}x", res["pass"])


if __name__ == "__main__":
    sys.exit(main(__doc__, RESULTS, measure, markdown))
