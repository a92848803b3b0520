"""``labrig identify``: fit R, L, J, B, K (+ effects) with JFO, PSO or CO."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from .registry import command, emit_json
from ..errors import UserError
from ..identify.modelfile import load_identify_config
from .progress import Progress


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


def refuse_existing(paths, force: bool, what: str = "file") -> None:
    """Refuse to replace existing output files unless ``--force``.

    Commands call this before any fitting, so a user is not refused after a 30 s wait.
    ``what="folder"``: ``paths[0]`` is the output folder (it may exist; it must not be
    a file) and the rest are the files the command would write into it.
    """
    paths = [Path(p) for p in paths]
    if what == "folder":
        if paths[0].exists() and not paths[0].is_dir():
            raise UserError(f"{paths[0]}: exists and is not a folder; give a folder name for -o")
        paths = paths[1:]
    else:
        for p in paths:
            if p.is_dir():
                raise UserError(f"{p}: is a folder; give a file name for -o")
    existing = [p for p in paths if p.exists()]
    if existing and not force:
        more = f" (and {len(existing) - 1} more output file{'s' * (len(existing) > 2)})" \
            if len(existing) > 1 else ""
        raise UserError(f"{existing[0]}: already exists{more}; add --force to replace it")


def null_unbounded(identifiable: dict) -> dict:
    """A copy of an identifiability dict in which an interval with an infinite or NaN
    end is null, as an interval the data do not bound at all already is (a [0, inf]
    interval says nothing, and strict JSON cannot carry it)."""
    def fix(d):
        if isinstance(d, dict) and d.get("interval95") is not None and \
                not all(isinstance(x, (int, float)) and math.isfinite(x) for x in d["interval95"]):
            return {**d, "interval95": None}
        return d

    out = dict(identifiable)
    for key in ("km", "tau_m_s", "tau_e_s"):
        if key in out:
            out[key] = fix(out[key])
    if isinstance(out.get("parameters"), dict):
        out["parameters"] = {n: fix(d) for n, d in out["parameters"].items()}
    return out


def identification_dict(res) -> dict:
    """``res.to_dict()`` (keys unchanged) with unbounded intervals null and the bound and
    fit warnings under ``warnings``."""
    from ..identify.result import identification_warnings

    d = res.to_dict()
    d["identifiable"] = null_unbounded(d.get("identifiable") or {})
    d["warnings"] = identification_warnings(res)
    return d


def common_model_options(p):
    p.add_argument("data", nargs="+", help="folder(s) of runs, or run files")
    p.add_argument("--effects", help="effects by catalogue name or FILE.py:Class, comma separated")
    p.add_argument("--fix", help="fixed parameters, e.g. R=8.2,L=0.009 (SI units)")
    p.add_argument("--bounds", help="search bounds, e.g. R=1:20,deadband.d_v=0:1")
    p.add_argument("--config", help="TOML with [bounds], [fixed] and effects = [...]")
    p.add_argument("--weights", default="p=1,q=1", help="position and speed weights (default p=1,q=1)")


@command("identify", "fit the servo model (R, L, J, B, K + effects) with JFO, PSO or CO")
def cmd_identify(args):
    """Identify the DC-servo model on a data set. Reports the identifiable combinations
    (Km, tau_m, tau_e) first, then R, L, J, B, K with identifiability warnings."""
    from ..identify.engine import identify
    from ..model.effectset import EffectSet
    from ..model.model import Model
    from ..runs import read_dataset

    runs = read_dataset(args.data)
    # the command line first: naming FILE.py:Class there is the user's own choice
    asked = EffectSet.parse(args.effects)
    cfg = load_identify_config(args.config)
    start, effects = None, asked
    if args.model:
        model = Model.load(args.model)
        start = model.flat()
        effects = model.effects + [e for e in asked if e.name not in model.names]
    if not len(effects) and cfg.get("effects"):
        effects = EffectSet.parse(cfg["effects"], origin=f"{args.config}: key 'effects'")
    bounds = {**cfg.get("bounds", {}), **parse_assignments(args.bounds, "--bounds", pair=True)}
    fixed = {**cfg.get("fixed", {}), **parse_assignments(args.fix, "--fix")}
    w = parse_assignments(args.weights, "--weights")
    if set(w) - {"p", "q"}:
        raise UserError("--weights: only p (position) and q (speed)")
    methods = ["jfo", "pso", "co"] if args.method == "all" else [args.method]
    # before the fit, not after it
    refuse_existing([args.output] if args.output else [], args.force)
    if args.figures:
        refuse_existing([args.figures, Path(args.figures) / "convergence.png"], args.force,
                        what="folder")
    dataset = {"paths": [str(Path(d)) for d in args.data], "runs": [r.name for r in runs]}
    results = []
    for m in methods:
        iters = args.iters if m != "co" else 1
        with Progress(f"identify {m}", total=iters if m != "co" else args.starts) as bar:
            def cb(it, best, bar=bar):
                bar.update(it)
                bar.note(f"best fitness {best:.4g}")
            res = identify(runs, m, effects, seed=args.seed, bounds=bounds, fixed=fixed,
                           p=w.get("p", 1.0), q=w.get("q", 1.0), pop=args.pop, iters=args.iters,
                           starts=args.starts, polish=args.polish, start=start, callback=cb,
                           dataset=dataset, rule=args.rule)
        results.append(res)
    best = min(results, key=lambda r: r.fitness)
    if args.output:
        best.model().save(args.output)
    if args.figures:
        from ..report.compare_plots import save
        from ..report.identify_plots import plot_convergence

        Path(args.figures).mkdir(parents=True, exist_ok=True)
        save(plot_convergence(results), Path(args.figures) / "convergence.png", dpi=120)
    if args.json:
        dicts = {r.method: identification_dict(r) for r in results}
        if len(results) == 1:
            emit_json(dicts[results[0].method])
        else:
            emit_json({**dicts[best.method], "method": "all", "best": best.method,
                       "results": dicts, "warnings": _all_warnings(results)})
    else:
        print(format_identification(results))
        if args.output:
            print(f"\nmodel saved to {args.output}")
    return 0


def _configure(p):
    common_model_options(p)
    p.add_argument("--method", default="co", choices=["jfo", "pso", "co", "all"],
                   help="identifier (default co; all = the paper's Table 2 side by side)")
    p.add_argument("--seed", type=int, help="random seed (recorded; same seed, same result)")
    p.add_argument("--model", help="start from a saved model (its effects are kept)")
    p.add_argument("-o", "--output", help="save the model (best method) as JSON")
    p.add_argument("--force", action="store_true",
                   help="replace existing output files (-o, --figures)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--pop", type=int, default=50, help="population of JFO/PSO (default 50)")
    p.add_argument("--iters", type=int, default=200, help="iterations of JFO/PSO (default 200)")
    p.add_argument("--starts", type=int, default=8, help="CO multi-starts (default 8)")
    p.add_argument("--polish", action="store_true", help="polish JFO/PSO results with CO")
    p.add_argument("--rule", default="paper", choices=["paper", "reference"],
                   help="JFO passive/active test: the paper's (|c|) or the authors' MATLAB "
                        "code's (signed c, half the passive moves)")
    p.add_argument("--figures", help="folder for the convergence plot")


cmd_identify.configure = _configure


def _fmt(v, unit=""):
    if v is None:
        return "-"
    return f"{v:.4g}{(' ' + unit) if unit else ''}"


def format_identification(results) -> str:
    """The paper's Table 2, done right: combinations first, then R..K, side by side."""
    from ..model.servo import PLANT_NAMES, PLANT_UNITS

    heads = [r.method for r in results]
    rows = [("identifiable", None)]
    for key, label in (("km", "Km (rad/s per V)"), ("tau_m_s", "tau_m (s)"), ("tau_e_s", "tau_e (s)")):
        rows.append((label, [_interval(r.identifiable.get(key)) for r in results]))
    rows.append(("parameters", None))
    for n in PLANT_NAMES:
        rows.append((f"{n} ({PLANT_UNITS[n]})",
                     [_fmt(r.params[n]) + ("" if r.identifiable.get("parameters", {}).get(n, {}).get("identifiable", True) else " ?")
                      for r in results]))
    for r in results[:1]:
        for e, ps in r.effect_params.items():
            for k in ps:
                rows.append((f"{e}.{k}", [_fmt(x.params.get(f"{e}.{k}")) for x in results]))
    rows.append(("fit", None))
    rows.append(("fitness (eq. 26)", [_fmt(r.fitness) for r in results]))
    rows.append(("rmse/noise speed", [_fmt(r.metrics["rmse_over_noise"].get("speed")) for r in results]))
    rows.append(("rmse/noise position", [_fmt(r.metrics["rmse_over_noise"].get("position")) for r in results]))
    rows.append(("fit % speed", [_fmt(r.metrics["fit_percent"].get("speed")) for r in results]))
    rows.append(("fit % position", [_fmt(r.metrics["fit_percent"].get("position")) for r in results]))
    infos = [r.step_info() for r in results]
    rows.append(("closed-loop step", None))
    rows.append(("rise time (s)", [_fmt(i["rise_time_s"]) for i in infos]))
    rows.append(("settling time (s)", [_fmt(i["settling_time_s"]) for i in infos]))
    rows.append(("overshoot (%)", [_fmt(i["overshoot_percent"]) for i in infos]))
    rows.append(("nfev / seconds", [f"{r.result.nfev} / {r.seconds:.1f}" for r in results]))
    rows.append(("seed", [str(r.result.seed) for r in results]))
    w0 = max(len(a) for a, _ in rows) + 2
    w1 = max(24, *(len(c) + 2 for _, cs in rows if cs for c in cs))
    lines = ["".ljust(w0) + "".join(h.ljust(w1) for h in heads)]
    for label, cells in rows:
        if cells is None:
            lines.append(f"-- {label} " + "-" * (w0 + w1 * len(heads) - len(label) - 4))
        else:
            lines.append(label.ljust(w0) + "".join(c.ljust(w1) for c in cells))
    for w in _all_warnings(results):  # at a bound, fit below zero: the result is suspect
        lines.append(f"\nwarning: {w}")
    warns = {w for r in results for w in r.identifiable.get("warnings", [])}
    for w in sorted(warns):
        lines.append(f"\nwarning: {w}")
    if any("?" in c for _, cs in rows if cs for c in cs):
        lines.append("? = not identifiable from these data alone (see the warning); the "
                     "combinations above are.")
    return "\n".join(lines)


def _all_warnings(results) -> list[str]:
    """Bound and fit warnings of each result; prefixed by the method when several."""
    from ..identify.result import identification_warnings

    if len(results) == 1:
        return identification_warnings(results[0])
    return [f"{r.method}: {w}" for r in results for w in identification_warnings(r)]


def _interval(d):
    if not d:
        return "-"
    if not null_unbounded({"km": d})["km"].get("interval95"):  # none, or unbounded
        return f"{d['value']:.4g} ? (not seen by these data)"
    lo, hi = d["interval95"]
    return f"{d['value']:.4g} [{lo:.3g}, {hi:.3g}]"
