"""Run files (docs/design.md, 'Run files'): read, validate, write atomically, import foreign CSVs.

A run is ``stem.csv`` (raw volts: t, u, tacho and/or pos, optional ref, current; or,
imported without a tacho, physical ``speed`` instead of ``tacho``) plus ``stem.json``
(sidecar: format, sample rate, experiment, sensors, rig). Loading gives physical units
through the sidecar's calibration: ``Run.speed`` is the motor speed in rad/s (tacho / Kt,
or the ``speed`` column as it is) and ``Run.position`` the output-shaft angle in rad
((pos - offset) / Kpot).
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from html import escape
from pathlib import Path

import numpy as np
import pandas as pd

from labrig.core.errors import AnalysisError, RunFileError, UserError
from labrig.io.bridge_record import check_encoder, check_gaps, cut_at_trip
from labrig.io.csvfile import SENSOR_COLUMNS, read_run_csv
from labrig.core.fileio import atomic_write, json_default, not_regular
from labrig.model.plants import AXES, check_axis

FORMAT = "labrig-run/1"
#: the order labrig writes a run's columns in (others follow); a run has ``tacho`` or
#: ``speed``, never both, so speed lands right after u either way
COLUMN_ORDER = ("t", "u", "tacho", "speed", "pos", "ref", "current")


@dataclass(repr=False)
class Run:
    """One acquired or imported run, in raw volts plus its sidecar metadata.

    Attributes
    ----------
    name : str
        The run file's name without ``.csv``.
    data : pandas.DataFrame
        The samples: ``t``, ``u`` and the sensors' columns as recorded (volts, or the
        import's units), ``gap`` where the link lost a sample.
    meta : dict
        The sidecar (``.json``): the experiment, the rig, the sensors' gains.
    path : Path or None
        The file it was read from.

    The channels are properties: ``t``, ``u``, ``speed`` and ``position`` in physical
    units (None where the run has no such sensor), ``measured`` (False where the link
    lost the sample).

    Examples
    --------
    >>> import labrig as lr
    >>> run = lr.read_runs("data/sweep_default")[2]
    >>> run.name, len(run.u) > 0
    ('sq_1.20V', True)
    """

    name: str
    data: pd.DataFrame
    meta: dict
    path: Path | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    # -- raw columns ---------------------------------------------------------
    @property
    def t(self) -> np.ndarray:
        """Sample times in s since the start of the record (the ``t`` column)."""
        return self.data["t"].to_numpy(float)

    @property
    def u(self) -> np.ndarray:
        """The input in V as the bridge output it (``u``): the amplifier input in open
        loop, the position reference in closed loop."""
        return self.data["u"].to_numpy(float)

    @property
    def ref(self) -> np.ndarray | None:
        """The reference in V as the board read it back (``ref``), or None without one."""
        return self.data["ref"].to_numpy(float) if "ref" in self.data else None

    @property
    def measured(self) -> np.ndarray:
        """True for each sample the bridge delivered; False for one the link lost
        (``gap = 1``: interpolated to keep the time base, never data to fit)."""
        if "gap" not in self.data:
            return np.ones(len(self.data), bool)
        return self.data["gap"].to_numpy(float) == 0

    @property
    def n_gaps(self) -> int:
        """How many samples the link lost (rows with ``gap = 1``)."""
        return int(np.count_nonzero(self.data["gap"].to_numpy())) if "gap" in self.data else 0

    @property
    def fs(self) -> float:
        """The sample rate in Hz (the sidecar's ``sample_rate_hz``)."""
        return float(self.meta["sample_rate_hz"])

    @property
    def dt(self) -> float:
        """The sample period in s (``1 / fs``)."""
        return 1.0 / self.fs

    @property
    def has_tacho(self) -> bool:
        """A tachogenerator's volts (``tacho``): Kt is known and can be checked."""
        return "tacho" in self.data

    @property
    def has_speed(self) -> bool:
        """A speed channel: the tacho, or physical speed imported without one (``speed``)."""
        return self.has_tacho or "speed" in self.data

    @property
    def has_pos(self) -> bool:
        """A position channel (``pos``: a pot's volts or an encoder's counts)."""
        return "pos" in self.data

    # -- metadata ------------------------------------------------------------
    @property
    def experiment(self) -> dict:
        """The sidecar's ``experiment`` table (loop, input, controller, ...); {} if none."""
        return self.meta.get("experiment", {})

    @property
    def loop(self) -> str:
        """``"open"`` or ``"closed"`` (``experiment.loop``; default open)."""
        return self.experiment.get("loop", "open")

    @property
    def sensors(self) -> dict:
        """The sidecar's ``sensors`` table (the channels' gains and offsets); {} if none."""
        return self.meta.get("sensors", {})

    @property
    def controller(self) -> dict | None:
        """A closed loop's controller as the sidecar states it (``experiment.controller``:
        kind, kp, kd, ki, output_limit_v), or None (open loop, or the MS150's analog loop
        given by ``position_gain``/``velocity_gain``)."""
        return self.experiment.get("controller") if self.loop == "closed" else None

    @property
    def gains(self) -> dict | None:
        """The closed loop's ``{"kp": ..., "kv": ...}`` as the simulators use them
        (amplifier input = kp (ref - Kpot x) - kv Kt w, volts per volt); None for an
        open-loop run. A closed-loop run always states its loop (checked when read)."""
        if self.loop != "closed":
            return None
        c = self.controller
        if c is not None:  # a digital PD on the position in axis units: see ``constants``
            return {"kp": float(c["kp"]), "kv": float(c.get("kd", 0.0))}
        return {"kp": float(self.experiment["position_gain"]),
                "kv": float(self.experiment["velocity_gain"])}

    # -- the plant --------------------------------------------------------------------
    @property
    def drive(self) -> str:
        """What the input drives: ``voltage`` (an armature), ``torque`` or ``force``."""
        return self.meta.get("rig", {}).get("drive") or "voltage"

    @property
    def input_measured(self) -> bool:
        """The input is a measured torque or force (``rig.input: measured``), not a command."""
        return self.meta.get("rig", {}).get("input") == "measured"

    @property
    def axis(self) -> str:
        """``rotary`` (rad, rad/s) or ``linear`` (m, m/s)."""
        return axis_of(self.meta)

    @property
    def units(self) -> tuple[str, str]:
        """The axis's (position unit, speed unit)."""
        return ("m", "m/s") if self.axis == "linear" else ("rad", "rad/s")

    @property
    def amplifier_gain(self) -> float:
        """Armature volts per bridge volt, or a torque/force drive's gain kd (N m or N per
        input volt); 1.0 when the sidecar does not say."""
        rig = self.meta.get("rig", {})
        if self.drive != "voltage" and rig.get("input_gain") is not None:
            return float(rig["input_gain"])
        return float(rig.get("amplifier_gain", 1.0))

    @property
    def constants(self) -> dict:
        """The rig constants a model of this run needs: Ka, N, Kt, Kpot (a channel the
        run does not have gets 1.0: it is never used; an imported ``speed`` column is
        already in the axis's unit, so its Kt is 1.0 too). Under a stated controller the
        loop is closed on the position in axis units: Kpot = 1 and Kt = 1/N make the
        simulators' ``kv Kt w`` the controller's ``kd x'``."""
        if self.controller is not None:
            return {"Ka": self.amplifier_gain, "N": self.gear_ratio, "Kt": 1.0 / self.gear_ratio,
                    "Kpot": 1.0}
        kt = 1.0 if "speed" in self.data else float(self.sensors.get("tacho_v_per_rad_s") or 1.0)
        return {"Ka": self.amplifier_gain, "N": self.gear_ratio, "Kt": kt,
                "Kpot": float(self.sensors.get("pos_v_per_rad") or 1.0)}

    @property
    def current(self) -> np.ndarray | None:
        """Armature current in A (``current`` column times ``current_a_per_v``), or None."""
        if "current" not in self.data:
            return None
        return self.data["current"].to_numpy(float) * float(
            self.sensors.get("current_a_per_v") or 1.0)

    @property
    def speed_window_s(self) -> float:
        """The window a speed channel is computed over (``sensors.speed_window_s``: the
        travel in the last window over its length), 0 when the speed is not so filtered."""
        return float(self.sensors.get("speed_window_s") or 0.0)

    @property
    def pos_quantum(self) -> float:
        """The position sensor's quantum in axis units (an encoder's count); 0 unknown."""
        return float(self.sensors.get("pos_quantum") or 0.0)

    @property
    def start(self) -> str:
        """How the run starts as its sidecar states it (``experiment.start``: "rest" or
        "moving"), else "auto": decided from the data (:mod:`labrig.model.start`)."""
        return str(self.experiment.get("start") or "auto")

    @property
    def input_step(self) -> float:
        """One step of the input (V) as the sidecar states it (``bridge.dac_step_v``, or
        ``experiment.input_step_v`` for an imported run); 0 unknown."""
        declared = (self.meta.get("bridge") or {}).get("dac_step_v") or \
            self.experiment.get("input_step_v")
        try:
            return max(float(declared or 0.0), 0.0)
        except (TypeError, ValueError):
            return 0.0

    @property
    def kt(self) -> float:
        """The tacho's gain Kt in V per rad/s of the motor shaft (``tacho_v_per_rad_s``)."""
        return float(self.sensors["tacho_v_per_rad_s"])

    @property
    def kpot(self) -> float:
        """The position sensor's gain Kpot in V per rad of the output shaft (an
        encoder's: counts per axis unit; ``pos_v_per_rad``)."""
        return float(self.sensors["pos_v_per_rad"])

    @property
    def pos_offset(self) -> float:
        """The pot's volts at 0 rad (``pos_offset_v``; default 0)."""
        return float(self.sensors.get("pos_offset_v", 0.0))

    @property
    def gear_ratio(self) -> float:
        """The gear ratio N, motor turns per output turn (``rig.gear_ratio``; default 1)."""
        return float(self.meta.get("rig", {}).get("gear_ratio", 1.0))

    @property
    def amplitude(self) -> float:
        """Largest ``abs(u)`` applied (V): the run's amplitude for grouping and reports."""
        return float(np.max(np.abs(self.u)))

    # -- physical units -----------------------------------------------------
    @property
    def speed(self) -> np.ndarray | None:
        """Motor speed in the axis's unit (rad/s, m/s): the ``speed`` column as it is, else
        the tacho's volts over Kt; None for a position-only run."""
        if "speed" in self.data:
            return self.data["speed"].to_numpy(float)
        if not self.has_tacho:
            return None
        return self.data["tacho"].to_numpy(float) / self.kt

    @property
    def position(self) -> np.ndarray | None:
        """Output-shaft position in the axis's unit (rad, m): ``(pos - pos_offset) / kpot``;
        None for a run without a position channel."""
        if not self.has_pos:
            return None
        return (self.data["pos"].to_numpy(float) - self.pos_offset) / self.kpot

    def __len__(self) -> int:
        return len(self.data)

    def __repr__(self) -> str:
        e = self.experiment
        what = " ".join(str(x) for x in (e.get("loop", ""), e.get("waveform", "")) if x)
        amp = f" {self.amplitude:g} V" if self.amplitude else ""
        chans = ", ".join(c for c in self.data.columns if c != "t")
        return (f"Run({self.name!r}: {len(self)} samples at {self.fs:g} Hz, "
                f"{what or 'unknown experiment'}{amp}; columns {chans})")

    def _repr_html_(self) -> str:
        return f"<pre>{escape(repr(self))}</pre>"


# -- reading -------------------------------------------------------------------

def _stem_paths(path: Path) -> tuple[Path, Path]:
    path = Path(path)
    if path.suffix in (".csv", ".json"):
        return path.with_suffix(".csv"), path.with_suffix(".json")
    return path.with_name(path.name + ".csv"), path.with_name(path.name + ".json")


def read_run(path: Path | str) -> Run:
    """Read and validate one run (give the CSV, the JSON or the stem)."""
    csv_path, json_path = _stem_paths(Path(path))
    for p in (csv_path, json_path):
        what = not_regular(p)
        if what:
            raise RunFileError(f"{p}: is {what}, not a run file; a run is a regular .csv "
                               "file with its .json sidecar (move it out of the folder)")
    if not csv_path.exists():
        raise RunFileError(f"{csv_path}: run file not found")
    meta = read_sidecar(json_path, csv_path)
    data = read_run_csv(csv_path, float(meta["sample_rate_hz"]))
    _check_against_sidecar(csv_path, json_path, data, meta)
    run = Run(name=csv_path.stem, data=data, meta=meta, path=csv_path)
    run = cut_at_trip(run)
    check_gaps(run)
    check_encoder(run)
    return run


def read_dataset(paths) -> list[Run]:
    """Read every run in the given folders and/or run files, sorted by name, numbers in
    names by value (:func:`natural_key`).

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
    return sorted(runs, key=lambda r: natural_key(r.name))


def natural_key(name: str) -> tuple:
    """Sort key that reads the numbers in a name as numbers: ``step_3.00V`` before
    ``step_12.00V`` (as text, "1" sorts before "3")."""
    parts = re.split(r"(\d+(?:\.\d+)?)", name)
    return tuple((0, float(p), "") if k % 2 else (1, 0.0, p) for k, p in enumerate(parts))


def read_sidecar(json_path: Path, csv_path: Path) -> dict:
    # core.schemas brings pydantic (~0.07 s more to import): not for a module that only
    # needs Run (analysis, the sweep), only once a run is read
    from labrig.core.schemas import read_json, validate
    from labrig.core.sidecar_schema import Sidecar

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
    if exp.loop == "closed" and exp.controller is None and (
            exp.position_gain is None or exp.velocity_gain is None):
        raise RunFileError(f"{json_path}: a closed-loop run must state its controller: key "
                           "'experiment.controller' ({\"kind\": \"pd\", \"kp\": .., \"kd\": ..}) "
                           "or the analog loop's 'experiment.position_gain' and "
                           "'experiment.velocity_gain' missing; add it, or import with "
                           "`loop=closed` `controller=pd:kp=..,kd=..`")
    if checked.rig.drive is not None or checked.rig.axis is not None:
        drive = checked.rig.drive or "voltage"
        axis = checked.rig.axis or ("linear" if drive == "force" else "rotary")
        try:
            check_axis(drive, axis, f"{json_path}: key 'rig.axis'")
        except UserError as exc:
            raise RunFileError(str(exc)) from None
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
        cols = [c for c in SENSOR_COLUMNS if any(c in r.data for r in runs)]
        raise AnalysisError(f"runs {names}: {' and '.join(cols)} "
                            f"{'are' if len(cols) > 1 else 'is'} constant in every run while u "
                            f"changes, so there is nothing to {what}; is the motor powered "
                            "and are the sensors wired?")


def axis_of(meta: dict) -> str:
    """A sidecar's axis: as stated, else what its drive implies (a force moves a carriage)."""
    rig = meta.get("rig", {})
    return rig.get("axis") or ("linear" if rig.get("drive") == "force" else "rotary")


def _check_against_sidecar(csv_path, json_path, data, meta):
    sensors = meta["sensors"]
    if "speed" in data:
        _check_speed_column(csv_path, json_path, data, meta)
    need = ([("tacho_v_per_rad_s", "tacho")] if "tacho" in data else []) + \
           ([("pos_v_per_rad", "pos")] if "pos" in data else [])
    for key, col in need:
        if sensors.get(key) is None:
            raise RunFileError(f"{json_path}: key 'sensors.{key}' missing; it must be a "
                               f"nonzero number (the run has a '{col}' column to convert)")


def _check_speed_column(csv_path, json_path, data, meta):
    """A ``speed`` column is physical speed: alone (a tacho's volts would be a second,
    disagreeing speed) and in the unit the sidecar states, the axis's."""
    if "tacho" in data:
        raise RunFileError(f"{csv_path}: both a 'speed' and a 'tacho' column; a run measures "
                           "speed once: keep 'tacho' (volts, with sensors.tacho_v_per_rad_s) "
                           "or 'speed' (with sensors.speed_unit), not both")
    axis = axis_of(meta)
    want = AXES[axis][1]
    unit = meta["sensors"].get("speed_unit")
    if unit is None:
        raise RunFileError(f"{json_path}: key 'sensors.speed_unit' missing; the run has a "
                           f"'speed' column, so say its unit: add \"speed_unit\": \"{want}\" "
                           "(the axis's unit) to 'sensors'")
    if unit != want:
        raise RunFileError(f"{json_path}: key 'sensors.speed_unit' = {unit!r} but the axis is "
                           f"{axis} ({want}); convert the 'speed' column to {want} or fix "
                           "rig.axis")


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
    from labrig.core.schemas import check_run_name  # pydantic, ~0.07 s: only once a run is written

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
    cols = [c for c in COLUMN_ORDER if c in run.data] + \
           [c for c in run.data.columns if c not in COLUMN_ORDER]
    atomic_write(csv_path, run.data[cols].to_csv(index=False, float_format="%.7g",
                                                  lineterminator="\n"))
    atomic_write(json_path, json.dumps(run.meta, indent=2, default=json_default) + "\n")
    run.path = csv_path
    return csv_path


def run_exists(directory: Path | str, name: str) -> bool:
    """A finished run: both files present (the sidecar is written last)."""
    d = Path(directory)
    return (d / f"{name}.csv").exists() and (d / f"{name}.json").exists()
