"""Run files (docs/design.md, 'Run files'): read, validate, write atomically, import foreign CSVs.

A run is ``stem.csv`` (raw volts: t, u, tacho and/or pos, optional ref, current)
plus ``stem.json`` (sidecar: format, sample rate, experiment, sensors, rig). Loading
gives physical units through the sidecar's calibration: ``Run.speed`` is the motor
speed in rad/s (tacho / Kt) and ``Run.position`` the output-shaft angle in rad
((pos - offset) / Kpot).
"""
from __future__ import annotations

import csv
import difflib
import json
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import AnalysisError, RunFileError
from .fileio import atomic_write, json_default

FORMAT = "labrig-run/1"
REQUIRED_COLUMNS = ("t", "u")
SENSOR_COLUMNS = ("tacho", "pos")
#: every column labrig reads; ``gap`` flags samples the link lost (interpolated)
KNOWN_COLUMNS = ("t", "u", "tacho", "pos", "ref", "current", "gap")
#: relative spread of the sampling interval still called uniform (scope exports
#: print t with few digits; a missing sample doubles dt and is caught)
UNIFORM_TOL = 0.02
RATE_TOL = 0.01


@dataclass
class Run:
    """One acquired or imported run, in raw volts plus its sidecar metadata."""

    name: str
    data: pd.DataFrame
    meta: dict
    path: Path | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    # -- raw columns ---------------------------------------------------------
    @property
    def t(self) -> np.ndarray:
        return self.data["t"].to_numpy(float)

    @property
    def u(self) -> np.ndarray:
        return self.data["u"].to_numpy(float)

    @property
    def ref(self) -> np.ndarray | None:
        return self.data["ref"].to_numpy(float) if "ref" in self.data else None

    @property
    def fs(self) -> float:
        return float(self.meta["sample_rate_hz"])

    @property
    def dt(self) -> float:
        return 1.0 / self.fs

    @property
    def has_tacho(self) -> bool:
        return "tacho" in self.data

    @property
    def has_pos(self) -> bool:
        return "pos" in self.data

    # -- metadata ------------------------------------------------------------
    @property
    def experiment(self) -> dict:
        return self.meta.get("experiment", {})

    @property
    def loop(self) -> str:
        return self.experiment.get("loop", "open")

    @property
    def sensors(self) -> dict:
        return self.meta.get("sensors", {})

    @property
    def gains(self) -> dict | None:
        """The closed loop's ``{"kp": ..., "kv": ...}`` (amplifier input = kp (ref - pos)
        - kv tacho, in volts per volt); None for an open-loop run. A closed-loop run
        always states them (checked when it is read)."""
        if self.loop != "closed":
            return None
        return {"kp": float(self.experiment["position_gain"]),
                "kv": float(self.experiment["velocity_gain"])}

    @property
    def amplifier_gain(self) -> float:
        """Armature volts per bridge volt (1.0 when the sidecar does not say)."""
        return float(self.meta.get("rig", {}).get("amplifier_gain", 1.0))

    @property
    def constants(self) -> dict:
        """The rig constants a model of this run needs: Ka, N, Kt, Kpot (a channel the
        run does not have gets 1.0: it is never used)."""
        return {"Ka": self.amplifier_gain, "N": self.gear_ratio,
                "Kt": float(self.sensors.get("tacho_v_per_rad_s") or 1.0),
                "Kpot": float(self.sensors.get("pos_v_per_rad") or 1.0)}

    @property
    def kt(self) -> float:
        return float(self.sensors["tacho_v_per_rad_s"])

    @property
    def kpot(self) -> float:
        return float(self.sensors["pos_v_per_rad"])

    @property
    def pos_offset(self) -> float:
        return float(self.sensors.get("pos_offset_v", 0.0))

    @property
    def gear_ratio(self) -> float:
        return float(self.meta.get("rig", {}).get("gear_ratio", 1.0))

    @property
    def amplitude(self) -> float:
        """Largest |u| applied (V): the run's amplitude for grouping and reports."""
        return float(np.max(np.abs(self.u)))

    # -- physical units -----------------------------------------------------
    @property
    def speed(self) -> np.ndarray | None:
        """Motor speed in rad/s from the tacho, or None for a position-only run."""
        if not self.has_tacho:
            return None
        return self.data["tacho"].to_numpy(float) / self.kt

    @property
    def position(self) -> np.ndarray | None:
        """Output-shaft angle in rad from the pot, or None for a tacho-only run."""
        if not self.has_pos:
            return None
        return (self.data["pos"].to_numpy(float) - self.pos_offset) / self.kpot

    def __len__(self) -> int:
        return len(self.data)


