"""The diagnosis's words: thresholds stated through the effects in front of them, each
candidate's explanation and a round's verdict.

A rail behind a dead zone is reached at a larger input than ``vmax/Ka``; friction behind
a dead zone and an offset stops the motor at different inputs each way. These helpers
push a level back through the model's input effects, so every explanation is given in
the bridge's volts (what the student commands) as well as in the physics' units.
"""
from __future__ import annotations

import numpy as np

from labrig.diagnosis.evidence.criteria import FLOOR, UNDECIDED, undecided
from labrig.diagnosis.evidence.residuals import REGIME_TEXT
from labrig.model.drive_units import level, unit as drive_unit
from labrig.model.effects import get_effect
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


# -- the diagnosis's words ---------------------------------------------------------------

def explain(entry, ev0, const: dict) -> str:
    """Plain words with numbers: what, where in these runs, how much, how to confirm."""
    cv = entry.cross_validated
    if cv:
        held = (f" Cross-validated: {cv['baseline']:.2f} -> {cv['with_effect']:.2f} on held-out "
                f"data, better in {cv['folds_improved']} of {cv['folds']} folds.")
        for d in cv.get("not_counted", []):
            held += (f" Fold {d['fold']} is not counted: the data it trains on do not pin "
                     f"{d['parameter']} ({d['fold_value']:.3g} there, {d['value']:.3g} on all "
                     f"runs), so it cannot predict what it holds out.")
        ev = cv.get("evidence") or []
        if ev:
            held += " The held-out evidence is in the " + "; ".join(
                f"{REGIME_TEXT[d['regime']]} of the {d['channel']} ({d['base']:.2f} -> "
                f"{d['candidate']:.2f}, {100 * d['share_of_time']:.0f} % of the time)" for d in ev) + "."
    elif entry.out_of_reach is not None:
        held = (f" Not cross-validated: its error on all runs, {entry.rmse_over_noise:.2f}, is "
                f"already well above what the best supported candidate predicts on held-out "
                f"data ({entry.out_of_reach:.2f}).")
    else:
        held = " Not cross-validated (its in-sample gain is below the threshold)."
    bound = (" The fit ended at a bound: " + "; ".join(entry.at_bound) + ".") if entry.at_bound else ""
    size = f" Its size is not resolved: {entry.unresolved}." if entry.unresolved else ""
    r0 = ev0.rmse
    change = (f"rmse/noise {r0:.2f} -> {entry.rmse_over_noise:.2f} on all runs, "
              f"delta BIC {entry.delta_bic:.0f}.{held}{bound}{size}")
    if entry.move == "remove":
        eff = get_effect(entry.effect)
        verdict = ("Without it the model predicts held-out data as well: it no longer earns "
                   "its parameters." if entry.supported else
                   "Taking it out costs more than it saves: it stays.")
        return (f"The model without {entry.effect} ({eff.explain_params(entry.params, const)}), "
                f"re-fitted: {change} {verdict}")
    eff = entry.model.effects.by_name(entry.effect)
    verdict = ("It earns its parameters." if entry.supported else
               "It does not earn its parameters on these data.")
    instead = f" In place of {entry.replaces}." if entry.move == "replace" else ""
    return (f"{eff.summary[0].upper()}{eff.summary[1:]}.{instead} Fitted: "
            f"{eff.explain_params(entry.params, const)}. {change} {verdict} "
            f"Expected signature: {eff.signature}. To confirm: {eff.experiment}.")


def undecided_note(supported: list) -> str:
    """A word when the runner-up is a different explanation that predicts held-out data
    within :data:`UNDECIDED` of the first: the order between them is not evidence."""
    if len(supported) < 2:
        return ""
    a, b = supported[0], supported[1]
    if not undecided(a, b):
        return ""
    return (f" Undecided against {b.label}: its held-out error ({b.cross_validated['with_effect']:.2f}) "
            f"is within {100 * UNDECIDED:g} % of this one's, so these data do not tell the two "
            f"apart; this one comes first by the stated rule for such equals (fewer "
            f"parameters, then the catalogue's order), not by the last digits of the fits; "
            f"`labrig propose --between {a.effect},{b.effect}` designs the run that would "
            "tell them apart.")


def sensor_verdict(weights, per: dict) -> str:
    """The verdict when nothing earns its parameters and one channel was weighted down
    because the sensors disagree (``Weights.decides``, ``Weights.why``): which channel
    decides, how near its floor it is, and that the rest of the other channel's error is
    the sensor's."""
    decides = weights.decides
    other = "position" if decides == "speed" else "speed"
    what = "drift against the speed" if decides == "speed" else "lag against the position"
    # a late speed's remedy is in its why (declare the window); a drifting position's:
    advice = (" Zero or recalibrate the position channel, or fit the speed alone "
              "(--weights p=0,q=1)." if decides == "speed" else " Or log the raw counts.")
    r = per[decides]
    where = "at" if r <= FLOOR else "near" if r <= 1.5 else "above"
    return (f"No catalogue effect earns its parameters. The sensors disagree: {weights.why}. "
            f"The {decides}, which decides, is {where} its noise floor (rmse/noise {r:.2f}); "
            f"the {other} misses (rmse/noise {per[other]:.2f}) by its {what}: a sensor "
            f"matter, not the plant.{advice}")


def round_verdict(supported: list, ev0, weights, ripple, diverged: list, starts: dict) -> str:
    """A diagnosis's verdict in words: the recommended move and why (and a near rival),
    or why nothing is recommended (at the floor; the sensors disagree; a line locked to
    the shaft; outside the catalogue), then the candidates that could not be ranked and
    the runs simulated from their fitted start."""
    rmse0 = ev0.rmse
    if supported:
        verdict = f"{supported[0].action}: " + supported[0].explanation + undecided_note(supported)
    elif rmse0 <= FLOOR:
        verdict = (f"The model is at the noise floor (rmse/noise {rmse0:.2f}) and no effect "
                   "predicts held-out data better: nothing is missing that these data can show.")
    elif weights.decides:
        verdict = sensor_verdict(weights, ev0.metrics["rmse_over_noise"])
    elif ripple is not None:
        verdict = (f"The model misses (rmse/noise {rmse0:.2f}) and no catalogue effect earns "
                   f"its parameters: {ripple.describe()}. A plant effect cannot follow it. "
                   "Average the speed over a turn, filter the line out (a notch at "
                   f"{ripple.order:.2g} x the rotation frequency), or write it as an effect "
                   "of your own (docs/physics.md, 'Writing your own effect').")
    else:
        verdict = (f"The model misses (rmse/noise {rmse0:.2f}) but no catalogue effect earns its "
                   "parameters on BIC and on held-out data; the cause may be outside the catalogue "
                   "(write your own effect: docs/physics.md, 'Writing your own effect'), in the "
                   "sensors' calibration, or in effects that only act together (diagnose --auto "
                   "tries pairs).")
    if diverged:
        verdict += (f" Not ranked: {', '.join(diverged)} (every start of the re-fit diverged: "
                    "the simulation overflowed).")
    moving = [r for r, st in starts.items() if "w0" in st]
    if moving:   # stated: these runs are not simulated from rest (labrig.model.start)
        verdict += (f" Runs that start in motion, simulated from their fitted start: "
                    f"{', '.join(moving)}.")
    return verdict
