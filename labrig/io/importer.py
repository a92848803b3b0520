"""``labrig import``: bring a scope/DAQ export, another lab's CSV or a MATLAB .mat file
in as a run.

Physical speed is converted to the axis's SI unit (rad/s on a rotary axis, m/s on a
linear one) and stored as what it is: a ``speed`` column, with ``sensors.speed_unit``
naming that unit, so the run is self-describing and nothing pretends there was a tacho
(``labrig analyse`` then reports no tacho volts and no Kt). Physical position is
converted to rad or m and stored through a unit "virtual pot" (1 V per unit). Encoder
counts are kept as counts with their resolution (the position's known quantum). Raw
sensor volts (``tacho=``, ``pos=``) are kept as volts with the gains given on the
command line. The drive (voltage, torque, force), the axis and a closed loop's
controller go into the sidecar.
"""
from __future__ import annotations

from dataclasses import dataclass

import hashlib
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from labrig.core.errors import RunFileError, UserError
from labrig.model.plants import AXES, check_axis
from labrig.model.sensors import exact_grid, found_count
from labrig.core.schemas import RUN_NAME_MAX, check_run_name, validate
from labrig.core.sidecar_schema import Controller, Sidecar
from labrig.io.exportfile import CsvLayout, read_export
from labrig.io.runs import Run, make_meta, read_run, write_run
from labrig.io.matfile import read_mat_columns
from labrig.io.csvfile import check_ranges

#: physical units per axis -> factor to the axis's SI unit
SPEED_UNITS = {"rotary": {"rad/s": 1.0, "rpm": 2 * math.pi / 60.0, "deg/s": math.pi / 180.0},
               "linear": {"m/s": 1.0, "mm/s": 1e-3}}
POS_UNITS = {"rotary": {"rad": 1.0, "deg": math.pi / 180.0, "rev": 2 * math.pi},
             "linear": {"m": 1.0, "mm": 1e-3}}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
#: a unit row's time units (Keysight "second", PicoScope "(ms)", Rigol "Sequence": the
#: sample's number, times the Increment of that row)
UNIT_ROW_TIME = {"s": "s", "sec": "s", "second": "s", "seconds": "s", "ms": "ms",
                 "us": "us", "\u00b5s": "us", "\u03bcs": "us", "sequence": "sequence"}
MAP_TARGETS = ("t", "u", "speed", "pos", "tacho", "ref", "current")


def parse_map(text: str) -> dict[str, str]:
    """``"t=Time,u=CH1,speed=RPM"`` -> ``{"t": "Time", ...}`` (validated)."""
    out = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        if "=" not in item:
            raise UserError(f"`mapping`: '{item}' is not TARGET=COLUMN (e.g. t=Time,u=CH1,speed=RPM)")
        key, col = (s.strip() for s in item.split("=", 1))
        if key not in MAP_TARGETS:
            raise UserError(f"`mapping`: unknown target '{key}'; expected one of {', '.join(MAP_TARGETS)}")
        out[key] = col
    if "u" not in out and "ref" not in out:
        raise UserError("`mapping`: 'u=COLUMN' missing; t and u (or ref, in closed loop) are required")
    if not ({"speed", "tacho", "pos"} & set(out)):
        raise UserError("`mapping`: map at least one of speed=, tacho= or pos=")
    if "speed" in out and "tacho" in out:
        raise UserError("`mapping`: give speed= (physical units) or tacho= (volts), not both")
    return out


