"""Run files (design.md 3.1): read, validate, write atomically, import foreign CSVs.

A run is ``stem.csv`` (raw volts: t, u, tacho and/or pos, optional ref, current)
plus ``stem.json`` (sidecar: format, sample rate, experiment, sensors, rig). Loading
gives physical units through the sidecar's calibration: ``Run.speed`` is the motor
speed in rad/s (tacho / Kt) and ``Run.position`` the output-shaft angle in rad
((pos - offset) / Kpot).
"""
from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import RunFileError

FORMAT = "labrig-run/1"
REQUIRED_COLUMNS = ("t", "u")
SENSOR_COLUMNS = ("tacho", "pos")
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
    data = _read_csv(csv_path)
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
    if not json_path.exists():
        raise RunFileError(f"{json_path}: sidecar missing for {csv_path.name}; every run "
                           "needs a .json sidecar (see design.md 3.1 or `labrig import`)")
    try:
        meta = json.loads(json_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RunFileError(f"{json_path}: sidecar is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise RunFileError(f"{json_path}: sidecar must be a JSON object")
    fmt = meta.get("format")
    if fmt is None:
        raise RunFileError(f"{json_path}: key 'format' missing; expected \"{FORMAT}\"")
    if fmt != FORMAT:
        raise RunFileError(f"{json_path}: key 'format' is {fmt!r}; this labrig reads \"{FORMAT}\"")
    rate = meta.get("sample_rate_hz")
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not rate > 0 \
            or not math.isfinite(rate):
        raise RunFileError(f"{json_path}: key 'sample_rate_hz' must be a positive number, "
                           f"got {rate!r}")
    for key in ("experiment", "sensors", "rig"):
        if not isinstance(meta.get(key), dict):
            raise RunFileError(f"{json_path}: key '{key}' missing or not an object")
    loop = meta["experiment"].get("loop")
    if loop not in ("open", "closed"):
        raise RunFileError(f"{json_path}: key 'experiment.loop' must be \"open\" or "
                           f"\"closed\", got {loop!r}")
    gr = meta["rig"].get("gear_ratio", 1.0)
    if isinstance(gr, bool) or not isinstance(gr, (int, float)) or not gr > 0:
        raise RunFileError(f"{json_path}: key 'rig.gear_ratio' must be a positive number")
    return meta


def _read_raw(path: Path, empty_hint: str = "") -> pd.DataFrame:
    """A CSV as strings with stripped column names, or one clear error."""
    try:
        raw = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise RunFileError(f"{path}: file is empty{empty_hint}") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise RunFileError(f"{path}: not a readable CSV ({str(exc).splitlines()[0]})") from None
    raw.columns = [c.strip() for c in raw.columns]
    return raw


def _finite_column(path: Path, raw: pd.DataFrame, c: str) -> np.ndarray:
    """Column ``c`` as floats; the first NaN, inf, empty or non-numeric cell is an error
    naming its row (header = row 1) and column."""
    col = raw[c].str.strip()
    values = pd.to_numeric(col, errors="coerce").to_numpy(float)
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.argmax(bad))
        cell = col.iloc[i]
        what = ("NaN or inf" if cell.lower().lstrip("+-") in ("nan", "inf", "infinity")
                else f"non-numeric value {cell!r}" if cell else "an empty cell")
        raise RunFileError(f"{path}: row {i + 2}, column '{c}': {what}; every "
                           "sample must be a finite number")
    return values


def _read_csv(csv_path: Path) -> pd.DataFrame:
    raw = _read_raw(csv_path, "; expected a header row t,u,tacho,pos and one row per sample")
    cols = list(raw.columns)
    if not any(c in ("t", "u", "tacho", "pos") for c in cols):
        raise RunFileError(f"{csv_path}: no header row; the first line must name the "
                           "columns, e.g. t,u,tacho,pos")
    for c in REQUIRED_COLUMNS:
        if c not in cols:
            raise RunFileError(f"{csv_path}: column '{c}' missing (header has "
                               f"{', '.join(cols)}); a run needs t and u")
    if not any(c in cols for c in SENSOR_COLUMNS):
        raise RunFileError(f"{csv_path}: both 'tacho' and 'pos' missing; a run needs at "
                           "least one sensor column")
    if len(raw) < 2:
        raise RunFileError(f"{csv_path}: only {len(raw)} data row(s); a run needs samples")
    known = [c for c in cols if c in ("t", "u", "tacho", "pos", "ref", "current")]
    data = {}
    for c in cols:
        # unknown columns are kept as text and ignored
        data[c] = _finite_column(csv_path, raw, c) if c in known else raw[c].str.strip()
    df = pd.DataFrame(data)
    t = df["t"].to_numpy()
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise RunFileError(f"{csv_path}: row {i + 3}, column 't': time {t[i + 1]:g} s is not "
                           f"after {t[i]:g} s; t must be strictly increasing")
    med = float(np.median(dt))
    dev = np.abs(dt - med) > UNIFORM_TOL * med
    if dev.any():
        i = int(np.argmax(dev))
        raise RunFileError(f"{csv_path}: row {i + 3}, column 't': step {dt[i]:g} s where the "
                           f"run samples every {med:g} s; t must be uniform (resample first, "
                           "or a sample was lost)")
    return df


def _check_against_sidecar(csv_path, json_path, data, meta):
    med = float(np.median(np.diff(data["t"].to_numpy())))
    fs = float(meta["sample_rate_hz"])
    if abs(1.0 / med - fs) > RATE_TOL * fs:
        raise RunFileError(f"{json_path}: key 'sample_rate_hz' = {fs:g} but column 't' of "
                           f"{csv_path.name} samples at {1 / med:.6g} Hz; fix one of them")
    sensors = meta["sensors"]
    need = ([("tacho_v_per_rad_s", "tacho")] if "tacho" in data else []) + \
           ([("pos_v_per_rad", "pos")] if "pos" in data else [])
    for key, col in need:
        v = sensors.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v == 0 or not math.isfinite(v):
            raise RunFileError(f"{json_path}: key 'sensors.{key}' must be a nonzero number "
                               f"(the run has a '{col}' column to convert)")


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


def _atomic_write(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_run(run: Run, directory: Path | str, overwrite: bool = False) -> Path:
    """Write ``run`` as ``directory/name.csv`` + ``.json``, each atomically.

    The CSV lands first and the sidecar last, so a crash in between leaves a CSV
    without sidecar, which readers reject by name and ``sweep --resume`` redoes;
    never a half-written file. An existing run is only replaced with ``overwrite``.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    csv_path, json_path = directory / f"{run.name}.csv", directory / f"{run.name}.json"
    if not overwrite and json_path.exists():
        raise RunFileError(f"{json_path}: a run named '{run.name}' already exists; choose "
                           "another output folder or remove it first")
    cols = [c for c in ("t", "u", "tacho", "pos", "ref", "current") if c in run.data] + \
           [c for c in run.data.columns if c not in ("t", "u", "tacho", "pos", "ref", "current")]
    _atomic_write(csv_path, run.data[cols].to_csv(index=False, float_format="%.7g",
                                                  lineterminator="\n"))
    _atomic_write(json_path, json.dumps(run.meta, indent=2, default=_json_default) + "\n")
    run.path = csv_path
    return csv_path


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, tuple):
        return list(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def run_exists(directory: Path | str, name: str) -> bool:
    """A finished run: both files present (the sidecar is written last)."""
    d = Path(directory)
    return (d / f"{name}.csv").exists() and (d / f"{name}.json").exists()


def _read_csv_numeric(path: Path, columns: list[str]) -> dict[str, np.ndarray]:
    """Read named numeric columns of a foreign CSV, with row/column errors."""
    path = Path(path)
    if not path.exists():
        raise RunFileError(f"{path}: file not found")
    raw = _read_raw(path)
    out = {}
    for c in columns:
        if c not in raw.columns:
            raise RunFileError(f"{path}: column '{c}' not found; the header has "
                               f"{', '.join(raw.columns)}")
        out[c] = _finite_column(path, raw, c)
    if len(raw) < 2:
        raise RunFileError(f"{path}: fewer than two data rows")
    return out
