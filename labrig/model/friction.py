"""Friction laws of the catalogue: Coulomb friction and stiction (Karnopp), and the
open-ended friction curve: a level of its own each way, with a Stribeck peak at rest."""
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
    pair_rank = 1
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
        "position_steps": ("through the loop Coulomb friction brakes each step to a stop "
                           "short of its reference, by up to its level over kp"),
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

    def as_member(self, name, params):
        """Stiction's Coulomb level (its breakaway dropped); a friction curve's mean level."""
        if name == "stiction":
            return [{"tc_v": params["tc_v"]}]
        if name == "friction_curve":
            return [{"tc_v": 0.5 * (params["tcp_v"] + params["tcn_v"])}]
        return []


class Stiction(FrictionEffect):
    """Coulomb friction plus a higher breakaway torque (Karnopp): ``ts = tc*(1 + s)``."""

    name = "stiction"
    pair_rank = 2
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
        "position_steps": ("through the loop stiction holds the output until the error's "
                           "drive passes the breakaway level: small steps stay stuck"),
    }
    stage = "friction"
    family = "friction law"
    params = (Param("tc_v", "V", 1e-3, 5.0, "Coulomb friction as a bridge voltage (see coulomb_friction)"),
              Param("excess", "-", 0.01, 8.0, "breakaway excess: Ts = Tc (1 + excess)"))
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

    def as_member(self, name, params):
        """Coulomb friction as stiction with the smallest breakaway excess, then with one
        a fifth above the level (the error is flat in the excess near zero: a breakaway
        changes the fit only where it holds a rotor the simpler law lets move)."""
        if name != "coulomb_friction":
            return []
        return [{"tc_v": params["tc_v"], "excess": e} for e in (0.01, 0.2)]


#: the steady speed residual's common shift (noise floors) from which friction is larger one
#: way (the open-ended friction curve is offered)
ONE_SHIFT = 1.0


