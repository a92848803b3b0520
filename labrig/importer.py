"""``labrig import``: bring a scope/DAQ export or another lab's CSV in as a run.

Physical speed (rad/s or rpm) and position (rad or deg) columns are stored as a
unit "virtual sensor" (1 V per rad/s, 1 V per rad), so the run is self-describing
and ``Run.speed`` returns the original values in rad/s. Raw sensor volts are kept
as volts with the gains given on the command line.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import RunFileError, UserError
from .schemas import check_run_name
from .runs import Run, make_meta, read_csv_columns, write_run

SPEED_UNITS = {"rad/s": 1.0, "rpm": 2 * math.pi / 60.0}
POS_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}
TIME_UNITS = {"s": 1.0, "ms": 1e-3}
MAP_TARGETS = ("t", "u", "speed", "pos", "tacho", "ref", "current")


def parse_map(text: str) -> dict[str, str]:
    """``"t=Time,u=CH1,speed=RPM"`` -> ``{"t": "Time", ...}`` (validated)."""
    out = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        if "=" not in item:
            raise UserError(f"--map: '{item}' is not TARGET=COLUMN (e.g. t=Time,u=CH1,speed=RPM)")
        key, col = (s.strip() for s in item.split("=", 1))
        if key not in MAP_TARGETS:
            raise UserError(f"--map: unknown target '{key}'; expected one of {', '.join(MAP_TARGETS)}")
        out[key] = col
    for need in ("t", "u"):
        if need not in out:
            raise UserError(f"--map: '{need}=COLUMN' missing; t and u are required")
    if not ({"speed", "tacho", "pos"} & set(out)):
        raise UserError("--map: map at least one of speed=, tacho= or pos=")
    if "speed" in out and "tacho" in out:
        raise UserError("--map: give speed= (physical units) or tacho= (volts), not both")
    return out


def import_csv(src: Path | str, outdir: Path | str, mapping: dict[str, str], *,
               speed_unit: str = "rad/s", pos_unit: str = "rad", time_unit: str = "s",
               tacho_gain: float | None = None, pos_gain: float | None = None,
               pos_offset: float = 0.0, gear_ratio: float = 1.0, amplifier_gain: float = 1.0,
               name: str | None = None, waveform: str = "custom", loop: str = "open",
               overwrite: bool = False, position_gain: float | None = None,
               velocity_gain: float | None = None) -> Path:
    """Convert a foreign CSV into a labrig run in ``outdir``; return the CSV path."""
    src = Path(src)
    if name is None:  # a file name may hold spaces or brackets; a run name may not
        name = re.sub(r"[^A-Za-z0-9_.+\-]", "_", src.stem).lstrip(".") or "run"
    check_run_name(name, "--name")
    for opt, val, table in (("--speed-unit", speed_unit, SPEED_UNITS),
                            ("--pos-unit", pos_unit, POS_UNITS),
                            ("--time-unit", time_unit, TIME_UNITS)):
        if val not in table:
            raise UserError(f"{opt}: unknown unit '{val}'; expected one of {', '.join(table)}")
    for opt, val, positive in (("--tacho-gain", tacho_gain, False), ("--pos-gain", pos_gain, False),
                               ("--pos-offset", pos_offset, None),
                               ("--gear-ratio", gear_ratio, True),
                               ("--amplifier-gain", amplifier_gain, True)):
        if val is None:
            continue
        if not math.isfinite(val) or (positive and val <= 0) or (positive is False and val == 0):
            need = "a positive number" if positive else "a nonzero number" \
                if positive is False else "a finite number"
            raise UserError(f"{opt}: {val:g} is not {need}")
    if loop not in ("open", "closed"):
        raise UserError(f"--loop: expected open or closed, got '{loop}'")
    experiment = {"loop": loop, "waveform": waveform}
    if loop == "closed":
        # fitted through the loop, the controller is part of the model: without its
        # gains the fit would be of a different system
        for opt, v in (("--position-gain", position_gain), ("--velocity-gain", velocity_gain)):
            if v is None or not math.isfinite(v) or v < 0:
                raise UserError(f"{opt}: a closed-loop import needs the loop's gains "
                                f"(>= 0, volts per volt); got {v}")
        experiment.update(position_gain=float(position_gain), velocity_gain=float(velocity_gain))
    elif position_gain is not None or velocity_gain is not None:
        raise UserError("--position-gain/--velocity-gain: only with --loop closed")
    if "pos" in mapping and pos_gain is None and "tacho" in mapping:
        raise UserError("--pos-gain is needed with raw-volt columns (tacho=...,pos=...)")
    if "tacho" in mapping and tacho_gain is None:
        raise UserError("--tacho-gain (V per rad/s) is needed when mapping raw tacho volts")
    frame = read_csv_columns(src, list(mapping.values()))
    t = frame[mapping["t"]] * TIME_UNITS[time_unit]
    t = t - t[0]
    cols = {"t": t, "u": frame[mapping["u"]]}
    sensors = {}
    if "speed" in mapping:
        cols["tacho"] = frame[mapping["speed"]] * SPEED_UNITS[speed_unit]
        sensors["tacho_v_per_rad_s"] = 1.0
    if "tacho" in mapping:
        cols["tacho"] = frame[mapping["tacho"]]
        sensors["tacho_v_per_rad_s"] = float(tacho_gain)
    if "pos" in mapping:
        if pos_gain is None:  # physical position: unit virtual pot
            cols["pos"] = frame[mapping["pos"]] * POS_UNITS[pos_unit]
            sensors["pos_v_per_rad"] = 1.0
            sensors["pos_offset_v"] = 0.0
        else:
            cols["pos"] = frame[mapping["pos"]]
            sensors["pos_v_per_rad"] = float(pos_gain)
            sensors["pos_offset_v"] = float(pos_offset)
    for extra in ("ref", "current"):
        if extra in mapping:
            cols[extra] = frame[mapping[extra]]
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise RunFileError(f"{src}: row {i + 3}, column '{mapping['t']}': time is not "
                           "increasing; sort the export or remove repeated rows")
    fs = 1.0 / float(np.median(dt))
    if abs(fs - round(fs)) < 1e-3 * fs:
        fs = float(round(fs))
    run = Run(name=name or src.stem, data=pd.DataFrame(cols),
              meta=make_meta(sample_rate_hz=fs, source="import",
                             experiment=experiment,
                             sensors=sensors,
                             rig={"gear_ratio": float(gear_ratio),
                                  "amplifier_gain": float(amplifier_gain),
                                  "name": f"imported from {src.name}"},
                             imported_from=str(src.name)))
    from .schemas import Sidecar, validate  # never write a run nobody can read back

    validate(Sidecar, run.meta, f"{src} (as imported)", RunFileError)
    path = write_run(run, outdir, overwrite=overwrite)
    from .runs import read_run  # validate what we wrote, exactly as every reader will

    read_run(path)
    return path
