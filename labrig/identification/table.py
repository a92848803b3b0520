"""How an identification is shown: the paper's Table 2 (done right: the identifiable
combinations first, then R..K, methods side by side), the JSON of ``identify --json``,
and the warnings that make a suspect fit say so."""
from __future__ import annotations

import math

from labrig.model.effectset import param_key
from labrig.model.drive_units import unit as drive_unit
from labrig.model.plants import plant_class
from labrig.core.tables import Table, fmt
from labrig.identification.doc import IdentRecord
from labrig.identification.result import identification_warnings


def null_unbounded(identifiable: dict) -> dict:
    """A copy of an identifiability dict in which an interval with an infinite or NaN
    end is null, as an interval the data do not bound at all already is (a [0, inf]
    interval says nothing, and strict JSON cannot carry it)."""
    def fix(d):
        if isinstance(d, dict) and d.get("interval95") is not None and \
                not all(isinstance(x, (int, float)) and math.isfinite(x) for x in d["interval95"]):
            return {**d, "interval95": None}
        return d

    out = dict(identifiable)
    for key in ("km", "tau_m_s", "tau_e_s"):
        if key in out:
            out[key] = fix(out[key])
    if isinstance(out.get("physical"), dict):
        out["physical"] = {n: fix(d) for n, d in out["physical"].items()}
    if isinstance(out.get("parameters"), dict):
        out["parameters"] = {n: fix(d) for n, d in out["parameters"].items()}
    return out


def identification_record(res):
    """The fit's record (:class:`~labrig.identification.doc.IdentRecord`, its one
    declaration): ``res.to_dict()`` with unbounded intervals null and the bound and fit
    warnings under ``warnings``. A key the record does not declare is an error here, where
    it is written, not a surprise where it is read."""
    d = res.to_dict()
    d["identifiable"] = null_unbounded(d.get("identifiable") or {})
    d["physical"] = null_unbounded({"physical": d.get("physical") or {}})["physical"]
    d["warnings"] = identification_warnings(res)
    return IdentRecord.model_validate(d, extra="forbid")


def identification_dict(res) -> dict:
    """The JSON of ``labrig identify --json``: :func:`identification_record` as a dict
    (the keys it was given)."""
    return identification_record(res).model_dump(exclude_unset=True)


#: what the "fitness (eq. 26)" row is (labrig.identification.objective.adequacy computes it)
FITNESS_NOTE = ("fitness (eq. 26 of the seed paper, made dimensionless) = the weighted RMSE "
                "of position and speed (and current, when measured), each residual in units "
                "of its channel's noise floor: sqrt((p sum e_pos^2 + q sum e_speed^2) / N) "
                "over all N samples; with the default p = q = 1 it is rmse/noise overall, "
                "and 1.0 is the noise floor.")


def _fmt(v, spec=".4g"):
    return fmt(v, spec)


def _record(r) -> dict:
    """An Identification (live) or its JSON record (read back) as the JSON record."""
    if hasattr(r, "to_json"):
        return r.to_json()
    if hasattr(r, "model_dump"):
        return r.model_dump()
    return dict(r)


def interval_text(value: float, lo: float, hi: float) -> str:
    """``value [lo, hi]`` with as many digits as the interval needs: its ends differ and
    the value is printed to at least their precision (never ``89.99 [90, 90]``)."""
    for d in range(3, 10):
        a, b = fmt(lo, f".{d}g"), fmt(hi, f".{d}g")
        if float(a) < float(b) or lo >= hi:
            break
    return f"{fmt(value, f'.{max(d, 4)}g')} [{a}, {b}]"


def _interval(d) -> str:
    if not d or d.get("value") is None:
        return "-"
    iv = d.get("interval95")
    if d.get("identifiable") is False or not iv or any(x is None for x in iv):
        return f"{fmt(d['value'], '.4g')} ? (not seen by these data)"
    return interval_text(d["value"], iv[0], iv[1])


