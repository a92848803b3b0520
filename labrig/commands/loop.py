"""``labrig compare``, ``labrig diagnose`` and ``labrig ladder``: the missing-physics loop."""
from __future__ import annotations

import sys
from pathlib import Path

import labrig.verbs as lr
import labrig.verbs.figures as lrf
from labrig.commands.identification import add_through_option, parse_assignments, read_for_fit
from labrig.commands.progress import Progress
from labrig.commands.registry import add_loop_option, command, emit_json, refuse_existing
from labrig.core.defaults import SEED
from labrig.core.errors import UserError
from labrig.core.fileio import atomic_write, write_json


def _load(args):

    runs, way = read_for_fit(args)
    if way.told and not getattr(args, "json", False):
        print(f"closed-loop runs ({way.runs}): {way.why}\n")
    model = lr.load_model(args.model) if getattr(args, "model", None) else None
    return runs, model


@command("compare", "overlay model and measurement; residuals by regime; whiteness")
def cmd_compare(args):
    """For every run: measured and simulated speed and position (fit % in the legend),
    residuals in noise units with the stretches outside the noise band shaded by regime,
    residual autocorrelation and input cross-correlation with their bands."""
    from labrig.core.figures import save


    runs, model = _load(args)
    hand = parse_assignments(args.set, "--set")
    out = Path(args.output)
    # the figures this command writes, refused before the simulation if they exist
    refuse_existing([out] + [out / f"compare_{r.name}.png" for r in runs] + [out / "regimes.png"],
                    args.force, what="folder")
    if args.save_model:
        refuse_existing([args.save_model], args.force)
    if hand:
        try:
            model = lr.set_by_hand(runs, model, hand)
        except UserError as exc:   # the verb names the parameter; the command, its option
            raise UserError(f"--set: {exc}") from None
    ev = lr.compare(runs, model, through=None)
    out.mkdir(parents=True, exist_ok=True)
    table = ev.runs()
    for rr, row in zip(ev.per_run, table):
        row["figure"] = str(save(lrf.run_figure(rr), out / f"compare_{rr['name']}.png"))
    save(lrf.regimes_figure(ev.regimes), out / "regimes.png")
    if args.save_model:   # the hand-set model: `identify --model` fits from it
        model.save(args.save_model)
    if args.json:
        emit_json({"model": str(args.model), "set_by_hand": hand,
                   "saved_model": args.save_model, "runs": table,
                   "fit_percent": ev.metrics["fit_percent"],
                   "rmse_over_noise": ev.metrics["rmse_over_noise"],
                   "figures": [t["figure"] for t in table] + [str(out / "regimes.png")],
                   "warnings": ev.warnings()})
        return 0
    print(ev.table_rows().to_text())
    for w in ev.warnings():
        print(f"\nwarning: {w}")
    print(f"\nfigures in {out}/ (compare_<run>.png, regimes.png)")
    if hand:
        print("set by hand, nothing fitted: " + ", ".join(f"{k}={v:g}" for k, v in hand.items()))
    if args.save_model:
        print(f"the model as compared: {args.save_model} (fit from it: labrig identify "
              f"{' '.join(args.data)} --model {args.save_model} --starts 1)")
    return 0


def _last_options(p, force_help: str) -> None:
    """The options each loop command's list ends with: ``--force`` (``force_help``
    says what it replaces), ``--json`` and ``--through``."""
    p.add_argument("--force", action="store_true", help=force_help)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_through_option(p)


def _configure_compare(p):
    p.add_argument("data", nargs="+", help="folder(s) of runs")
    p.add_argument("--model", required=True, help="a model saved by `labrig identify -o`")
    p.add_argument("-o", "--output", default="compare", help="folder for the figures")
    p.add_argument("--set", metavar="NAME=VALUE,...",
                   help="set parameters by hand, nothing fitted: a plant's (J=4e-5) or an "
                        "effect's (coulomb_friction.tc_v=0.13; an effect the model lacks is "
                        "added); see what the value does to the curves before any fit says")
    p.add_argument("--save-model", metavar="FILE",
                   help="save the model as compared (with --set: the hand-set one)")
    _last_options(p, "replace figures already in the folder (and the --save-model file)")


cmd_compare.configure = _configure_compare


