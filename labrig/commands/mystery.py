"""``labrig mystery new | reveal | check``: simulated rigs with hidden physics for labs."""
from __future__ import annotations

from labrig.commands.registry import command, emit_json, float_opt, refuse_existing
from labrig.core.errors import UserError
import labrig.verbs as lr


@command("mystery", "mystery rigs for the lab: new (student file), reveal, check (grading)")
def cmd_mystery(args):
    """Mystery rigs: `new --seed N -o FILE.mystery` draws a simulated rig with 1-2 hidden
    effects (use it with `labrig sweep --sim --rig FILE.mystery`); `reveal FILE` shows the
    truth (instructor); `check FILE MODEL.json` grades a model against it. The file is
    obfuscated against casual reading, not encrypted."""

    if args.action == "new":

        refuse_existing([args.output], args.force)  # the same words as every other -o
        doc = lr.new_mystery(args.seed, args.rig)
        path = lr.write_mystery(doc, args.output, seed=args.seed, overwrite=args.force)
        n = len(doc["effects"])
        print(f"wrote {path}: mystery rig {args.seed} ({n} hidden effect{'s' * (n != 1)}); "
              f"acquire with `labrig sweep --sim --rig {path} -o runs`")
        return 0
    if args.action == "reveal":
        res = lr.reveal(args.file)
        if args.json:
            emit_json(res)
        else:
            print(lr.format_reveal(res))
        return 0
    if args.action == "check":
        res = lr.check_mystery(args.file, args.model, tolerance=args.tolerance / 100.0)
        if args.blind:
            res = lr.blind(res)
        if args.json:
            emit_json(res)
        else:
            print(lr.format_check(res, blind_mode=args.blind))
        return 0
    raise UserError("mystery: give an action: new, reveal or check "
                    "(e.g. `labrig mystery new --seed 7 -o lab.mystery`)")


def _configure(p):

    sub = p.add_subparsers(dest="action", metavar="ACTION")

    pn = sub.add_parser("new", help="draw a mystery rig and write it (not plain text)")
    pn.add_argument("--seed", type=int, required=True, help="which mystery (same seed, same rig)")
    pn.add_argument("-o", "--output", required=True, help="file to write, ending in .mystery")
    pn.add_argument("--rig", help="the rig to draw the mystery around (default the MS150; any "
                                  "plant and axis, e.g. configs/rig_linear_axis.toml)")
    pn.add_argument("--force", action="store_true", help="replace an existing file")

    pr = sub.add_parser("reveal", help="show the hidden truth (instructor)")
    pr.add_argument("file", help="a .mystery file")
    pr.add_argument("--json", action="store_true", help="print one JSON object")

    pc = sub.add_parser("check", help="grade a model.json against the hidden truth")
    pc.add_argument("file", help="a .mystery file")
    pc.add_argument("model", help="a model saved by `labrig identify -o` or `labrig diagnose -o`")
    pc.add_argument("--json", action="store_true", help="print one JSON object")
    pc.add_argument("--blind", action="store_true",
                    help="student self-check: say how many effects are missing, not which")
    pc.add_argument("--tolerance", type=float_opt, default=20.0,
                    help="parameter error (%%) within which an effect passes (default 20)")


cmd_mystery.configure = _configure
