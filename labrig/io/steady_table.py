"""Steady-state tables like the seed paper's Table 1 (data/paper_table1.csv)."""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from labrig.core.errors import RunFileError

COLUMNS = ("test", "input_v", "speed_rpm")


def is_table(path: Path) -> bool:
    """A steady-state table has ``input_v`` and ``speed_rpm`` columns."""
    path = Path(path)
    if path.suffix != ".csv" or not path.is_file():
        return False
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if not line.startswith("#"):
                return "input_v" in line and "speed_rpm" in line
    return False


def read_table1(path: Path | str) -> pd.DataFrame:
    """Read a steady-state table; adds ``omega_rad_s``."""
    path = Path(path)
    try:
        df = pd.read_csv(path, comment="#")
    except Exception as exc:
        raise RunFileError(f"{path}: not a readable steady-state table ({exc})") from None
    for c in COLUMNS[1:]:
        if c not in df:
            raise RunFileError(f"{path}: column '{c}' missing")
        if not pd.api.types.is_numeric_dtype(df[c]) or df[c].isna().any():
            raise RunFileError(f"{path}: column '{c}' must be all numbers")
    df["omega_rad_s"] = df["speed_rpm"] * 2 * math.pi / 60
    return df
