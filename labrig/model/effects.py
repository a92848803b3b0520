"""The effect catalogue: physical effects as small composable objects.

Each effect knows its name, its parameters (with units, bounds and a readable
description), how to guess them from data, and *where* it enters the servo
simulation (its ``stage``):

``input``     maps the amplifier's input voltage (deadband, offset, asymmetry)
``drive``     maps the armature voltage Ka*u (saturation)
``friction``  gives a friction torque level for the Karnopp stick-slip rule
``output``    acts on the output-shaft angle seen by the pot (backlash)
``delay``     shifts the input in time (transport delay)

The simulators (``labrig.model.truth`` and ``labrig.model.simulate``) call these
hooks with numpy arrays vectorised over a population of candidates, so the same
object serves the simulated rig, the identifiers and the diagnosis.

Writing your own effect (an exercise-sheet-sized example)::

    from labrig.model.effects import Effect, Param

    class MyCoulomb(Effect):
        '''Dry friction of the brushes and bearings: a constant torque against motion.'''
        name = "my_coulomb"
        stage = "friction"
        params = (Param("tc_v", "V", 1e-3, 2.0, "friction as the input voltage that balances it"),)

        def friction(self, plant, tc_v):
            # torque levels opposing motion; the simulator applies the stick-slip rule
            t = tc_v * plant.Ka * plant.K / plant.R   # stall torque of tc_v volts
            return t, t                               # (kinetic, breakaway)

        def initial_guess(self, runs, plant):
            return {"tc_v": 0.1}

and use it with ``labrig identify DIR --effects my_effects.py:MyCoulomb``.
"""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np

from labrig.core.errors import UserError
from labrig.model.effect_base import (STAGE_BASES, STAGES, DelayEffect, DriveEffect,  # noqa: F401
                                      Effect, FrictionEffect, InputEffect, OutputEffect, Param)
from labrig.model.drive_units import level, unit as drive_unit
from labrig.model.curves import InputCurve
from labrig.model.friction import (CoulombFriction, FrictionCurve, Stiction, StribeckCurve,
                                    run_amplitudes as _run_amplitudes)



class Deadband(InputEffect):
    """Amplifier dead zone / brush voltage drop: ``v = sign(u) max(|u| - d, 0)``.

    Physics: the SA150D's input stage and the brushes need a threshold voltage before
    any current flows. Residual signature of a linear model: tau unchanged, apparent
    gain w/V rises with amplitude, the speed-vs-voltage line meets zero speed at
    u = d, small amplitudes barely move. Same steady state as Coulomb friction; the
    transients differ (deadband does not brake a coast-down).
    """

    name = "deadband"
    pair_rank = 3
    threshold = "d_v"
    size = "d_v"
    rival = "coulomb_friction"
    look_alikes = ("stiction", "coulomb_friction", "asymmetric_deadband")
    responses = {
        "ramp": ("with a dead zone the motor creeps up from |u| = d and coasts freely "
                 "through zero speed"),
        "dwells": ("a dead zone lets the motor creep up from the threshold on, the same "
                   "way every time"),
        "coast": ("with a dead zone the motor coasts freely and the speed decays "
                  "exponentially with tau_m"),
        "reversals": ("with a dead zone the motor coasts through every reversal while the "
                      "input crosses the zone"),
        "staircase": "with a dead zone every step's speed rises from the threshold on",
        "steps": ("with a dead zone each step's speed rises only from the threshold on, "
                  "and at 0 V the motor coasts down exponentially with tau_m"),
        "position_steps": ("through the loop a dead zone leaves each position short of "
                           "its reference by up to d/kp, reached without braking"),
    }
    stage = "input"
    params = (Param("d_v", "V", 1e-3, 2.0, "dead-zone half width at the bridge input"),)
    summary = "a dead zone of the amplifier input: below d volts the motor gets nothing"
    signature = ("apparent gain rises with amplitude; speed-vs-voltage line crosses zero "
                 "speed at u = d; coast-downs are exponential (not braked)")
    experiment = "a slow voltage ramp through zero: the speed stays at 0 until |u| = d"
    kernel_columns = {"d_v": "d"}
    family = "dead zone"

    def explain_params(self, params, context):
        if context.get("plant", "voltage") != "voltage":
            return f"d = {level(params['d_v'], context)} at the drive"
        return (f"d = {params['d_v']:.3g} V at the bridge input "
                f"({params['d_v'] * context['Ka']:.3g} V at the armature)")

    def data_bounds(self, reach):
        return {"d_v": (1e-3, reach.amax)}  # a hobby H-bridge's 3-4 V included

    def scan_grid(self, reach):
        return {"d_v": np.linspace(0.02, 0.9, 12) * reach.amax}

    def apply(self, v, d_v):
        return np.sign(v) * np.maximum(np.abs(v) - d_v, 0.0)

    def initial_guess(self, runs, plant):
        return {"d_v": 0.05 * float(np.min(_run_amplitudes(runs)))}

    def as_member(self, name, params):   # an asymmetric dead zone: its mean width
        return [{"d_v": 0.5 * (params["dpos_v"] + params["dneg_v"])}] * (name == "asymmetric_deadband")