def parse_controller(text: str | None) -> dict | None:
    """``"pd:kp=2,kd=0.1"`` -> the run's ``experiment.controller`` (validated)."""
    if text is None:
        return None
    kind, _, rest = text.partition(":")
    body = {"kind": kind.strip().lower()}
    names = {"kp": "kp", "kd": "kd", "ki": "ki", "limit": "output_limit_v"}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, _, val = item.partition("=")
        if key.strip() not in names:
            raise UserError(f"`controller`: unknown gain '{key.strip()}'; use kp, kd, ki, limit "
                            "(e.g. pd:kp=2,kd=0.1)")
        try:
            body[names[key.strip()]] = float(val)
        except ValueError:
            raise UserError(f"`controller`: '{item}' is not NAME=NUMBER") from None
    if body["kind"] not in ("pd", "pid"):
        raise UserError(f"`controller`: kind '{kind}' unknown; use pd or pid (e.g. pd:kp=2,kd=0.1)")
    if "kp" not in body:
        raise UserError("`controller`: kp missing (e.g. pd:kp=2,kd=0.1)")
    if body["kind"] == "pd" and body.get("ki"):
        raise UserError("`controller`: a pd controller has no ki; write pid:kp=..,kd=..,ki=..")

    return validate(Controller, body, "`controller`", UserError).model_dump(exclude_none=True)


def _units(axis: str, pos_unit: str, speed_unit: str) -> tuple[float | None, float, float]:
    """Counts per axis unit (an encoder) or None, the position and speed factors."""
    if pos_unit.startswith("counts:"):
        try:
            per = float(pos_unit.split(":", 1)[1])
        except ValueError:
            per = float("nan")
        if not math.isfinite(per) or per <= 0:
            raise UserError(f"`pos_unit`: '{pos_unit}' is not counts:N with N > 0 counts per "
                            f"{'revolution' if axis == 'rotary' else 'metre'}")
        return (per / (2 * math.pi) if axis == "rotary" else per), 1.0, \
            _factor("`speed_unit`", speed_unit, SPEED_UNITS, axis)
    return None, _factor("`pos_unit`", pos_unit, POS_UNITS, axis), \
        _factor("`speed_unit`", speed_unit, SPEED_UNITS, axis)


def _factor(opt, unit, table, axis):
    if unit in table[axis]:
        return table[axis][unit]
    other = "linear" if axis == "rotary" else "rotary"
    if unit in table[other]:
        raise UserError(f"{opt}: '{unit}' is a unit of a {other} axis, and this import is "
                        f"{axis}; add `axis={other}` (with `drive=force` for a linear axis) or "
                        f"use {', '.join(table[axis])}")
    raise UserError(f"{opt}: unknown unit '{unit}'; expected one of {', '.join(table[axis])}"
                    + (", counts:N" if opt == "`pos_unit`" else ""))


def read_columns(src: Path, columns: list[str],
                 skip_rows: int | None = None) -> tuple[dict, CsvLayout | None]:
    """Named channels of a CSV export (and where its header and data were found) or of a
    MATLAB .mat file (no layout)."""
    if src.suffix.lower() == ".mat":
        if skip_rows is not None:
            raise UserError(f"`skip_rows`: only for a CSV export; {src.name} is a MATLAB file")
        return read_mat_columns(src, columns), None
    return read_export(src, columns, skip_rows)


def default_name(src: Path) -> str:
    """A run name from the source file's stem: made safe (a file name may hold spaces or
    brackets, a run name may not) and, over RUN_NAME_MAX characters, cut with a short hash of
    the whole stem so that two long names stay apart."""
    name = re.sub(r"[^A-Za-z0-9_.+\-]", "_", src.stem).lstrip(".") or "run"
    if len(name) > RUN_NAME_MAX:
        digest = hashlib.sha1(src.stem.encode("utf-8", "surrogateescape")).hexdigest()[:8]
        name = f"{name[:RUN_NAME_MAX - 9]}-{digest}"
    return name