@command("diagnose", "where the model fails and which physical effect is missing", fits=True)
def cmd_diagnose(args):
    """Locate the model's error (by regime and amplitude, against each channel's noise
    floor), then rank every catalogue effect the model lacks: re-fitted from scanned
    starts, compared on BIC and by cross-validation, each with its evidence and the
    experiment that would confirm it."""

    runs, model = _load(args)
    fixed = parse_assignments(args.fix, "--fix")
    weights = _weights(args.weights)
    if args.ask_rig and not args.auto:
        raise UserError("--ask-rig: only with --auto (the confusable pairs come from its rounds)")
    if args.auto:
        return _auto(args, runs, model, fixed, weights)
    refuse_existing([args.output] if args.output else [], args.force)  # before the 30 s
    with Progress("diagnose", total=8) as bar:
        cands = [c.strip() for c in args.candidates.split(",")] if args.candidates else None
        # (unknown names fail in the verb, with the catalogue listed)
        res = lr.diagnose(runs, model, seed=args.seed, fixed=fixed, candidates=cands,
                          weights=weights, through=None, progress=bar.hook,
                          screen=not args.full)
    keep = res.recommended_model()
    if args.output and keep is not None:
        keep.save(args.output)
    check = _decide(runs, model, args.seed)
    saved = _saved_text(args.output, res.recommendation, res.refined) if args.output else None
    if args.json:
        emit_json(_json_with_check(res, check))
        if saved and not res.recommendation:  # stdout is the JSON: its note goes beside it
            print(f"labrig: {saved}", file=sys.stderr)
    else:
        print(_text_with_check(res, check))
        if saved:
            print(f"\n{saved}")
    return 0


def _saved_text(output, recommendation, refined=False) -> str:
    """What ``diagnose -o FILE`` did with FILE, in one line."""
    if recommendation:
        return f"model saved to {output}"
    if refined:
        return (f"no effect earns its parameters; the model with its own parameters "
                f"re-fitted to better values saved to {output}")
    kept = " (the file already there is left as it was)" if Path(output).exists() else ""
    return (f"nothing saved to {output}: there is no recommendation (no effect earns its "
            f"parameters), so there is no new model to save{kept}")


def _decide(runs, model, seed):
    """Runs proposed by `labrig propose` among the data: how the pair's separation moved."""
    with Progress("the proposed runs", total=None) as bar:
        return lr.decide(runs, model, seed=seed, through=None, progress=bar.hook)


def _json_with_check(res, check) -> dict:
    """``res``'s JSON, with the proposal check's when the data hold proposed runs."""
    return {**res.to_json(), **({"proposal_check": check.to_json()} if check else {})}


def _text_with_check(res, check) -> str:
    """``res``'s text, then the proposal check's after a blank line when there is one."""
    return res.to_text() + ("\n\n" + check.to_text() if check else "")


AUTO_FILES = ("model.json", "ladder.json", "ladder.png", "diagnosis.json")


def _weights(text):
    """``--weights p=..,q=..`` -> Weights (None: balanced on the starting model)."""
    if not text:
        return None

    w = parse_assignments(text, "--weights")
    if set(w) - {"p", "q"}:
        raise UserError("--weights: only p (position) and q (speed), e.g. p=1,q=1")
    p, q = float(w.get("p", 1.0)), float(w.get("q", 1.0))
    if p < 0 or q < 0 or p + q == 0:
        raise UserError("--weights: p and q must be >= 0 and not both 0")
    return lr.channel_weights(p=p, q=q)


def _auto(args, runs, model, fixed, weights) -> int:
    """``diagnose --auto``: the rounds to the end; -o is a folder of their results."""
    from labrig.core.figures import save

    if args.max_rounds < 1:
        raise UserError(f"--max-rounds: {args.max_rounds} adds nothing; give 1 or more")
    if args.ask_rig and not (args.sim or args.port):
        raise UserError("--ask-rig: say which rig to ask, --sim or --port DEV")
    if args.step_s is not None and not args.ask_rig:
        raise UserError("--step-s: only with --ask-rig (the length of each experiment asked)")
    if args.loop != "open" and not args.ask_rig:
        raise UserError("--loop: only with --ask-rig (which inputs the rig is asked to play)")
    if args.step_s is not None and not 2.0 <= args.step_s <= args.budget_s:
        raise UserError(f"--step-s: {args.step_s:g} s; give 2 s up to --budget-s "
                        f"({args.budget_s:g} s)")
    out = Path(args.output) if args.output else None
    if out:
        refuse_existing([out] + [out / f for f in AUTO_FILES], args.force, what="folder")
    if args.candidates:
        raise UserError("--candidates: not with --auto (every round tries the whole catalogue)")
    # the rig to ask is reached before the search (an unplugged board is said at once)
    rig = lr.load_rig(args.rig) if args.ask_rig else None
    make = _reachable(rig, args) if args.ask_rig else None
    with Progress("diagnose --auto", total=args.max_rounds) as bar:
        res = lr.auto(runs, model, max_rounds=args.max_rounds, seed=args.seed, fixed=fixed,
                      weights=weights, through=None, progress=bar.hook, screen=not args.full)
    if out:
        out.mkdir(parents=True, exist_ok=True)
        res.model.save(out / "model.json")
        write_json(out / "ladder.json", res.ladder.to_json())
        write_json(out / "diagnosis.json", res.to_json())
        save(res.plot(), out / "ladder.png", dpi=120)
    check = _decide(runs, model, args.seed)
    asked = _ask_rig(args, runs, res, rig, make) if args.ask_rig else None
    if args.json:
        emit_json({**_json_with_check(res, check), **({"asked": asked} if asked else {})})
    else:
        print(_text_with_check(res, check))
        if out:
            print(f"\nwritten to {out}/: {', '.join(AUTO_FILES)}")
        if asked:
            print("\n" + asked["text"])
    return 0