class Saturation(DriveEffect):
    """Amplifier rail: ``v_arm = clip(Ka u, -vmax, vmax)``.

    Physics: the amplifier cannot drive the armature beyond its supply rail. Residual
    signature: identical steady speeds for every amplitude above the limit, apparent
    gain w/V falling as 1/A, the largest errors at the largest amplitudes.
    """

    name = "saturation"
    stage = "drive"
    params = (Param("vmax_v", "V", 0.1, 100.0, "armature voltage limit of the amplifier"),)

    def inert(self):
        return {"vmax_v": 1e9}   # a rail no drive reaches
    summary = "the amplifier's output rail: the armature voltage cannot exceed vmax"
    signature = ("steady speed the same for all large amplitudes; apparent gain falls "
                 "as 1/A; errors grow with amplitude")
    experiment = "a staircase of constant inputs: the speed stops rising at the rail"
    kernel_columns = {"vmax_v": "vmax"}

    def explain_params(self, params, context):
        to_input = context.get("to_input")
        if context.get("plant", "voltage") != "voltage":   # the rail is at the drive
            up, down = (to_input(params["vmax_v"] / context["Ka"]) if to_input is not None
                        else (params["vmax_v"] / context["Ka"],) * 2)
            u = drive_unit(context["plant"])
            return (f"vmax = {params['vmax_v']:.3g} {u} at the drive, reached by commands "
                    f"above {level(up, context)} and below {level(-abs(down), context)}")
        if to_input is not None:  # through the effects in front (a dead zone, an offset)
            up, down = to_input(params["vmax_v"] / context["Ka"])
            return (f"vmax = {params['vmax_v']:.3g} V at the armature, reached by inputs "
                    f"above {up:.3g} V and below {down:.3g} V")
        return (f"vmax = {params['vmax_v']:.3g} V at the armature, i.e. inputs above "
                f"{params['vmax_v'] / context['Ka']:.3g} V saturate")

    def data_bounds(self, reach):
        # a rail above the largest drive is never met: the upper bound says "not reached"
        return {"vmax_v": (0.02 * reach.drive_max, 1.5 * reach.drive_max)}

    def scan_grid(self, reach):
        return {"vmax_v": np.geomspace(0.08, 1.2, 14) * reach.drive_max}

    def apply(self, v, vmax_v):
        return np.clip(v, -vmax_v, vmax_v)

    def initial_guess(self, runs, plant):
        return {"vmax_v": 0.8 * plant.Ka * float(np.max(_run_amplitudes(runs)))}


class Backlash(OutputEffect):
    """Gear play: a play operator of half-gap ``a`` on the output-shaft angle.

    Physics: the gear teeth have clearance; at each reversal the motor turns through
    the gap before the output shaft follows. Residual signature: position only — a
    flat segment of width 2a at every reversal; the tacho (on the motor) is unaffected.
    """

    name = "backlash"
    threshold = "a_rad"
    size = "a_rad"
    rival = "delay"
    look_alikes = ("delay",)
    responses = {
        "ramp": ("backlash keeps the output still at the reversal while the motor crosses "
                 "the gap"),
        "coast": "backlash lets the output stop before the motor does",
        "steps": ("backlash leaves the output behind the motor by the gap, one way after "
                  "a step up and the other after a step down, whatever the speed"),
        "reversals": ("backlash keeps the output still while the motor crosses the gap, "
                      "for a time that grows as the speed falls"),
        "position_steps": ("the loop reads the pot behind the gap: the motor crosses it "
                           "at every reversal and the output settles off by up to the gap"),
    }
    stage = "output"
    params = (Param("a_rad", "rad", 1e-4, 0.5, "half the gear play, at the output shaft"),)
    summary = "play in the gearbox: the output shaft lags the motor by up to the gap"
    signature = ("position error only, a constant offset of about 2a after each "
                 "reversal; speed residual unaffected")
    experiment = "reverse slowly and watch the output pot stand still while the motor turns"
    kernel_columns = {"a_rad": "a"}

    def explain_params(self, params, context):
        return (f"half gap a = {params['a_rad']:.3g} rad = {math.degrees(params['a_rad']):.2f} deg "
                "at the output shaft")

    def data_bounds(self, reach):
        return {"a_rad": (1e-4, float(np.clip(reach.theta_span / 2, 2e-3, 0.5)))}

    def scan_grid(self, reach):
        return {"a_rad": np.geomspace(1e-3, float(np.clip(reach.theta_span / 4, 2e-3, 0.25)), 10)}

    def output(self, state, x, a_rad):
        y = np.clip(state, x - a_rad, x + a_rad)
        return y, y

    def initial_guess(self, runs, plant):
        return {"a_rad": math.radians(1.0)}


