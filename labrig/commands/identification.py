"""``labrig identify``: fit R, L, J, B, K (+ effects) with JFO, PSO or CO."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

import labrig.verbs as lr
import labrig.verbs.figures as lrf
from labrig.core.defaults import METHOD, SEED
from labrig.core.errors import UserError
from labrig.commands.progress import Progress
from labrig.commands.registry import command, emit_json, refuse_existing


def parse_assignments(text: str | None, opt: str, pair: bool = False) -> dict:
    """``R=8,L=0.0085`` -> dict; with ``pair``: ``R=1:20`` -> {"R": (1, 20)}."""
    out = {}
    for item in filter(None, (s.strip() for s in (text or "").split(","))):
        key, sep, val = item.partition("=")
        if not sep:
            raise UserError(f"{opt}: '{item}' is not NAME=VALUE")
        try:
            if pair:
                lo, sep2, hi = val.partition(":")
                if not sep2:
                    raise ValueError
                out[key.strip()] = (float(lo), float(hi))
            else:
                out[key.strip()] = float(val)
            if not all(map(math.isfinite, np.atleast_1d(out[key.strip()]))):
                raise ValueError
        except ValueError:
            raise UserError(f"{opt}: '{item}' needs {'LOW:HIGH finite numbers' if pair else 'a finite number'}") from None
    return out


def common_model_options(p):
    p.add_argument("data", nargs="+", help="folder(s) of runs, or run files")
    p.add_argument("--effects", help="effects by catalogue name or FILE.py:Class, comma separated")
    p.add_argument("--fix", help="fixed parameters, e.g. R=8.2,L=0.009 (SI units)")
    p.add_argument("--bounds", help="search bounds, e.g. R=1:20,deadband.d_v=0:1")
    p.add_argument("--config", help="TOML with [bounds], [fixed] and effects = [...]")
    p.add_argument("--weights", default="p=1,q=1",
                   help="weights of position p, speed q and, when measured, armature "
                        "current i (default p=1,q=1,i=1)")
    add_through_option(p)


def add_through_option(p):
    p.add_argument("--through", default="auto", choices=["auto", "loop", "input"],
                   help="closed-loop runs: fit through the loop (the reference is the input, "
                        "the controller part of the model) or from the logged controller "
                        "output as the input; auto (default) takes input when it was logged")


def read_for_fit(args):
    """The data set as it will be fitted (closed-loop runs by --through) and the way."""
    return lr.runs_for_fit(args.data, getattr(args, "through", "auto"))


@command("identify",
         "fit the plant (R, L, J, B, K; J, B; or M, Fv) + effects with JFO, PSO or CO",
         fits=True)
def cmd_identify(args):
    """Identify the plant model on a data set (the plant the runs were recorded on:
    voltage, torque or force driven). Reports the identifiable combinations (Km, tau_m,
    tau_e) first, then the plant's parameters with identifiability warnings, and the
    physical parameters in the axis's units."""
    runs, way = read_for_fit(args)
    # the command line first: naming FILE.py:Class there is the user's own choice
    asked = lr.parse_effects(args.effects)
    cfg = lr.load_identify_config(args.config)
    model, effects = None, asked
    if args.model:
        model = lr.load_model(args.model)
        effects = model.effects_with(asked)
    if not len(effects) and cfg.get("effects"):
        effects = lr.parse_effects(cfg["effects"], origin=f"{args.config}: key 'effects'")
    bounds = {**cfg.get("bounds", {}), **parse_assignments(args.bounds, "--bounds", pair=True)}
    fixed = {**cfg.get("fixed", {}), **parse_assignments(args.fix, "--fix")}
    w = parse_assignments(args.weights, "--weights")
    if set(w) - {"p", "q", "i"}:
        raise UserError("--weights: only p (position), q (speed) and i (current)")
    methods = ["jfo", "pso", "co"] if args.method == "all" else [args.method]
    # before the fit, not after it
    refuse_existing([args.output] if args.output else [], args.force)
    if args.figures:
        refuse_existing([args.figures, Path(args.figures) / "convergence.png"], args.force,
                        what="folder")
    dataset = {"paths": [str(Path(d)) for d in args.data], "runs": [r.name for r in runs]}
    if way.runs:
        dataset["closed_loop"] = way.to_json()
    if args.seed is None:   # asked for a fresh one: draw it here, say it, so it can be repeated
        import sys

        args.seed = int(np.random.default_rng().integers(2 ** 31))
        print(f"labrig identify: seed {args.seed} (a fresh one; --seed {args.seed} repeats "
              "this fit)", file=sys.stderr)
    results = []
    for m in methods:
        iters = args.iters if m != "co" else 1
        with Progress(f"identify {m}", total=iters if m != "co" else args.starts) as bar:
            # the runs as chosen above (through=None); from the model's values, if given
            res = lr.identify(runs, m, effects, model=model, seed=args.seed, bounds=bounds,
                              fixed=fixed, through=None, p=w.get("p", 1.0), q=w.get("q", 1.0),
                              c=w.get("i", 1.0), pop=args.pop, iters=args.iters,
                              starts=args.starts, polish=args.polish, progress=bar.hook,
                              dataset=dataset, rule=args.rule, start_state=args.start_state)
        results.append(res)
    best = min(results, key=lambda r: r.fitness)
    if args.output:
        best.model().save(args.output)
    if args.figures:
        from labrig.core.figures import save

        Path(args.figures).mkdir(parents=True, exist_ok=True)
        save(lrf.convergence_figure(results), Path(args.figures) / "convergence.png", dpi=120)
    if args.json:
        dicts = {r.method: {**r.to_json(), **({"closed_loop": way.to_json()}
                                                          if way.runs else {})}
                 for r in results}
        if len(results) == 1:
            emit_json(dicts[results[0].method])
        else:
            emit_json({**dicts[best.method], "method": "all", "best": best.method,
                       "results": dicts, "warnings": lrf.fits_warnings(results)})
    else:
        if way.told:
            print(f"closed-loop runs ({way.runs}): {way.why}\n")
        print(lrf.fits_text(results))
        if args.output:
            print(f"\nmodel saved to {args.output}")
    return 0