def _ask_rig(args, runs, res, rig, make) -> dict:
    """``--ask-rig``: propose the experiment for the first confusable pair, play it on the
    rig (``make()`` a bridge to it, within the rig file's limits), and decide with the new
    run."""

    if not res.confusable:
        return {"text": "asked the rig nothing: no two effects explain the data about "
                        "equally well", "pair": None}
    first, second = (lr.proposed_as(n) for n in (res.confusable[0].first,
                                                     res.confusable[0].second))
    newdir = Path(args.data[0]) / "asked"
    if args.step_s:
        return _ask_until_sure(args, runs, res, f"{first},{second}", rig, make, newdir)
    refuse_existing([newdir, newdir / "plan.toml", newdir / "proposed.csv"], args.force,
                    what="folder")
    with Progress("ask the rig", total=None) as bar:
        # (the input within the data's amplitudes; the rig bounds the travel)
        prop = lr.propose(runs, res.model, f"{first},{second}", budget_s=args.budget_s,
                          seed=args.seed, progress=bar.hook, rig=rig, through=None,
                          rig_amplitude=False, loop=args.loop)
        if not prop.separates:   # nothing worth playing: the rig is not asked
            return {"pair": list(prop.pair), "proposal": prop.to_json(), "folder": None,
                    "decision": None,
                    "text": f"asked the rig nothing: no input within {args.budget_s:g} s is "
                            f"predicted to separate {first} and {second}; {prop.advice}"}
        newdir.mkdir(parents=True, exist_ok=True)
        for old in (newdir / "proposed.csv", newdir / "proposed.json"):   # --force: replaced
            old.unlink(missing_ok=True)
        atomic_write(newdir / "plan.toml", prop.to_toml())
        bar.log(f"playing {prop.chosen.candidate.label} on the rig")
        lr.play(make(), lr.load_plan(newdir / "plan.toml", rig), rig, newdir)
        d = lr.decide([*args.data, newdir], res.model, seed=args.seed, through=None,
                      progress=bar.hook)
    return {"pair": list(prop.pair), "proposal": prop.to_json(), "folder": str(newdir),
            "decision": d.to_json(),
            "text": f"asked the rig: {prop.chosen.candidate.label} ({prop.why}); runs in "
                    f"{newdir}/\n{d.to_text()}"}


def _reachable(rig, args):
    """How to reach the rig asked; a board is greeted now, before any proposal is
    computed or written (an unplugged port is said at once, with nothing left behind)."""
    make, _, _ = lr.open_bridge(rig, port=None if args.sim else args.port)
    if args.port:
        board = make()
        try:
            board.open()
        finally:
            board.close()
    return make


def _ask_until_sure(args, runs, res, between, rig, make, newdir) -> dict:
    """``--ask-rig --step-s S``: experiments of at most S seconds played one at a time
    into DATA/asked/step<k>/, each chosen on the data so far, until one explanation wins
    or the budget is spent."""
    refuse_existing([newdir], args.force, what="folder")

    def play(plan, k):
        folder = newdir / f"step{k}"
        if folder.exists():   # --force: the earlier asking's step is replaced
            for old in folder.iterdir():
                old.unlink()
        folder.mkdir(parents=True, exist_ok=True)
        atomic_write(folder / "plan.toml", plan)
        lr.play(make(), lr.load_plan(folder / "plan.toml", rig), rig, folder)
        return lr.read_runs(folder, through=None)

    with Progress("ask the rig", total=None) as bar:
        asking = lr.ask_until_sure(runs, res.model, between, play, budget_s=args.budget_s,
                                   step_s=args.step_s, seed=args.seed, rig=rig, through=None,
                                   rig_amplitude=False, loop=args.loop, progress=bar.hook)
    return {"pair": list(asking.pair), "asking": asking.to_json(), "folder": str(newdir),
            "decision": asking.decision.to_json() if asking.decision else None,
            "text": f"{asking.to_text()}\nruns in {newdir}/step<k>/"}


