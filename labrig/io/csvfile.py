"""The CSV of a run, and of a foreign export to import: named numeric columns read with
row and column errors that say where and how to fix, within memory bounds
(docs/design.md, 'The CSV')."""
from __future__ import annotations

import csv
import difflib
import re
from pathlib import Path

import numpy as np
import pandas as pd

from labrig.core.errors import RunFileError

REQUIRED_COLUMNS = ("t", "u")
#: ``speed`` is physical speed (an import without a tacho), in the sidecar's speed_unit
SENSOR_COLUMNS = ("tacho", "speed", "pos")
#: every column labrig reads; ``gap`` flags samples the link lost (interpolated)
#: ``drive`` is a closed loop's logged controller output (input volts), ``u`` its reference
KNOWN_COLUMNS = ("t", "u", "tacho", "speed", "pos", "ref", "current", "drive", "gap")
#: relative spread of the sampling interval still called uniform (scope exports
#: print t with few digits; a missing sample doubles dt and is caught)
UNIFORM_TOL = 0.02
RATE_TOL = 0.01


# -- CSV ----------------------------------------------------------------------------

#: a run file larger than this is refused before reading (2 GB is ~40 million rows of
#: t,u,tacho,pos): split the recording instead
MAX_CSV_BYTES = 2_000_000_000
MAX_ROWS = 20_000_000
#: how people name labrig's columns elsewhere: a header with one of these where the
#: labrig name is missing is a misspelling to fix, not an extra column to ignore
SYNONYMS = {"time": "t", "time_s": "t", "input": "u", "voltage": "u", "u_v": "u",
            "velocity": "speed", "omega": "speed", "w": "speed",
            "position": "pos", "angle": "pos", "theta": "pos", "reference": "ref",
            "i": "current", "ia": "current"}
CHUNK_ROWS = 500_000
#: the largest magnitude each column can physically hold, in its own unit: bridge and
#: sensor volts (an input of 1e300 V is a broken export, not an experiment), N m or N
#: of an imported torque/force, rad/s or m/s of an imported speed, a position in counts
#: (an encoder's count accumulates), seconds
COLUMN_LIMITS = {"t": 1e7, "u": 1e5, "ref": 1e5, "drive": 1e5, "tacho": 1e4,
                 "current": 1e4, "speed": 1e7, "pos": 1e12}


def _near_miss(col: str, present: list[str]) -> str | None:
    """The labrig column ``col`` probably means, if that column is not there."""
    low = col.lower()
    cand = low if low in KNOWN_COLUMNS else SYNONYMS.get(low)
    if cand is None and len(low) >= 3:
        close = difflib.get_close_matches(low, [c for c in KNOWN_COLUMNS if len(c) >= 3],
                                          n=1, cutoff=0.75)
        cand = close[0] if close else None
    return cand if cand is not None and cand not in present else None


def _read_header(path: Path, empty_hint: str = "") -> list[str]:
    try:
        size = path.stat().st_size
        if size > MAX_CSV_BYTES:
            raise RunFileError(f"{path}: {size / 1e9:.1f} GB is more than labrig reads in one "
                               f"run ({MAX_CSV_BYTES / 1e9:.0f} GB); split the recording")
        with path.open(encoding="utf-8", newline="") as fh:
            line = fh.readline()
            while line and not line.strip():
                line = fh.readline()
    except UnicodeDecodeError:
        raise RunFileError(f"{path}: not a readable CSV (not UTF-8 text)") from None
    if not line.strip():
        raise RunFileError(f"{path}: file is empty{empty_hint}")
    return [c.strip() for c in next(csv.reader([line]))]


def _no_duplicates(path: Path, cols: list[str]) -> None:
    dup = sorted({c for c in cols if cols.count(c) > 1})
    if dup:
        raise RunFileError(f"{path}: column '{dup[0]}' appears twice in the header; "
                           "rename one of them")


def _parse_error(path: Path, exc: Exception, ncols: int) -> RunFileError:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", text)
    if m:
        return RunFileError(f"{path}: row {m.group(2)} has {m.group(3)} fields where the "
                            f"header names {ncols} columns; fix that row or the header")
    return RunFileError(f"{path}: not a readable CSV ({text})")


def _cell_problem(cell) -> str:
    if not isinstance(cell, str):
        return "a missing field (the row is shorter than the header)"
    if not cell:
        return "an empty cell"
    if cell.lower().lstrip("+-") in ("nan", "inf", "infinity"):
        return "NaN or inf"
    return f"non-numeric value {cell!r}"


#: the run CSV's row and cell messages, shared with an export's reader (labrig.io.exportfile)
parse_error = _parse_error
cell_problem = _cell_problem


def _locate_bad_cell(path: Path, columns: list[str]) -> RunFileError:
    """Stream the file as text to name the first cell that is not a finite number."""
    row0 = 2  # the header is row 1
    try:
        reader = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True,
                             chunksize=CHUNK_ROWS)
        for chunk in reader:
            chunk.columns = [c.strip() for c in chunk.columns]
            for c in columns:
                col = chunk[c].str.strip()
                values = pd.to_numeric(col, errors="coerce").to_numpy(float)
                bad = ~np.isfinite(values)
                if bad.any():
                    i = int(np.argmax(bad))
                    return RunFileError(f"{path}: row {row0 + i}, column '{c}': "
                                        f"{_cell_problem(col.iloc[i])}; every sample must be "
                                        "a finite number")
            row0 += len(chunk)
    except (pd.errors.ParserError, ValueError) as exc:
        return _parse_error(path, exc, 0)
    return RunFileError(f"{path}: a cell is not a finite number")


