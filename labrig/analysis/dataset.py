"""``analyse``: a dataset of runs (or a steady-state table) to one AnalysisResult."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from labrig.core.errors import AnalysisError
from labrig.analysis.levels import kt_from_levels
from labrig.analysis.result import GAIN_TOLERANCE, AnalysisResult
from labrig.analysis.run_result import RunAnalysis
from labrig.analysis.run import analyse_run
from labrig.analysis.summarise import summarise
from labrig.analysis.table1 import analyse_table
from labrig.io.runs import Run, read_dataset
from labrig.io.steady_table import is_table


def analyse(paths, *, tolerance: float = GAIN_TOLERANCE) -> AnalysisResult:
    """Analyse a dataset (folders and/or run files) or a steady-state table.

    Parameters
    ----------
    paths : str, Path, list of them, or list of Run
        Runs to analyse; a single steady-state table CSV (like
        ``data/paper_table1.csv``) is analysed as such.
    tolerance : float
        Relative change of w/V over the amplitude range still called constant.

    Returns
    -------
    AnalysisResult

    Raises
    ------
    AnalysisError, RunFileError
        With the file or run name and how to fix it.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = list(paths)
    if len(paths) == 1 and not isinstance(paths[0], Run) and is_table(Path(paths[0])):
        return analyse_table(paths[0], tolerance=tolerance)
    runs = paths if paths and all(isinstance(p, Run) for p in paths) else read_dataset(paths)
    results, errors = _analyse_each(runs)
    good = [r for r in results if not r.skipped]
    if not good:
        why = "; ".join(errors) if errors else "every run is closed-loop"
        raise AnalysisError(f"{', '.join(map(str, paths))}: no open-loop run could be "
                            f"analysed ({why}); record open-loop square waves or steps "
                            "(`labrig sweep`)")
    levels = [L for r in good for L in r.levels]
    kcfg = [r.kt_configured for r in good if r.kt_configured is not None]
    return summarise(results, levels, tolerance,
                     kt_configured=float(np.median(kcfg)) if kcfg else None,
                     kt_est=kt_from_levels(levels),   # pooled over runs with both sensors
                     speed_unit=runs[0].units[1])


def _analyse_each(runs):
    """Every run analysed; with several runs, one that fails is skipped with its reason."""
    results: list[RunAnalysis] = []
    errors = []
    for run in runs:
        try:
            results.append(analyse_run(run))
        except AnalysisError as exc:
            if len(runs) == 1:
                raise
            errors.append(str(exc))
            results.append(RunAnalysis(name=run.name, loop=run.loop, fs=run.fs,
                                       skipped=str(exc)))
    return results, errors
