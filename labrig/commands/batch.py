"""``labrig batch``: one task over many run folders, in parallel, one table of results."""
from __future__ import annotations

import sys
from pathlib import Path

from labrig.commands.registry import command, emit_json, float_opt, refuse_existing
from labrig.commands.options import translate
from labrig.commands.progress import Progress
from labrig.core.defaults import METHOD
from labrig.core.errors import UserError

TASK_NAMES = ("analyse", "identify", "diagnose", "check")


@command("batch", "run analyse, identify, diagnose --auto or mystery check over many folders")
def cmd_batch(args):
    """Run one task on every folder given (a class's hand-ins, a parameter study), in
    parallel: --jobs N processes on this machine (joblib), or the workers of a running
    Dask distributed cluster (--scheduler tcp://HOST:PORT). Writes results.csv and
    results.json (folder, status, key figures, error message) and each folder's model or
    report under -o OUT/NAME/. A folder that fails is a row with its message; the others
    go on, even when a worker process dies under one. Exit status: 0 when every folder
    succeeded, 1 when any failed (the table says which)."""
    from labrig.classroom.batch import check_scheduler, output_names, run_batch, write_batch

    out = Path(args.output)
    if args.scheduler:
        check_scheduler(args.scheduler)
    # every file the batch may write, the folders' own results included, before any work
    refuse_existing([out, out / "results.csv", out / "results.json",
                     *(out / n for n in output_names(args.folders))], args.force,
                    what="folder")
    if args.jobs == 0 or args.jobs < -1:
        raise UserError(f"--jobs: {args.jobs}; give 1 or more processes, or -1 for one per core")
    options = {"seed": args.seed}
    for key in ("method", "effects", "pop", "iters", "max_rounds", "mystery", "model",
                "tolerance"):
        if getattr(args, key) is not None:
            options[key] = getattr(args, key)
    if options.get("effects"):
        options["effects"] = [e.strip() for e in options["effects"].split(",") if e.strip()]
    with Progress(f"batch {args.task}", total=len(args.folders)) as bar:
        failed = []

        def progress(row):
            bar.advance()
            if row["status"] != "ok":
                failed.append(row["name"])
            bar.note(f"{row['name']}: {row['status']}" + (f" ({len(failed)} failed)"
                                                          if failed else ""))

        res = run_batch(args.task, args.folders, options=options, jobs=args.jobs,
                        scheduler=args.scheduler, progress=progress)
    for row in res.rows:   # a folder's error as the command line says it (--model, ...)
        row["error"] = translate(row["error"])
    write_batch(res, out)
    if args.json:
        emit_json({**res.to_json(), "output": str(out)})
    else:
        print(res.to_text())
        print(f"\nwritten to {out}/: results.csv, results.json and a folder per run folder")
    if res.failed:  # a grading script must be able to tell without reading the table
        print(f"labrig: {res.failed} of {len(res.rows)} folders failed (status 'failed' in "
              f"{out / 'results.csv'})", file=sys.stderr)
    return 1 if res.failed else 0


def _configure(p):
    p.add_argument("task", type=str.lower, choices=TASK_NAMES,
                   help="analyse | identify | diagnose (the --auto search) | check (a "
                        "hand-in's model against its .mystery file)")
    p.add_argument("folders", nargs="+", help="run folders, e.g. `handins/*/`")
    p.add_argument("-o", "--output", required=True,
                   help="folder for results.csv, results.json and one folder per run folder")
    p.add_argument("--jobs", type=int, default=1,
                   help="processes on this machine (joblib; default 1, -1: one per core)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="send the folders to a running Dask distributed cluster instead "
                        "(start one with `dask scheduler` and `dask worker tcp://HOST:8786`)")
    p.add_argument("--seed", type=int, default=1,
                   help="random seed of every fit (default 1: the same folder gives the "
                        "same result, whichever worker runs it)")
    p.add_argument("--method", type=str.lower, choices=("jfo", "pso", "co"),
                   help=f"identify: the optimiser (default {METHOD}, as labrig identify)")
    p.add_argument("--effects", help="identify: effects to fit, comma separated (default none)")
    p.add_argument("--pop", type=int, help="identify: population of JFO/PSO (default 50)")
    p.add_argument("--iters", type=int, help="identify: iterations of JFO/PSO (default 200)")
    p.add_argument("--max-rounds", type=int, help="diagnose: rounds of the search (default 3)")
    p.add_argument("--mystery", help="check: the .mystery file for every folder (default: the "
                                     "one .mystery file inside each folder)")
    p.add_argument("--model", help="check: the model file's name inside each folder "
                                   "(default model.json)")
    p.add_argument("--tolerance", type=float_opt,
                   help="check: pass tolerance in percent (default 20)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--force", action="store_true", help="replace earlier results in -o")


cmd_batch.configure = _configure