def _seed(text: str):
    """``--seed N`` or ``--seed new`` (None: a fresh seed, drawn and printed)."""
    if text.strip().lower() == "new":
        return None
    try:
        return int(text)
    except ValueError:
        raise UserError(f"--seed: {text!r} is not a whole number or 'new'") from None


def _configure(p):
    common_model_options(p)
    p.add_argument("--method", default=METHOD, choices=["jfo", "pso", "co", "all"],
                   help=f"identifier (default {METHOD}; all = the paper's Table 2 side by side)")
    p.add_argument("--seed", type=_seed, default=SEED, metavar="N|new",
                   help=f"random seed (default {SEED}: the same files and command give the same "
                        "answer); 'new' draws a fresh one and prints it, to repeat the fit")
    p.add_argument("--model", help="start from a saved model (its effects are kept)")
    p.add_argument("-o", "--output", help="save the model (best method) as JSON")
    p.add_argument("--force", action="store_true",
                   help="replace existing output files (-o, --figures)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--pop", type=int, default=50, help="population of JFO/PSO (default 50)")
    p.add_argument("--iters", type=int, default=200, help="iterations of JFO/PSO (default 200)")
    p.add_argument("--starts", type=int, default=8, help="CO multi-starts (default 8)")
    p.add_argument("--polish", action="store_true", help="polish JFO/PSO results with CO")
    p.add_argument("--start", dest="start_state", default="auto",
                   choices=("auto", "rest", "estimate"),
                   help="each run's initial state: auto (a run that starts in motion, or an "
                        "encoder's count, gets its speed and position at the first sample "
                        "fitted; default), rest (every run from rest), estimate (every run's "
                        "fitted)")
    p.add_argument("--rule", default="paper", choices=["paper", "reference"],
                   help="JFO passive/active test: the paper's (the magnitude of c) or the authors' MATLAB "
                        "code's (signed c, half the passive moves)")
    p.add_argument("--figures", help="folder for the convergence plot")


cmd_identify.configure = _configure
