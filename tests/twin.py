"""A second simulated MS150, written apart from labrig: it shares no code with labrig's
model, simulators or file readers, so a proposal that separates two explanations on it
separates them on physics, not on labrig's own arithmetic.

What differs from labrig's simulators (docs/physics.md, 'The simulators'):

- **integrator**: classic fourth-order Runge-Kutta with a fixed step (4 per sample), not
  semi-implicit sub-steps or an exact zero-order hold;
- **friction law**: a smoothed Stribeck curve, ``(Tc + (Ts - Tc) exp(-(w/ws)^2))
  tanh(w/eps)``, not Karnopp's stick-slip rule: a stuck rotor creeps a little, breakaway
  is gradual;
- **backlash**: the pot's shaft pushed across the gear's gap on the integrator's own
  steps;
- **delay**: the held input shifted by the delay on the integrator's own time grid;
- **sensors**: the bridge's 12-bit DAC on the input, Gaussian noise then a 10-bit ADC
  over +-10 V on the tacho and the pot, as the board reads them; optionally a tacho
  whose gain ripples with the motor's angle (a commutator's ripple).

It writes runs and reads plans as the files a user would (CSV + ``labrig-run/1`` JSON
sidecar; a plan's ``[[experiment]]`` table), with the standard library and numpy only.
"""
from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