def _parameter(r: dict, name: str) -> str:
    info = ((r.get("identifiable") or {}).get("parameters") or {}).get(name) or {}
    v = _fmt(r["params"].get(name))
    if info.get("fixed"):
        return f"{v} (fixed)"
    return v + (" ?" if info.get("identifiable") is False else "")


def comparison_table(results, best: str | None = None) -> Table:
    """The paper's Table 2, done right: the identifiable combinations first, then R..K
    (one member of the family the data allow), the fit, the identified model's
    closed-loop step and the cost; one column per method.

    ``results``: live :class:`~labrig.identification.fit.Identification` objects or their
    JSON records (``identify --json``), so the CLI and the report print the same table.
    """
    recs = [_record(r) for r in results]
    rows: list = []
    plant = plant_class(recs[0].get("plant") or "voltage") if recs else plant_class("voltage")
    speed = plant.speed_unit()

    def group(label):
        rows.append([f"-- {label}"] + [""] * len(recs))

    group("identifiable combinations (95 % intervals)")
    labels = {"km": f"Km ({speed} per V)", "tau_m_s": "tau_m (s)", "tau_e_s": "tau_e (s)"}
    for key in plant.combinations:
        rows.append([labels[key]] + [_interval((r.get("identifiable") or {}).get(key))
                                     for r in recs])
    rank = (recs[0].get("identifiable") or {}).get("structural_rank") if recs else None
    group("physical parameters" + ("" if plant.kind != "voltage" or rank == 5 else
                                   " (one member of the family the data allow)"))
    for n in plant.names:
        rows.append([f"{n} ({plant.units[n]})"] + [_parameter(r, n) for r in recs])
    extra = list(dict.fromkeys(n for r in recs for n in (r.get("physical") or {})
                               if n not in plant.names))
    for n in extra:  # friction and offset in the axis's units
        unit = next(r["physical"][n]["unit"] for r in recs if n in (r.get("physical") or {}))
        rows.append([f"{n} ({unit})"] + [_interval((r.get("physical") or {}).get(n)) for r in recs])
    keys = list(dict.fromkeys((e, k) for r in recs for e, ps in (r.get("effect_params") or {}).items()
                              for k in ps))
    for e, k in keys:
        rows.append([param_key(e, k)] + [_effect_parameter(r, e, k) for r in recs])
    group("fit")
    rows.append(["fitness (eq. 26)"] + [_fmt(r.get("fitness")) for r in recs])
    chans = ["speed", "position"] + (["current"] if any(
        "current" in (r.get("rmse_over_noise") or {}) for r in recs) else [])
    for ch in ["overall"] + chans:
        rows.append([f"rmse/noise {ch}"] + [_fmt((r.get("rmse_over_noise") or {}).get(ch), ".3g")
                                             for r in recs])
    for ch in chans:
        rows.append([f"fit % {ch}"] + [_fmt((r.get("fit_percent") or {}).get(ch), ".2f")
                                       for r in recs])
    no_loop = all("loop" in (r.get("step_info") or {}) for r in recs)
    if not no_loop:
        group("closed-loop position step of the identified model")
        for key, label in (("rise_time_s", "rise time (s)"),
                           ("settling_time_s", "settling time (s)"),
                           ("overshoot_percent", "overshoot (%)")):
            rows.append([label] + [_fmt((r.get("step_info") or {}).get(key), ".3g")
                                   for r in recs])
    group("cost")
    rows.append(["evaluations (nfev)"] + [_fmt(r.get("nfev"), "d") for r in recs])
    rows.append(["seconds"] + [_fmt(r.get("seconds"), ".1f") for r in recs])
    rows.append(["seed"] + [_fmt(r.get("seed"), "d") for r in recs])
    heads = [str(r.get("method", "?")).upper() + (" (best)" if r.get("method") == best else "")
             for r in recs]
    table = Table("identified models (Table 2)", [""] + heads, rows)
    table.notes.append(FITNESS_NOTE)
    if no_loop:
        table.notes.append("closed-loop step of the identified model: none (no closed-loop "
                           "runs, and no tacho for the lab's standard loop)")
    prefix = len(recs) > 1
    for r in recs:  # at a bound, fit below zero: the result is suspect
        for w in r.get("warnings") or []:
            table.notes.append(f"warning: {r.get('method')}: {w}" if prefix else f"warning: {w}")
    # identifiability depends on where each method ended (one sees a pole, another ends
    # where it is invisible): a warning not shared by every column names its methods
    said: dict = {}
    for r in recs:
        for w in (r.get("identifiable") or {}).get("warnings", []):
            said.setdefault(w, []).append(str(r.get("method")))
    for w, methods in said.items():
        table.notes.append(f"warning: {w}" if len(methods) == len(recs) else
                           f"warning: {', '.join(methods)}: {w}")
    if any(c.endswith("?") or "? (not seen" in c for row in rows for c in row[1:]):
        table.notes.append("? = not identifiable from these data alone (see the warning); the "
                           "combinations above are.")
    table.notes += _row_notes(plant, extra, keys)
    return table


