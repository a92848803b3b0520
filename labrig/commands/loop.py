"""``labrig compare``, ``labrig diagnose`` and ``labrig ladder``: the missing-physics loop."""
from __future__ import annotations

import sys
from pathlib import Path

from ..cli import command, emit_json
from ..errors import UserError
from .progress import Progress


def _load(args):
    from ..identify.modelfile import load_model
    from ..runs import read_dataset

    runs = read_dataset(args.data)
    model = load_model(args.model) if getattr(args, "model", None) else None
    return runs, model


@command("compare", "overlay model and measurement; residuals by regime; whiteness")
def cmd_compare(args):
    """For every run: measured and simulated speed and position (fit % in the legend),
    residuals in noise units with the stretches outside the noise band shaded by regime,
    residual autocorrelation and input cross-correlation with their bands."""
    from ..diagnose import ModelState, evaluate
    from ..report.compare_plots import plot_regimes, plot_run_comparison

    from ..identify.result import fit_warnings
    from .identification import refuse_existing

    runs, model = _load(args)
    out = Path(args.output)
    # the figures this command writes, refused before the simulation if they exist
    refuse_existing([out] + [out / f"compare_{r.name}.png" for r in runs] + [out / "regimes.png"],
                    args.force, what="folder")
    ev = evaluate(runs, ModelState.from_model(model))
    out.mkdir(parents=True, exist_ok=True)
    warnings, table = [], []
    lines = [f"{'run':<16}{'fit % speed':>13}{'fit % pos':>11}{'rmse/noise w':>14}{'rmse/noise th':>15}"
             "  worst stretch"]
    for rr in ev["per_run"]:
        plot_run_comparison(rr, out / f"compare_{rr['name']}.png")
        fits = {ch: c["fit_percent"] for ch, c in rr["channels"].items()}
        rms = {ch: c["rmse_over_noise"] for ch, c in rr["channels"].items()}
        st = sorted((s for c in rr["channels"].values() for s in c["stretches"]),
                    key=lambda s: -s["rms"])
        worst = f"{st[0]['regime']} at {rr['t'][st[0]['start']]:.2f} s ({st[0]['rms']:.1f} x noise)" if st else "-"
        f = lambda d, k: f"{d[k]:.1f}" if k in d else "-"  # noqa: E731
        lines.append(f"{rr['name']:<16}{f(fits, 'speed'):>13}{f(fits, 'position'):>11}"
                     f"{f(rms, 'speed'):>14}{f(rms, 'position'):>15}  {worst}")
        warnings += fit_warnings(fits, f"run '{rr['name']}'")
        table.append({"run": rr["name"], "fit_percent": fits, "rmse_over_noise": rms,
                      "worst_stretch": {"regime": st[0]["regime"], "t_s": float(rr["t"][st[0]["start"]]),
                                        "rms_over_noise": st[0]["rms"]} if st else None,
                      "figure": str(out / f"compare_{rr['name']}.png")})
    plot_regimes(ev["regimes"], out / "regimes.png")
    if args.json:
        emit_json({"model": str(args.model), "runs": table,
                   "fit_percent": ev["metrics"]["fit_percent"],
                   "rmse_over_noise": ev["metrics"]["rmse_over_noise"],
                   "figures": [t["figure"] for t in table] + [str(out / "regimes.png")],
                   "warnings": warnings})
        return 0
    print("\n".join(lines))
    for w in warnings:
        print(f"\nwarning: {w}")
    print(f"\nfigures in {out}/ (compare_<run>.png, regimes.png)")
    return 0


def _configure_compare(p):
    p.add_argument("data", nargs="+", help="folder(s) of runs")
    p.add_argument("--model", required=True, help="a model saved by `labrig identify -o`")
    p.add_argument("-o", "--output", default="compare", help="folder for the figures")
    p.add_argument("--force", action="store_true", help="replace figures already in the folder")
    p.add_argument("--json", action="store_true", help="print one JSON object")


cmd_compare.configure = _configure_compare


@command("diagnose", "where the model fails and which physical effect is missing")
def cmd_diagnose(args):
    """Locate the model's error (by regime and amplitude, against the noise floor), then
    rank every catalogue effect the model lacks: re-fitted, compared on BIC and on a
    held-out run, each with its evidence and the experiment that would confirm it."""
    from ..diagnose import diagnose
    from .identification import parse_assignments, refuse_existing

    runs, model = _load(args)
    fixed = parse_assignments(args.fix, "--fix")
    refuse_existing([args.output] if args.output else [], args.force)  # before the 30 s
    with Progress("diagnose", total=8) as bar:
        cands = [c.strip() for c in args.candidates.split(",")] if args.candidates else None
        if cands:
            from ..model.effects import get_effect

            for c in cands:
                get_effect(c)  # unknown names fail here, with the catalogue listed
        res = diagnose(runs, model, seed=args.seed, fixed=fixed, candidates=cands,
                       progress=lambda i, name: (bar.update(i), bar.note(f"re-fitting {name}")))
    if args.output:
        from ..identify.modelfile import save_model
        from ..identify.result import finite_json

        if res["recommendation"]:
            save_model(finite_json(res_model(res, runs, res["recommendation"])), args.output)
    if args.json:
        emit_json({k: v for k, v in res.items() if not k.startswith("_")})
    else:
        print(format_diagnosis(res))
    return 0