def time_factor(src: Path, column: str, layout: CsvLayout | None,
                time_unit: str | None) -> float:
    """Seconds per unit of the time column: ``time_unit``, else the unit row's (a Rigol
    'Sequence' column counts samples: its unit row's Increment is the step), else s."""
    cell = layout.unit(column) if layout is not None else ""
    said = UNIT_ROW_TIME.get(cell.strip("()[] ").lower())
    if said == "sequence":
        inc = None
        if "Increment" in layout.header:
            k = layout.header.index("Increment")
            try:
                inc = float(layout.unit_row[k]) if k < len(layout.unit_row) else None
            except ValueError:
                inc = None
        if inc is None or not math.isfinite(inc) or inc <= 0:
            raise RunFileError(f"{src}: column '{column}' numbers the samples (its unit row "
                               "says 'Sequence') and the file gives no Increment > 0; map a "
                               "time column")
        if time_unit is not None:
            raise UserError(f"`time_unit`: column '{column}' of {src.name} numbers the "
                            f"samples and its Increment ({inc:g} s) makes them seconds; "
                            "drop `time_unit`")
        return inc
    if said is not None and time_unit is not None and said != time_unit:
        raise UserError(f"`time_unit`: {time_unit}, but column '{column}' of {src.name} is "
                        f"in {said} (its unit row says {cell!r}); drop `time_unit` or fix it")
    return TIME_UNITS[time_unit or said or "s"]


def _warn(text: str) -> None:
    warnings.warn(text, UserWarning, stacklevel=3)


@dataclass(frozen=True)
class ImportOptions:
    """How to read a foreign file: units, sensor gains, the plant and the loop (the
    options of ``labrig import``, with its defaults). ``time_unit`` None is the unit
    row's, else s; ``gear_ratio`` None is 1, not said (counts then warn); ``skip_rows``
    the lines before a CSV's header when the search for it cannot find it."""

    speed_unit: str | None = None
    pos_unit: str | None = None
    time_unit: str | None = None
    tacho_gain: float | None = None
    pos_gain: float | None = None
    pos_offset: float = 0.0
    gear_ratio: float | None = None
    amplifier_gain: float = 1.0
    waveform: str = "custom"
    loop: str = "open"
    position_gain: float | None = None
    velocity_gain: float | None = None
    drive: str = "voltage"
    axis: str | None = None
    input_gain: float | None = None
    controller: dict | None = None
    current_gain: float = 1.0
    skip_rows: int | None = None
    #: the speed column is the travel over this window (s) over its length (a sketch's
    #: moving window of encoder counts): declared, the window is modelled
    speed_window: float | None = None
    #: one step of the input (V): a PWM's duty step, a DAC's code
    input_step: float | None = None
    #: how the run starts when its owner knows: "rest", "moving" (None: from the data)
    start: str | None = None
    #: the input column is a measured torque or force (a current times its constant)
    input_measured: bool = False
    #: samples per second of a log with no time column (a sketch printing ``u,count`` at a
    #: fixed rate): sample k is at k / rate_hz
    rate_hz: float | None = None


def _find_position_count(src: Path, position, unit: str, sensors: dict, notes: list) -> None:
    """An undeclared position that is an exact count (:func:`labrig.model.sensors.
    exact_grid`: every reading on one grid, and no noise flipping it up and down) is
    modelled as the quantiser it is: its step is the position's quantum
    (``pos_quantum``), so each run's start within a step is fitted and the count's own
    bias (a count is a floor: half a step below the shaft while it moves) is not taken
    for physics (an input offset creeping by half a count over a run)."""
    q = exact_grid(np.asarray(position, float))
    if not q:
        return
    sensors["pos_quantum"] = q
    notes.append(f"{src.name}: the position reads whole steps of {q:.4g} {unit} with no "
                 "noise at rest: taken as an exact count of that step (each run's start "
                 "within a step is fitted); declare `pos_unit=counts:N` to say so")


def _find_count(src: Path, speed, fs: float, sensors: dict, notes: list) -> None:
    """An undeclared speed that reads whole counts and stands at zero when still is a
    count, not an ADC's codes (:func:`labrig.model.sensors.found_count`): taken as counted
    over the sample before, as a sketch's ``(count - last) / dt`` reads, so the model reads
    it as the sensor does (half a sample late) and its floor is the counting noise. Only
    for a speed logged without the position: beside the counts, the window is measured
    against them (:func:`labrig.analysis.agreement.channel_agreement`), not assumed."""
    q = found_count([np.asarray(speed, float)])
    if not q:
        return
    sensors["speed_window_s"] = 1.0 / fs
    sensors["speed_window_found"] = True
    notes.append(f"{src.name}: the speed reads whole counts ({q:.4g} {sensors['speed_unit']} "
                 f"each) and stands at exactly 0 when still: taken as counted over the "
                 f"sample before ({1e3 / fs:.4g} ms); give `speed_window=S` if the logger "
                 "counts over another window")


