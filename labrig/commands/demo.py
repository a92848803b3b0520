"""``labrig demo``: the main job on the simulated rig, from a fresh clone.

sweep -> analyse -> identify (JFO, PSO, CO) -> diagnose -> add the recommended effect
-> compare and error ladder -> report, each stage's output kept in the work folder so
a student can open every file and rerun any stage by hand.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from labrig.commands.registry import command
from labrig.core.fileio import atomic_write, json_default
import labrig.verbs as lr
import labrig.verbs.figures as lrf


def _say(text):
    print(text, file=sys.stderr, flush=True)


def _dump(obj, path):

    atomic_write(Path(path), json.dumps(obj, indent=2, default=json_default) + "\n")


@command("demo", "the whole lab on the simulated rig: sweep to report", fits=True)
def cmd_demo(args):
    """Run the main job on the simulated rig: sweep, analyse, identify with JFO, PSO and
    CO, diagnose what the model misses, add the recommended effect, compare, error
    ladder, report. Everything lands in the output folder."""
    from labrig.core.figures import save
    from labrig.report.html import build_report

    t0 = time.perf_counter()
    out = Path(args.output)
    runs_dir, figs = out / "runs", out / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    rig = lr.load_rig(args.rig)
    plan = lr.load_plan(args.plan, rig)

    _say(f"[1/7] sweep on the simulated rig ({len(plan)} experiments) -> {runs_dir}")
    make, _, _ = lr.open_bridge(rig, seed=args.seed)
    lr.play(make(), plan, rig, runs_dir, resume=True)
    runs = lr.read_runs(runs_dir, through=None)    # every fit below: the runs as read

    _say("[2/7] analyse: deadband, Km, tau_m, Kt, gain trend")
    ana = lr.analyse([runs_dir])
    for name, fig in ana.figures().items():
        save(fig, figs / name)
    _dump(ana.to_json(), out / "analysis.json")
    print(ana.summary())

    methods = ["co"] if args.quick else ["jfo", "pso", "co"]
    _say(f"[3/7] identify the linear model with {', '.join(m.upper() for m in methods)}")
    results = [lr.identify(runs, m, [], seed=args.seed, through=None, pop=50,
                           iters=200 if not args.quick else 60, starts=4) for m in methods]
    save(lrf.convergence_figure(results), figs / "convergence.png", dpi=120)
    best = min(results, key=lambda r: r.fitness)
    _dump({**best.to_dict(), "method": "all", "best": best.method,
           "results": {r.method: r.to_dict() for r in results}}, out / "identify_all.json")
    best.model().save(out / "model0.json")
    print("\n" + lrf.fits_text(results))

    _say("[4/7] diagnose: where the model fails and which effect is missing")
    model0 = lr.load_model(out / "model0.json")
    diag = lr.diagnose(runs, model0, seed=args.seed, through=None)
    _dump(diag.to_json(), out / "diagnosis.json")
    rec = diag.recommendation
    print(f"\n{diag.verdict}")

    models = [out / "model0.json"]
    if rec:
        _say(f"[5/7] identify again with {rec} added (warm start from model0)")
        res1 = lr.add_effect(runs, model0, rec, seed=args.seed, through=None, starts=1)
        res1.model().save(out / "model1.json")
        models.append(out / "model1.json")
    else:
        _say("[5/7] nothing to add: the model is at the noise floor")

    _say("[6/7] compare and the error ladder")
    ev = lr.compare(runs, models[-1], through=None)
    ev0 = lr.compare(runs, model0, through=None)
    worst = ev0.worst_run()
    save(lrf.run_figure(worst, title=f"{worst['name']}: linear model vs measurement"),
         figs / f"compare_{worst['name']}_model0.png")
    for rr in ev.per_run:
        save(lrf.run_figure(rr), figs / f"compare_{rr['name']}.png")
    save(lrf.regimes_figure(ev0.regimes, title="Where the linear model fails"),
         figs / "regimes.png")
    ladder = lr.ladder(runs, [str(m) for m in models], through=None)
    save(ladder.plot(), figs / "ladder.png", dpi=120)
    _dump(ladder.to_json(), out / "ladder.json")

    _say("[7/7] report")
    # every artefact above is in `out`, so the report only reads and renders
    report = build_report(runs_dir, out / "report.html", work=out, seed=args.seed, log=_say)
    dt = time.perf_counter() - t0
    print("\n== summary ==")
    print(f"analysis: km = {ana.km:.4g} rad/s per V, tau = {ana.tau_s:.4g} s, "
          f"gain trend {ana.gain_trend}" if ana.km and ana.tau_s else "analysis: see above")
    for s in ladder.steps:
        print(f"  {s.label:<24} rmse/noise {s.rmse_over_noise['overall']:.2f}")
    print(f"recommendation: {rec or 'none (at the noise floor)'}")
    print(f"outputs in {out}/" + (f", report: {report}" if report else ""))
    print(f"demo finished in {dt:.0f} s")
    return 0


def _configure(p):
    p.add_argument("-o", "--output", default="demo_out", help="work folder (default demo_out)")
    p.add_argument("--rig", help="rig file (default: configs/rig_default.toml)")
    p.add_argument("--plan", help="sweep plan (default: the rig family's, "
                   "configs/plan_default.toml (MS150) or configs/plan_arduino.toml (H-bridge))")
    p.add_argument("--seed", type=int, default=1,
                   help="seed of the simulated rig's noise and of the fits (default 1)")
    p.add_argument("--quick", action="store_true", help="CO only, fewer iterations")


cmd_demo.configure = _configure
