"""``labrig propose``: the experiment that tells two explanations apart."""
from __future__ import annotations

from pathlib import Path

from labrig.commands.registry import (add_loop_option, command, emit_json, float_opt,
                                     refuse_existing)
from labrig.commands.progress import Progress
from labrig.core.defaults import SEED
import labrig.verbs as lr
from labrig.commands.identification import add_through_option, read_for_fit
from labrig.core.fileio import atomic_write


@command("propose", "propose the experiment that tells two explanations apart")
def cmd_propose(args):
    """Fit the model with each of two effects (by default the model's effect and its usual
    look-alike), search the inputs the rig can play (ramps through zero, dwells near the
    threshold, coast-downs, reversals, staircases, steps across the range) for the one that
    best separates them after the rival re-fits, and write it as a plan to run with
    `labrig sweep`. The separation it predicts is the one `labrig diagnose DIR DIR/new`
    reports afterwards: the worse rmse/noise over the better, minus one (1 or more is
    decisive). When no input within the limits reaches it, it says so and what would
    help, writes no plan and exits with status 1."""
    from labrig.core.figures import save

    out = Path(args.output)
    figure = out.with_suffix(".png")
    refuse_existing([out, figure], args.force)
    out.parent.mkdir(parents=True, exist_ok=True)   # before the work, not after it
    runs, _ = read_for_fit(args)
    model = lr.load_model(args.model)
    # the rig file may allow more than the data use, and knows its sensors
    rig = lr.load_rig(args.rig) if args.rig else None
    between = args.between or lr.pair_from_diagnosis(args.model)
    with Progress("propose", total=None) as bar:
        prop = lr.propose(runs, model, between, budget_s=args.budget_s, seed=args.seed,
                          progress=bar.hook, rig=rig, through=None, loop=args.loop)
    import sys

    if not prop.separates:   # the analysis is printed; no plan is proposed
        if args.json:
            emit_json({**prop.to_json(), "plan": None, "figure": None})
        else:
            print(prop.to_text())
        print(f"labrig propose: no plan written: nothing within {args.budget_s:g} s separates "
              f"{prop.pair[0]} and {prop.pair[1]}; {prop.advice}", file=sys.stderr)
        return 1
    atomic_write(out, prop.to_toml())
    save(prop.plot(), figure, dpi=120)
    if args.json:
        emit_json({**prop.to_json(), "plan": str(out), "figure": str(figure)})
    else:
        print(prop.to_text())
        print(f"\nplan: {out}   figure: {figure}\nnext: labrig sweep --sim|--port DEV --plan "
              f"{out} -o {Path(args.data[0]) / 'new'}, then labrig diagnose "
              f"{args.data[0]} {Path(args.data[0]) / 'new'}")
    return 0


def _configure(p):

    p.add_argument("data", nargs="+", help="folder(s) of runs")
    p.add_argument("--model", required=True,
                   help="the current model (e.g. from `labrig diagnose --auto -o DIR`)")
    p.add_argument("--between", help="the two effects to tell apart, e.g. "
                                     "deadband,coulomb_friction (default: the first confusable "
                                     "pair of the diagnosis.json beside the model, as `diagnose "
                                     "--auto -o DIR` writes it; else the model's effect and "
                                     "its usual look-alike)")
    p.add_argument("--budget-s", type=float_opt, default=20.0,
                   help="at most this many seconds of new data (default 20)")
    p.add_argument("--rig", help="rig file: the inputs may then use up to its output limit, "
                                 "and its position sensor's range bounds the travel (default: "
                                 "the largest input and the travel the data show)")
    add_loop_option(p)
    p.add_argument("--seed", type=int, default=SEED,
                   help=f"seed of the fits and the noise (default {SEED})")
    p.add_argument("-o", "--output", required=True,
                   help="the plan to write (TOML); its figure goes beside it (.png)")
    p.add_argument("--force", action="store_true", help="replace an existing plan or figure")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_through_option(p)


cmd_propose.configure = _configure
