"""The public verbs: what ``import labrig as lr`` gives a notebook or a script, and the
one door through which the front ends (the command line, the lab station, the classroom
batch, the report, the demo) reach the library.

Every verb takes its data the same way — a folder of runs, a run file, a list of them,
or runs already read (:func:`read_runs`) — and has the command line's defaults, so
``lr.identify("runs")`` is ``labrig identify runs``. Each returns the result object the
command prints: it shows a one-screen summary as text, its tables and its figure in a
notebook, and has ``to_json()`` (the command's ``--json``), ``to_pandas()`` and
``plot(ax=None)``. Models go in and come out as :class:`~labrig.model.model.Model`
objects (a model file's path or a fit are taken too).

The loop in five lines::

    import labrig as lr
    runs = lr.read_runs("data/sweep_default")
    fit = lr.identify(runs)                     # the linear model (CO)
    diag = lr.diagnose(runs, fit.model())       # which effect is missing?
    better = lr.add_effect(runs, fit.model(), diag.recommendation)

One module per topic: :mod:`~labrig.verbs.data` (runs, models, the catalogue, rig and
plan files), :mod:`~labrig.verbs.acquire` (bridges and sweeps), :mod:`~labrig.verbs.fit`
(analyse, identify, add and remove an effect, compare, the ladder),
:mod:`~labrig.verbs.loop` (diagnose, the search, propose, decide) and
:mod:`~labrig.verbs.mystery` (mystery rigs for a class); :mod:`~labrig.verbs.figures`
and :mod:`~labrig.verbs.types` give the front ends the figures and types of results.

Each verb imports the library inside itself, on first use: imported eagerly, the
library's modules (numba, scipy, matplotlib) would cost every ``labrig --help`` and every
``import labrig`` in a notebook half a second or more (benchmarks/bench_startup.py
records it).
"""
from labrig.verbs.acquire import (board_id, doctor, emulator, find_board, flash, format_board_id,
                                  live, open_bridge, play, ports, sweep, wiring)
from labrig.verbs.data import (check_plan, drive_units, effect, effects, import_run,
                               load_identify_config,
                               load_model, load_plan, load_rig, model_from_json, model_of,
                               parse_effects, plan_files, read_runs, run_origins, runs_for_fit,
                               runs_of)
from labrig.verbs.fit import (add_effect, analyse, compare, identify, ladder, remove_effect,
                              set_by_hand, try_effect)
from labrig.verbs.loop import (ask_until_sure, auto, auto_ladder, channel_weights,
                               confusable_pairs, decide, diagnose, pair_from_diagnosis, propose,
                               proposed_as, warm_up)
from labrig.verbs.mystery import (blind, check_mystery, format_check, format_reveal,
                                  new_mystery, reveal, write_mystery)

__all__ = [
    # data
    "read_runs", "runs_of", "runs_for_fit", "import_run", "load_model", "model_from_json",
    "model_of", "effects", "effect", "parse_effects", "load_rig", "load_plan", "plan_files",
    "check_plan", "load_identify_config", "drive_units", "run_origins",
    # acquisition
    "sweep", "open_bridge", "live", "play", "emulator", "wiring", "ports", "find_board", "flash",
    "board_id", "format_board_id", "doctor",
    # fits
    "analyse", "identify", "add_effect", "remove_effect", "try_effect", "set_by_hand", "compare",
    "ladder",
    # the loop
    "diagnose", "auto", "auto_ladder", "channel_weights", "confusable_pairs", "propose",
    "ask_until_sure",
    "proposed_as", "pair_from_diagnosis", "decide", "warm_up",
    # mystery rigs
    "new_mystery", "write_mystery", "reveal", "check_mystery", "blind", "format_reveal",
    "format_check",
]
