"""Inputs a rig can play that tell effects apart: a small family of physically meaningful
piecewise-linear waveforms (``pwl``), each with the words that say why it separates.

Every candidate starts and ends at 0 V, lasts at most the budget, stays within
``+-amax`` (the inputs the data already use, or what the rig file allows) and holds at
most :data:`MAX_POINTS` breakpoints (the board's table holds 32). Time scales come from the
model (tau_m: how long the speed needs to settle), levels from the threshold of the
effects compared (a dead zone's d, a friction level).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from labrig.core.defaults import LOOP_GAINS
from labrig.model.effects import get_effect
from labrig.io.experiment import pwl_values

#: breakpoints of a proposed input: what the boards' table holds (32), with room to spare,
#: so a proposal plays on the board as on the simulated rig
MAX_POINTS = 30

#: what each kind of input is
KINDS = {
    "ramp": "a slow ramp through zero",
    "dwells": "dwells from rest at several levels, back to 0 V between them",
    "coast": "coast-downs from speed (the drive cut to 0 V)",
    "reversals": "reversals at several speeds",
    "staircase": "a staircase of levels through the threshold",
    "steps": "steps at several amplitudes, each ending in a coast to rest at 0 V",
    "position_steps": ("position steps through the rig's own loop, there and back, at "
                       "several sizes"),
}


def why(kind: str, pair) -> str:
    """Why ``kind`` of input separates the two effects of ``pair``, in plain words (each
    effect says how it responds: :attr:`labrig.model.effect_base.Effect.responses`)."""
    said = [get_effect(e).responses.get(kind) for e in pair]
    told = "; ".join(x for x in said if x)
    return f"{KINDS[kind]}: {told}" if told else \
        f"{KINDS[kind]}: the two explanations predict different responses to it"


@dataclass
class InputCandidate:
    """One input the rig could play."""

    kind: str
    points: list          # [[t_s, u_v], ...], t from 0
    label: str            # e.g. "ramp +-1.2 V over 12 s"
    #: the loop's gains ``{"kp": ..., "kv": ...}`` when the points are a position loop's
    #: reference (V of the pot, from where the run starts), else None: the amplifier's input
    gains: dict | None = None

    @property
    def loop(self) -> str:
        return "open" if self.gains is None else "closed"

    @property
    def duration(self) -> float:
        return float(self.points[-1][0])

    def values(self, fs: float, lead_in: float) -> np.ndarray:
        """The input per sample at ``fs`` after ``lead_in`` s at 0 V (as the rig plays it)."""
        n0 = int(round(lead_in * fs))
        n = n0 + int(round(self.duration * fs)) + 1
        k = np.arange(n) - n0
        return np.where(k >= 0, pwl_values(self.points, k, fs), 0.0)


def _pts(segments) -> list:
    """[(duration, level), ...] of straight pieces -> breakpoints from (0, 0)."""
    t, out = 0.0, [[0.0, 0.0]]
    for dur, level in segments:
        t += dur
        out.append([round(t, 4), round(float(level), 4)])
    return out


def _from_rest(levels, hold: float, rest: float, edge: float) -> list:
    """Pieces that take each level in turn, alternating in sign, for ``hold`` s from rest
    and back to 0 V for ``rest`` s."""
    segs, sign = [], 1.0
    for lv in levels:
        segs += [(edge, sign * lv), (hold, sign * lv), (edge, 0.0), (rest, 0.0)]
        sign = -sign
    return segs


def _admit(out: list, kind: str, pts: list, label: str, *, amax: float, budget_s: float,
           gains: dict | None = None) -> None:
    """Append the input ``pts`` and its mirror image (the same test starting the other
    way: the travel the data allow may differ by direction) when it fits the board's table,
    the budget and the input limit."""
    if len(pts) <= MAX_POINTS and pts[-1][0] <= budget_s + 1e-9 and \
            max(abs(u) for _, u in pts) <= amax + 1e-9:
        out.append(InputCandidate(kind, pts, label, gains))
        out.append(InputCandidate(kind, [[t, -u if u else 0.0] for t, u in pts],
                                  label + ", mirrored", gains))


def _holds(usual, fill: float) -> list:
    """The usual hold times and, when longer, the one that fills the budget."""
    return sorted(set(usual) | ({round(fill, 3)} if fill > usual[0] else set()))


def candidates(*, threshold: float | None, amax: float, tau: float, budget_s: float,
               dt: float) -> list[InputCandidate]:
    """The candidate inputs for effects whose threshold is ``threshold`` V (0 when they
    have none, like a delay and backlash; None when the data do not pin it: then every
    level is spread across the whole range, never set around a fitted value)."""
    edge = max(10 * dt, 0.01)                  # a fast edge the drive can follow
    settle = float(np.clip(4 * tau, 0.2, budget_s / 6))
    pinned = threshold is not None
    th = threshold if pinned and threshold > 0 else 0.3 * amax
    out: list[InputCandidate] = []

    def add(kind, segs, label):
        _admit(out, kind, _pts(segs), label, amax=amax, budget_s=budget_s)

    near_th = {min(f * th, amax) for f in (1.5, 2.5)} if pinned else set()
    for U in sorted(near_th | {0.5 * amax, amax}):
        for T in (budget_s / 4, budget_s / 2, budget_s):
            add("ramp", [(T / 4, -U), (T / 2, U), (T / 4, 0.0)],
                f"ramp through zero +-{U:.2f} V over {T:.3g} s")
    # dwells near the fitted threshold, and (where it is uncertain) across the whole range
    near = [min(f * th, amax) for f in (0.9, 1.1, 1.3, 1.6, 2.0)]
    spread = [f * amax for f in (0.15, 0.25, 0.35, 0.45, 0.6, 0.8, 1.0)]
    for levels, what in ((near, f"0.9-2.0 x {th:.2f} V"),
                         (spread, f"{spread[0]:.2f}-{spread[-1]:.2f} V"))[0 if pinned else 1:]:
        # and dwells that fill the budget: more of the regime where the laws differ
        fill = 0.98 * budget_s / (1.5 * len(levels)) - 2 * edge
        for dwell in _holds((settle, 2 * settle), fill):
            add("dwells", _from_rest(levels, dwell, dwell / 2, edge),
                f"dwells at {what}, {dwell:.2f} s each")
    for U in sorted({0.5 * amax, amax}):
        segs = []
        for sign in (1.0, -1.0, 1.0, -1.0):
            segs += [(edge, sign * U), (settle, sign * U), (edge, 0.0), (settle, 0.0)]
        add("coast", segs, f"coast-downs from {U:.2f} V")
    for U in sorted({0.5 * amax, amax}):
        for ramp in (settle, 3 * settle):
            segs = [(ramp, U), (settle / 2, U)]
            for _ in range(3):
                segs += [(2 * ramp, -U), (settle / 2, -U), (2 * ramp, U), (settle / 2, U)]
            segs.append((ramp, 0.0))
            add("reversals", segs, f"reversals +-{U:.2f} V, ramps of {2 * ramp:.2f} s")
    # square reversals from several speeds: a gap's dead time grows as the speed falls,
    # a delay's does not
    for hold in (1.5 * tau, 3 * tau):
        segs = []
        for f in (0.3, 0.6, 1.0, 0.45, 0.8):
            segs += [(edge, f * amax), (hold, f * amax), (edge, -f * amax), (hold, -f * amax)]
        segs.append((edge, 0.0))
        add("reversals", segs, f"reversals from 0.3-1.0 x {amax:.2f} V, {hold:.2f} s each")
    stairs = [min(f * th, amax) for f in (0.5, 0.8, 1.0, 1.2, 1.5, 2.0, 3.0)]
    # full reversals, as often as the board's table allows: every edge swings the drive
    # from one rail of the input to the other, where a delay and a slow pole part most
    for hold in (0.5 * tau, tau, 2 * tau):
        segs = []
        for _ in range((MAX_POINTS - 2) // 4):
            segs += [(edge, amax), (hold, amax), (edge, -amax), (hold, -amax)]
        segs.append((edge, 0.0))
        add("reversals", segs, f"full reversals +-{amax:.2f} V, {hold:.2f} s each")
    for levels in ([stairs, spread] if pinned else [spread]):
        add("staircase", [seg for lv in levels for seg in ((edge, lv), (settle, lv))]
            + [(edge, 0.0)], f"staircase {levels[0]:.2f}-{levels[-1]:.2f} V")
    # steps across the range, each ending in a coast to rest at 0 V: every amplitude
    # crosses any threshold the data allow, and the coasts are where the laws part (a
    # dead zone leaves the motor braked by its back-EMF only, friction stops it sooner)
    fill = 0.98 * budget_s / (2.5 * len(spread)) - 2 * edge
    for hold in _holds((settle, 1.5 * settle), fill):
        add("steps", _from_rest(spread, hold, 1.5 * hold, edge), f"steps {spread[0]:.2f}-{spread[-1]:.2f} V, each coasting to "
                           f"rest, {hold:.2f} s each")
    return out


def closed_candidates(*, threshold: float | None, amax: float, gains: dict, tau: float,
                      budget_s: float, dt: float) -> list[InputCandidate]:
    """Position steps through the rig's own loop (amplifier input = kp (ref - pot) - kv
    tacho): the points are the reference. A step of the reference by r drives the amplifier
    with kp r at first, so the steps stay within ``amax / kp``: the drive the open-loop data
    already explain. Sizes spread over that range, and (when the data pin the threshold)
    around the band ``threshold / kp`` where the loop stops short of its reference; ``tau``
    is the loop's slowest time constant."""
    kp = float(gains["kp"])
    top = amax / kp
    # the MS150's reference is in pot volts; a board's is in the axis's units from the start
    unit, where = ("rad", "board's loop") if "board" in gains else ("V", "loop")
    edge = max(10 * dt, 0.01)
    settle = float(np.clip(4 * tau, 0.2, budget_s / 6))
    out: list[InputCandidate] = []
    # fewer sizes where the budget is short (a step of a sequence asked one at a time)
    sizes = [[f * top for f in fs] for fs in ((0.15, 0.25, 0.35, 0.45, 0.6, 0.8, 1.0),
                                              (0.2, 0.5, 1.0), (0.4, 1.0))]
    if threshold:   # steps across the error band the threshold leaves: some stop in it
        sizes.append([min(f * threshold / kp, top) for f in (0.8, 1.2, 1.6, 2.0, 3.0, 4.0)])
    for levels in sizes:
        fill = 0.98 * budget_s / (2 * len(levels)) - 2 * edge
        for hold in _holds((settle, 2 * settle), fill):
            _admit(out, "position_steps", _pts(_from_rest(levels, hold, hold, edge)),
                   f"position steps {levels[0]:.2f}-{levels[-1]:.2f} {unit} through the "
                   f"{where} (kp {kp:g}), {hold:.2f} s each", amax=amax, budget_s=budget_s,
                   gains=dict(gains))
    return out


def loop_gains(runs, rig) -> dict | None:
    """The gains of the rig's own position loop, or None when neither the data nor the
    rig file show one: the MS150's analog loop (amplifier input = kp (ref - pot) - kv
    tacho: a closed-loop run's own gains, else the standard loop of a rig file with a tacho
    and a pot on a voltage drive), or a board's own PD on its count (a closed-loop run of
    the board in the data: its gains, and ``board`` its law's constants, with which the
    proposal's runs are simulated as the board plays them). A PD of a controller the rig
    does not run itself (an imported record's) is not proposed."""
    for r in runs:
        if r.loop == "closed" and r.controller is None and r.drive == "voltage":
            return r.gains
        # (a run fitted from its logged output was played through the loop all the same)
        played = r.experiment.get("played_closed") or (r.experiment if r.loop == "closed"
                                                       else {})
        c = played.get("controller") or {}
        if c.get("sampled"):
            return {"kp": float(c["kp"]), "kv": float(c.get("kd", 0.0)),
                    "board": dict(c["sampled"])}
    if rig is not None and rig.drive == "voltage" and not rig.digital_loop:
        return {"kp": LOOP_GAINS["position_gain"], "kv": LOOP_GAINS["velocity_gain"]}
    return None