def _folder(folder) -> Path:
    """``folder`` as a Path, made (with its parents) when missing: where a run is written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _write_csv(path: Path, header: str, row: str, *columns) -> Path:
    """``columns`` side by side in the CSV file ``path``: ``header``, then a line a sample
    through ``row`` (a ``str.format`` template with a field a column); returns ``path``."""
    lines = [header] + [row.format(*values) for values in zip(*columns)]
    path.write_text("\n".join(lines) + "\n")
    return path


@dataclass
class Twin:
    """An MS150-type rig (the default rig's plant and sensors) with hidden effects.

    Frictions are in volts at the amplifier input that balance them at stall (the
    convention a student meets in labrig's effect texts), converted here to torque.
    """

    R: float = 8.0
    L: float = 0.0085
    J: float = 5.2245e-5
    B: float = 1.0e-5
    K: float = 0.05
    Ka: float = 5.0
    rail: float = 13.0
    N: float = 30.0
    kt: float = 0.026
    kpot: float = 0.5
    pot0: float = -4.0
    fs: float = 1000.0
    deadzone_v: float = 0.0       # at the amplifier input, symmetric
    coulomb_v: float = 0.0        # kinetic friction
    breakaway_v: float = 0.0      # static friction (Stribeck peak); 0: as kinetic
    stribeck_rad_s: float = 3.0   # motor speed over which the peak decays
    smooth_rad_s: float = 0.05    # tanh smoothing of the sign of the speed
    gap_rad: float = 0.0          # half the gear's backlash, at the output shaft
    delay_s: float = 0.0
    offset_v: float = 0.0         # an input offset: the amplifier sees u + offset_v
    tacho_noise_v: float = 0.010
    pot_noise_v: float = 0.004
    tacho_ripple: float = 0.0     # relative ripple of the tacho's gain ...
    ripple_cycles: int = 0        # ... at this many cycles per motor turn
    seed: int = 11
    _rng: np.random.Generator = field(init=False, repr=False)

    def __post_init__(self):
        self._rng = np.random.default_rng(self.seed)

    # -- physics ---------------------------------------------------------------------
    def _torque_per_volt(self) -> float:
        return self.Ka * self.K / self.R   # stall torque of 1 V at the amplifier input

    def _friction(self, w: float) -> float:
        tc = self.coulomb_v * self._torque_per_volt()
        ts = max(self.breakaway_v, self.coulomb_v) * self._torque_per_volt()
        if tc == 0.0 and ts == 0.0:
            return 0.0
        level = tc + (ts - tc) * math.exp(-(w / self.stribeck_rad_s) ** 2)
        return level * math.tanh(w / self.smooth_rad_s)

    def _armature(self, u: float) -> float:
        u = u + self.offset_v
        d = self.deadzone_v
        v = math.copysign(max(abs(u) - d, 0.0), u) if d > 0.0 else u
        return min(max(self.Ka * v, -self.rail), self.rail)

    def _deriv(self, x, va):
        i, w, _ = x
        di = (va - self.R * i - self.K * w) / self.L
        dw = (self.K * i - self.B * w - self._friction(w)) / self.J
        return (di, dw, w)

    def play(self, u: np.ndarray, gains: dict | None = None) -> dict:
        """The input per sample (V, held between samples) -> sensor volts per sample.
        With ``gains`` ({"kp", "kv"}) the input is the reference of the MS150's analog
        position loop: amplifier input = kp (ref - pot) - kv tacho, the pot read from where
        the run starts (the bridge's delay is on its output, outside the loop)."""
        dac = 10.0 / 4096
        u = np.round(np.clip(u, -5.0, 5.0) / dac) * dac
        n, dt, sub = len(u), 1.0 / self.fs, 4
        h = dt / sub
        x = (0.0, 0.0, 0.0)   # current, motor speed, motor angle
        load = 0.0            # the output shaft the pot reads
        lag = self.delay_s
        w_out, th_out, angle = np.empty(n), np.empty(n), np.empty(n)
        for k in range(n):
            w_out[k] = x[1]
            angle[k] = x[2]
            th_out[k] = load if self.gap_rad > 0.0 else x[2] / self.N
            for j in range(sub):
                t = k * dt + j * h - lag   # the input the armature sees now
                kk = int(math.floor(t * self.fs + 1e-9))
                r = u[kk] if kk >= 0 else 0.0
                if gains is not None:
                    pot = (load if self.gap_rad > 0.0 else x[2] / self.N) * self.kpot
                    r = gains["kp"] * (r - pot) - gains["kv"] * self.kt * x[1]
                va = self._armature(r)
                k1 = self._deriv(x, va)
                k2 = self._deriv(tuple(a + 0.5 * h * b for a, b in zip(x, k1)), va)
                k3 = self._deriv(tuple(a + 0.5 * h * b for a, b in zip(x, k2)), va)
                k4 = self._deriv(tuple(a + h * b for a, b in zip(x, k3)), va)
                x = tuple(a + h / 6.0 * (b + 2 * c + 2 * d + e)
                          for a, b, c, d, e in zip(x, k1, k2, k3, k4))
                if self.gap_rad > 0.0:   # the pot's shaft, held by its own friction in
                    gear = x[2] / self.N  # the gap, is pushed only at the gap's ends
                    load = min(max(load, gear - self.gap_rad), gear + self.gap_rad)
        rng = self._rng
        adc = 20.0 / 1024
        gain = self.kt * (1.0 + self.tacho_ripple * np.sin(self.ripple_cycles * angle))
        tacho = w_out * gain + rng.normal(0.0, self.tacho_noise_v, n)
        pot = th_out * self.kpot + self.pot0 + rng.normal(0.0, self.pot_noise_v, n)
        q = lambda v: np.round(np.clip(v, -10.0, 10.0) / adc) * adc   # noqa: E731
        return {"u": u, "tacho": q(tacho), "pos": q(pot), "theta": th_out}

    # -- files -------------------------------------------------------------------------
    def record(self, folder, name: str, u: np.ndarray, experiment: dict,
               gains: dict | None = None) -> Path:
        """Play ``u`` and write the run as ``folder/name.csv`` + ``.json`` (with ``gains``,
        a closed-loop run: ``u`` is the reference, recorded as ``ref`` too)."""
        folder = _folder(folder)
        y = self.play(u, gains)
        t = np.arange(len(u)) / self.fs
        if gains is None:
            _write_csv(folder / f"{name}.csv", "t,u,tacho,pos", "{:.6f},{:.6f},{:.6f},{:.6f}",
                       t, y["u"], y["tacho"], y["pos"])
            loop = {"loop": "open"}
        else:
            _write_csv(folder / f"{name}.csv", "t,u,tacho,pos,ref",
                       "{:.6f},{:.6f},{:.6f},{:.6f},{:.6f}", t, y["u"], y["tacho"], y["pos"],
                       y["u"])
            loop = {"loop": "closed", "position_gain": gains["kp"],
                    "velocity_gain": gains["kv"]}
        side = {"format": "labrig-run/1", "sample_rate_hz": self.fs, "source": "twin",
                "experiment": {**loop, "sample_rate_hz": self.fs, **experiment},
                "sensors": {"tacho_v_per_rad_s": self.kt, "pos_v_per_rad": self.kpot,
                            "pos_offset_v": self.pot0},
                "rig": {"gear_ratio": self.N, "amplifier_gain": self.Ka,
                        "name": "second simulator (tests/twin.py)"}}
        (folder / f"{name}.json").write_text(json.dumps(side, indent=1))
        return folder / f"{name}.csv"

    def square(self, folder, amplitude: float = 2.5, freq: float = 0.25, periods: int = 2,
               lead: float = 0.5, gains: dict | None = None) -> Path:
        """One square wave, as the exercise sheets' first run (with ``gains``, of the
        position loop's reference, as the default sweep's closed-loop runs)."""
        n0, n = int(lead * self.fs), int((lead + periods / freq) * self.fs)
        t = (np.arange(n) - n0) / self.fs
        u = np.where(t < 0, 0.0, np.where((t * freq) % 1.0 < 0.5, amplitude, -amplitude))
        return self.record(folder, f"{'cl_' if gains else ''}sq_{amplitude:.2f}V", u,
                           {"waveform": "square", "amplitude_v": amplitude,
                            "frequency_hz": freq, "periods": periods, "lead_in_s": lead},
                           gains)

    def play_plan(self, plan, folder) -> list[Path]:
        """Every ``pwl`` experiment of a plan file, as the board plays it."""
        doc = tomllib.loads(Path(plan).read_text())
        out = []
        for e in doc["experiment"]:
            pts = np.array(e["points"], float)
            lead = float(e.get("lead_in_s", 0.5))
            n0 = int(round(lead * self.fs))
            n = n0 + int(round(pts[-1, 0] * self.fs)) + 1
            t = (np.arange(n) - n0) / self.fs
            u = np.where(t < 0, 0.0, np.interp(t, pts[:, 0], pts[:, 1]))
            exp = {"waveform": "pwl", "lead_in_s": lead, "points": e["points"]}
            if "between" in e:
                exp["between"] = e["between"]
            gains = {"kp": e["position_gain"], "kv": e["velocity_gain"]} \
                if e.get("loop") == "closed" else None
            out.append(self.record(folder, e["name"], u, exp, gains))
        return out


# -- a torque-driven servo, recorded as a scope export ---------------------------------

def torque_drive_from_rest(folder, *, J=2e-4, B=2e-3, coulomb=0.02, offset=0.006,
                           torques=(0.05, -0.05, 0.08, -0.08), fs=500.0, position=True,
                           drift=0.02, seed=5) -> list[Path]:
    """A current-mode drive stepped from rest in both directions: ``J w' = u + offset -
    B w - Tc sign(w)`` (the rotor sticks while ``|u + offset| <= Tc``), Euler with 20
    steps per sample. Each run is a foreign CSV ``t,torque,speed,pos`` as a scope would
    export it: the logged torque with its noise, the speed, and, with ``position``, a
    position that is not zeroed between runs and wanders (a random walk of ``drift``
    rad per sample) like an integrated channel of a real drive."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    dt, sub = 1.0 / fs, 20
    h = dt / sub
    out, pos0 = [], 0.0
    for i, a in enumerate(torques):
        n = int(3.0 * fs)
        u = np.zeros(n)
        u[int(0.2 * fs):int(2.2 * fs)] = a
        w = th = 0.0
        ws, ths = np.empty(n), np.empty(n)
        for k in range(n):
            ws[k], ths[k] = w, th
            drive = u[k] + offset
            for _ in range(sub):
                if w == 0.0 and abs(drive) <= coulomb:
                    continue                                   # stuck
                s = math.copysign(1.0, w if w != 0.0 else drive)
                w_new = w + h * (drive - B * w - coulomb * s) / J
                if w != 0.0 and w_new * w < 0.0:
                    w_new = 0.0                                # stops rather than reverses
                th += 0.5 * h * (w + w_new)
                w = w_new
        t = np.arange(n) * dt
        cols = [t, u + rng.normal(0.0, 2e-4, n), ws + rng.normal(0.0, 0.05, n)]
        head = "t,torque,speed"
        if position:
            pos0 += rng.normal(0.0, 50.0)
            cols.append(pos0 + ths + np.cumsum(rng.normal(0.0, drift, n))
                        + rng.normal(0.0, 0.002, n))
            head += ",pos"
        out.append(_write_csv(folder / f"run{i}.csv", head, ",".join(["{:.7g}"] * len(cols)),
                              *cols))
    return out


def _rk4_dw(f, w, v, h):
    """One classic Runge-Kutta step of ``w' = f(w, v)`` with ``v`` held: the change of w."""
    k1 = f(w, v)
    k2 = f(w + 0.5 * h * k1, v)
    k3 = f(w + 0.5 * h * k2, v)
    k4 = f(w + h * k3, v)
    return h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


# -- an Arduino + H-bridge gear motor, logged by its sketch -----------------------------

def hbridge_staircase(folder, *, window_s=0.05, dpos=1.2, dneg=1.8, fs=100.0,
                      levels=(2.0, 3.0, 4.0, 6.0, 8.0, 0.0, -2.0, -3.0, -4.0, -6.0, -8.0, 0.0),
                      step_s=1.0, R=2.5, K=0.02, J=2e-5, B=1e-6, N=30.0, cpr=48,
                      pwm_bits=8, supply=12.0, ripple=0.0, ripple_cycles=0,
                      seed=7) -> Path:
    """A 12 V gear motor behind an H-bridge, one staircase up then down through zero at
    ``fs``, as a sketch logs it: ``ms,u_V,count,speed_rpm``. The bridge passes nothing
    below ``dpos`` volts forward and ``dneg`` in reverse (a threshold that depends on
    the direction); the input is the PWM's duty in ``2^pwm_bits`` steps of the supply.
    The armature's L/R (0.2 ms) is far below a sample, so the current follows the
    voltage: ``J w' = K (v - K w) / R - B w`` (RK4, 10 steps per sample). The count is
    the quadrature encoder's on the motor (``cpr`` per motor turn); the speed is the
    sketch's moving window: the counts gained over the last ``window_s`` over
    ``window_s`` (0: the last sample's), in rpm of the motor. ``ripple`` adds a ripple
    of that fraction at ``ripple_cycles`` per motor turn to the logged speed."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    dt = 1.0 / fs
    n0 = int(0.5 * fs)
    per = int(round(step_s * fs))
    cmd = np.concatenate([np.zeros(n0)] + [np.full(per, v) for v in levels])
    q = supply / (2 ** pwm_bits - 1)
    u = np.round(cmd / q) * q
    n = len(u)

    def bridge(v):
        return v - dpos if v > dpos else v + dneg if v < -dneg else 0.0

    def f(w, v):
        return (K * (v - K * w) / R - B * w) / J

    w, ang = 0.0, rng.uniform(0.0, 2 * math.pi)
    angle = np.empty(n)
    sub = 10
    h = dt / sub
    for k in range(n):
        angle[k] = ang
        v = bridge(u[k])
        for _ in range(sub):
            dw = _rk4_dw(f, w, v, h)
            ang += h * (w + 0.5 * dw)
            w += dw
    count = np.floor(angle * cpr / (2 * math.pi)).astype(int)
    count -= count[0]
    win = max(int(round(window_s * fs)), 1)
    before = np.concatenate([np.full(win, count[0]), count[:-win]])
    rpm = (count - before) / cpr / (win * dt) * 60.0
    if ripple:
        rpm = rpm * (1.0 + ripple * np.sin(ripple_cycles * angle))
    ms = [int(round(1e3 * k * dt)) for k in range(len(u))]
    return _write_csv(folder / "stair.csv", "ms,u_V,count,speed_rpm", "{},{:.4f},{},{:.3f}",
                      ms, u, count, rpm)


# -- a force-driven linear axis in a digital position loop, logged with its drive -------

def force_axis_closed_loop(folder, *, M=2.5, Fv=40.0, coulomb=22.0, offset=3.0, kd=20.0,
                           kp=400.0, kv=8.0, fs=500.0, counts_per_m=2e5,
                           steps=((0.03, -0.03, 0.06, 0.0), (-0.05, 0.02, -0.02, 0.0),
                                  (0.08, -0.04, 0.01, 0.0)), step_s=1.0,
                           seed=9) -> list[Path]:
    """A carriage on a ball screw driven by a force-mode drive (``kd`` N per volt, an
    ``offset`` N of bias), in a digital PD loop: at each sample the controller reads the
    encoder and holds ``u = kp (ref - x) - kv x'`` volts (``x'`` the last sample's
    difference) until the next. ``M v' = kd u + offset - Fv v - Fc sign(v)``; the
    carriage sticks while the force is within the Coulomb level. Euler, 50 steps per
    sample. Each run is a CSV ``t,ref,drive,pos`` (position in m, quantised by the
    encoder's count)."""
    folder = _folder(folder)
    dt, sub = 1.0 / fs, 50
    q = 1.0 / counts_per_m
    out = []
    for j, levels in enumerate(steps):
        n0, per = int(0.2 * fs), int(step_s * fs)
        ref = np.concatenate([np.zeros(n0)] + [np.full(per, r) for r in levels])
        n = len(ref)
        pos, drive = _carriage_in_a_loop(ref, np.zeros(n), M=M, Fv=Fv, coulomb=coulomb,
                                         offset=offset, kd=kd, kp=kp, kv=kv, dt=dt, sub=sub, q=q)
        t = np.arange(n) * dt
        out.append(_write_csv(folder / f"loop{j}.csv", "t,ref,drive,pos",
                              "{:.4f},{:.5f},{:.6f},{:.6f}", t, ref, drive, pos))
    return out


def _carriage_in_a_loop(ref, drive_noise, *, M, Fv, coulomb, offset, kd, kp, kv, dt, sub, q):
    """A carriage driven by a force-mode drive in a digital PD loop on its encoder: at each
    sample the controller reads the count and holds ``u = kp (ref - x) - kv x'`` (plus
    ``drive_noise``) until the next; ``M v' = kd u + offset - Fv v - Fc sign(v)``, the
    carriage sticking while the force is within the Coulomb level; Euler, ``sub`` steps a
    sample. Returns the measured positions and the drive per sample."""
    n = len(ref)
    h = dt / sub
    x = v = 0.0
    meas_prev = 0.0
    pos, drive = np.empty(n), np.empty(n)
    for k in range(n):
        meas = math.floor(x / q + 0.5) * q
        u = kp * (ref[k] - meas) - kv * (meas - meas_prev) / dt + drive_noise[k]
        meas_prev = meas
        pos[k], drive[k] = meas, u
        force = kd * u + offset
        for _ in range(sub):
            if v == 0.0 and abs(force) <= coulomb:
                continue
            s = math.copysign(1.0, v if v != 0.0 else force)
            v_new = v + h * (force - Fv * v - coulomb * s) / M
            if v != 0.0 and v_new * v < 0.0:
                v_new = 0.0
            x += 0.5 * h * (v + v_new)
            v = v_new
    return pos, drive


# -- a long force-driven axis record, in the shape of the EMPS benchmark ----------------

def emps_like_axis(folder, *, M=95.1, Fv=203.5, coulomb=20.4, offset=-3.16, kd=35.15065,
                   fs=1000.0, duration_s=24.8, counts_per_m=2e6, seed=13) -> Path:
    """A prismatic axis in the shape of the EMPS benchmark record (Janot et al. 2019): a
    carriage of ``M`` kg with viscous ``Fv`` and Coulomb friction and a force ``offset``,
    driven through a force-mode drive of ``kd`` N per volt by a digital PD position loop
    following point-to-point moves over 0.2 m for ``duration_s``; logged at ``fs`` as
    ``t,qg,vir,qm`` (reference m, the drive's input V, the encoder's position m). Euler,
    20 steps per sample; the carriage sticks while the force is within the Coulomb
    level."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    dt, sub = 1.0 / fs, 20
    n = int(round(duration_s * fs))
    t = np.arange(n) * dt
    # point-to-point moves: a smooth (cosine) ramp to each target, then a dwell
    targets = [0.0, 0.2, 0.05, 0.15, 0.0, 0.1, 0.2, 0.0, 0.12, 0.02, 0.18, 0.0]
    ref = np.zeros(n)
    seg = n // (len(targets) - 1)
    for j in range(len(targets) - 1):
        a, b = targets[j], targets[j + 1]
        k0, k1 = j * seg, min(n, (j + 1) * seg)
        ramp = np.clip(np.arange(k1 - k0) / (0.6 * seg), 0.0, 1.0)
        ref[k0:k1] = a + (b - a) * 0.5 * (1.0 - np.cos(np.pi * ramp))
    ref[(len(targets) - 1) * seg:] = targets[-1]
    wn, zeta = 30.0, 0.7
    kp = M * wn ** 2 / kd
    kv = (2 * zeta * wn * M - Fv) / kd
    qm, vir = _carriage_in_a_loop(ref, rng.normal(0.0, 2e-3, n), M=M, Fv=Fv, coulomb=coulomb,
                                  offset=offset, kd=kd, kp=kp, kv=kv, dt=dt, sub=sub,
                                  q=1.0 / counts_per_m)
    return _write_csv(folder / "emps.csv", "t,qg,vir,qm", "{:.4f},{:.6f},{:.6f},{:.7f}",
                      t, ref, vir, qm)


# -- a teaching kit's recordings: PRBS around an operating point, a step from a speed ---

def _kit_motor(u, w0, *, R, K, J, B, dz, fs, sub=20):
    """The kit's motor, ``J w' = K (v - K w) / R - B w`` with ``v`` the bridge's dead zone
    of the held input, from ``w0``; RK4 with ``sub`` steps per sample. Returns the speed
    at each sample and the travel over each sample's interval."""
    h = 1.0 / fs / sub

    def f(w, v):
        return (K * (v - K * w) / R - B * w) / J

    w = w0
    ws, travel = np.empty(len(u)), np.empty(len(u))
    for k, uk in enumerate(u):
        v = math.copysign(max(abs(uk) - dz, 0.0), uk)
        ws[k] = w
        d = 0.0
        for _ in range(sub):
            dw = _rk4_dw(f, w, v, h)
            d += h * (w + 0.5 * dw)
            w += dw
        travel[k] = d
    return ws, travel


def kit_recordings(folder, *, R=4.0, K=0.5, J=0.02, B=0.002, dz=1.0, fs=50.0, cpr=2000,
                   levels=(2.5, 3.5, 4.5), prbs_v=0.6, prbs_s=10.0, step=(2.5, 4.5),
                   step_s=6.0, seed=21) -> list[Path]:
    """A teaching kit's recordings as its logger writes them (``t,u,speed``, 50 Hz): three
    PRBS runs around the operating points ``levels`` (the input switches between level
    +- ``prbs_v`` at random sample edges) and a step from a running speed (``step``: the
    input held at the first level, stepped to the second after 1 s). Every run starts in
    motion: the logger starts after the motor has run at the run's first input for 3 s. The
    bridge passes nothing below ``dz`` volts. The speed is the encoder's counts (``cpr`` a
    turn) over the 20 ms before each sample, in rad/s; the input is logged exactly."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    dt = 1.0 / fs
    inputs = []
    for lv in levels:
        n = int(prbs_s * fs)
        bits = rng.integers(0, 2, n // 3 + 1).repeat(3)[:n]   # a bit lasts three samples
        inputs.append((f"prbs_{lv:.1f}V", lv + prbs_v * (2 * bits - 1)))
    n = int(step_s * fs)
    inputs.append(("step", np.where(np.arange(n) < int(1.0 * fs), step[0], step[1])))
    out = []
    for name, u in inputs:
        n0 = int(3.0 * fs)                                    # the pre-roll, not logged
        full = np.concatenate([np.full(n0, u[0]), u])
        _, travel = _kit_motor(full, 0.0, R=R, K=K, J=J, B=B, dz=dz, fs=fs)
        angle = np.concatenate([[0.0], np.cumsum(travel)]) + rng.uniform(0, 2 * math.pi / cpr)
        counts = np.floor(angle * cpr / (2 * math.pi))       # at each sample's start
        # logged sample k (time k dt): the counts gained over the 20 ms before it
        speed = (counts[n0:n0 + len(u)] - counts[n0 - 1:n0 - 1 + len(u)]) * 2 * math.pi / cpr / dt
        t = np.arange(len(u)) * dt
        out.append(_write_csv(folder / f"{name}.csv", "t,u,speed", "{:.3f},{:.4f},{:.5f}",
                              t, u, speed))
    return out


def encoder_squares(twin: "Twin", folder, *, cpr=4000, amps=(1.2, 1.5, 2.0, 2.5), freq=0.25,
                    periods=2, lead=0.5, seed=17) -> list[Path]:
    """Square waves on ``twin``, logged as a position-only encoder rig logs them: the
    output shaft's count (``cpr`` a turn) from wherever within its first count the shaft
    happened to stand, ``t,u,count``; the input as the DAC played it."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    q = 2 * math.pi / cpr
    out = []
    for a in amps:
        n0, n = int(lead * twin.fs), int((lead + periods / freq) * twin.fs)
        t = (np.arange(n) - n0) / twin.fs
        u = np.where(t < 0, 0.0, np.where((t * freq) % 1.0 < 0.5, a, -a))
        y = twin.play(u)
        u = y["u"]                                        # as the DAC played it
        th = y["theta"] + rng.uniform(0.0, q)             # the start within a count
        count = np.floor(th / q).astype(int)
        out.append(_write_csv(folder / f"sq_{a:.2f}V.csv", "t,u,count", "{:.4f},{:.4f},{}",
                              t + lead, u, count))
    return out


def back_to_back_squares(twin: "Twin", folder, *, cpr=4000, amps=(1.5, 2.0, 2.5), freq=0.5,
                         periods=2, lead=0.5, pause_s=0.15) -> list[Path]:
    """Square waves played one after another with ``pause_s`` at 0 V between them, as a
    sweep plays them on a bench: each run's lead-in starts while the shaft still coasts
    from the run before (its last half period is negative), the gear's teeth where that
    coast left them. Logged as a position-only encoder rig logs them (``t,u,count``, the
    output shaft's count, ``cpr`` a turn, from the first run's start)."""
    folder = _folder(folder)
    q = 2 * math.pi / cpr
    pieces, spans = [], []
    for a in amps:
        n0, n = int(lead * twin.fs), int((lead + periods / freq) * twin.fs)
        t = (np.arange(n) - n0) / twin.fs
        start = sum(len(p) for p in pieces)
        pieces.append(np.where(t < 0, 0.0, np.where((t * freq) % 1.0 < 0.5, a, -a)))
        spans.append((a, start, start + n))
        pieces.append(np.zeros(int(pause_s * twin.fs)))
    y = twin.play(np.concatenate(pieces))
    count = np.floor(y["theta"] / q).astype(int)
    out = []
    for a, i, j in spans:
        t = np.arange(j - i) / twin.fs
        out.append(_write_csv(folder / f"sq_{a:.2f}V.csv", "t,u,count", "{:.4f},{:.4f},{}",
                              t, y["u"][i:j], count[i:j] - count[i]))
    return out


# -- a torque drive logged with its measured current, friction larger one way -----------

def measured_current_rig(folder, *, J=2e-4, B=2e-3, kt=0.05, forward=0.02, reverse=0.03,
                         torques=(0.05, -0.05, 0.08, -0.08), fs=500.0, seed=23,
                         breakaway=0.0, stribeck=0.3) -> list[Path]:
    """A servo driven through a current loop, stepped from rest in both directions, logged
    as ``t,current,speed``: the current is the drive's measured one (A, with its sensor's
    noise), the torque on the rotor ``kt`` times it. Coulomb friction is ``forward`` N m
    while turning forward and ``reverse`` in reverse (the rotor sticks while the torque
    is within the level of the way it would turn). With ``breakaway`` (N m), a Stribeck
    peak: friction ``level + breakaway exp(-(w/stribeck)^2)`` while moving, and the rotor
    held at rest up to ``level + breakaway``. Euler, 20 steps per sample."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    dt, sub = 1.0 / fs, 20
    h = dt / sub
    out = []
    for i, a in enumerate(torques):
        n = int(3.0 * fs)
        tq = np.zeros(n)
        tq[int(0.2 * fs):int(2.2 * fs)] = a
        w = 0.0
        ws = np.empty(n)
        for k in range(n):
            ws[k] = w
            for _ in range(sub):
                way = w if w != 0.0 else tq[k]
                level = forward if way > 0 else reverse
                if breakaway:
                    if w == 0.0 and abs(tq[k]) <= level + breakaway:
                        continue                               # held by the peak
                    level = level + breakaway * math.exp(-(w / stribeck) ** 2)
                elif w == 0.0 and abs(tq[k]) <= level:
                    continue                                   # stuck
                w_new = w + h * (tq[k] - B * w - math.copysign(level, way)) / J
                if w != 0.0 and w_new * w < 0.0:
                    w_new = 0.0                                # stops rather than reverses
                w = w_new
        t = np.arange(n) * dt
        current = tq / kt + rng.normal(0.0, 4e-3, n)
        speed = ws + rng.normal(0.0, 0.05, n)
        out.append(_write_csv(folder / f"step{i}.csv", "t,current,speed", "{:.5f},{:.6g},{:.6g}",
                              t, current, speed))
    return out


# -- a hobby shield whose drive is a concave function of the command --------------------

def _shield_speed(volts, ang, *, R, K, J, B, dt, sub, cpr) -> np.ndarray:
    """The shield's motor driven by ``volts`` (held a sample each) from rest at angle
    ``ang``: ``J w' = K (v - K w)/R - B w`` in ``sub`` steps a sample; the encoder's counts
    (``cpr`` a turn) over the sample before each sample, in rad/s."""
    h = dt / sub
    w = 0.0
    angle = np.empty(len(volts) + 1)
    angle[0] = ang
    for k, v in enumerate(volts):
        for _ in range(sub):
            dw = h * (K * (v - K * w) / R - B * w) / J
            ang += h * (w + 0.5 * dw)
            w += dw
        angle[k + 1] = ang
    counts = np.floor(angle * cpr / (2 * math.pi))
    return np.concatenate([[0.0], np.diff(counts)[:-1]]) * 2 * math.pi / cpr / dt


def shield_steps(folder, *, R=2.0, K=0.01, J=2e-6, B=1e-7, supply=12.0, power=0.55, fs=100.0,
                 cpr=400, levels=(1.2, 1.8, 2.4, 2.9, 3.4, 3.8, 4.2, 4.6), seed=29) -> list[Path]:
    """An Arduino motor shield stepped from rest to each command (0-5 V) and back, logged
    at ``fs`` as ``t,u,speed``: the motor's voltage is ``supply (u/5)^power`` (a concave
    PWM mapping: the bridge's dead time and the winding's inductance eat less of a long
    duty than of a short one), ``J w' = K (v - K w)/R - B w``; the speed is the encoder's
    counts (``cpr`` a turn) over the sample before, in rad/s."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    dt, sub = 1.0 / fs, 400   # the count resolves 0.1 % of the speed: 20 steps left 1.45x its noise
    out = []
    for lv in levels:
        n0, n1, n2 = int(0.3 * fs), int(1.5 * fs), int(1.0 * fs)
        u = np.concatenate([np.zeros(n0), np.full(n1, lv), np.zeros(n2)])
        volts = [supply * (uk / 5.0) ** power if uk > 0 else 0.0 for uk in u]
        speed = _shield_speed(volts, rng.uniform(0, 2 * math.pi / cpr), R=R, K=K, J=J, B=B,
                              dt=dt, sub=sub, cpr=cpr)
        t = np.arange(len(u)) * dt
        out.append(_write_csv(folder / f"step_{lv:.1f}V.csv", "t,u,speed", "{:.3f},{:.3f},{:.4f}",
                              t, u, speed))
    return out


# -- a voltage drive with its armature current logged, recorded from a running motor -------

def running_with_current(folder, *, R=2.0, L=0.04, K=0.05, J=1e-4, B=1e-4, fs=1000.0,
                         levels=((3.0, 5.0), (5.0, 2.0), (2.0, 4.0)), seed=31) -> list[Path]:
    """A motor on a voltage drive, its speed and armature current logged at ``fs``; each
    recording starts the moment the drive steps from the level it has long been running
    at to a new one (``levels``: (before, after) volts), so the first sample finds the
    motor turning at the old level's speed with the old level's current (a slow armature,
    L/R = 20 ms: the current needs 20 samples to follow); after 0.3 s it steps back.
    Written as ``t,u,speed,current`` (rad/s, A). RK4, 8 steps per sample."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    dt, sub = 1.0 / fs, 8
    h = dt / sub

    def f(x, v):
        i, w = x
        return np.array([(v - R * i - K * w) / L, (K * i - B * w) / J])

    out = []
    for j, (before, after) in enumerate(levels):
        w = before * K / (K * K + R * B)            # steady at the old level
        x = np.array([(before - K * w) / R, w])
        n = int(0.6 * fs)
        u = np.where(np.arange(n) < n // 2, after, before)
        ws, cur = np.empty(n), np.empty(n)
        for k in range(n):
            ws[k], cur[k] = x[1], x[0]
            for _ in range(sub):
                x = x + _rk4_dw(f, x, u[k], h)
        t = np.arange(n) * dt
        speed = ws + rng.normal(0.0, 0.2, n)
        current = cur + rng.normal(0.0, 0.01, n)
        out.append(_write_csv(folder / f"run{j}.csv", "t,u,speed,current",
                              "{:.5f},{:.6g},{:.6g},{:.6g}", t, u, speed, current))
    return out


# -- a small gearmotor whose friction is large against its drive, logged at 20 Hz -------

def stiction_gearmotor(folder, *, km=3.0, tau=0.04, tc_v=0.7, ts_v=3.2, fs=20.0, cpr=600,
                       sub=400, seed=5) -> list[Path]:
    """A small gearmotor with strong stiction, logged as its sketch logs it (``t,u,speed``,
    ``fs`` Hz): the speed is the encoder's counts (``cpr`` a turn of the output shaft) over
    the sample before, in rad/s. Motor ``tau w' = km (v - f) - w``, friction in volts at
    the input: Karnopp's law, stuck while ``|w|`` is within a stick band and ``|v|`` below
    the breakaway ``ts_v``, ``tc_v sign(w)`` while it turns. Integrated with ``sub`` Euler
    steps a sample (semi-implicit in the viscous term). Two records: a slow triangle
    (+-6 V, 16 s a period, two periods), where motion starts near ``ts_v`` and stops near
    ``tc_v``, and square waves of 2, 4 and 5 V (0.25 Hz, 2 periods each), played back to
    back, the 2 V one below the breakaway."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    dt = 1.0 / fs
    t_tri = np.arange(int(32.0 * fs)) * dt
    phase = (t_tri / 16.0) % 1.0
    tri = 6.0 * np.where(phase < 0.25, 4 * phase, np.where(phase < 0.75, 2 - 4 * phase,
                                                            4 * phase - 4))
    sq = np.concatenate([np.where((np.arange(int(8.0 * fs)) * dt * 0.25) % 1.0 < 0.5, a, -a)
                         for a in (2.0, 4.0, 5.0)])
    h = dt / sub
    band = 1e-3 * km   # rad/s: the stick band
    out = []
    for name, u in (("triangle", tri), ("squares", sq)):
        w, angle = 0.0, 0.0
        angles = np.empty(len(u) + 1)
        angles[0] = 0.0
        for k, v in enumerate(u):
            for _ in range(sub):
                if abs(w) < band and abs(v) <= ts_v:
                    w = 0.0
                    continue
                f = tc_v * (np.sign(w) if abs(w) >= band else np.sign(v))
                w = (w + h / tau * km * (v - f)) / (1.0 + h / tau)
                angle += h * w
            angles[k + 1] = angle
        angles += rng.uniform(0.0, 2 * math.pi / cpr)
        counts = np.floor(angles * cpr / (2 * math.pi))
        speed = np.concatenate([[0.0], np.diff(counts)[:-1]]) * 2 * math.pi / cpr / dt
        t = np.arange(len(u)) * dt
        out.append(_write_csv(folder / f"{name}.csv", "t,u,speed", "{:.3f},{:.4f},{:.5f}",
                              t, u, speed))
    return out


def shield_long_record(folder, *, R=2.0, K=0.01, J=2e-6, B=1e-7, supply=12.0, power=0.55,
                       offset_v=0.25, fs=50.0, cpr=400, seconds=96.0, hold_s=1.5,
                       seed=31) -> Path:
    """One long record of the motor shield of :func:`shield_steps` (its concave PWM
    mapping, ``supply (|u + offset_v| / 5)^power`` with the sign of ``u + offset_v``: a
    bridge whose zero sits off the command's), ``seconds`` at ``fs`` Hz: the command held
    ``hold_s`` at each of a random sequence of levels in +-4.6 V and at 0 V between, the
    speed the encoder's counts (``cpr`` a turn) over the sample before, ``t,u,speed``."""
    folder = _folder(folder)
    rng = np.random.default_rng(seed)
    dt, sub = 1.0 / fs, 400   # (as shield_steps)
    hold = int(hold_s * fs)
    u = np.zeros(int(seconds * fs))
    for k in range(0, len(u), 2 * hold):
        u[k:k + hold] = rng.choice([-1.0, 1.0]) * rng.uniform(1.0, 4.6)
    volts = [math.copysign(supply * min(abs(uk + offset_v) / 5.0, 1.0) ** power, uk + offset_v)
             for uk in u]
    speed = _shield_speed(volts, rng.uniform(0, 2 * math.pi / cpr), R=R, K=K, J=J, B=B, dt=dt,
                          sub=sub, cpr=cpr)
    t = np.arange(len(u)) * dt
    return _write_csv(folder / "long.csv", "t,u,speed", "{:.3f},{:.3f},{:.4f}", t, u, speed)
