"""``labrig analyse``: first-order analysis of open-loop runs (thin wrapper)."""
from __future__ import annotations

import sys

from labrig.commands.registry import command, emit_json, float_opt, refuse_existing
import labrig.verbs as lr
from labrig.verbs.figures import save_figures


@command("analyse", "deadband, Km, tau_m, Kt and the gain-vs-amplitude verdict of a dataset")
def cmd_analyse(args):
    """Analyse open-loop runs (square waves, steps, staircases; levels and edges are found
    from u) or a steady-state table like data/paper_table1.csv. Prints a table like the
    paper's Table 1 and a verdict; --json prints one JSON object; -o writes figures."""
    from pathlib import Path


    res = lr.analyse(args.paths, tolerance=args.tolerance)
    if args.output:
        out = Path(args.output)
        figs = res.figures()    # names only: nothing is drawn or written yet
        refuse_existing([out] + [out / name for name in figs], args.force, what="folder")
        _save(res, figs, out)
    if args.json:
        emit_json(res.to_json())
    else:
        print(res.summary())
    return 0


def _save(res, figs, out):
    """Save each figure as PNG and close it at once (one figure in memory at a time)."""

    saved = save_figures(figs, out)
    res.record_figures(saved)          # the paths go into --json and the summary
    for p in saved.values():
        print(f"wrote {p}", file=sys.stderr)


def _configure(p):

    p.add_argument("paths", nargs="+", metavar="DIR",
                   help="dataset folder(s) or run files, or a steady-state table CSV")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("-o", "--output", metavar="FIGDIR", help="write the figures (PNG) here")
    p.add_argument("--force", action="store_true", help="replace figures already in FIGDIR")
    p.add_argument("--tolerance", type=float_opt, default=0.03,
                   help="relative change of w/V over the amplitude range still called "
                        "constant (default 0.03)")


cmd_analyse.configure = _configure