class Delay(DelayEffect):
    """Transport delay ``u(t - Td)``: conversion latency, filters, the ZOH itself.

    Residual signature: error spikes right after each edge, about ``-Td dy/dt``; the
    residual-input cross-correlation peaks at a small positive lag.
    """

    name = "delay"
    threshold = "td_s"
    size = "td_s"
    rival = "backlash"
    look_alikes = ("backlash",)
    responses = {
        "ramp": "a delay shifts the whole response by the same time",
        "coast": "a delay starts every coast-down late by the same time",
        "steps": "a delay shifts every step and every coast by the same time",
        "reversals": "a delay shifts every response by the same time, whatever the speed",
        "position_steps": "a delay shifts every position step by the same time",
    }
    stage = "delay"
    params = (Param("td_s", "s", 1e-5, 0.1, "transport delay"),)
    summary = "a pure time delay between the bridge output and the motor's response"
    signature = "error spikes right after each edge; cross-correlation peak at small lag"
    experiment = "a single fast step at a high sample rate: the response starts late"
    def explain_params(self, params, context):
        return f"Td = {params['td_s'] * 1e3:.3g} ms"

    def delay_s(self, td_s):
        return td_s

    def data_bounds(self, reach):
        return {"td_s": (1e-5, float(np.clip(reach.duration / 20, 0.01, 0.25)))}

    def scan_grid(self, reach):
        hi = float(np.clip(reach.duration / 40, 0.005, 0.12))
        return {"td_s": np.geomspace(max(reach.dt / 2, 1e-4), hi, 12)}

    def initial_guess(self, runs, plant):
        return {"td_s": 1.0 / max(r.fs for r in runs) if runs else 1e-3}


class Offset(InputEffect):
    """Amplifier input offset ``u + u0``: drift of the SA150D's zero."""

    name = "offset"
    pair_rank = 0
    stage = "input"
    size = "u0_v"
    params = (Param("u0_v", "V", -0.5, 0.5, "input offset voltage", log=False),)
    summary = "an offset at the amplifier input: the motor creeps at zero command"
    signature = "same-sign residual in both half-periods; drift at zero command"
    experiment = "command 0 V for a while: the motor creeps"
    kernel_columns = {"u0_v": "u0"}

    def apply(self, v, u0_v):
        return v + u0_v

    def explain_params(self, params, context):
        if context.get("plant", "voltage") != "voltage":
            return f"u0 = {level(params['u0_v'], context)} at the drive"
        return f"u0 = {params['u0_v'] * 1e3:.3g} mV at the bridge input"

    def data_bounds(self, reach):
        # a force or torque drive's command spans tens of volts: an offset of a fifth of
        # the largest input is still an offset (the catalogue's 0.5 V is a bench amplifier's)
        half = max(0.5, 0.2 * reach.amax)
        return {"u0_v": (-half, half)}

    def scan_grid(self, reach):
        return {"u0_v": np.linspace(-0.2, 0.2, 9) * min(reach.amax, 2.5)}

    def initial_guess(self, runs, plant):
        return {"u0_v": 0.0}


class Asymmetry(InputEffect):
    """Different gains in the two directions: ``u (1 + k)`` for u > 0, ``u (1 - k)`` below."""

    name = "asymmetry"
    stage = "input"
    size = "k"
    params = (Param("k", "-", -0.3, 0.3, "relative gain difference between directions",
                    log=False),)
    summary = "the amplifier or motor is stronger in one direction than the other"
    signature = "residual sign alternates with direction, grows with amplitude"
    experiment = "equal positive and negative steps: the steady speeds differ"
    kernel_columns = {"k": "asym"}

    def apply(self, v, k):
        return np.where(v >= 0, v * (1.0 + k), v * (1.0 - k))

    def scan_grid(self, reach):
        return {"k": np.linspace(-0.2, 0.2, 9)}

    def initial_guess(self, runs, plant):
        return {"k": 0.0}


