"""Friction laws of the catalogue: Coulomb friction and stiction (Karnopp)."""
from __future__ import annotations

import numpy as np

from labrig.model.drive_units import level
from labrig.model.effect_base import FrictionEffect, Param


def run_amplitudes(runs) -> np.ndarray:
    amps = [r.amplitude for r in runs if r.loop == "open"]
    return np.array(amps or [1.0])


class CoulombFriction(FrictionEffect):
    """Dry friction ``Tc sign(w)`` with stiction through a Karnopp stick band.

    Physics: brushes and bearings rub with a torque nearly independent of speed;
    at rest the rotor stays stuck until the drive torque exceeds the breakaway
    torque (equal to Tc here; ``stiction`` makes it larger). Residual signature:
    apparent tau too short, a kink where w crosses 0, coast-downs that stop in
    finite time, relative error ~1/A.

    The parameter is the friction expressed in volts at the bridge input,
    ``tc_v = Tc R / (Ka K)``: the input whose stall torque just balances it. Tc in
    N m is not identifiable from speed and position alone (it scales with R and J
    along the model's symmetry, docs/physics.md, 'Identifiability'); tc_v is, and it
    is directly comparable with a deadband.
    """

    name = "coulomb_friction"
    threshold = "tc_v"
    size = "tc_v"
    rival = "deadband"
    look_alikes = ("stiction", "deadband")
    responses = {
        "ramp": ("with Coulomb friction it starts at the same input but is braked to a "
                 "standstill at every reversal, where it waits until the drive overcomes "
                 "the friction again"),
        "dwells": "Coulomb friction lets it creep up from the same level",
        "coast": ("with Coulomb friction the friction keeps braking, so the speed falls "
                  "faster and stops in a finite time"),
        "reversals": ("with Coulomb friction it is braked to a stop at every reversal and "
                      "waits there until the drive overcomes the friction"),
        "staircase": ("with friction the steps below the friction level stay at rest and "
                      "the others start braked"),
        "steps": ("with Coulomb friction every coast to 0 V is braked by the friction too "
                  "and stops in a finite time"),
    }
    stage = "friction"
    family = "friction law"
    params = (Param("tc_v", "V", 1e-3, 5.0, "Coulomb friction as the bridge voltage that balances "
                    "it at stall (Tc = tc_v Ka K / R)"),)
    summary = "dry friction of brushes and bearings: a constant torque against motion"
    signature = ("apparent gain rises with amplitude like a deadband, but reversals "
                 "decelerate faster into zero speed and leave it later, with a kink at w = 0")
    experiment = ("a coast-down from speed with the amplifier off (the speed falls "
                  "linearly and stops in finite time) or a slow ramp in both directions")
    def explain_params(self, params, context):
        if context.get("plant", "voltage") != "voltage":   # a torque or force drive
            text = (f"Tc = {level(params['tc_v'], context)}: friction cancels the first "
                    f"{level(params['tc_v'], context)} of drive "
                    f"({100 * params['tc_v'] / context['amin']:.0f} % of the smallest command, "
                    f"{level(context['amin'], context)})")
            to_input = context.get("to_input")
            if to_input is not None:
                up, down = to_input(params["tc_v"])
                text += (f"; the axis keeps moving for commands above {level(up, context)} "
                         f"or below {level(down, context)}")
            return text
        # Tc in N m slides along the model's symmetry with R and J; in the model it is
        text = (f"tc_v = {params['tc_v']:.3g} V: friction cancels the first "
                f"{params['tc_v']:.3g} V of drive ({100 * params['tc_v'] / context['amin']:.0f} % "
                f"of the smallest amplitude, {context['amin']:.2g} V)")
        # in the physics' units: armature volts (the torque Tc = tc_v Ka K / R needs R or K
        # known, --fix: along the model's symmetry it slides with R and J)
        text += f", {params['tc_v'] * context['Ka']:.3g} V at the armature"
        to_input = context.get("to_input")
        if to_input is not None:  # behind a dead zone or an offset
            up, down = to_input(params["tc_v"])
            text += f"; the motor keeps turning for inputs above {up:.3g} V or below {down:.3g} V"
        return text

    def data_bounds(self, reach):
        return {"tc_v": (1e-3, reach.amax)}

    def scan_grid(self, reach):
        return {"tc_v": np.linspace(0.02, 0.9, 12) * reach.amax}

    def friction(self, plant, tc_v):
        t = tc_v * plant.Ka * plant.K / plant.R
        return t, t

    def initial_guess(self, runs, plant):
        return {"tc_v": 0.05 * float(np.min(run_amplitudes(runs)))}


class Stiction(FrictionEffect):
    """Coulomb friction plus a higher breakaway torque (Karnopp): ``ts = tc*(1 + s)``."""

    name = "stiction"
    threshold = "tc_v"
    size = "tc_v"
    simpler = "coulomb_friction"
    rival = "deadband"
    look_alikes = ("coulomb_friction", "deadband")
    responses = {
        "ramp": "with stiction it is held until the breakaway level and then jumps",
        "dwells": ("stiction holds it until the drive passes the breakaway level, then it "
                   "jumps to speed"),
        "coast": ("with stiction the friction keeps braking and holds the motor once it "
                  "stops"),
        "reversals": "with stiction it sticks at every reversal until the breakaway level",
        "staircase": ("with stiction the motor stays at rest until a step passes the "
                      "breakaway level, then jumps"),
        "steps": ("with stiction a step below the breakaway level leaves the motor at "
                  "rest, and every coast to 0 V ends held by the friction"),
    }
    stage = "friction"
    family = "friction law"
    params = (Param("tc_v", "V", 1e-3, 5.0, "Coulomb friction as a bridge voltage (see coulomb_friction)"),
              Param("excess", "-", 0.01, 3.0, "breakaway excess: Ts = Tc (1 + excess)"))
    summary = "static friction: starting from rest needs more torque than keeping moving"
    signature = "a delay before each start from rest, near the breakaway voltage only"
    experiment = "a very slow ramp from rest: the motor jumps into motion at breakaway"
    def explain_params(self, params, context):
        return (CoulombFriction().explain_params(params, context)
                + f", breakaway {1 + params['excess']:.2f} x Coulomb")

    def friction(self, plant, tc_v, excess):
        t = tc_v * plant.Ka * plant.K / plant.R
        return t, t * (1.0 + excess)

    def data_bounds(self, reach):
        return {"tc_v": (1e-3, reach.amax)}

    def scan_grid(self, reach):
        tc = np.linspace(0.02, 0.8, 8) * reach.amax
        return {"tc_v": np.tile(tc, 2), "excess": np.repeat([0.3, 1.0], len(tc))}

    def initial_guess(self, runs, plant):
        g = CoulombFriction().initial_guess(runs, plant)
        return {"tc_v": g["tc_v"], "excess": 0.5}
