"""The plants labrig can model, one class each, behind the same :class:`~labrig.model.model.Model`,
simulators and identifiers (docs/physics.md, 'Plants and axes').

``voltage``  the DC servo driven by an armature voltage: armature circuit and back-EMF,
             ``L i' = Ka u - R i - K w``, ``J w' = K i - B w - T_f`` (R, L, J, B, K);
``torque``   a rotary axis whose drive imposes the torque (a current-mode amplifier):
             ``J w' = kd u - B w - T_f`` (J, B; kd known, in N m per input volt);
``force``    a linear axis whose drive imposes the force:
             ``M v' = kd u - Fv v - F_f`` (M, Fv; kd known, in N per input volt).

Torque and force plants run on the same kernels as the voltage plant: the drive is a
"current" state that follows ``kd u`` with a time constant far below any sample
period (:data:`DRIVE_LAG_S`) and no back-EMF, so ``K = R = 1`` and ``Ke = 0``. Every
effect then works unchanged: a friction level of ``tc_v`` input volts is ``kd tc_v``
N m (or N), a dead zone or offset is in the input's volts, backlash is in the axis's
position unit.
"""
from __future__ import annotations

import abc

import numpy as np

from labrig.core.errors import UserError
from labrig.model.servo import DRIVE_LAG_S, ServoParams

#: the axes: position and speed units
AXES = {"rotary": ("rad", "rad/s"), "linear": ("m", "m/s")}


class Plant(abc.ABC):
    """One kind of plant: its parameters, their units and bounds, and its kernel form."""

    kind: str = ""
    #: the axis this plant moves
    axis: str = "rotary"
    names: tuple = ()
    units: dict = {}
    #: generic search bounds (SI units)
    bounds: dict = {}
    #: the combinations the data fix, in the order reported
    combinations: tuple = ("km", "tau_m_s")
    #: whether a measured armature current is an output of this model
    current_output = False
    #: parameter name -> the rig file's key under [plant]
    toml_keys: dict = {}

    @classmethod
    @abc.abstractmethod
    def servo(cls, params: dict, constants: dict) -> ServoParams:
        """The plant's parameters and the rig's constants in the simulators' form."""

    @classmethod
    @abc.abstractmethod
    def kernel(cls, plant: np.ndarray) -> np.ndarray:
        """(P, len(names)) plant parameters -> (P, 6) kernel columns R, L, J, B, K, Ke."""

    @classmethod
    def position_unit(cls) -> str:
        return AXES[cls.axis][0]

    @classmethod
    def speed_unit(cls) -> str:
        return AXES[cls.axis][1]

    @classmethod
    def physical(cls, params: dict, effect_params: dict, constants: dict) -> dict:
        """The identified plant and friction in the axis's units.

        Returns ``{name: (value, unit, key, scale)}``: ``key`` is the fitted parameter
        it comes from (``coulomb_friction.tc_v``) and ``scale`` the factor that makes it
        physical, so its interval scales the same way.
        """
        out = {n: (float(params[n]), cls.units[n], n, 1.0) for n in cls.names}
        sp = cls.servo(params, constants)
        per_v = sp.Ka * sp.K / sp.R   # N m (or N) per input volt, the rotor held
        kinetic, offset, unit = cls.friction_names
        for eff, ps in effect_params.items():
            for p, name in (("tc_v", kinetic), ("u0_v", offset)):
                if p in ps:
                    out[name] = (float(ps[p]) * per_v, unit, f"{eff}.{p}", per_v)
            if "excess" in ps:  # stiction's breakaway level, Ts = Tc (1 + excess)
                k = per_v * (1.0 + float(ps["excess"]))
                out[kinetic[0] + "s"] = (float(ps["tc_v"]) * k, unit, f"{eff}.tc_v", k)
        return out

    friction_names = ("Tc", "T0", "N m")

    #: parameters a settled fit leaves where the fit put them (below)
    left_as_fitted: tuple = ()

    @classmethod
    def settling_point(cls, bounds: dict, fitted: dict) -> dict:
        """Where a fit's unpinned directions are settled (:mod:`labrig.identification.settle`):
        each parameter's geometric middle of ``bounds`` ``{name: (lower, upper)}``, those
        in :attr:`left_as_fitted` at their ``fitted`` value."""
        return {n: float(fitted[n]) if n in cls.left_as_fitted else float(np.sqrt(lo * hi))
                for n, (lo, hi) in bounds.items()}