class AsymmetricDeadband(InputEffect):
    """A dead zone wider one way: ``v = u - d+`` above ``d+``, ``u + d-`` below ``-d-``.

    Physics: an H-bridge or amplifier whose two half-bridges switch on at different
    inputs, or brushes set off the neutral axis. It equals a symmetric dead zone
    ``d = (d+ + d-)/2`` behind an input offset ``u0 = (d- - d+)/2`` exactly, which is
    how the fast simulator holds it.
    """

    name = "asymmetric_deadband"
    pair_rank = 4
    simpler = "deadband"
    rival = "coulomb_friction"
    proposed_as = "deadband"
    look_alikes = ("deadband", "offset")   # it is a dead zone behind an offset
    responses = Deadband.responses
    stage = "input"
    family = "dead zone"
    def inert(self):
        return {"dpos_v": 0.0, "dneg_v": 0.0}

    def as_member(self, name, params):   # a symmetric dead zone: the same width each way
        return [{"dpos_v": params["d_v"], "dneg_v": params["d_v"]}] * (name == "deadband")

    params = (Param("dpos_v", "V", 1e-3, 2.0, "dead zone for positive inputs"),
              Param("dneg_v", "V", 1e-3, 2.0, "dead zone for negative inputs"))
    summary = "a dead zone wider in one direction: the rig starts later one way"
    signature = ("like a dead zone, but the steady speeds of +A and -A differ by a "
                 "constant amount; the error alternates sign with direction")
    experiment = "slow ramps from 0 V up and from 0 V down: the speed leaves 0 at different |u|"

    def explain_params(self, params, context):
        if context.get("plant", "voltage") != "voltage":
            return (f"d+ = {level(params['dpos_v'], context)} forward, d- = "
                    f"{level(params['dneg_v'], context)} in reverse, at the drive")
        return (f"d+ = {params['dpos_v']:.3g} V forward, d- = {params['dneg_v']:.3g} V in "
                f"reverse (a symmetric {0.5 * (params['dpos_v'] + params['dneg_v']):.3g} V "
                f"dead zone behind a {0.5e3 * (params['dneg_v'] - params['dpos_v']):.3g} mV offset)")

    def apply(self, v, dpos_v, dneg_v):
        return np.where(v >= 0, np.maximum(v - dpos_v, 0.0), np.minimum(v + dneg_v, 0.0))

    def to_kernel(self, kernel, p, plant) -> bool:
        kernel.set("d", 0.5 * (p["dpos_v"] + p["dneg_v"]))
        kernel.add("u0", 0.5 * (p["dneg_v"] - p["dpos_v"]))
        return True

    def data_bounds(self, reach):
        return {"dpos_v": (1e-3, reach.amax), "dneg_v": (1e-3, reach.amax)}

    def scan_grid(self, reach):
        d = np.linspace(0.04, 0.8, 6) * reach.amax
        return {"dpos_v": np.repeat(d, len(d)), "dneg_v": np.tile(d, len(d))}

    def initial_guess(self, runs, plant):
        d = 0.05 * float(np.min(_run_amplitudes(runs)))
        return {"dpos_v": d, "dneg_v": d}


#: input-stage effects act in this order (then any user effects), in every simulator
INPUT_ORDER = ("offset", "asymmetry", "deadband", "asymmetric_deadband")


def ordered(effects) -> list:
    """Effects in the canonical order every simulator applies them."""
    rank = {n: i for i, n in enumerate(INPUT_ORDER)}
    return sorted(effects, key=lambda e: rank.get(e.name, len(rank)))


CATALOGUE: dict[str, type[Effect]] = {cls.name: cls for cls in (
    Deadband, CoulombFriction, Saturation, Backlash, Delay, Stiction, Offset, Asymmetry,
    AsymmetricDeadband, FrictionCurve, StribeckCurve, InputCurve)}


#: where an amplifier's own effects act: before and after its gain (a dead zone, an input
#: offset, an asymmetry of its gain, its rail)
AMPLIFIER_STAGES = ("input", "drive")


def input_can_have(effect: Effect, runs) -> bool:
    """The one rule of what the runs' input can have in front of it. A measured torque or
    force (a current channel times its constant, ``labrig import --input-measured``) is
    what reaches the rotor: an effect that lives at an amplifier's input or output (dead
    zone, rail, input offset, asymmetric gain) cannot act on it, and a threshold the data
    show in it is friction (docs/physics.md, 'Effects the input cannot have')."""
    measured = any(getattr(r, "input_measured", False) for r in runs)
    return not (measured and effect.stage in AMPLIFIER_STAGES)


