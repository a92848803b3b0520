"""``labrig report``: the whole story of a data set in one self-contained HTML page."""
from __future__ import annotations

import sys
from pathlib import Path

from labrig.commands.registry import command, refuse_existing
from labrig.core.errors import UserError


@command("report", "the whole story in one self-contained HTML page (figures embedded)")
def cmd_report(args):
    """Write one HTML page telling the whole story of a data set: the sweep, the
    analysis (Table 1), the identified models side by side, where the model fails,
    the diagnosis and the error ladder. Figures are embedded and the CSS is inline, so
    the file opens in any browser and prints cleanly (one section per page).

    Artefacts of the earlier stages (analysis.json, identify_all.json, model0.json,
    diagnosis.json, model1.json, ladder.json, figures/) are read from the work folder
    (--work; default: the parent of DIR when it holds any, as `labrig demo -o OUT`
    leaves them); what is missing is computed: the analysis, a CO identification,
    and -- unless --quick -- the diagnosis and the ladder (the slow part)."""
    from labrig.report.html import build_report, find_work

    # before the analysis, identification and diagnosis (which can take a minute)
    refuse_existing([args.output], args.force)
    data = Path(args.data)
    if not data.exists():
        raise UserError(f"{data}: no such folder of runs")
    if data.is_dir() and not any(data.glob("*.csv")) and (data / "runs").is_dir():
        # the work folder itself (labrig demo -o OUT): its runs are in OUT/runs
        print(f"report: reading the runs in {data / 'runs'}", file=sys.stderr)
        data = data / "runs"
    work = None
    if args.no_work:
        work = None
    elif args.work:
        work = Path(args.work)
        if not work.is_dir():
            raise UserError(f"--work {work}: no such folder")
    else:
        work = find_work(data)
    if work is not None:
        print(f"report: reading artefacts from {work}", file=sys.stderr)

    def log(text):
        print(text, file=sys.stderr, flush=True)

    out = build_report(data, args.output, work=work if work is not None else False,
                       quick=args.quick, seed=args.seed, log=log)
    print(f"wrote {out}")
    return 0


def _configure(p):
    p.add_argument("data", metavar="DIR", help="folder of runs")
    p.add_argument("-o", "--output", default="report.html",
                   help="the HTML file to write (default report.html)")
    p.add_argument("--force", action="store_true", help="replace an existing -o file")
    p.add_argument("--work", metavar="WORKDIR",
                   help="folder with analysis.json, identify_all.json, model0.json, "
                        "diagnosis.json, model1.json, ladder.json, figures/ (default: the "
                        "parent of DIR when it holds any of them)")
    p.add_argument("--no-work", action="store_true",
                   help="ignore any work folder: compute everything here")
    p.add_argument("--quick", action="store_true",
                   help="do not compute the diagnosis and the ladder (the slow part); "
                        "their JSON files are still used when present")
    p.add_argument("--seed", type=int, default=1,
                   help="seed of what the report identifies or diagnoses itself (default 1)")


cmd_report.configure = _configure