def res_model(res, runs, effect_name) -> dict:
    """The re-fitted model with ``effect_name`` added, as a model file."""
    from ..identify.engine import dataset_constants
    from ..identify.modelfile import FORMAT

    st = res["_states"][effect_name]
    plant = {k: st.params[k] for k in ("R", "L", "J", "B", "K")}
    eps = {e.name: {p.name: st.params[f"{e.name}.{p.name}"] for p in e.params} for e in st.effects}
    entry = next(e for e in res["ranking"] if e["effect"] == effect_name)
    return {"format": FORMAT, "structure": "dc-servo", "method": "co (diagnose re-fit)",
            "effects": [e.name for e in st.effects], "params": plant, "effect_params": eps,
            "constants": dataset_constants(runs), "rmse_over_noise": {"overall": entry["rmse_over_noise"]},
            "dataset": {"runs": [r.name for r in runs]}}


def _configure_diagnose(p):
    p.add_argument("data", nargs="+", help="folder(s) of runs")
    p.add_argument("--model", help="the current model (default: identify one without effects)")
    p.add_argument("--fix", help="parameters known from other measurements, e.g. R=8.2")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--candidates", help="only these catalogue effects (default: all the model lacks)")
    p.add_argument("-o", "--output", help="save the model with the recommended effect added")
    p.add_argument("--force", action="store_true", help="replace an existing -o file")
    p.add_argument("--json", action="store_true", help="print one JSON object")


cmd_diagnose.configure = _configure_diagnose


def format_diagnosis(res) -> str:
    from ..residuals import REGIME_TEXT

    b = res["baseline"]
    out = [f"baseline ({b['source']}; effects: {', '.join(b['effects']) or 'none'}): "
           f"rmse/noise {b['rmse_over_noise']['overall']:.2f} "
           f"(speed {b['rmse_over_noise'].get('speed', float('nan')):.2f}, "
           f"position {b['rmse_over_noise'].get('position', float('nan')):.2f}); 1.0 is the noise floor",
           "", "where it fails (rmse/noise by regime; share of time):"]
    for ch, regs in res["regimes"]["by_regime"].items():
        cells = ", ".join(f"{REGIME_TEXT[r]} {v['rmse_over_noise']:.2f} ({100 * v['share_of_time']:.0f}%)"
                          for r, v in sorted(regs.items(), key=lambda kv: -kv[1]["rmse_over_noise"]))
        out.append(f"  {ch}: {cells}")
    for ch, amps in res["regimes"]["by_amplitude"].items():
        out.append(f"  {ch} by run amplitude: " + ", ".join(f"{k} {v:.2f}" for k, v in amps.items()))
    out += ["", f"{'rank':<5}{'effect':<18}{'rmse/noise':>11}{'gain':>8}{'dBIC':>10}{'held-out':>16}  supported"]
    for i, e in enumerate(res["ranking"], 1):
        ho = e.get("held_out")
        hs = f"{ho['baseline']:.2f}->{ho['with_effect']:.2f}" if ho else "-"
        out.append(f"{i:<5}{e['effect']:<18}{e['rmse_over_noise']:>11.2f}{100 * e['improvement']:>7.0f}%"
                   f"{e['delta_bic']:>10.0f}{hs:>16}  {'yes' if e['supported'] else 'no'}")
    out += ["", f"recommendation: {res['recommendation'] or 'none'}", "", res["verdict"]]
    if res["recommendation"]:
        out.append(f"\nnext: labrig identify DATA --model MODEL.json --effects {res['recommendation']} -o next.json")
    return "\n".join(out)


@command("ladder", "the error falling step by step as effects are added")
def cmd_ladder(args):
    """Evaluate a chain of models (`--models m0.json,m1.json,...`, as saved by
    `labrig identify --model PREV --effects NEW -o NEXT`), or, without --models, run the
    loop automatically: identify, diagnose, add the recommended effect, repeat."""
    from ..ladder import auto_ladder, evaluate_ladder
    from ..report.compare_plots import plot_ladder
    from ..runs import read_dataset

    from .identification import refuse_existing

    runs = read_dataset(args.data)
    out = Path(args.output)
    # automatic mode saves step0..stepN.json; N is not known in advance, so every
    # step file it may write counts
    written = [] if args.models else [out / f"step{k}.json" for k in range(args.max_steps + 1)]
    refuse_existing([out, out / "ladder.png", *written], args.force, what="folder")
    if args.models:
        steps = evaluate_ladder(runs, [m.strip() for m in args.models.split(",") if m.strip()])
    else:
        with Progress("ladder", total=args.max_steps) as bar:
            steps = auto_ladder(runs, max_steps=args.max_steps, outdir=args.output, seed=args.seed,
                                log=lambda s: bar.log(s))
    out.mkdir(parents=True, exist_ok=True)
    plot_ladder(steps, out / "ladder.png")
    if args.json:
        emit_json({"steps": steps})
    else:
        print(f"{'step':<28}{'rmse/noise':>11}{'speed':>8}{'position':>10}{'fit % w':>9}{'fit % th':>10}")
        for s in steps:
            r, f = s["rmse_over_noise"], s["fit_percent"]
            print(f"{s['label']:<28}{r['overall']:>11.2f}{r.get('speed', float('nan')):>8.2f}"
                  f"{r.get('position', float('nan')):>10.2f}{f.get('speed', float('nan')):>9.2f}"
                  f"{f.get('position', float('nan')):>10.2f}")
        print(f"noise floor = 1.00; figure: {out / 'ladder.png'}")
    return 0


def _configure_ladder(p):
    p.add_argument("data", nargs="+", help="folder(s) of runs")
    p.add_argument("--models", help="comma-separated model files, in order")
    p.add_argument("--max-steps", type=int, default=3, help="automatic mode: at most this many effects")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", default="ladder", help="folder for models and the figure")
    p.add_argument("--force", action="store_true", help="replace files already in the folder")
    p.add_argument("--json", action="store_true")


cmd_ladder.configure = _configure_ladder
