"""Effect parameters in the drive's units (V, N m or N).

Inside, an effect's levels are volts at the input, the unit the kernels use on every
plant (:mod:`labrig.model.plants`). On the MS150 that is what they are: volts at the
bridge. A torque- or force-driven axis's input is a command of ``kd`` N m (N) per volt;
there a dead zone, an offset or a friction acting at that input is a torque (force):
``kd tc_v`` N m. Wherever a user reads them, in the text, the JSON and the model file,
such parameters are named and valued in the drive's unit: ``tc_v`` becomes ``tc_nm``
on a torque drive and ``tc_n`` on a force drive (a rail, already at the drive, keeps its
value). A model file in drive units is read back through the same table.
"""
from __future__ import annotations

#: per plant: the suffix of a drive-unit parameter and the unit
DRIVE = {"voltage": ("_v", "V"), "torque": ("_nm", "N m"), "force": ("_n", "N")}


def unit(plant: str) -> str:
    """The drive's unit: V, N m or N."""
    return DRIVE.get(plant, DRIVE["voltage"])[1]


def scale(effect, pname: str, plant: str, constants: dict) -> float | None:
    """The factor from an input-volt parameter to the drive's unit; None when the
    parameter is not one (a voltage plant, a time, an angle, a ratio)."""
    if plant not in DRIVE or plant == "voltage" or not pname.endswith("_v"):
        return None
    p = next((p for p in effect.params if p.name == pname), None)
    if p is None or p.unit != "V":
        return None
    # a drive-stage level (the rail) is already at the drive: Ka u there is kd u
    return 1.0 if effect.stage == "drive" else float(constants.get("Ka", 1.0))


def name(pname: str, plant: str) -> str:
    """``tc_v`` -> ``tc_nm`` (torque) or ``tc_n`` (force); unchanged on a voltage plant."""
    return pname[:-2] + DRIVE[plant][0] if plant in DRIVE and plant != "voltage" else pname


def to_drive(effects, effect_params: dict, plant: str, constants: dict) -> dict:
    """``{effect: {param: value}}`` in input volts -> named and valued in the drive's unit."""
    by = {e.name: e for e in effects}
    out = {}
    for ename, ps in effect_params.items():
        eff = by.get(ename)
        row = {}
        for k, v in ps.items():
            s = scale(eff, k, plant, constants) if eff is not None else None
            row[name(k, plant) if s is not None else k] = v * s if s is not None else v
        out[ename] = row
    return out


def from_drive(effects, effect_params: dict, plant: str, constants: dict) -> dict:
    """The inverse of :func:`to_drive` for a model file: a parameter given under its
    drive-unit name is turned back into input volts; one under its own name is taken as
    it is (a file written before drive units)."""
    by = {e.name: e for e in effects}
    out = {}
    for ename, ps in (effect_params or {}).items():
        eff = by.get(ename)
        row = dict(ps) if isinstance(ps, dict) else ps
        if eff is not None and isinstance(ps, dict):
            for p in eff.params:
                s = scale(eff, p.name, plant, constants)
                shown = name(p.name, plant)
                if s and p.name not in ps and isinstance(ps.get(shown), (int, float)):
                    row = {k: v for k, v in row.items() if k != shown}
                    row[p.name] = float(ps[shown]) / s
        out[ename] = row
    return out


def intervals(effects, parameters: dict, plant: str, constants: dict) -> dict:
    """An identification's ``{key: {value, interval95, ...}}`` with the effects' input-volt
    parameters renamed and scaled to the drive's unit (the plant's keys unchanged)."""
    by = {e.name: e for e in effects}
    out = {}
    for k, info in (parameters or {}).items():
        ename, _, pname = k.partition(".")
        eff = by.get(ename)
        s = scale(eff, pname, plant, constants) if eff is not None and pname else None
        if s is None or not isinstance(info, dict):
            out[k] = info
            continue
        row = dict(info)
        for f in ("value", "sigma"):
            if isinstance(row.get(f), (int, float)):
                row[f] = row[f] * s
        if row.get("interval95"):
            row["interval95"] = [v * s for v in row["interval95"]]
        out[f"{ename}.{name(pname, plant)}"] = row
    return out


def level(volts: float, context: dict) -> str:
    """An input-volt level as a user of this drive reads it: ``0.8 V`` on a voltage drive,
    ``16 N`` (``kd`` x volts) on a force drive (``context``: an effect text's, with
    ``plant`` and ``Ka``)."""
    plant = context.get("plant", "voltage")
    if plant == "voltage" or plant not in DRIVE:
        return f"{volts:.3g} V"
    return f"{volts * float(context.get('Ka', 1.0)):.3g} {unit(plant)}"


def shown_keys(effects, plant: str, constants: dict) -> dict:
    """``{"coulomb_friction.tc_v": ("coulomb_friction.tc_nm", kd, "N m")}`` for every
    input-volt parameter of ``effects`` on this drive; empty on a voltage drive."""
    return {f"{e.name}.{p.name}": (f"{e.name}.{name(p.name, plant)}", f, unit(plant))
            for e in effects for p in e.params
            if (f := scale(e, p.name, plant, constants))}
