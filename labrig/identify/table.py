"""How an identification is shown: the paper's Table 2 (done right: the identifiable
combinations first, then R..K, methods side by side), the JSON of ``identify --json``,
and the warnings that make a suspect fit say so."""
from __future__ import annotations

import math

from ..model.servo import PLANT_NAMES, PLANT_UNITS
from ..tables import Table
from .result import identification_warnings


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
    if isinstance(out.get("parameters"), dict):
        out["parameters"] = {n: fix(d) for n, d in out["parameters"].items()}
    return out


def identification_dict(res) -> dict:
    """``res.to_dict()`` (keys unchanged) with unbounded intervals null and the bound and
    fit warnings under ``warnings``."""
    d = res.to_dict()
    d["identifiable"] = null_unbounded(d.get("identifiable") or {})
    d["warnings"] = identification_warnings(res)
    return d


def _fmt(v, unit=""):
    if v is None:
        return "-"
    return f"{v:.4g}{(' ' + unit) if unit else ''}"


def comparison_table(results) -> Table:
    """The paper's Table 2, done right: combinations first, then R..K, side by side."""
    heads = [r.method for r in results]
    rows = [("identifiable", None)]
    for key, label in (("km", "Km (rad/s per V)"), ("tau_m_s", "tau_m (s)"), ("tau_e_s", "tau_e (s)")):
        rows.append((label, [_interval(r.identifiable.get(key)) for r in results]))
    rows.append(("parameters", None))
    for n in PLANT_NAMES:
        rows.append((f"{n} ({PLANT_UNITS[n]})",
                     [_fmt(r.params[n]) + ("" if r.identifiable.get("parameters", {}).get(n, {}).get("identifiable", True) else " ?")
                      for r in results]))
    for r in results[:1]:
        for e, ps in r.effect_params.items():
            for k in ps:
                rows.append((f"{e}.{k}", [_fmt(x.params.get(f"{e}.{k}")) for x in results]))
    rows.append(("fit", None))
    rows.append(("fitness (eq. 26)", [_fmt(r.fitness) for r in results]))
    rows.append(("rmse/noise speed", [_fmt(r.metrics["rmse_over_noise"].get("speed")) for r in results]))
    rows.append(("rmse/noise position", [_fmt(r.metrics["rmse_over_noise"].get("position")) for r in results]))
    rows.append(("fit % speed", [_fmt(r.metrics["fit_percent"].get("speed")) for r in results]))
    rows.append(("fit % position", [_fmt(r.metrics["fit_percent"].get("position")) for r in results]))
    infos = [r.step_info() for r in results]
    rows.append(("closed-loop step", None))
    rows.append(("rise time (s)", [_fmt(i["rise_time_s"]) for i in infos]))
    rows.append(("settling time (s)", [_fmt(i["settling_time_s"]) for i in infos]))
    rows.append(("overshoot (%)", [_fmt(i["overshoot_percent"]) for i in infos]))
    rows.append(("nfev / seconds", [f"{r.result.nfev} / {r.seconds:.1f}" for r in results]))
    rows.append(("seed", [str(r.result.seed) for r in results]))
    table = Table("identification (Table 2)", ["", *heads], numeric=())
    for label, cells in rows:
        table.rows.append([f"-- {label}", *([""] * len(heads))] if cells is None
                          else [label, *cells])
    for w in all_warnings(results):  # at a bound, fit below zero: the result is suspect
        table.notes.append(f"warning: {w}")
    for w in sorted({w for r in results for w in r.identifiable.get("warnings", [])}):
        table.notes.append(f"warning: {w}")
    if any("?" in c for _, cs in rows if cs for c in cs):
        table.notes.append("? = not identifiable from these data alone (see the warning); the "
                           "combinations above are.")
    return table


def format_identification(results) -> str:
    """Table 2 as text (rich), warnings under it."""
    return comparison_table(results).to_text()


def all_warnings(results) -> list[str]:
    """Bound and fit warnings of each result; prefixed by the method when several."""
    if len(results) == 1:
        return identification_warnings(results[0])
    return [f"{r.method}: {w}" for r in results for w in identification_warnings(r)]


def _interval(d):
    if not d:
        return "-"
    if not null_unbounded({"km": d})["km"].get("interval95"):  # none, or unbounded
        return f"{d['value']:.4g} ? (not seen by these data)"
    lo, hi = d["interval95"]
    return f"{d['value']:.4g} [{lo:.3g}, {hi:.3g}]"