def _configure_diagnose(p):
    p.add_argument("data", nargs="+", help="folder(s) of runs")
    p.add_argument("--model", help="the current model (default: identify one without effects)")
    p.add_argument("--fix", help="parameters known from other measurements, e.g. R=8.2")
    p.add_argument("--weights", help="channel weights p (position), q (speed), e.g. p=1,q=1 "
                   "(default: balanced so that neither channel drowns the other)")
    p.add_argument("--seed", type=int, default=SEED,
                   help="random seed of the re-fits (and, with --ask-rig, of the proposal); "
                        f"same seed, same result (default {SEED})")
    p.add_argument("--candidates", help="only these catalogue effects (default: all the model lacks)")
    p.add_argument("-o", "--output", help="save the model with the recommended effect added "
                   "(with none: the model itself where its candidates found better values "
                   "of its own parameters, else nothing is saved; with --auto: a folder "
                   "for the final model, the ladder and the rounds)")
    p.add_argument("--auto", action="store_true",
                   help="run the rounds to the end: add the recommended effect and diagnose "
                        "again until nothing more earns its parameters")
    p.add_argument("--max-rounds", type=int, default=3,
                   help="with --auto: add at most this many effects (default 3)")
    p.add_argument("--ask-rig", action="store_true",
                   help="with --auto: when two effects explain the data about equally well, "
                        "propose the experiment that tells them apart, play it on the rig "
                        "(--sim or --port) into DATA/asked and decide")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--sim", action="store_true", help="--ask-rig on the simulated rig")
    src.add_argument("--port", help="--ask-rig on the board at this serial device")
    p.add_argument("--rig", help="--ask-rig: the rig file (its limits hold); default "
                                 "configs/rig_default.toml")
    p.add_argument("--budget-s", type=float, default=20.0,
                   help="--ask-rig: at most this many seconds of new data (default 20)")
    p.add_argument("--step-s", type=float, default=None,
                   help="--ask-rig: ask until sure, in experiments of at most this many "
                        "seconds played one at a time (each chosen on the data so far; it "
                        "stops as soon as one explanation wins), instead of one plan of the "
                        "whole budget")
    add_loop_option(p)
    p.add_argument("--full", action="store_true", help="re-fit every candidate to the end "
                   "(default: one that stalls without gaining is screened out early)")
    _last_options(p, "replace an existing -o file")


cmd_diagnose.configure = _configure_diagnose


@command("ladder", "the error falling step by step as effects are added", fits=True)
def cmd_ladder(args):
    """Evaluate a chain of models (`--models m0.json,m1.json,...`, as saved by
    `labrig identify --model PREV --effects NEW -o NEXT`), or, without --models, run the
    loop automatically: identify, diagnose, add the recommended effect, repeat."""
    from labrig.core.figures import save


    runs, _ = read_for_fit(args)
    out = Path(args.output)
    # automatic mode saves step0..stepN.json (swaps and removals add rungs): any step file
    written = [] if args.models else (sorted(out.glob("step*.json")) if out.is_dir() else [])
    refuse_existing([out, out / "ladder.png", *written], args.force, what="folder")
    out.mkdir(parents=True, exist_ok=True)
    if args.models:
        ladder = lr.ladder(runs, [m.strip() for m in args.models.split(",") if m.strip()],
                           through=None)
    else:
        with Progress("ladder", total=args.max_steps) as bar:
            ladder = lr.auto_ladder(runs, max_steps=args.max_steps, output=out,
                                    seed=args.seed, through=None, progress=bar.hook)
    save(ladder.plot(), out / "ladder.png", dpi=120)
    if args.json:
        emit_json(ladder.to_json())
    else:
        print(ladder.table_rows().to_text())
        print(f"figure: {out / 'ladder.png'}")
    return 0


def _configure_ladder(p):
    p.add_argument("data", nargs="+", help="folder(s) of runs")
    p.add_argument("--models", help="comma-separated model files, in order")
    p.add_argument("--max-steps", type=int, default=3, help="automatic mode: at most this many effects")
    p.add_argument("--seed", type=int, default=SEED,
                   help="automatic mode: random seed of the fits; same seed, same ladder "
                        f"(default {SEED})")
    p.add_argument("-o", "--output", default="ladder", help="folder for models and the figure")
    _last_options(p, "replace files already in the folder")


cmd_ladder.configure = _configure_ladder