class VoltagePlant(Plant):
    """The voltage-driven DC servo: armature circuit, back-EMF, rotor, gear, sensors."""

    kind = "voltage"
    names = ("R", "L", "J", "B", "K")
    units = {"R": "ohm", "L": "H", "J": "kg m^2", "B": "N m s/rad", "K": "N m/A"}
    #: wide enough for bench servos from 10 W to 1 kW
    bounds = {"R": (0.1, 100.0), "L": (1e-5, 1.0), "J": (1e-7, 1e-1),
              "B": (1e-9, 1e-1), "K": (1e-3, 2.0)}
    combinations = ("km", "tau_m_s", "tau_e_s")
    current_output = True
    #: an electrical time constant the data do not resolve is left where the fit put it: the
    #: middle of the bounds (L 3 mH) would put a millisecond's lag into a 1 kHz record and
    #: worsen its fit, and the smallest L started the loop's later re-fits from no lag at
    #: all, from where a hidden 12 ms delay was found as 10 ms beside a 3 ms pole
    left_as_fitted = ("L",)
    toml_keys = {"R": "R_ohm", "L": "L_h", "J": "J_kgm2", "B": "B_nms_per_rad",
                 "K": "K_nm_per_a"}

    @classmethod
    def servo(cls, params, constants):
        return ServoParams(**{k: float(params[k]) for k in cls.names},
                           Ka=constants.get("Ka", 1.0), N=constants.get("N", 1.0),
                           Kt=constants.get("Kt", 0.026), Kpot=constants.get("Kpot", 1.0))

    @classmethod
    def kernel(cls, plant):
        plant = np.atleast_2d(plant)
        return np.column_stack([plant, plant[:, 4]])


class TorquePlant(Plant):
    """A rotary axis driven through a current-mode amplifier: the input sets the torque."""

    kind = "torque"
    names = ("J", "B")
    units = {"J": "kg m^2", "B": "N m s/rad"}
    bounds = {"J": (1e-8, 10.0), "B": (1e-9, 10.0)}
    toml_keys = {"J": "J_kgm2", "B": "B_nms_per_rad"}
    friction_names = ("Tc", "T0", "N m")

    @classmethod
    def servo(cls, params, constants):
        return ServoParams.current_mode(
            params[cls.names[0]], params[cls.names[1]], Ka=constants.get("Ka", 1.0),
            N=constants.get("N", 1.0), Kt=constants.get("Kt", 1.0),
            Kpot=constants.get("Kpot", 1.0))

    @classmethod
    def kernel(cls, plant):
        plant = np.atleast_2d(plant)
        P = plant.shape[0]
        one = np.ones(P)
        return np.column_stack([one, np.full(P, DRIVE_LAG_S), plant[:, 0], plant[:, 1], one,
                                np.zeros(P)])


class ForcePlant(TorquePlant):
    """A linear axis driven through a current-mode amplifier: the input sets the force."""

    kind = "force"
    axis = "linear"
    names = ("M", "Fv")
    units = {"M": "kg", "Fv": "N s/m"}
    bounds = {"M": (1e-4, 1e5), "Fv": (1e-6, 1e6)}
    toml_keys = {"M": "M_kg", "Fv": "Fv_ns_per_m"}
    friction_names = ("Fc", "F0", "N")


#: plant kind (the model file's ``structure``, the rig's ``drive``) -> plant class
PLANTS = {c.kind: c for c in (VoltagePlant, TorquePlant, ForcePlant)}
#: names earlier model files used
ALIASES = {"dc-servo": "voltage"}
#: the axes each drive may move (a voltage-driven linear axis is a rotary motor and a
#: screw: describe it as rotary with the screw in the gear ratio)
DRIVE_AXES = {"voltage": ("rotary",), "torque": ("rotary",), "force": ("linear",)}


def plant_class(kind: str, origin: str = "drive") -> type[Plant]:
    """The plant class of ``kind`` (a drive or model structure name)."""
    kind = ALIASES.get(kind, kind)
    if kind not in PLANTS:
        raise UserError(f"{origin}: unknown plant {kind!r}; choose {', '.join(PLANTS)}")
    return PLANTS[kind]


def check_axis(drive: str, axis: str, origin: str = "`axis`") -> None:
    """Refuse a drive/axis pair labrig has no plant for, saying what to use instead."""
    plant_class(drive)
    if axis not in AXES:
        raise UserError(f"{origin}: unknown axis {axis!r}; choose rotary or linear")
    if axis not in DRIVE_AXES[drive]:
        fix = {"voltage": "a voltage-driven screw axis is a rotary motor: import it with "
                          "`axis=rotary` and the screw in `gear_ratio`",
               "torque": "a linear axis is force-driven: use `drive=force`",
               "force": "a rotary axis is torque-driven: use `drive=torque`"}[drive]
        raise UserError(f"{origin}: a {drive}-driven plant moves a "
                        f"{' or '.join(DRIVE_AXES[drive])} axis, not a {axis} one; {fix}")


def plant_of_runs(runs) -> type[Plant]:
    """The plant every run in a data set was recorded on (they must agree)."""
    kinds = {r.drive for r in runs}
    if len(kinds) > 1:
        raise UserError("the runs mix drives (" + ", ".join(sorted(kinds)) + "): identify "
                        "each rig's runs on their own")
    return plant_class(kinds.pop() if kinds else "voltage")
