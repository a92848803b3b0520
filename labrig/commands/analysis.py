"""``labrig analyse``: first-order analysis of open-loop runs (thin wrapper)."""
from __future__ import annotations

import sys

from ..cli import command, emit_json


@command("analyse", "deadband, Km, tau_m, Kt and the gain-vs-amplitude verdict of a dataset")
def cmd_analyse(args):
    """Analyse open-loop runs (square waves, steps, staircases; levels and edges are found
    from u) or a steady-state table like data/paper_table1.csv. Prints a table like the
    paper's Table 1 and a verdict; --json prints one JSON object; -o writes figures."""
    from pathlib import Path

    from ..analyse import analyse
    from .identification import refuse_existing

    res = analyse(args.paths, tolerance=args.tolerance)
    if args.output:
        # the figures it would write (analysis takes a second; nothing is written yet)
        out = Path(args.output)
        names = [f"edges_{ra.name}.png" for ra in res.runs
                 if getattr(ra, "skipped", None) is None and getattr(ra, "edges", None)]
        refuse_existing([out] + [out / n for n in names + ["speed_vs_voltage.png",
                                                          "km_vs_amplitude.png"]],
                        args.force, what="folder")
        res.plot(args.output)
        for p in res.figures:
            print(f"wrote {p}", file=sys.stderr)
    if args.json:
        emit_json(res.to_dict())
    else:
        print(res.summary())
    return 0


def _configure(p):
    from ..cli import _float_opt

    p.add_argument("paths", nargs="+", metavar="DIR",
                   help="dataset folder(s) or run files, or a steady-state table CSV")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("-o", "--output", metavar="FIGDIR", help="write the figures (PNG) here")
    p.add_argument("--force", action="store_true", help="replace figures already in FIGDIR")
    p.add_argument("--tolerance", type=_float_opt, default=0.03,
                   help="relative change of w/V over the amplitude range still called "
                        "constant (default 0.03)")


cmd_analyse.configure = _configure
