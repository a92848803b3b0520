"""The tables and the readable summary of an AnalysisResult (CLI text output)."""
from __future__ import annotations

import math

from labrig.core.tables import Table, fmt

LEVEL_COLUMNS = ["run", "Vm (V)", "n (rpm)", "w (rad/s)", "spread", "Vt (V)", "Km=w/V",
                 "tau (ms)", "note"]
#: the kt cell when the speed was imported in physical units: there are no tacho volts
NO_TACHO = "not measured (no tacho: speed imported)"


def table_rows(res) -> list[Table]:
    """Two tables: the steady speed per level (like the paper's Table 1) with the
    skipped runs as notes, and the summary quantities."""
    return [level_table(res), summary_table(res)]


def level_table(res) -> Table:
    """One row per run and input level."""
    rows = []
    columns = list(LEVEL_COLUMNS)
    if res.speed_unit != "rad/s":  # a linear axis: no rpm, speed in its own unit
        columns[2:4] = ["-", f"v ({res.speed_unit})"]
    for lv in res.levels:
        note = "" if lv.moving is not False else "at rest"
        if not lv.n_settled:
            note = "not settled"
        rows.append([str(lv.run), fmt(lv.v, ".3f"),
                     fmt(None if lv.speed is None or res.speed_unit != "rad/s"
                         else lv.speed * 30 / math.pi, ".0f"),
                     fmt(lv.speed, ".2f"), fmt(lv.spread, ".2f"), fmt(lv.tacho_v, ".3f"),
                     fmt(lv.km_paper, ".2f"),
                     fmt(None if lv.tau_s is None else lv.tau_s * 1e3, ".1f"), note])
    notes = [f"{r.name}: skipped ({r.skipped})" for r in res.runs
             if not isinstance(r, dict) and r.skipped]
    notes += [f"{r.name}: {n}" for r in res.runs if not isinstance(r, dict) and not r.skipped
              for n in r.notes if "lost on the link" in n]
    return Table("Steady speed per input level", columns, rows, notes,
                 numeric=tuple(range(1, 8)))


def summary_table(res) -> Table:
    """km, deadband, breakaway, tau_m, kt and the gain trend, each with its detail."""
    line = res.line

    def g(x, spec, unit=""):
        return "not measurable" if x is None else format(x, spec) + unit
    rows = [["km (incremental)", g(res.km, ".4g", f" {res.speed_unit} per V"),
             f"forward {line.km_fwd:.4g}, reverse {line.km_rev:.4g}"
             if line.km_fwd is not None and line.km_rev is not None else ""],
            ["deadband", g(res.deadband_v, ".3f", " V"),
             f"forward {line.deadband_fwd:.3f}, reverse {line.deadband_rev:.3f}"
             if line.deadband_fwd is not None and line.deadband_rev is not None else ""]]
    if res.breakaway_v is not None:
        rows.append(["breakaway", f"{res.breakaway_v:.3f} V", "stiction"])
    rows.append(["tau_m", g(None if res.tau_s is None else res.tau_s * 1e3, ".1f", " ms"), ""])
    kt_detail = ""
    if res.kt_configured is not None:
        kt_detail = f"configured {res.kt_configured:.4g}" + (", MISMATCH" if res.kt_mismatch else "")
    kt = NO_TACHO if res.kt is None and speed_without_tacho(res) else \
        g(res.kt, ".4g", " V per rad/s")
    rows.append(["kt", kt, kt_detail])
    rows.append(["gain trend", res.gain_trend, _trend_detail(res)])
    return Table("Summary", ["quantity", "value", "detail"], rows)


def speed_without_tacho(res) -> bool:
    """The analysed runs measured speed, but none with a tacho (imported speed)."""
    sensors = {r.sensor for r in res.runs if not r.skipped}
    return "speed" in sensors and "tacho" not in sensors


def _trend_detail(res) -> str:
    """The gain trend's number and what it is: the plain change of w/V from the smallest
    to the largest amplitude, and the band a constant gain may wander in."""
    thr = res.trend.get("threshold", res.tolerance)
    rel = res.trend.get("relative_change")
    span = res.trend.get("amplitude_range_v")
    if rel is None or not span:
        return "one amplitude only: no trend to judge"
    return (f"w/V changes by {rel * 100:+.1f} % from {span[0]:.3g} V to {span[1]:.3g} V "
            "(mean w/V at the largest amplitude over that at the smallest, minus 1); "
            # a noisy trend is judged against two standard errors instead
            + (f"the runs' w/V scatter so much that only a change beyond {thr * 100:.1f} % (2 "
               f"standard errors of the scatter) counts as a trend, not the "
               f"{res.tolerance * 100:.0f} % tolerance a clean sweep is judged by"
               if thr > res.tolerance else
               f"a constant gain may change by up to {thr * 100:.1f} % (the tolerance)"))


def summary_text(res, width: int = 110) -> str:
    """The tables, the verdict, and the figures saved so far."""
    parts = [t.to_text(width) for t in res.table_rows()]
    parts.append(res.verdict)
    if res.figure_paths:
        parts.append("\n".join(f"figure: {p}" for p in res.figure_paths))
    return "\n\n".join(parts)
