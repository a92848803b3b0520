"""One fast simulator for all identifiers: a whole population of candidate
parameter sets across every run of a data set, in one call.

How it stays both fast and faithful to the truth integrator:

- the linear part is advanced with an exact zero-order hold per sample,
  ``x+ = Ad x + g_old s_old + g_new s_new + g_f Tf`` (batched ``expm`` of the
  augmented matrix per candidate and run; the two input terms carry a fractional
  transport delay exactly);
- in open loop every input/drive effect is a static map of the held input, so it
  is applied to the input sequence beforehand (vectorised over candidates) and the
  ZOH stays exact;
- Coulomb friction is a piecewise-constant torque input while the speed keeps its
  sign; only the samples where the speed reaches zero, or the rotor is stuck, are
  resolved with semi-implicit sub-steps and the Karnopp rule (as in the truth);
- a closed loop with an input nonlinearity or backlash inside is affine in each piece of
  its drive map (dead zone, linear for either sign of the error, rail; a backlash gap
  open or closed), so each piece has its own exact ZOH (the loop table); only the samples
  where the drive crosses into another piece are sub-stepped.

The kernels (:mod:`labrig.simulation.kernels`) are compiled with numba; they advance a block
of candidates per thread, the candidates in the inner loop so the update vectorises.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from labrig.core.errors import UserError
from labrig.model.effects import AsymmetricDeadband, Asymmetry, Deadband, Effect, Offset, Saturation, ordered
from labrig.simulation.discretise import discretise, plant_matrices
from labrig.simulation.expm import loop_slot_fill
from labrig.simulation.layout import (C_A, C_ASYM, C_D, C_GAP0, C_I0, C_KE, C_TC, C_TD, C_TH0,
                                 C_TS, C_U0, C_VMAX, C_W0,
                                 MAP_COLUMNS, N_COLS, N_SLOTS, S_FLAT, S_NEG, S_NEG_GAP, S_POS,
                                 S_POS_GAP, SLOT_W, T_OK)
from labrig.simulation.kernels import run_kernels
from labrig.simulation.sampled_kernel import first_output, pd_constants, run_sampled
from labrig.model.sensors import windowed_speed
from labrig.model.start import initial_current
from labrig.model.plants import VoltagePlant
from labrig.simulation.warm import ready

# kernel parameter columns: R, L, J, B, K (labrig.model.plants: every plant's kernel
# form), then the effects' (C_D..C_TD), then the back-EMF constant Ke (0 for a
# current-mode drive), then the run's initial state (C_I0, C_W0, C_TH0, C_GAP0: labrig.model.start)
#: open-loop input and drive effects the kernel applies itself (their formulas are in
#: labrig.simulation.candidate_kernel.input_map); a subclass or a user's effect takes the numpy path
_MAPPED = (Offset, Asymmetry, Deadband, AsymmetricDeadband, Saturation)
_NO_MAP = np.zeros((0, len(MAP_COLUMNS)))
_NO_TABLE = np.zeros((0, N_SLOTS, SLOT_W))
#: the kernel's effect columns by name: an effect's ``to_kernel`` writes into these
#: (dead zone, input offset, asymmetry, armature rail, kinetic and breakaway friction
#: torque, backlash half gap, delay)
KERNEL_COLUMNS = {"d": C_D, "u0": C_U0, "asym": C_ASYM, "vmax": C_VMAX, "tc": C_TC,
                  "ts": C_TS, "a": C_A, "td": C_TD}


class _KernelTable:
    """Named access to the (P, N_COLS) parameter table for ``Effect.to_kernel``."""

    def __init__(self, prm: np.ndarray):
        self.prm = prm

    def set(self, column: str, values) -> None:
        self.prm[:, KERNEL_COLUMNS[column]] = np.broadcast_to(values, (self.prm.shape[0],))

    def add(self, column: str, values) -> None:
        self.prm[:, KERNEL_COLUMNS[column]] += np.broadcast_to(values, (self.prm.shape[0],))


@dataclass
class RunData:
    """One run prepared for simulation: input, constants and measured channels."""

    name: str
    u: np.ndarray
    dt: float
    loop: str
    kp: float
    kv: float
    Ka: float
    N: float
    Kt: float
    Kpot: float
    w: np.ndarray | None
    theta: np.ndarray | None
    theta0: float
    amplitude: float
    #: measured armature current (A), an output of the voltage plant's fit
    current: np.ndarray | None = None
    #: the position sensor's quantum (an encoder's count) in position units; 0: unknown
    pos_q: float = 0.0
    #: rotary (rad, rad/s) or linear (m, m/s)
    axis: str = "rotary"
    #: False where the link lost the sample (the run's ``gap`` rows); None: all measured
    measured: np.ndarray | None = None
    #: the speed channel is a moving window of this many samples (0: not filtered)
    speed_window: int = 0
    #: that window was found in the readings by the import, not declared
    window_found: bool = False
    #: how the run starts as its file states it: "auto" (from the data), "rest", "moving"
    start: str = "auto"
    #: a board's own loop (``experiment.controller.sampled``): its PD's constants as
    #: :mod:`labrig.simulation.sampled_kernel` takes them (``u`` is then the reference in
    #: position units); None: an open loop or a continuous one
    pd: np.ndarray | None = None

    def keep(self) -> np.ndarray:
        """The samples that are measurements (every one unless the link lost some)."""
        return np.ones(len(self.u), bool) if self.measured is None else self.measured

    @classmethod
    def from_run(cls, run) -> "RunData":
        th = run.position
        # start the model where the pot says the shaft is (the rig starts at rest)
        first = np.flatnonzero(run.measured)[: max(1, min(20, len(th) // 50))] \
            if th is not None else None  # a lost sample says nothing of where it starts
        theta0 = float(np.mean(th[first])) if th is not None and len(first) else 0.0
        gains = run.gains or {"kp": 0.0, "kv": 0.0}  # open loop: no feedback
        sampled = (run.controller or {}).get("sampled")
        pd = None if not sampled else pd_constants(sampled)
        return cls(name=run.name, u=run.u.astype(float), dt=run.dt, loop=run.loop, pd=pd,
                   kp=gains["kp"], kv=gains["kv"], **run.constants,
                   w=run.speed, theta=th, theta0=theta0, amplitude=run.amplitude,
                   current=run.current, pos_q=run.pos_quantum, axis=run.axis,
                   measured=run.measured if run.n_gaps else None,
                   speed_window=int(round(run.speed_window_s / run.dt)) if run.has_speed else 0,
                   window_found=bool(run.sensors.get("speed_window_found")),
                   start=run.start)


class _PlantView:
    """What a friction hook may read: R, K (arrays over candidates) and Ka."""

    def __init__(self, R, K, Ka):
        self.R, self.K, self.Ka = R, K, Ka


def prepare(runs) -> list[RunData]:
    return [r if isinstance(r, RunData) else RunData.from_run(r) for r in runs]


#: sub-steps a sample at least, and the longest sub-step (s): a small motor's time constant
#: (tens of ms) is shorter than a slow logger's sample, and a friction sub-stepped coarsely
#: against it reads as a slower motor (16 sub-steps of a 20 Hz sample: tau_m 12 % long)
MIN_SUBSTEPS, MAX_SUBSTEP_S = 16, 1e-3


def substeps_for(runs) -> int:
    """Sub-steps per sample for ``runs``: :data:`MIN_SUBSTEPS`, more where a sample is
    longer than :data:`MAX_SUBSTEP_S` that many times."""
    dt = max((float(r.dt) for r in runs), default=0.0)
    return max(MIN_SUBSTEPS, int(np.ceil(dt / MAX_SUBSTEP_S - 1e-9)))


class Simulator:
    """Simulate P candidates on every run at once.

    Parameters
    ----------
    runs : list of Run or RunData
    effects : list of Effect
        The effects in the model (built-in or user-written).
    substeps : int, optional
        Sub-steps per sample where the ZOH cannot be exact (zero-speed crossings,
        stuck rotor, nonlinear closed loops); default :func:`substeps_for` the runs.
    plant : Plant class, optional
        The kind of plant (:mod:`labrig.model.plants`); default the voltage-driven servo.
    """

    def __init__(self, runs, effects=(), substeps: int | None = None, plant=None):
        ready()  # a cold numba cache is compiled now, with a message, not inside a timing

        self.plant = plant or VoltagePlant
        self.runs = prepare(runs)
        #: a run whose speed is a sensor's window needs the trajectories (sse)
        self._windowed = any(r.speed_window >= 1 for r in self.runs)
        self.effects = ordered(list(effects))
        self._output_mapped = any(e.stage == "output" for e in self.effects)
        self.substeps = int(substeps) if substeps else substeps_for(self.runs)
        # an effect that acts inside a closed loop's drive or on the pot's shaft (or adds a
        # constant drive: a friction larger one way, labrig.model.friction.FrictionCurve)
        self._in_loop = any(e.stage in ("input", "drive") or "a_rad" in e.kernel_columns
                            or hasattr(e, "input_bias") for e in self.effects)
        self._biased = [e for e in self.effects if hasattr(e, "input_bias")]
        for e in self.effects:
            if e.stage in ("input", "drive") and not e.kernel_columns \
                    and type(e).to_kernel is Effect.to_kernel \
                    and any(r.loop == "closed" for r in self.runs):
                raise UserError(f"effect '{e.name}': a user-written {e.stage} effect can only be "
                                "simulated on open-loop runs; leave the closed-loop runs out")

    def _params(self, plant, effect_params):
        """Candidate parameters -> the kernel's (P, N_COLS) table, effect arrays, user outputs."""
        plant = self.plant.kernel(np.asarray(plant, dtype=float))
        P = plant.shape[0]
        prm = np.zeros((P, N_COLS))
        prm[:, :5] = plant[:, :5]
        prm[:, C_KE] = plant[:, 5]
        prm[:, C_VMAX] = np.inf
        ep = {e.name: {k: np.broadcast_to(np.asarray(v, float), (P,))
                       for k, v in (effect_params or {}).get(e.name, {}).items()}
              for e in self.effects}
        user_output = []
        table = _KernelTable(prm)
        view = _PlantView(plant[:, 0], plant[:, 4], self.runs[0].Ka)
        for e in self.effects:
            # the effect says where it lives in the kernel; what the kernel cannot hold
            # (a user's input map, a user's output map) takes the general path
            if not e.to_kernel(table, ep[e.name], view) and e.stage == "output":
                user_output.append(e)
        return prm, ep, user_output

    def simulate(self, plant: np.ndarray, effect_params: dict | None = None,
                 starts: list | None = None) -> list[dict]:
        """Simulate.

        Parameters
        ----------
        plant : array (P, len(plant.names))
            The plant's parameters per candidate (R, L, J, B, K for the voltage plant).
        effect_params : dict
            ``{effect name: {param: array (P,) or scalar}}``.
        starts : list, optional
            Per run, None (from rest, where the first samples say) or ``{"w0": (P,),
            "i0": (P,), "dtheta": (P,)}`` (any may be missing): the speed and current at
            the first sample and the output shaft's offset (:mod:`labrig.model.start`);
            without ``i0`` the current starts in equilibrium with the first drive.

        Returns
        -------
        list of dict, one per run, with ``w``, ``theta`` and ``i`` (the armature current,
        or the drive's torque/force) arrays of shape (P, n).
        """
        prm, ep, user_output = self._params(plant, effect_params)
        disc = {}
        starts = starts or [None] * len(self.runs)
        sims = [self._simulate_run(run, self._started(run, prm, ep, st), ep, user_output, disc)
                for run, st in zip(self.runs, starts)]
        for run, sim in zip(self.runs, sims):
            if run.speed_window >= 1:   # the speed as the sensor reads it
                # (the motor's own angle where no output map bends the pot's shaft)
                exact = None if self._output_mapped else sim["theta"] * run.N
                sim["w"] = windowed_speed(sim["w"], run.speed_window, run.dt, exact)
        return sims

    def sse(self, plant, effect_params, weights, starts: list | None = None) -> np.ndarray:
        """Weighted sum of squared residuals per candidate, without storing trajectories.

        ``weights`` is a list, per run, of ``(w_meas, inv_sigma_w, theta_meas,
        inv_sigma_theta, i_meas, inv_sigma_i)`` (a missing channel has weight 0). This is
        the identifiers' hot path: the kernel accumulates the residuals as it goes.
        """
        prm, ep, user_output = self._params(plant, effect_params)
        if user_output or self._windowed:
            # a user's output map, a sensor's window: the trajectories are needed
            total = np.zeros(prm.shape[0])
            sims = self.simulate(plant, effect_params, starts)
            for run, sim, (wm, iw, tm, it, im, ii) in zip(self.runs, sims, weights):
                total += iw ** 2 * np.sum((wm - sim["w"]) ** 2, axis=1) if iw else 0.0
                total += it ** 2 * np.sum((tm - sim["theta"]) ** 2, axis=1) if it else 0.0
                total += ii ** 2 * np.sum((im - sim["i"]) ** 2, axis=1) if ii else 0.0
            return total
        disc = {}
        total = np.zeros(prm.shape[0])
        for run, wts, st in zip(self.runs, weights, starts or [None] * len(self.runs)):
            total += self._simulate_run(run, self._started(run, prm, ep, st), ep, user_output,
                                        disc, wts)
        return total

    def _started(self, run: RunData, prm, ep, start):
        """``prm`` with the run's initial state (a copy; ``prm`` itself when the run
        starts at rest: the kernels' columns are zeros there)."""
        if not start:
            return prm
        P = prm.shape[0]
        out = prm.copy()
        w0 = np.broadcast_to(np.asarray(start.get("w0", 0.0), float), (P,))
        out[:, C_W0] = w0
        out[:, C_TH0] = np.broadcast_to(np.asarray(start.get("dtheta", 0.0), float), (P,))
        out[:, C_GAP0] = np.broadcast_to(np.asarray(start.get("gap0", 0.0), float), (P,))
        if "i0" in start:      # measured, and fitted (labrig.model.start)
            out[:, C_I0] = np.broadcast_to(np.asarray(start["i0"], float), (P,))
        elif np.any(w0 != 0.0):
            out[:, C_I0] = initial_current(self._first_drive(run, out, ep), w0, out[:, 0],
                                           out[:, C_KE])
        return out

    def _bias(self, ep, P) -> np.ndarray:
        """The constant drive (input volts) of a friction larger one way, per candidate."""
        return sum((e.input_bias(**ep[e.name]) for e in self._biased), np.zeros(P))

    def _first_drive(self, run: RunData, prm, ep) -> np.ndarray:
        """The armature voltage (the kernel's drive) of the first sample per candidate: the
        input through the effects' maps in open loop; in closed loop the linear loop's
        drive from the start state (the current settles within the electrical lag)."""
        P = prm.shape[0]
        u = np.full((1, P), float(run.u[0])) + self._bias(ep, P)[None, :]
        if run.pd is not None:   # the board's first output, on its count or its sensors
            o = first_output(run.pd, float(run.u[0]), run.theta0 + prm[:, C_TH0], prm[:, C_W0])
            u = o[None, :] + self._bias(ep, P)[None, :]
            return np.asarray(self._through_maps(u, ep, run.Ka), float)[0]
        if run.loop == "closed":
            th = (run.theta0 + prm[:, C_TH0])
            return run.Ka * (run.kp * (u[0] - run.Kpot * th) - run.kv * run.Kt * prm[:, C_W0])
        return np.asarray(self._through_maps(u, ep, run.Ka), float)[0]

    def _through_maps(self, e, ep, Ka):
        """Inputs (samples, 1 or candidates) through the input effects, the gain ``Ka`` and
        the drive effects, each candidate with its own parameters (the general path)."""
        for eff in self.effects:
            if eff.stage == "input":
                e = eff.apply(e, **{k: v[None, :] for k, v in ep[eff.name].items()})
        e = e * Ka
        for eff in self.effects:
            if eff.stage == "drive":
                e = eff.apply(e, **{k: v[None, :] for k, v in ep[eff.name].items()})
        return e

    # ------------------------------------------------------------------------------
    def _map_table(self, ep, P):
        """The built-in input and drive effects per candidate, as the kernels apply them
        (:data:`MAP_COLUMNS`); a constant drive enters as an offset."""
        imap = np.zeros((P, len(MAP_COLUMNS)))
        imap[:, MAP_COLUMNS.index("vmax_v")] = np.inf
        for e in self.effects:
            if e.stage in ("input", "drive"):
                for k, v in ep[e.name].items():
                    imap[:, MAP_COLUMNS.index(k)] = v
        imap[:, MAP_COLUMNS.index("u0_v")] += self._bias(ep, P)
        return imap

    def _open_loop_input(self, run: RunData, ep, P):
        """The open-loop drive: the shared input and the candidates' input maps for the
        kernels to apply (built-in effects), or the mapped inputs laid out (samples,
        candidates) for a user's effect."""
        staged = [e for e in self.effects if e.stage in ("input", "drive")]
        bias = self._bias(ep, P)
        if not staged and not self._biased:
            return np.ascontiguousarray(run.u[:, None] * run.Ka), _NO_MAP
        if all(type(e) in _MAPPED for e in staged):
            return np.ascontiguousarray(run.u[:, None], dtype=float), self._map_table(ep, P)
        e = self._through_maps(run.u[:, None] + bias[None, :], ep, run.Ka)  # samples contiguous
        return np.ascontiguousarray(e, dtype=float), _NO_MAP

    def _sampled_run(self, run: RunData, prm, ep, user_output, disc, weights=None):
        """A run of a board's own loop (:mod:`labrig.simulation.sampled_kernel`): the
        plant open loop between samples, driven by the board's law on the model's count."""
        unmapped = user_output + [e for e in self.effects if e.stage in ("input", "drive")
                                  and type(e) not in _MAPPED]
        if unmapped:
            raise UserError(f"effect '{unmapped[0].name}': a user-written effect is not simulated "
                            f"inside a board's loop (run '{run.name}'); fit that run from its "
                            "logged output (through='input')")
        td = prm[:, C_TD]
        m = np.floor(td / run.dt + 1e-9)
        frac = td / run.dt - m
        key = (run.dt, "open", run.Ka, run.N)
        if key not in disc:   # the plant as an open loop shares the open-loop discretisation
            disc[key] = discretise(prm, run, frac)
        Ad, g_old, g_new, gf = disc[key]
        consts = np.array([run.dt, run.Ka, run.N, run.Kt, run.Kpot, 0.0, 0.0, run.theta0])
        return run_sampled(run.u, run.pd, m.astype(np.int64), frac, Ad, g_old, g_new, gf, prm,
                           self.substeps, consts, self._map_table(ep, prm.shape[0]),
                           None if weights is None else _weights_of(weights, len(run.u)))

    def _simulate_run(self, run: RunData, prm, ep, user_output, disc, weights=None):
        if run.pd is not None:
            return self._sampled_run(run, prm, ep, user_output, disc, weights)
        P, n = prm.shape[0], len(run.u)
        closed = run.loop == "closed"
        td = prm[:, C_TD]
        m = np.floor(td / run.dt + 1e-9)
        frac = td / run.dt - m
        key = (run.dt, run.loop, run.Ka, run.kp, run.kv, run.Kt, run.Kpot, run.N)
        # a closed loop with an input or drive effect or backlash inside: every candidate
        # through the loop's affine pieces (decided by the model, not by a candidate's
        # values, so a candidate's result never depends on the population it is in); the
        # linear loop's discretisation is then not used
        mapped = closed and self._in_loop
        if key not in disc:  # runs with the same rate and loop share one discretisation
            disc[key] = discretise(prm, run, frac) if not mapped else (
                np.zeros((P, 3, 3)), np.zeros((P, 3)), np.zeros((P, 3)), np.zeros((P, 3)))
        Ad, g_old, g_new, gf = disc[key]
        imap = _NO_MAP
        table = _NO_TABLE
        if closed:
            s = run.u[:, None]
            if mapped:
                if ("table",) + key not in disc:
                    disc[("table",) + key] = _loop_table(prm, run, frac, self.substeps)
                table = disc[("table",) + key]
            nonlinear = np.full(P, mapped)
        else:
            s, imap = self._open_loop_input(run, ep, P)
            nonlinear = np.zeros(P, dtype=bool)
        consts = np.array([run.dt, run.Ka, run.N, run.Kt, run.Kpot, run.kp, run.kv, run.theta0])
        mi = m.astype(np.int64)
        if weights is not None:
            out = np.zeros(P)
            dummy = np.empty((1, 1))
            run_kernels(s, mi, frac, Ad, g_old, g_new, gf, prm, nonlinear, 1 if closed else 0,
                        self.substeps, consts, dummy, dummy, dummy, False,
                        *_weights_of(weights, n), out, imap, table)
            return out
        w, th, cur = (np.empty((P, n)) for _ in range(3))
        run_kernels(s, mi, frac, Ad, g_old, g_new, gf, prm, nonlinear, 1 if closed else 0,
                    self.substeps, consts, w, th, cur, True, np.zeros(1), 0.0, np.zeros(1), 0.0,
                    np.zeros(1), 0.0, np.zeros(P), imap, table)
        for eff in user_output:  # a user's output map: per sample, vectorised over candidates
            p = {k: v for k, v in ep[eff.name].items()}
            state = th[:, 0].copy()
            for k in range(n):
                state, th[:, k] = eff.output(state, th[:, k], **p)
        return {"w": w, "theta": th, "i": cur}