def _effect_parameter(r: dict, effect: str, name: str) -> str:
    """An effect's fitted parameter with its 95 % interval, or '?' when not seen."""
    key = param_key(effect, name)
    v = (r.get("effect_params") or {}).get(effect, {}).get(name)
    info = ((r.get("identifiable") or {}).get("parameters") or {}).get(key)
    if v is None or not info:
        return _fmt(v)
    if info.get("fixed"):
        return f"{_fmt(v)} (fixed)"
    return _interval({**info, "value": v})


#: what each derived row of the table is
_DERIVED = {"Tc": "Coulomb friction torque, tc_v x Ka K / R", "Ts": "breakaway torque of stiction",
            "T0": "the input offset as a torque at the motor, u0_v x Ka K / R",
            "Fc": "Coulomb friction force, tc_v x kd", "Fs": "breakaway force of stiction",
            "F0": "the input offset as a force, u0_v x kd"}


#: the same on a torque or force drive, whose effect rows are already in N m or N
_DRIVE_DERIVED = {"Tc": "Coulomb friction torque (tc_nm)", "Ts": "breakaway torque of stiction",
                  "T0": "the drive's offset as a torque (u0_nm)",
                  "Fc": "Coulomb friction force (tc_n)", "Fs": "breakaway force of stiction",
                  "F0": "the drive's offset as a force (u0_n)"}


def _row_notes(plant, extra: list, keys: list) -> list[str]:
    """One line saying what the table's derived and effect rows are."""
    out = []
    derived = _DERIVED if plant.kind == "voltage" else _DRIVE_DERIVED
    said = [f"{n} = {derived[n]}" for n in extra if n in derived]
    if said:
        tail = (" (on a voltage plant they scale with K/R, so they are seen only where R and "
                "K are)" if plant.kind == "voltage" else "")
        out.append("rows: " + "; ".join(said) + tail)
    if keys and plant.kind == "voltage":
        out.append("effect.parameter rows: the effects' fitted values in the bridge's units "
                   "(volts at the input, s, rad) with their 95 % intervals")
    elif keys:
        out.append(f"effect.parameter rows: the effects' fitted values in the drive's units "
                   f"({drive_unit(plant.kind)} at the drive, s, {plant.position_unit()}) with "
                   "their 95 % intervals")
    return out


def format_identification(results) -> str:
    """Table 2 as text (rich), warnings under it."""
    return comparison_table(results).to_text()


def all_warnings(results) -> list[str]:
    """Bound and fit warnings of each result; prefixed by the method when several."""
    if len(results) == 1:
        return identification_warnings(results[0])
    return [f"{r.method}: {w}" for r in results for w in identification_warnings(r)]