class FrictionCurve(FrictionEffect):
    """Coulomb friction of its own size in each direction: ``Tc+`` while turning forward,
    ``Tc-`` in reverse, each the torque that also holds the rotor at rest that way.

    Physics: bearings preloaded one way, a gear mesh or a seal that drags more in one
    direction, a drive's current sensor that reads a little high one way: the torque it
    takes to move forward and in reverse differ (Rhoban/bam measured such asymmetries on
    real servos). Viscous friction is the plant's own B. It is the same as symmetric
    friction of the mean level plus a constant torque of half the difference, which is how
    the simulators apply it (the constant torque enters with the drive, so on a voltage
    drive a dead zone or rail in the model acts on it too). Residual signature of a model
    with symmetric friction: the steady speeds of +A and -A are both off in the same
    direction, by an amount that does not grow with A; the start that way is late.
    Offered by ``diagnose`` only where the residual shows it (:meth:`offered`).

    The parameters are friction levels as bridge voltages, as ``coulomb_friction``'s.
    """

    name = "friction_curve"
    threshold = "tcp_v"
    size = "tcp_v"
    family = "friction law"
    simpler = "coulomb_friction"
    rival = "coulomb_friction"
    look_alikes = ("coulomb_friction",)
    open_ended = True
    responses = CoulombFriction.responses
    params = (Param("tcp_v", "V", 1e-3, 5.0, "friction while turning forward, as the bridge "
                    "voltage that balances it at stall"),
              Param("tcn_v", "V", 1e-3, 5.0, "friction while turning in reverse, likewise"))
    summary = "friction larger one way: Coulomb friction with its own level in each direction"
    signature = ("the steady speeds of +A and -A are both off in the same direction by an "
                 "amount that does not grow with A; the start one way is late")
    experiment = ("slow ramps from rest in each direction: the drive at which it starts to "
                  "move differs, and so does the steady drive to keep a low speed")

    def inert(self) -> dict:
        return {"tcp_v": 0.0, "tcn_v": 0.0}

    def as_member(self, name, params):
        """Coulomb friction as the same level each way."""
        if name != "coulomb_friction":
            return []
        return [{"tcp_v": params["tc_v"], "tcn_v": params["tc_v"]}]

    def friction(self, plant, tcp_v, tcn_v):
        t = 0.5 * (np.asarray(tcp_v) + np.asarray(tcn_v)) * plant.Ka * plant.K / plant.R
        return t, t

    def input_bias(self, tcp_v, tcn_v, **_):
        """Half the difference, as the input that drives with it (forward when the reverse
        friction is the larger)."""
        return 0.5 * (np.asarray(tcn_v) - np.asarray(tcp_v))

    def to_kernel(self, kernel, p, plant) -> bool:
        FrictionEffect.to_kernel(self, kernel, p, plant)
        kernel.add("u0", self.input_bias(p["tcp_v"], p["tcn_v"]))
        return True

    def explain_params(self, params, context):
        up, down = params["tcp_v"], params["tcn_v"]
        big, small = (down, up) if down >= up else (up, down)
        way = "in reverse" if down >= up else "forward"
        return (f"friction is {100 * (big / max(small, 1e-12) - 1):.0f} % larger {way}: "
                f"{level(up, context)} forward, {level(down, context)} in reverse "
                f"(as the {'drive' if context.get('plant', 'voltage') != 'voltage' else 'input'} "
                "that balances it)")

    def data_bounds(self, reach):
        return {"tcp_v": (1e-3, reach.amax), "tcn_v": (1e-3, reach.amax)}

    def scan_grid(self, reach):
        tc = np.linspace(0.02, 0.8, 6) * reach.amax
        a, b = np.meshgrid(tc, tc)
        return {"tcp_v": a.ravel(), "tcn_v": b.ravel()}

    def initial_guess(self, runs, plant):
        g = CoulombFriction().initial_guess(runs, plant)["tc_v"]
        return {"tcp_v": g, "tcn_v": g}

    def offered(self, evaluation, runs) -> bool:
        """Only on a measured torque or force (``labrig import --input-measured``: on a
        commanded input the same torques are Coulomb friction plus an input offset, named
        effects the search pairs) and where the model's speed residual says one direction
        drags more: in steady motion both directions' mean residuals lie on the same side,
        by a noise floor at least and 5 standard errors (symmetric friction leaves them on
        opposite sides, each towards zero speed)."""
        if evaluation is None or not any(getattr(r, "input_measured", False) for r in runs):
            return False
        fwd, rev = [], []
        for rr in evaluation.per_run:
            c = rr["channels"].get("speed")
            if c is None:
                continue
            steady = np.asarray(rr["labels"]) == "steady"
            y = c["measured"]
            fwd.append(c["residual"][steady & (y > 0)])
            rev.append(c["residual"][steady & (y < 0)])
        fwd = np.concatenate(fwd) if fwd else np.zeros(0)
        rev = np.concatenate(rev) if rev else np.zeros(0)
        if len(fwd) < 20 or len(rev) < 20:
            return False
        a, b = float(np.mean(fwd)), float(np.mean(rev))
        se = np.sqrt(np.var(fwd) / len(fwd) + np.var(rev) / len(rev))
        # residual = measured - model: friction larger forward leaves both negative; a
        # shift of a noise floor at least, and clear of the samples' scatter
        shift = 0.5 * (a + b)
        return a * b > 0 and abs(shift) > max(5.0 * se, ONE_SHIFT)