def import_csv(src: Path | str, outdir: Path | str, mapping: dict[str, str],
               options: ImportOptions | None = None, *, name: str | None = None,
               overwrite: bool = False, warn=None, **settings) -> Path:
    """Convert a foreign CSV or .mat file into a labrig run in ``outdir``; return the CSV path.

    ``options`` (or its fields as keywords, ``settings``) say how to read the file;
    ``drive`` and ``axis`` choose the plant (:mod:`labrig.model.plants`); a torque/force
    drive needs ``input_gain`` (N m or N per input volt). In closed loop a mapped ``ref``
    is the loop's reference and ``u`` the logged controller output (kept as ``drive``).
    ``warn(text)`` is told what is imported but probably not meant (default: a
    UserWarning).
    """
    o = options if options is not None else ImportOptions(**settings)
    axis, pos_unit, speed_unit = o.axis, o.pos_unit, o.speed_unit
    src = Path(src)
    if name is None:  # from the file's stem, made a safe run name
        name = default_name(src)
    check_run_name(name, "`name`")
    if axis is None:  # from the drive; a unit never switches the plant behind the user
        axis = "linear" if o.drive == "force" else "rotary"
    check_axis(o.drive, axis)
    pos_unit = pos_unit or next(iter(POS_UNITS[axis]))
    speed_unit = speed_unit or next(iter(SPEED_UNITS[axis]))
    counts_per_unit, pos_factor, speed_factor = _units(axis, pos_unit, speed_unit)
    if o.time_unit is not None and o.time_unit not in TIME_UNITS:
        raise UserError(f"`time_unit`: unknown unit '{o.time_unit}'; expected one of "
                        f"{', '.join(TIME_UNITS)}")
    for opt, val, positive in (("`tacho_gain`", o.tacho_gain, False), ("`pos_gain`", o.pos_gain, False),
                               ("`pos_offset`", o.pos_offset, None),
                               ("`gear_ratio`", o.gear_ratio, True),
                               ("`amplifier_gain`", o.amplifier_gain, True),
                               ("`input_gain`", o.input_gain, True),
                               ("`current_gain`", o.current_gain, False),
                               ("`speed_window`", o.speed_window, True),
                               ("`input_step`", o.input_step, True)):
        if val is None:
            continue
        if not math.isfinite(val) or (positive and val <= 0) or (positive is False and val == 0):
            need = "a positive number" if positive else "a nonzero number" \
                if positive is False else "a finite number"
            raise UserError(f"{opt}: {val:g} is not {need}")
    if o.drive != "voltage" and o.input_gain is None:
        raise UserError(f"`input_gain`: a {o.drive}-driven axis needs its drive's gain kd "
                        f"({'N m' if o.drive == 'torque' else 'N'} per input volt), e.g. "
                        "`input_gain=20`")
    if o.input_measured and o.drive == "voltage":
        raise UserError("`input_measured`: only for `drive=torque` or force (the input is a "
                        "measured current times its torque or force constant, `input_gain`)")
    if o.drive == "voltage" and o.input_gain is not None:
        raise UserError("`input_gain`: only for `drive=torque` or force; a voltage drive's "
                        "gain is `amplifier_gain`")
    if axis == "linear" and o.gear_ratio not in (None, 1.0):
        raise UserError("`gear_ratio`: a linear axis has none (positions are the carriage's)")
    if o.loop not in ("open", "closed"):
        raise UserError(f"`loop`: expected open or closed, got '{o.loop}'")
    experiment = {"loop": o.loop, "waveform": o.waveform}
    if o.input_step is not None:  # what the input can resolve: an effect below it is not
        experiment["input_step_v"] = float(o.input_step)
    if o.start not in (None, "auto"):
        if o.start not in ("rest", "moving"):
            raise UserError(f"`start`: expected auto, rest or moving, got '{o.start}'")
        experiment["start"] = o.start
    if o.loop == "closed":
        # fitted through the loop, the controller is part of the model: without its
        # gains the fit would be of a different system
        if o.controller is not None:
            if o.position_gain is not None or o.velocity_gain is not None:
                raise UserError("`controller`: give the controller or `position_gain`/"
                                "`velocity_gain` (the MS150's analog loop), not both")
            experiment["controller"] = o.controller
        else:
            for opt, v in (("`position_gain`", o.position_gain), ("`velocity_gain`", o.velocity_gain)):
                if v is None or not math.isfinite(v) or v < 0:
                    raise UserError(f"`controller`: a closed-loop import needs its controller, "
                                    "e.g. `controller=pd:kp=2,kd=0.1` (or the MS150 loop's "
                                    f"{opt}); got none")
            experiment.update(position_gain=float(o.position_gain),
                              velocity_gain=float(o.velocity_gain))
    elif o.controller is not None or o.position_gain is not None or o.velocity_gain is not None:
        raise UserError("`controller`/`position_gain`/`velocity_gain`: only with `loop=closed`")
    elif "u" not in mapping:
        raise UserError("`mapping`: 'u=COLUMN' missing; an open-loop run needs its input")
    if "pos" in mapping and o.pos_gain is None and "tacho" in mapping:
        raise UserError("`pos_gain` is needed with raw-volt columns (tacho=...,pos=...)")
    if "tacho" in mapping and o.tacho_gain is None:
        raise UserError("`tacho_gain` (V per rad/s) is needed when mapping raw tacho volts")
    if "t" not in mapping and o.rate_hz is None:
        raise UserError("`mapping`: 't=COLUMN' missing; map the time column, or give "
                        "`rate_hz=HZ` for a log at a fixed rate without one")
    if o.rate_hz is not None:
        if "t" in mapping:
            raise UserError(f"`rate_hz`: the time column t={mapping['t']} gives the samples' "
                            "times; give the column or the rate, not both")
        if o.time_unit is not None:
            raise UserError("`time_unit`: a log read at `rate_hz` has no time column to "
                            "give a unit; drop `time_unit`")
        if isinstance(o.rate_hz, bool) or not isinstance(o.rate_hz, (int, float)) \
                or not math.isfinite(o.rate_hz) or not 0 < o.rate_hz <= 1e7:
            raise UserError(f"`rate_hz`: {o.rate_hz!r} is not a sample rate in Hz "
                            "(above 0, at most 1e7)")
    if o.skip_rows is not None and (isinstance(o.skip_rows, bool)
                                    or not isinstance(o.skip_rows, int)):
        raise UserError(f"`skip_rows`: {o.skip_rows!r} is not a number of lines")
    frame, layout = read_columns(src, list(mapping.values()), o.skip_rows)
    first_row = layout.first_row if layout is not None else 2  # the file's line of sample 0
    if o.rate_hz is not None:   # a fixed-rate log: sample k at k / rate
        t = np.arange(len(next(iter(frame.values())))) / float(o.rate_hz)
    else:
        t = frame[mapping["t"]] * time_factor(src, mapping["t"], layout, o.time_unit)
        t = t - t[0]
    closed_ref = o.loop == "closed" and "ref" in mapping
    # in closed loop the run's u is the reference; a logged controller output is 'drive'
    cols = {"t": t, "u": frame[mapping["ref"] if closed_ref else mapping["u"]]}
    if closed_ref and "u" in mapping:
        cols["drive"] = frame[mapping["u"]]
    sensors = {}
    notes = []  # warnings, told once the run is written (an error stays one line)
    if "speed" in mapping:  # physical speed: kept as speed, never as made-up tacho volts
        cols["speed"] = frame[mapping["speed"]] * speed_factor
        sensors["speed_unit"] = AXES[axis][1]
    if o.speed_window is not None:
        if not ({"speed", "tacho"} & set(mapping)):
            raise UserError("`speed_window`: the file has no speed channel (map speed= or "
                            "tacho=), or leave the option out")
        sensors["speed_window_s"] = float(o.speed_window)
    if "tacho" in mapping:
        cols["tacho"] = frame[mapping["tacho"]]
        sensors["tacho_v_per_rad_s"] = float(o.tacho_gain)
    if "pos" in mapping:
        if counts_per_unit is not None:  # encoder counts, kept as counts
            if axis == "rotary" and o.gear_ratio is None:
                notes.append(f"{src.name}: `pos_unit={pos_unit}` counts per turn of the "
                             "output shaft and no `gear_ratio` was given, so the motor is "
                             "taken to be that shaft (ratio 1); for an encoder on a geared "
                             "motor add `gear_ratio=N` and give counts:(counts per motor "
                             "turn x N)")
            cols["pos"] = frame[mapping["pos"]]
            sensors.update(pos_v_per_rad=counts_per_unit, pos_offset_v=0.0, pos_kind="encoder",
                           pos_quantum=1.0 / counts_per_unit)
        elif o.pos_gain is None:  # physical position: unit virtual pot
            cols["pos"] = frame[mapping["pos"]] * pos_factor
            sensors["pos_v_per_rad"] = 1.0
            sensors["pos_offset_v"] = 0.0
        else:
            cols["pos"] = frame[mapping["pos"]]
            sensors["pos_v_per_rad"] = float(o.pos_gain)
            sensors["pos_offset_v"] = float(o.pos_offset)
    if "current" in mapping:
        cols["current"] = frame[mapping["current"]]
        sensors["current_a_per_v"] = float(o.current_gain)
    if "ref" in mapping and not closed_ref:
        cols["ref"] = frame[mapping["ref"]]
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise RunFileError(f"{src}: row {first_row + i + 1}, column '{mapping['t']}': time "
                           "is not increasing; sort the export or remove repeated rows")
    fs = 1.0 / float(np.median(dt))
    if abs(fs - round(fs)) < 1e-3 * fs:
        fs = float(round(fs))
    check_ranges(src, pd.DataFrame(cols), mapping, first_row)  # before anything is written
    if "speed" in mapping and "pos" not in mapping and o.speed_window is None:
        _find_count(src, cols["speed"], fs, sensors, notes)
    if "pos" in mapping and counts_per_unit is None:
        k, off = sensors["pos_v_per_rad"], sensors["pos_offset_v"]
        _find_position_count(src, (np.asarray(cols["pos"], float) - off) / k,
                             "m" if axis == "linear" else "rad", sensors, notes)
    rig = {"gear_ratio": float(o.gear_ratio if o.gear_ratio is not None else 1.0),
           "amplifier_gain": float(o.amplifier_gain),
           "name": f"imported from {src.name}", "drive": o.drive, "axis": axis}
    if o.input_gain is not None:
        rig["input_gain"] = float(o.input_gain)
    if o.input_measured:
        rig["input"] = "measured"
    run = Run(name=name or src.stem, data=pd.DataFrame(cols),
              meta=make_meta(sample_rate_hz=fs, source="import",
                             experiment=experiment,
                             sensors=sensors,
                             rig=rig,
                             imported_from=str(src.name)))
    # never write a run nobody can read back
    validate(Sidecar, run.meta, f"{src} (as imported)", RunFileError)
    if not overwrite and (Path(outdir) / f"{name}.json").exists():
        raise UserError(f"{Path(outdir) / name}.json: a run named '{name}' already exists; "
                        "add `overwrite` to replace it, or choose another `name` or output folder")
    path = write_run(run, outdir, overwrite=overwrite)
    read_run(path)  # validate what we wrote, exactly as every reader will
    for text in notes:
        (warn or _warn)(text)
    return path