def _check_effect_class(cls, where: str) -> type[Effect]:
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise UserError(f"{where}: not a subclass of labrig.model.effects.Effect")
    if cls.stage not in STAGES:
        raise UserError(f"{where}: stage {cls.stage!r} is not one of {', '.join(STAGES)}")
    hook = {"input": "apply", "drive": "apply", "friction": "friction",
            "output": "output", "delay": "delay_s"}[cls.stage]
    if getattr(cls, hook, None) is None:
        raise UserError(f"{where}: a '{cls.stage}' effect must define {hook}()")
    for p in cls.params:
        if not p.lower < p.upper:
            raise UserError(f"{where}: parameter {p.name} has lower >= upper")
    return cls


#: user-effect files the user trusted on this command line (``--trust-code FILE.py``)
_TRUSTED: set[Path] = set()


def trust_code(files) -> None:
    """Allow data files (model, rig, identify config) to name effects from ``files``.

    A user effect is Python code and runs when it is loaded. labrig loads one named on
    the command line (``--effects FILE.py:Class``: the user asked for it), but one named
    inside a data file only for files the user trusted explicitly, so opening a
    student's model never runs the student's code by surprise.
    """
    for f in files or ():
        path = Path(f)
        if path.suffix != ".py" or not path.is_file():
            raise UserError(f"`trust_code`: '{f}' is not a Python file (give FILE.py)")
        _TRUSTED.add(path.resolve())


def reset_trust() -> None:
    _TRUSTED.clear()


def is_user_spec(name: str) -> bool:
    return ":" in name and name.rpartition(":")[0].endswith(".py")


def load_user_effect(spec: str, origin: str | None = None) -> type[Effect]:
    """``path/to/file.py:ClassName`` -> the effect class, checked.

    ``origin`` is the data file that names it (``None``: the command line); a data file
    may only name a trusted file (see :func:`trust_code`).
    """
    file, _, clsname = spec.rpartition(":")
    path = Path(file)
    where = origin or "`effects`"
    if origin is not None and (not path.is_file() or path.resolve() not in _TRUSTED):
        raise UserError(f"{origin}: names the user effect '{spec}', which is Python code; "
                        "labrig never runs code named in a data file unless you pass "
                        f"`trust_code={file}` (only for code you have read)")
    if not path.is_file():
        raise UserError(f"{where}: file '{file}' not found (expected FILE.py:ClassName)")
    if origin is None:  # named on the command line: the user asked for this code
        _TRUSTED.add(path.resolve())
    modname = f"labrig_user_{path.stem}_{abs(hash(str(path.resolve())))}"
    spec_ = importlib.util.spec_from_file_location(modname, path)
    module = importlib.util.module_from_spec(spec_)
    try:
        spec_.loader.exec_module(module)
    except Exception as exc:  # the user's file: report, don't crash
        raise UserError(f"{file}: failed to import ({type(exc).__name__}: {exc})") from None
    cls = getattr(module, clsname, None)
    if cls is None:
        raise UserError(f"{file}: no class '{clsname}'")
    return _check_effect_class(cls, spec)


def catalogue_name(name):
    """The catalogue's spelling (lower case) of a catalogue effect named in any case
    (``"Deadband"`` -> ``"deadband"``); any other name (a user effect's FILE.py:Class)
    unchanged. Effect names are user input in options and files alike."""
    key = name.strip().lower() if isinstance(name, str) else name
    return key if key in CATALOGUE else name


def get_effect(name: str, origin: str | None = None) -> Effect:
    """An effect instance by catalogue name or ``file.py:ClassName``.

    ``origin`` names the data file the name comes from (``None``: the command line);
    see :func:`load_user_effect` for what a data file may name.
    """
    if not isinstance(name, str):
        raise UserError(f"{origin or '`effects`'}: an effect name must be text, got {name!r}")
    if is_user_spec(name):
        eff = load_user_effect(name, origin)()
        eff.spec = name  # saved in model files, so later commands can load it again
        return eff
    try:
        return CATALOGUE[name.strip().lower()]()
    except KeyError:
        raise UserError(f"{origin + ': ' if origin else ''}unknown effect '{name}'; the "
                        f"catalogue has {', '.join(CATALOGUE)} (or give FILE.py:ClassName "
                        "on the command line)") from None
