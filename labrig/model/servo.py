"""The DC servo (docs/physics.md, 'The DC servo'): armature + rotor + gear + sensors, as
python-control objects, open loop and with the position/tacho loop of the paper's eq. 29 set-up.

States x = [i (A), w (rad/s, motor), theta_m (rad, motor)]; input: the bridge voltage
(open loop) or the reference voltage (closed loop).

Closed loop (analog, in the SA150D set-up): amplifier input
``e = Kp (r - Kpot theta_out) - Kv Kt w`` with theta_out = theta_m / N.
"""
from __future__ import annotations

from dataclasses import dataclass, replace, asdict
from typing import TYPE_CHECKING

import numpy as np

from labrig.core.offload import handler

if TYPE_CHECKING:  # python-control costs ~0.8 s to import: only the methods that
    import control  # build its objects load it (labrig's own simulators do not need it)

PLANT_NAMES = ("R", "L", "J", "B", "K")
PLANT_UNITS = {"R": "ohm", "L": "H", "J": "kg m^2", "B": "N m s/rad", "K": "N m/A"}
#: the drive's lag in a torque/force plant (s): far below any sample period (the
#: truth integrator takes it as instantaneous, the fast simulator's exact hold keeps it)
DRIVE_LAG_S = 1e-7


@dataclass
class ServoParams:
    """Everything the model needs: plant (R, L, J, B, K) and the known rig constants."""

    R: float
    L: float
    J: float
    B: float
    K: float
    Ka: float = 1.0          # amplifier gain (armature V per bridge V)
    N: float = 1.0           # gear ratio
    Kt: float = 0.026        # tacho V per rad/s
    Kpot: float = 1.0        # pot V per rad (output shaft)
    #: back-EMF constant (V s/rad); None: equal to K (a DC motor). A torque- or force-
    #: driven plant has none: its current-mode drive cancels the back-EMF
    Ke: float | None = None

    @property
    def ke(self) -> float:
        return self.K if self.Ke is None else self.Ke

    @classmethod
    def current_mode(cls, J: float, B: float, **constants) -> "ServoParams":
        """A torque- or force-driven plant (``J w' = kd u - B w``, kd = Ka) in this form:
        no back-EMF, and a drive lag far below any sample period (labrig.model.plants)."""
        return cls(R=1.0, L=DRIVE_LAG_S, J=float(J), B=float(B), K=1.0, Ke=0.0, **constants)

    @classmethod
    def from_rig(cls, rig, **override) -> "ServoParams":
        """The simulated rig's plant and constants, whatever its drive."""
        p = rig.plant
        const = {"Ka": rig.amplifier.gain, "N": rig.gear_ratio,
                 "Kt": rig.sensors.tacho_v_per_rad_s or 1.0, "Kpot": rig.sensors.pos_v_per_rad}
        if rig.drive == "voltage":
            base = cls(R=p.R, L=p.L, J=p.J, B=p.B, K=p.K, **const)
        else:
            base = cls.current_mode(*((p.J, p.B) if rig.drive == "torque" else (p.M, p.Fv)),
                                    **const)
        return replace(base, **override)

    def plant_dict(self) -> dict:
        return {k: getattr(self, k) for k in PLANT_NAMES}

    def as_dict(self) -> dict:
        return asdict(self)

    # -- identifiable combinations (docs/physics.md, 'Identifiability') ----------
    @property
    def km(self) -> float:
        """Steady motor speed per bridge volt: Ka K / (B R + K Ke)."""
        return self.Ka * self.K / (self.B * self.R + self.K * self.ke)

    @property
    def poles(self) -> np.ndarray:
        a2, a1 = self.J * self.L, self.J * self.R + self.B * self.L
        a0 = self.B * self.R + self.K * self.ke
        return np.roots([a2, a1, a0])

    @property
    def tau_m(self) -> float:
        """Mechanical (slow) time constant from the exact poles."""
        return float(-1.0 / np.max(np.real(self.poles)))

    @property
    def tau_e(self) -> float:
        """Electrical (fast) time constant from the exact poles."""
        return float(-1.0 / np.min(np.real(self.poles)))

    @property
    def tau_m_approx(self) -> float:
        """The paper's first-order tau_m = J R / (B R + K Ke)."""
        return self.J * self.R / (self.B * self.R + self.K * self.ke)

    def stall_torque(self, runs=None, volts: float = 1.0) -> float:
        return self.K * self.Ka * volts / self.R

    # -- state-space models -------------------------------------------------------
    def A_open(self) -> np.ndarray:
        R, L, J, B, K = self.R, self.L, self.J, self.B, self.K
        return np.array([[-R / L, -self.ke / L, 0.0], [K / J, -B / J, 0.0], [0.0, 1.0, 0.0]])

    def B_open(self) -> np.ndarray:
        return np.array([[self.Ka / self.L], [0.0], [0.0]])

    def C_out(self) -> np.ndarray:
        """Outputs: [w (rad/s), theta_out (rad)]."""
        return np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0 / self.N]])

    def open_loop(self) -> "control.StateSpace":
        """u (bridge V) -> [w, theta_out]."""
        import control  # python-control: ~0.8 s to import

        return control.ss(self.A_open(), self.B_open(), self.C_out(), np.zeros((2, 1)),
                          inputs=["u"], outputs=["w", "theta"], states=["i", "w", "theta_m"])

    def closed_loop(self, kp: float, kv: float) -> "control.StateSpace":
        """r (bridge V) -> [w, theta_out] with e = kp (r - Kpot theta) - kv Kt w.

        Built by python-control's feedback composition of the plant with the
        sensor gains, so the loop is exactly the one in the paper's Fig. 3/eq. 29.
        """
        import control  # python-control: ~0.8 s to import

        plant = self.open_loop()
        sensors = control.ss([], [], [], [[kv * self.Kt, kp * self.Kpot]],
                             inputs=["w", "theta"], outputs=["fb"])
        pre = control.ss([], [], [], [[kp]], inputs=["r"], outputs=["rk"])
        summ = control.summing_junction(inputs=["rk", "-fb"], output="u")
        return control.interconnect([plant, sensors, pre, summ], inplist=["r"],
                                    outlist=["w", "theta"])

    def A_closed(self, kp: float, kv: float) -> np.ndarray:
        A = self.A_open().copy()
        b = self.B_open()[:, 0]
        # u = kp r - kv Kt w - kp Kpot theta_m / N
        A[:, 1] -= b * kv * self.Kt
        A[:, 2] -= b * kp * self.Kpot / self.N
        return A

    def B_closed(self, kp: float) -> np.ndarray:
        return self.B_open() * kp

    def speed_tf(self) -> "control.TransferFunction":
        """W/U = Ka K / (J L s^2 + (J R + B L) s + B R + K Ke)."""
        import control  # python-control: ~0.8 s to import

        return control.tf([self.Ka * self.K],
                          [self.J * self.L, self.J * self.R + self.B * self.L,
                           self.B * self.R + self.K * self.ke])

    def closed_tau(self, kp: float, kv: float) -> float:
        """The closed position loop's slowest time constant (s)."""
        slow = np.min(np.abs(np.real(np.linalg.eigvals(self.A_closed(kp, kv)))))
        return 1.0 / max(slow, 1e-6)

    def position_step_info(self, kp: float, kv: float) -> dict:
        """Rise time, settling time and overshoot of the closed position loop."""
        sys = self.closed_loop(kp, kv)
        # an explicit time grid: python-control's automatic one fails on the stiff
        # electrical pole of an identified model (tau_e can be microseconds)
        T = np.linspace(0.0, 12.0 * self.closed_tau(kp, kv), 6001)
        import control  # python-control: ~0.8 s to import

        info = control.step_info(sys[1, 0], T=T)
        return {"rise_time_s": float(info["RiseTime"]), "settling_time_s": float(info["SettlingTime"]),
                "overshoot_percent": float(info["Overshoot"])}


def step_info(servo: ServoParams, kp: float, kv: float) -> dict:
    """Rise time, settling time and overshoot of the closed position loop
    (:meth:`ServoParams.position_step_info`), in this process unless a front end handed
    the job elsewhere (:mod:`labrig.core.offload`, job ``"step_info"``: the command
    line's helper process)."""
    fn = handler("step_info")
    return fn(servo, kp, kv) if fn is not None else servo.position_step_info(kp, kv)