def _read_numeric(path: Path, cols: list[str], numeric: list[str]) -> pd.DataFrame:
    """The CSV with ``numeric`` columns as float64, read by pandas' C parser (about
    8 bytes a cell: 10 million rows fit in memory); any bad cell named by row."""
    dtypes = {c: "float64" if c in numeric else str for c in cols}
    try:
        raw = pd.read_csv(path, skipinitialspace=True, dtype=dtypes, engine="c",
                          keep_default_na=False, na_values=[""], nrows=MAX_ROWS + 1)
    except pd.errors.ParserError as exc:
        raise _parse_error(path, exc, len(cols)) from None
    except ValueError:  # a cell that is not a number
        raise _locate_bad_cell(path, numeric) from None
    except UnicodeDecodeError:
        raise RunFileError(f"{path}: not a readable CSV (not UTF-8 text)") from None
    if len(raw) > MAX_ROWS:
        raise RunFileError(f"{path}: more than {MAX_ROWS:,} rows; labrig reads at most that "
                           "many samples in one run: split the recording")
    raw.columns = [c.strip() for c in raw.columns]
    for c in numeric:
        if not np.isfinite(raw[c].to_numpy()).all():
            raise _locate_bad_cell(path, numeric)
    return raw


def check_ranges(path: Path, df: pd.DataFrame, names: dict | None = None,
                 first_row: int = 2) -> None:
    """Refuse a value no rig can produce (``COLUMN_LIMITS``) and a ``gap`` flag that is
    not 0 or 1, naming the row (the file's line) and the column. ``names`` maps labrig's
    column to the column's name in the file (an import's ``--map``); ``first_row`` is the
    file's line of the first sample (after a header, a scope's preamble and unit rows)."""
    names = names or {}
    for col, limit in COLUMN_LIMITS.items():
        if col not in df:
            continue
        v = np.abs(df[col].to_numpy(float))
        if v.max(initial=0.0) > limit:
            i = int(np.argmax(v > limit))
            raise RunFileError(f"{path}: row {first_row + i}, column '{names.get(col, col)}': "
                               f"{df[col].iloc[i]:g} is outside any physical range of "
                               f"'{col}' (|value| <= {limit:g}); is the column or its unit "
                               "right?")
    if "gap" in df:
        g = df["gap"].to_numpy(float)
        bad = (g != 0) & (g != 1)
        if bad.any():
            i = int(np.argmax(bad))
            raise RunFileError(f"{path}: row {first_row + i}, column 'gap': {g[i]:g}; a gap flag is "
                               "1 for a sample the link lost and 0 for a measured one")


def read_run_csv(csv_path: Path, fs: float | None = None) -> pd.DataFrame:
    cols = _read_header(csv_path, "; expected a header row t,u,tacho,pos and one row per "
                                  "sample")
    if not any(c in ("t", "u", *SENSOR_COLUMNS) for c in cols):
        raise RunFileError(f"{csv_path}: no header row; the first line must name the "
                           "columns, e.g. t,u,tacho,pos")
    _no_duplicates(csv_path, cols)
    for c in cols:
        means = _near_miss(c, cols) if c not in KNOWN_COLUMNS else None
        if means:
            raise RunFileError(f"{csv_path}: column '{c}' in the header looks like '{means}'; "
                               f"rename it to '{means}' (labrig's columns are "
                               f"{', '.join(KNOWN_COLUMNS)}, lower case)")
    for c in REQUIRED_COLUMNS:
        if c not in cols:
            raise RunFileError(f"{csv_path}: column '{c}' missing (header has "
                               f"{', '.join(cols)}); a run needs t and u")
    if not any(c in cols for c in SENSOR_COLUMNS):
        raise RunFileError(f"{csv_path}: no sensor column ('tacho', 'speed' or 'pos'); a "
                           "run needs at least one")
    numeric = [c for c in cols if c in KNOWN_COLUMNS]
    df = _read_numeric(csv_path, cols, numeric)
    if len(df) < 2:
        raise RunFileError(f"{csv_path}: only {len(df)} data row(s); a run needs samples")
    check_ranges(csv_path, df)
    # unknown columns are carried along as text, never used
    t = df["t"].to_numpy()
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise RunFileError(f"{csv_path}: row {i + 3}, column 't': time {t[i + 1]:g} s is not "
                           f"after {t[i]:g} s; t must be strictly increasing")
    med = float(np.median(dt))
    if fs is not None and abs(1.0 / med - fs) > RATE_TOL * fs:
        raise RunFileError(f"{csv_path.with_suffix('.json')}: key 'sample_rate_hz' = {fs:g} "
                           f"but column 't' of {csv_path.name} samples at {1 / med:.6g} Hz; "
                           "fix one of them")
    step = 1.0 / fs if fs is not None else med
    dev = np.abs(dt - step) > UNIFORM_TOL * step
    if dev.any():
        i = int(np.argmax(dev))
        said = f"the sidecar's {fs:g} Hz" if fs is not None else "the run's median rate"
        raise RunFileError(f"{csv_path}: row {i + 3}, column 't': the sampling interval "
                           f"changes to {dt[i]:g} s ({1 / dt[i]:.4g} Hz) where {said} means "
                           f"{step:g} s; t must be uniform (resample, split the run where "
                           "the rate changes, or a sample was lost)")
    return df
