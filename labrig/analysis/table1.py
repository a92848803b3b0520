"""A steady-state table (input_v, speed_rpm[, tacho_v]) like the paper's Table 1."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from labrig.core.errors import AnalysisError
from labrig.analysis.result import GAIN_TOLERANCE, AnalysisResult
from labrig.analysis.run_result import Level
from labrig.analysis.summarise import summarise
from labrig.io.steady_table import read_table1


def analyse_table(path, *, tolerance: float = GAIN_TOLERANCE) -> AnalysisResult:
    """Analyse a steady-state table (input_v, speed_rpm[, tacho_v]) like the paper's Table 1.

    Only steady states: ``tau_s`` is None; ``kt`` is the median of tacho_v / w when
    the table has a tacho voltage column.
    """
    path = Path(path)
    df = read_table1(path)
    name = path.stem
    levels = _table_levels(df, name)
    if not levels:
        raise AnalysisError(f"{path}: the table has no rows")
    kt = None
    if "tacho_v" in df:
        ok = df["omega_rad_s"].abs() > 0
        if ok.any():
            kt = float(np.median(df.loc[ok, "tacho_v"] / df.loc[ok, "omega_rad_s"]))
    kt_cfg = None
    for c in ("kt_v_per_rad_s", "kt"):
        if c in df and df[c].notna().any():
            kt_cfg = float(df[c].median())
    run_entry = {"name": name, "loop": "open", "skipped": None, "sensor": "table",
                 "tau_s": None, "kt_est": kt,
                 "levels": [{"v": L.v, "speed_rad_s": L.speed, "speed_rpm": L.speed * 30 / math.pi,
                             "km_paper": L.km_paper, "tacho_v": L.tacho_v, "test": L.run}
                            for L in levels],
                 "notes": ["steady-state table: no transients, so no time constant"]}
    res = summarise([run_entry], levels, tolerance, kt_configured=kt_cfg, kt_est=kt,
                    source="table")
    res.verdict += _flat_tacho_sentence(df)
    res.tau_s = None
    return res


def _table_levels(df, name) -> list[Level]:
    levels = []
    has_tacho = "tacho_v" in df
    for _, r in df.iterrows():
        w = float(r["omega_rad_s"])
        levels.append(Level(run=str(r.get("test", name)), v=float(r["input_v"]), speed=w,
                            spread=None, n_segments=1, n_settled=1, moving=bool(abs(w) > 0),
                            tacho_v=float(r["tacho_v"]) if has_tacho and not pd.isna(r["tacho_v"])
                            else None))
    return levels


def _flat_tacho_sentence(df) -> str:
    """A flat tacho voltage puts a speed limit in the drive, not in the rpm display."""
    if "tacho_v" not in df or len(df) < 2:
        return ""
    tv = df["tacho_v"].abs()
    if tv.max() - tv.min() < 0.05 * tv.max():
        return (f" The tacho voltage is flat too ({tv.min():.3f} to {tv.max():.3f} V), so "
                "the limit is in the drive, not in the rpm display.")
    return ""