def _loop_table(prm, run: RunData, frac, substeps: int):
    """The loop table of a closed loop with its input map inside (P, N_SLOTS, SLOT_W): in
    each affine piece of the drive ``v = c - Ka g (kp Kpot theta/N + kv Kt w)`` (g the
    asymmetry's gain for the error's sign, no position term inside a backlash gap, the
    loop open where the drive is flat) the exact ZOH of its own linear loop, the constant
    part ``c`` entering as a voltage. Pieces no candidate can reach are left empty, and
    the - error's slots copy the + ones when no candidate has an asymmetry.

    A current-mode drive (Ke = 0) whose armature is quasi-static at the sub-step (L/R below
    a tenth of it) is marked (``T_OK`` 0) and sub-stepped throughout, as before the
    pieces: the exponential of such a stiff lag needs some 15 squarings, whose rounding
    (1e-9 of the coefficients) made a fit's objective rough, and on such stiff loops the
    truth integrator's own error at 20 sub-steps is above an encoder count, so an exact
    model read effects into it (measured on the linear axis: stiction instead of Coulomb
    friction). A voltage drive's fitted armature as fast (an electrical pole the data do
    not resolve) takes the pieces: its rig is not stiff (docs/physics.md)."""
    P = prm.shape[0]
    A0, bs, bf = plant_matrices(prm)
    R, L = prm[:, 0], prm[:, 1]
    full = ~((L / R < run.dt / substeps / 10.0) & (prm[:, C_KE] == 0.0))
    T = np.zeros((P, N_SLOTS, SLOT_W))
    T[full, S_FLAT, T_OK] = 1.0
    if not full.any():
        return T

    fr, Lc = np.ascontiguousarray(frac, dtype=float), np.ascontiguousarray(L)
    gains = tuple(float(x) for x in (run.Ka, run.kv, run.Kt, run.kp, run.Kpot, run.N))

    def fill(slot, gain, pot):
        loop = gain is not None
        loop_slot_fill(T, slot, A0, bs, bf, fr, float(run.dt), Lc,
                       np.ascontiguousarray(gain) if loop else np.empty(0), *gains, loop, pot,
                       full)

    ak = prm[:, C_ASYM]
    asym = bool(np.any(ak != 0))
    gap = bool(np.any(prm[:, C_A] > 0))
    if np.any(prm[:, C_D] > 0) or np.any(np.isfinite(prm[:, C_VMAX])):
        fill(S_FLAT, None, False)
    for pot, (pos, neg) in ((True, (S_POS, S_NEG)), (False, (S_POS_GAP, S_NEG_GAP))):
        if pot or gap:
            fill(pos, 1.0 + ak, pot)
            if asym:
                fill(neg, 1.0 - ak, pot)
            else:
                T[:, neg, :T_OK] = T[:, pos, :T_OK]
    return T


def _weights_of(weights, n):
    """A run's ``(w, 1/sigma_w, theta, 1/sigma_theta, i, 1/sigma_i)`` as the kernels take
    them: each measured channel contiguous float64 (zeros if missing)."""
    def channel(y):
        return np.zeros(n) if y is None else np.ascontiguousarray(y, dtype=float)

    wm, iw, tm, it, im, ii = weights
    return channel(wm), float(iw), channel(tm), float(it), channel(im), float(ii)