# -- reading -------------------------------------------------------------------

def _stem_paths(path: Path) -> tuple[Path, Path]:
    path = Path(path)
    if path.suffix in (".csv", ".json"):
        return path.with_suffix(".csv"), path.with_suffix(".json")
    return path.with_name(path.name + ".csv"), path.with_name(path.name + ".json")


def read_run(path: Path | str) -> Run:
    """Read and validate one run (give the CSV, the JSON or the stem)."""
    csv_path, json_path = _stem_paths(Path(path))
    if not csv_path.exists():
        raise RunFileError(f"{csv_path}: run file not found")
    meta = _read_sidecar(json_path, csv_path)
    data = _read_csv(csv_path, float(meta["sample_rate_hz"]))
    _check_against_sidecar(csv_path, json_path, data, meta)
    return Run(name=csv_path.stem, data=data, meta=meta, path=csv_path)


def read_dataset(paths) -> list[Run]:
    """Read every run in the given folders and/or run files, sorted by name.

    Raises ``RunFileError`` when nothing is found, naming where it looked.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            files += sorted(p.glob("*.csv"))
        elif p.exists() or p.with_suffix(".csv").exists():
            files.append(p.with_suffix(".csv"))
        else:
            raise RunFileError(f"{p}: no such run file or folder")
    if not files:
        raise RunFileError(f"{', '.join(map(str, paths))}: no runs (*.csv with a .json "
                           "sidecar) found; run `labrig sweep` or `labrig import` first")
    runs = [read_run(f) for f in files]
    return sorted(runs, key=lambda r: r.name)


def _read_sidecar(json_path: Path, csv_path: Path) -> dict:
    from .schemas import Sidecar, read_json, validate

    if not json_path.exists():
        raise RunFileError(f"{json_path}: sidecar missing for {csv_path.name}; every run "
                           "needs a .json sidecar (docs/design.md, 'Run files', or "
                           "`labrig import`)")
    meta = read_json(json_path, "sidecar", RunFileError)
    if not isinstance(meta, dict):
        raise RunFileError(f"{json_path}: sidecar must be a JSON object")
    fmt = meta.get("format")
    if fmt is None:
        raise RunFileError(f"{json_path}: key 'format' missing; expected \"{FORMAT}\"")
    if fmt != FORMAT:
        raise RunFileError(f"{json_path}: key 'format' is {fmt!r}; this labrig reads \"{FORMAT}\"")
    for key in ("experiment", "sensors", "rig"):
        if not isinstance(meta.get(key), dict):
            raise RunFileError(f"{json_path}: key '{key}' missing or not an object")
    checked = validate(Sidecar, meta, json_path, RunFileError)
    exp = checked.experiment
    if exp.loop == "closed" and (exp.position_gain is None or exp.velocity_gain is None):
        raise RunFileError(f"{json_path}: a closed-loop run must state its controller: keys "
                           "'experiment.position_gain' and 'experiment.velocity_gain' (volts "
                           "per volt) missing; add them, or import with --loop closed "
                           "--position-gain KP --velocity-gain KV")
    # the validated values (ints as floats); keys the schema does not know ride along
    return checked.model_dump(exclude_unset=True)


def require_excitation(runs, what: str = "identify") -> None:
    """Refuse a data set that cannot show any dynamics: the input never changes in any
    run, or no sensor ever moves (an unpowered motor, an unplugged sensor)."""
    names = ", ".join(r.name for r in runs[:3]) + (" ..." if len(runs) > 3 else "")
    if all(np.ptp(r.u) == 0 for r in runs):
        raise AnalysisError(f"runs {names}: the input u is constant ({runs[0].u[0]:g} V) in "
                            f"every run, so there is nothing to {what}; record steps or "
                            "square waves (`labrig sweep`)")
    flat = all(all(np.ptp(r.data[c].to_numpy(float)) == 0 for c in SENSOR_COLUMNS
                   if c in r.data) for r in runs)
    if flat:
        raise AnalysisError(f"runs {names}: tacho and pos are constant in every run while u "
                            f"changes, so there is nothing to {what}; is the motor powered "
                            "and are the sensors wired?")


# -- CSV ----------------------------------------------------------------------------

#: a run file larger than this is refused before reading (2 GB is ~40 million rows of
#: t,u,tacho,pos): split the recording instead
MAX_CSV_BYTES = 2_000_000_000
MAX_ROWS = 20_000_000
#: how people name labrig's columns elsewhere: a header with one of these where the
#: labrig name is missing is a misspelling to fix, not an extra column to ignore
SYNONYMS = {"time": "t", "time_s": "t", "input": "u", "voltage": "u", "u_v": "u",
            "speed": "tacho", "velocity": "tacho", "omega": "tacho", "w": "tacho",
            "position": "pos", "angle": "pos", "theta": "pos", "reference": "ref",
            "i": "current", "ia": "current"}
CHUNK_ROWS = 500_000


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


def _read_csv(csv_path: Path, fs: float | None = None) -> pd.DataFrame:
    cols = _read_header(csv_path, "; expected a header row t,u,tacho,pos and one row per "
                                  "sample")
    if not any(c in ("t", "u", "tacho", "pos") for c in cols):
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
        raise RunFileError(f"{csv_path}: both 'tacho' and 'pos' missing; a run needs at "
                           "least one sensor column")
    numeric = [c for c in cols if c in KNOWN_COLUMNS]
    df = _read_numeric(csv_path, cols, numeric)
    if len(df) < 2:
        raise RunFileError(f"{csv_path}: only {len(df)} data row(s); a run needs samples")
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


def _check_against_sidecar(csv_path, json_path, data, meta):
    sensors = meta["sensors"]
    need = ([("tacho_v_per_rad_s", "tacho")] if "tacho" in data else []) + \
           ([("pos_v_per_rad", "pos")] if "pos" in data else [])
    for key, col in need:
        if sensors.get(key) is None:
            raise RunFileError(f"{json_path}: key 'sensors.{key}' missing; it must be a "
                               f"nonzero number (the run has a '{col}' column to convert)")


# -- writing -------------------------------------------------------------------

def make_meta(*, sample_rate_hz: float, experiment: dict, sensors: dict, rig: dict,
              source: str, bridge: dict | None = None, **extra) -> dict:
    meta = {"format": FORMAT, "sample_rate_hz": float(sample_rate_hz), "source": source,
            "created": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "experiment": experiment, "sensors": sensors, "rig": rig}
    if bridge is not None:
        meta["bridge"] = bridge
    meta.update(extra)
    return meta


def write_run(run: Run, directory: Path | str, overwrite: bool = False) -> Path:
    """Write ``run`` as ``directory/name.csv`` + ``.json``, each atomically.

    The CSV lands first and the sidecar last, so a crash in between leaves a CSV
    without sidecar, which readers reject by name and ``sweep --resume`` redoes;
    never a half-written file. An existing run is only replaced with ``overwrite``.
    """
    from .schemas import check_run_name

    directory = Path(directory)
    check_run_name(run.name, f"run '{run.name}'")
    directory.mkdir(parents=True, exist_ok=True)
    csv_path, json_path = directory / f"{run.name}.csv", directory / f"{run.name}.json"
    # belt and braces: whatever the name, nothing lands outside the output folder
    if csv_path.resolve().parent != directory.resolve():
        raise RunFileError(f"run '{run.name}': would be written outside {directory}; "
                           "a run name is a plain file name")
    if not overwrite and json_path.exists():
        raise RunFileError(f"{json_path}: a run named '{run.name}' already exists; choose "
                           "another output folder or remove it first")
    cols = [c for c in ("t", "u", "tacho", "pos", "ref", "current") if c in run.data] + \
           [c for c in run.data.columns if c not in ("t", "u", "tacho", "pos", "ref", "current")]
    atomic_write(csv_path, run.data[cols].to_csv(index=False, float_format="%.7g",
                                                  lineterminator="\n"))
    atomic_write(json_path, json.dumps(run.meta, indent=2, default=json_default) + "\n")
    run.path = csv_path
    return csv_path


def run_exists(directory: Path | str, name: str) -> bool:
    """A finished run: both files present (the sidecar is written last)."""
    d = Path(directory)
    return (d / f"{name}.csv").exists() and (d / f"{name}.json").exists()


def read_csv_columns(path: Path | str, columns: list[str]) -> dict[str, np.ndarray]:
    """Named numeric columns of a foreign CSV (an export to import), with the same
    row/column errors and memory bounds as a run file."""
    path = Path(path)
    if not path.is_file():
        raise RunFileError(f"{path}: file not found")
    cols = _read_header(path)
    _no_duplicates(path, cols)
    for c in columns:
        if c not in cols:
            close = difflib.get_close_matches(c, cols, n=1, cutoff=0.6)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise RunFileError(f"{path}: column '{c}' not found{hint}; the header has "
                               f"{', '.join(cols)}")
    raw = _read_numeric(path, cols, list(dict.fromkeys(columns)))
    if len(raw) < 2:
        raise RunFileError(f"{path}: fewer than two data rows")
    return {c: raw[c].to_numpy(float) for c in columns}
