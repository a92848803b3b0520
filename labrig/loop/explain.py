"""Thresholds stated through the effects in front of them.

A rail behind a dead zone is reached at a larger input than ``vmax/Ka``; friction behind
a dead zone and an offset stops the motor at different inputs each way. These helpers
push a level back through the model's input effects, so every explanation is given in
the bridge's volts (what the student commands) as well as in the physics' units.
"""
from __future__ import annotations

import numpy as np

from labrig.model.drive_units import level, unit as drive_unit
from labrig.model.model import Model


def input_chain(model: Model):
    """``u -> the input after the model's input effects`` (bridge volts), vectorised."""
    stages = [(e, {k: float(v) for k, v in model.effect_params[e.name].items()})
              for e in model.effects if e.stage == "input"]

    def chain(u):
        v = np.asarray(u, float)
        for e, p in stages:
            v = e.apply(v, **p)
        return v

    return chain, [e.name for e, _ in stages]


def input_for(model: Model, level: float, amax: float) -> tuple[float, float]:
    """The smallest forward input and the smallest reverse input (negative) at which
    the input chain's output reaches ``level`` (bridge volts); inf when never."""
    chain, _ = input_chain(model)
    u = np.linspace(0.0, 4.0 * max(amax, 1e-3), 40001)
    up = u[chain(u) >= level]
    down = u[chain(-u) <= -level]
    return (float(up[0]) if len(up) else np.inf, -float(down[0]) if len(down) else -np.inf)


def _largest_input(runs) -> float:
    return max(float(np.max(np.abs(r.u))) for r in runs)


def context(model: Model, runs) -> dict:
    """What an effect's ``explain_params`` may use: Ka, the smallest open-loop
    amplitude, the plant's R and K, and ``to_input`` when effects sit in front."""
    amps = [r.amplitude for r in runs if r.loop == "open"] or [1.0]
    amax = _largest_input(runs)
    sp = model.servo()  # R = K = 1 on a torque/force plant: a friction level is kd tc_v
    ctx = {"Ka": float(runs[0].constants["Ka"]), "amin": min(amps),
           "R": float(sp.R), "K": float(sp.K), "plant": model.plant}
    _, front = input_chain(model)
    if front:
        ctx["to_input"] = lambda level: input_for(model, level, amax)
        ctx["front"] = front
    return ctx


def thresholds(model: Model, runs) -> str:
    """One sentence: where the amplifier starts to get a drive, where friction stops the
    motor and where the rail is reached, each way, at the bridge input, through every
    effect in front; and which way the rig is stronger ('' when the model has none). On a
    torque or force drive the levels are said at the drive, in N m or N."""
    amax = _largest_input(runs)
    Ka = float(runs[0].constants["Ka"])
    volts = model.plant == "voltage"
    ctx = {"plant": model.plant, "Ka": Ka}

    def at(v):   # an input level as this drive's user reads it
        return f"{v:.3g} V" if volts else level(v, ctx)

    parts, start = [], None
    _, front = input_chain(model)
    zones = [e.name for e in model.effects if e.family_name == "dead zone"]
    if zones:
        start = input_for(model, 1e-9, amax)
        parts.append(f"the {'amplifier' if volts else 'drive'} gets nothing between "
                     f"{at(start[1])} and {at(start[0])} ({', '.join(front)})")
    elif "offset" in model.names:
        u0 = model.effect_params["offset"]["u0_v"]
        parts.append(f"an offset of {1e3 * u0:.3g} mV drives the motor at zero input" if volts
                     else f"an offset of {at(u0)} drives the axis at zero command")
    for e in model.effects:
        p = model.effect_params[e.name]
        if e.stage == "friction" and "tc_v" in p:
            start = input_for(model, p["tc_v"], amax)
            parts.append(f"friction stops the {'motor for inputs' if volts else 'axis for commands'}"
                         f" between {at(start[1])} and {at(start[0])}")
        if e.stage == "drive" and "vmax_v" in p:
            up, down = input_for(model, p["vmax_v"] / Ka, amax)
            rail = (f"{p['vmax_v']:.3g} V at the armature" if volts else
                    f"{p['vmax_v']:.3g} {drive_unit(model.plant)}")
            parts.append(f"the rail ({rail}) is reached above {at(up)} and below {at(down)}")
    if not parts:
        return ""
    text = ("At the bridge input: " if volts else "At the drive: ") + "; ".join(parts) + "."
    if start is not None and np.isfinite(start).all():
        up, down = start[0], -start[1]
        if abs(up - down) > 0.02 * max(up, down, 1e-9):
            text += (f" The rig is stronger {'forward' if up < down else 'in reverse'}: it "
                     "starts at a smaller input that way.")
    return text