class StribeckCurve(FrictionCurve):
    """The friction curve with a Stribeck peak: Coulomb friction of its own level each
    way, and a breakaway ``excess`` above each that holds the rotor at rest.

    Physics: a lubricated contact at rest has squeezed its film out; the torque to
    break it loose is higher than the torque to keep it sliding, and the friction falls
    from that peak to its kinetic level over a small speed (Stribeck's curve; Rhoban/bam
    measured it on real servos). The kernels hold friction constant while the speed
    keeps its sign (their exact zero-order hold), so the fall is a step: Karnopp's
    stick band, the peak held at rest and the kinetic level once moving. Viscous
    friction is the plant's B. The breakaway each way is the kinetic level plus
    ``excess`` times the mean level (a film's peak is common to both directions).
    Residual signature of the two-level curve: steps whose drive lies between a
    direction's kinetic level and its breakaway start in the model and stay at rest in
    the data; a start from rest is late by more than the kinetic level explains.

    Not offered alone: ``diagnose`` and ``--auto`` try it in place of the fitted
    friction curve or stiction, from their fitted levels (:meth:`from_simpler`), so a
    breakaway is only ever added to levels the data already pin.
    """

    name = "stribeck_curve"
    threshold = "tcp_v"
    size = "excess"
    simpler = "friction_curve"
    extends = ("friction_curve", "stiction")
    rival = "friction_curve"
    look_alikes = ("friction_curve", "stiction")
    params = FrictionCurve.params + (
        Param("excess", "-", 0.0, 3.0, "breakaway above each direction's kinetic level, "
              "as a fraction of their mean (the Stribeck peak at rest)"),)
    summary = ("friction larger one way with a Stribeck peak: each direction's Coulomb "
               "level, and a breakaway above it that holds the rotor at rest")
    signature = ("drives between a direction's kinetic level and its breakaway leave the "
                 "rotor at rest where the two-level curve lets it move; starts from rest "
                 "are late")
    experiment = ("slow ramps from rest in each direction: the rotor breaks loose above "
                  "the level that then keeps it moving, and jumps to speed")

    def inert(self) -> dict:
        return {"excess": 0.0}

    def friction(self, plant, tcp_v, tcn_v, excess):
        t, _ = FrictionCurve.friction(self, plant, tcp_v, tcn_v)
        return t, t * (1.0 + np.asarray(excess))

    def explain_params(self, params, context):
        mean = 0.5 * (params["tcp_v"] + params["tcn_v"])
        return (FrictionCurve.explain_params(self, params, context)
                + f"; it breaks loose {level(params['excess'] * mean, context)} above each "
                  f"(the Stribeck peak at rest, {100 * params['excess']:.0f} % of the mean "
                  "level; steps pin it only between the largest drive that left the rotor at "
                  "rest and the smallest that moved it, a slow ramp from rest pins it)")

    def data_bounds(self, reach):
        return {**FrictionCurve.data_bounds(self, reach), "excess": (0.0, 3.0)}

    def scan_grid(self, reach):
        g = FrictionCurve.scan_grid(self, reach)
        n = len(g["tcp_v"])
        return {"tcp_v": np.tile(g["tcp_v"], 2), "tcn_v": np.tile(g["tcn_v"], 2),
                "excess": np.repeat([0.0, 0.5], n)}

    def initial_guess(self, runs, plant):
        return {**FrictionCurve.initial_guess(self, runs, plant), "excess": 0.0}

    def offered(self, evaluation, runs) -> bool:
        """Never as an addition (see the class): only in place of a fitted simpler law."""
        return False

    def from_simpler(self, name: str, params: dict, runs) -> list[dict]:
        """The fitted simpler law ``name`` (``params``) exactly, then with breakaways of
        :data:`BREAKAWAY_STARTS` above it (a breakaway changes the fit only where it holds
        a rotor the simpler law lets move, so the error is flat in ``excess`` near zero
        and a re-fit from there alone stays there). Only on a measured torque or force, as
        the friction curve (:meth:`FrictionCurve.offered`)."""
        if not any(getattr(r, "input_measured", False) for r in runs):
            return []
        if name == "friction_curve":
            levels = {"tcp_v": params["tcp_v"], "tcn_v": params["tcn_v"], "excess": 0.0}
        elif name == "stiction":
            levels = {"tcp_v": params["tc_v"], "tcn_v": params["tc_v"],
                      "excess": params["excess"]}
        else:
            return []
        return [levels] + [{**levels, "excess": levels["excess"] + e} for e in BREAKAWAY_STARTS]


#: breakaways (fractions of the mean level) a Stribeck curve's re-fit also starts from,
#: above the simpler law it replaces
BREAKAWAY_STARTS = (0.25, 0.5, 1.0)
