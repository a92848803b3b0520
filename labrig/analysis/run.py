"""One open-loop run: its segments, fitted edges, steady levels and Kt check."""
from __future__ import annotations

import math

import numpy as np

from labrig.core.errors import AnalysisError
from labrig.analysis.edges import fit_run_edges
from labrig.analysis.levels import SETTLE_TAUS, Signal, kt_from_levels, pool_levels, segment_flat_parts
from labrig.analysis.run_result import RunAnalysis
from labrig.analysis.segments import Segments, robust_std

CLOSED_LOOP_SKIP = "closed-loop run: analyse uses open-loop runs only (identify uses both)"


def analyse_run(run) -> RunAnalysis:
    """Levels, edges and steady speeds of one open-loop run.

    A closed-loop run is returned with ``skipped`` set.

    Raises
    ------
    AnalysisError
        When the run has no edges, a constant input or never settles.
    """
    ra = RunAnalysis(name=run.name, loop=run.loop, fs=run.fs, speed_unit=run.units[1])
    if run.loop != "open":
        ra.skipped = CLOSED_LOOP_SKIP
        return ra
    where = f"run '{run.name}'" + (f" ({run.path})" if run.path else "")
    seg = _segments(run, where)
    sig = measured_signal(run)
    ra.sensor = speed_source(run) if sig.kind == "speed" else "pos"
    ra.kt_configured = run.kt if run.has_tacho else None
    min_step = _min_step(run.t, sig, seg)
    ra.edges = fit_run_edges(run.t, sig.y, seg, kind=sig.kind, sigma=sig.sigma,
                             min_step=min_step, measured=run.measured if run.n_gaps else None)
    if run.n_gaps:
        ra.notes.append(f"{run.n_gaps} of {len(run)} samples were lost on the link (gap = 1): "
                        "left out of the edge fits and steady levels")
    tau_run = _run_tau(ra.edges, seg, run.dt, where)
    parts = segment_flat_parts(run, seg, sig, ra.edges, tau_run, min_step)
    ra.levels = pool_levels(run.name, seg, parts, ra.edges, min_step)
    if not any(L.speed is not None and abs(L.v) > seg.vtol for L in ra.levels):
        raise AnalysisError(
            f"{where}: no level settles: after its edges the input is held at most "
            f"{seg.longest_after_edge(run.dt):.3g} s but the speed needs "
            f"about {SETTLE_TAUS:g} time constants ({SETTLE_TAUS * (tau_run or 0):.3g} s) to "
            "settle; use longer levels (a lower square-wave frequency or longer steps)")
    ra.kt_est = kt_from_levels(ra.levels)
    return ra


def speed_source(run) -> str:
    """Where a run's speed comes from: ``"tacho"`` (volts over a known Kt) or ``"speed"``
    (physical speed imported without a tacho: no tacho volts, no Kt to check)."""
    return "tacho" if run.has_tacho else "speed"


def measured_signal(run) -> Signal:
    """Motor speed (tacho or imported speed), else motor angle from the pot, with its
    noise."""
    if run.speed is not None:
        y = run.speed
        return Signal("speed", y, robust_std(np.diff(y)) / math.sqrt(2))
    y = run.position * run.gear_ratio
    # noise of an angle that moves: second differences remove the slope
    return Signal("angle", y, robust_std(np.diff(y, 2)) / math.sqrt(6))


def _segments(run, where) -> Segments:
    if len(run.t) < 20:
        raise AnalysisError(f"{where}: only {len(run.t)} samples; record at least a few time "
                            "constants per level")
    seg = Segments.of(run.u)
    if len(seg) < 2:
        raise AnalysisError(f"{where}: the input u is constant at {seg.volts[0]:.3g} V (no "
                            "edges); analyse needs steps, square waves or staircases with a "
                            "lead-in or reversals")
    return seg


def _min_step(t, sig: Signal, seg: Segments) -> float:
    """Smallest speed change that counts as motion: 5 % of the largest steady speed
    (the end of any segment), at least 5 sigma of the tacho noise."""
    y = sig.y

    def tail_speed(a, b):
        n = max(3, (b - a) // 5)
        if sig.kind == "speed":
            return float(np.median(y[b - n:b]))
        return float(np.polyfit(t[b - n:b], y[b - n:b], 1)[0]) if n >= 3 else 0.0
    wmax = max(abs(tail_speed(a, b)) for a, b in zip(seg.starts, seg.ends))
    return max(0.05 * wmax, 5 * (sig.sigma if sig.kind == "speed" else 0.0), 1e-9)


def _run_tau(edges, seg, dt, where) -> float | None:
    """Median tau of the accepted edges; raises when fits ran but none settled."""
    taus = [e.tau_s for e in edges if e.ok]
    if taus:
        return float(np.median(taus))
    raw = [e.fit.tau for e in edges if e.fit is not None and e.fit.ran]
    if raw and min(raw) > 0:
        raise AnalysisError(
            f"{where}: the speed never settles: after its edges the input is held at most "
            f"{seg.longest_after_edge(dt):.3g} s but "
            f"the time constant is about {np.median(raw):.3g} s; hold each level for at "
            f"least {SETTLE_TAUS + 1:.0f} time constants (a lower frequency or longer steps)")
    return None
