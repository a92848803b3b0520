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
- closed loops with an input nonlinearity or backlash inside the loop are
  sub-stepped throughout (they are short runs).

The kernel is compiled with numba and runs candidates in parallel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from ..errors import UserError
from .effects import Effect, ordered

# kernel parameter columns: R, L, J, B, K (labrig.model.plants: every plant's kernel
# form), then the effects', then the back-EMF constant Ke (0 for a current-mode drive)
C_D, C_U0, C_ASYM, C_VMAX, C_TC, C_TS, C_A, C_TD, C_KE = range(5, 14)
N_COLS = 14
#: the kernel's effect columns by name: an effect's ``to_kernel`` writes into these
#: (dead zone, input offset, asymmetry, armature rail, kinetic and breakaway friction
#: torque, backlash half gap, delay)
KERNEL_COLUMNS = {"d": C_D, "u0": C_U0, "asym": C_ASYM, "vmax": C_VMAX, "tc": C_TC,
                  "ts": C_TS, "a": C_A, "td": C_TD}


class _KernelTable:
    """Named access to the (P, 14) parameter table for ``Effect.to_kernel``."""

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

    @classmethod
    def from_run(cls, run) -> "RunData":
        th = run.position
        # start the model where the pot says the shaft is (the rig starts at rest)
        theta0 = float(np.mean(th[: max(1, min(20, len(th) // 50))])) if th is not None else 0.0
        gains = run.gains or {"kp": 0.0, "kv": 0.0}  # open loop: no feedback
        return cls(name=run.name, u=run.u.astype(float), dt=run.dt, loop=run.loop,
                   kp=gains["kp"], kv=gains["kv"], **run.constants,
                   w=run.speed, theta=th, theta0=theta0, amplitude=run.amplitude,
                   current=run.current, pos_q=run.pos_quantum, axis=run.axis)


class _PlantView:
    """What a friction hook may read: R, K (arrays over candidates) and Ka."""

    def __init__(self, R, K, Ka):
        self.R, self.K, self.Ka = R, K, Ka


def prepare(runs) -> list[RunData]:
    return [r if isinstance(r, RunData) else RunData.from_run(r) for r in runs]


class Simulator:
    """Simulate P candidates on every run at once.

    Parameters
    ----------
    runs : list of Run or RunData
    effects : list of Effect
        The effects in the model (built-in or user-written).
    substeps : int
        Sub-steps per sample where the ZOH cannot be exact (zero-speed crossings,
        stuck rotor, nonlinear closed loops).
    plant : Plant class, optional
        The kind of plant (:mod:`labrig.model.plants`); default the voltage-driven servo.
    """

    def __init__(self, runs, effects=(), substeps: int = 16, plant=None):
        from .plants import VoltagePlant

        self.plant = plant or VoltagePlant
        self.runs = prepare(runs)
        self.effects = ordered(list(effects))
        self.substeps = int(substeps)
        for e in self.effects:
            if e.stage in ("input", "drive") and not e.kernel_columns \
                    and type(e).to_kernel is Effect.to_kernel \
                    and any(r.loop == "closed" for r in self.runs):
                raise UserError(f"effect '{e.name}': a user-written {e.stage} effect can only be "
                                "simulated on open-loop runs; leave the closed-loop runs out")

    def _params(self, plant, effect_params):
        """Candidate parameters -> the kernel's (P, 14) table, effect arrays, user outputs."""
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

    def simulate(self, plant: np.ndarray, effect_params: dict | None = None) -> list[dict]:
        """Simulate.

        Parameters
        ----------
        plant : array (P, len(plant.names))
            The plant's parameters per candidate (R, L, J, B, K for the voltage plant).
        effect_params : dict
            ``{effect name: {param: array (P,) or scalar}}``.

        Returns
        -------
        list of dict, one per run, with ``w``, ``theta`` and ``i`` (the armature current,
        or the drive's torque/force) arrays of shape (P, n).
        """
        prm, ep, user_output = self._params(plant, effect_params)
        disc = {}
        return [self._simulate_run(run, prm, ep, user_output, disc) for run in self.runs]

    def sse(self, plant, effect_params, weights) -> np.ndarray:
        """Weighted sum of squared residuals per candidate, without storing trajectories.

        ``weights`` is a list, per run, of ``(w_meas, inv_sigma_w, theta_meas,
        inv_sigma_theta, i_meas, inv_sigma_i)`` (a missing channel has weight 0). This is
        the identifiers' hot path: the kernel accumulates the residuals as it goes.
        """
        prm, ep, user_output = self._params(plant, effect_params)
        if user_output:  # a user's output map needs the trajectories
            total = np.zeros(prm.shape[0])
            sims = self.simulate(plant, effect_params)
            for run, sim, (wm, iw, tm, it, im, ii) in zip(self.runs, sims, weights):
                total += iw ** 2 * np.sum((wm - sim["w"]) ** 2, axis=1) if iw else 0.0
                total += it ** 2 * np.sum((tm - sim["theta"]) ** 2, axis=1) if it else 0.0
                total += ii ** 2 * np.sum((im - sim["i"]) ** 2, axis=1) if ii else 0.0
            return total
        disc = {}
        total = np.zeros(prm.shape[0])
        for run, wts in zip(self.runs, weights):
            total += self._simulate_run(run, prm, ep, user_output, disc, wts)
        return total

    # ------------------------------------------------------------------------------
    def _simulate_run(self, run: RunData, prm, ep, user_output, disc, weights=None):
        P, n = prm.shape[0], len(run.u)
        closed = run.loop == "closed"
        td = prm[:, C_TD]
        m = np.floor(td / run.dt + 1e-9)
        frac = td / run.dt - m
        key = (run.dt, run.loop, run.Ka, run.kp, run.kv, run.Kt, run.Kpot, run.N)
        if key not in disc:  # runs with the same rate and loop share one discretisation
            disc[key] = _discretise(prm, run, frac)
        Ad, g_old, g_new, gf = disc[key]
        if closed:
            s = run.u[None, :]
            nonlinear = ((prm[:, C_D] != 0) | (prm[:, C_U0] != 0) | (prm[:, C_ASYM] != 0)
                         | np.isfinite(prm[:, C_VMAX]) | (prm[:, C_A] != 0))
        else:
            e = run.u[None, :]
            for eff in self.effects:
                if eff.stage == "input":
                    e = eff.apply(e, **{k: v[:, None] for k, v in ep[eff.name].items()})
            e = e * run.Ka
            for eff in self.effects:
                if eff.stage == "drive":
                    e = eff.apply(e, **{k: v[:, None] for k, v in ep[eff.name].items()})
            s = np.ascontiguousarray(e, dtype=float)
            nonlinear = np.zeros(P, dtype=bool)
        consts = np.array([run.dt, run.Ka, run.N, run.Kt, run.Kpot, run.kp, run.kv, run.theta0])
        mi = m.astype(np.int64)
        if weights is not None:
            wm, iw, tm, it, im, ii = weights
            out = np.zeros(P)
            dummy = np.empty((1, 1))
            _kernel(s, mi, frac, Ad, g_old, g_new, gf, prm, nonlinear, 1 if closed else 0,
                    self.substeps, consts, dummy, dummy, dummy, False,
                    wm if wm is not None else np.zeros(n), float(iw),
                    tm if tm is not None else np.zeros(n), float(it),
                    im if im is not None else np.zeros(n), float(ii), out)
            return out
        w = np.empty((P, n))
        th = np.empty((P, n))
        cur = np.empty((P, n))
        _kernel(s, mi, frac, Ad, g_old, g_new, gf, prm, nonlinear, 1 if closed else 0,
                self.substeps, consts, w, th, cur, True, np.zeros(1), 0.0, np.zeros(1), 0.0,
                np.zeros(1), 0.0, np.zeros(P))
        for eff in user_output:  # a user's output map: per sample, vectorised over candidates
            p = {k: v for k, v in ep[eff.name].items()}
            state = th[:, 0].copy()
            for k in range(n):
                state, th[:, k] = eff.output(state, th[:, k], **p)
        return {"w": w, "theta": th, "i": cur}


def _discretise(prm, run: RunData, frac):
    """Exact ZOH of the linear part per candidate, with the delay's split sample.

    Inputs of the continuous model: s (armature volts in open loop, reference volts
    in closed loop) and the friction torque Tf.
    """
    P = prm.shape[0]
    R, L, J, B, K = (prm[:, i] for i in range(5))
    A = np.zeros((P, 3, 3))
    A[:, 0, 0], A[:, 0, 1] = -R / L, -prm[:, C_KE] / L
    A[:, 1, 0], A[:, 1, 1] = K / J, -B / J
    A[:, 2, 1] = 1.0
    bs = np.zeros((P, 3))
    bs[:, 0] = 1.0 / L
    if run.loop == "closed":
        # e = kp r - kv Kt w - kp Kpot theta_m / N ; v = Ka e
        A[:, 0, 1] -= run.Ka * run.kv * run.Kt / L
        A[:, 0, 2] -= run.Ka * run.kp * run.Kpot / run.N / L
        bs = bs * run.Ka * run.kp
    bf = np.zeros((P, 3))
    bf[:, 1] = -1.0 / J
    M = np.zeros((P, 5, 5))
    M[:, :3, :3] = A
    M[:, :3, 3] = bs
    M[:, :3, 4] = bf
    h = run.dt
    E2 = _expm_batch(M * ((1.0 - frac) * h)[:, None, None])
    if np.any(frac > 0):
        E1 = _expm_batch(M * (frac * h)[:, None, None])
    else:  # no fractional delay: the first part of the sample is empty
        E1 = np.broadcast_to(np.eye(5), M.shape)
    A1, A2 = E1[:, :3, :3], E2[:, :3, :3]
    Ad = A2 @ A1
    g_old = np.einsum("pij,pj->pi", A2, E1[:, :3, 3])
    g_new = E2[:, :3, 3]
    gf = np.einsum("pij,pj->pi", A2, E1[:, :3, 4]) + E2[:, :3, 4]
    return (np.ascontiguousarray(Ad), np.ascontiguousarray(g_old),
            np.ascontiguousarray(g_new), np.ascontiguousarray(gf))


def _expm_batch(M):
    """Batched expm; threads only pay off for large populations."""
    return _expm_par(M) if M.shape[0] >= 32 else _expm_ser(M)


@numba.njit(cache=True)
def _expm_one(A0):
    n = A0.shape[0]
    nrm = 0.0
    for r in range(n):
        row = 0.0
        for q in range(n):
            row += abs(A0[r, q])
        nrm = max(nrm, row)
    sq = 0
    while nrm > 0.5:
        nrm *= 0.5
        sq += 1
    A = A0 / (2.0 ** sq)
    E = np.eye(n)
    term = np.eye(n)
    for k in range(1, 19):
        term = term @ A / k
        E = E + term
    for _ in range(sq):
        E = E @ E
    return E


@numba.njit(cache=True)
def _expm_ser(M):
    out = np.empty_like(M)
    for p in range(M.shape[0]):
        out[p] = _expm_one(M[p])
    return out


@numba.njit(parallel=True, cache=True)
def _expm_par(M):
    out = np.empty_like(M)
    for p in numba.prange(M.shape[0]):
        out[p] = _expm_one(M[p])
    return out


@numba.njit(cache=True, inline="always")
def _play(play, x, a):
    """The play operator (backlash of half gap a): the output follows x only at the gap's ends."""
    if play < x - a:
        return x - a
    if play > x + a:
        return x + a
    return play


@numba.njit(cache=True)
def _substeps(i, w, th, play, s_old, s_new, frac, prm, closed, S, c):
    """Semi-implicit sub-steps through one sample, Karnopp friction (as the truth)."""
    dt, Ka, N, Kt, Kpot, kp, kv = c[0], c[1], c[2], c[3], c[4], c[5], c[6]
    R, L, J, B, K, Ke = prm[0], prm[1], prm[2], prm[3], prm[4], prm[13]
    d, u0, ak, vmax, tc, ts, a = prm[5], prm[6], prm[7], prm[8], prm[9], prm[10], prm[11]
    h = dt / S
    quasi = L / R < h / 10.0
    for j in range(S):
        s = s_old if j < frac * S - 1e-9 else s_new
        if closed:
            seen = play if a > 0.0 else th / N
            e = kp * (s - Kpot * seen) - kv * Kt * w
            e = e + u0
            if ak != 0.0:
                e = e * (1.0 + ak) if e >= 0.0 else e * (1.0 - ak)
            if d > 0.0:
                e = math.copysign(max(abs(e) - d, 0.0), e)
            v = Ka * e
            if v > vmax:
                v = vmax
            elif v < -vmax:
                v = -vmax
        else:
            v = s
        if quasi:
            i = (v - Ke * w) / R
        else:
            i = (i + h / L * (v - Ke * w)) / (1.0 + h * R / L)
        tnf = K * i - B * w
        if tc > 0.0 or ts > 0.0:
            if w == 0.0:
                if abs(tnf) <= ts:
                    w = 0.0
                else:
                    w = h / J * (tnf - math.copysign(ts, tnf))
            else:
                wn = w + h / J * (tnf - math.copysign(tc, w))
                if wn * w <= 0.0 and abs(tnf) <= ts:
                    wn = 0.0
                w = wn
        else:
            w = w + h / J * tnf
        th = th + h * w
        if a > 0.0:
            play = _play(play, th / N, a)
    return i, w, th, play


@numba.njit(cache=True)
def _candidate(p, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w, out_th,
               out_i, store, wm, iw, tm, it, im, ii, sse):
    """Simulate candidate ``p`` on one run (the loop body of the kernels below)."""
    n = s.shape[1]
    shared = s.shape[0] == 1  # the same input sequence for every candidate
    N = c[2]
    row = np.int64(0)
    if not shared:
        row = np.int64(p)
    acc = 0.0
    i = 0.0
    w = 0.0
    th = c[7] * N
    play = c[7]
    pr = prm[p]
    tc, ts, a = pr[C_TC], pr[C_TS], pr[C_A]
    friction = tc > 0.0 or ts > 0.0
    mp = m[p]
    A = Ad[p]
    a00, a01, a02, a10, a11, a12 = A[0, 0], A[0, 1], A[0, 2], A[1, 0], A[1, 1], A[1, 2]
    a20, a21, a22 = A[2, 0], A[2, 1], A[2, 2]
    gn0, gn1, gn2 = g_new[p, 0], g_new[p, 1], g_new[p, 2]
    go0, go1, go2 = g_old[p, 0], g_old[p, 1], g_old[p, 2]
    gf0, gf1, gf2 = gf[p, 0], gf[p, 1], gf[p, 2]
    delayed = go0 != 0.0 or go1 != 0.0 or go2 != 0.0
    for k in range(n):
        yth = play if a > 0.0 else th / N
        if store:
            out_w[p, k] = w
            out_th[p, k] = yth
            out_i[p, k] = i
        else:
            acc += (iw * (wm[k] - w)) ** 2 + (it * (tm[k] - yth)) ** 2
            if ii != 0.0:
                acc += (ii * (im[k] - i)) ** 2
        ko = k - mp - 1
        kn = k - mp
        s_old = s[row, ko] if ko >= 0 else 0.0
        s_new = s[row, kn] if kn >= 0 else 0.0
        exact = not nonlinear[p] and (w != 0.0 or not friction)
        if not nonlinear[p] and friction and w == 0.0:
            # stuck rotor: only the current moves, exactly, while friction holds
            R, L, K = pr[0], pr[1], pr[4]
            if closed:
                v1 = c[1] * c[5] * (s_old - c[4] * th / N)
                v2 = c[1] * c[5] * (s_new - c[4] * th / N)
            else:
                v1 = s_old
                v2 = s_new
            fr = frac[p]
            i1 = v1 / R + (i - v1 / R) * math.exp(-R * fr * c[0] / L)
            i2 = v2 / R + (i1 - v2 / R) * math.exp(-R * (1.0 - fr) * c[0] / L)
            if abs(K * i1) <= ts and abs(K * i2) <= ts:
                i = i2
                continue
            i, w, th, play = _substeps(i, w, th, play, s_old, s_new, frac[p], pr, closed, S, c)
            continue
        if exact:
            # the generic update, with the terms that are zero for this candidate skipped
            # (the hot path of every identifier: no friction, no delay, open loop)
            ni = a00 * i + a01 * w + gn0 * s_new
            nw = a10 * i + a11 * w + gn1 * s_new
            nt = a20 * i + a21 * w + th + gn2 * s_new
            if closed:
                ni += a02 * th
                nw += a12 * th
                nt += (a22 - 1.0) * th
            if delayed:
                ni += go0 * s_old
                nw += go1 * s_old
                nt += go2 * s_old
            if friction and w != 0.0:
                tf = math.copysign(tc, w)
                ni += gf0 * tf
                nw += gf1 * tf
                nt += gf2 * tf
            if friction and nw * w <= 0.0:
                # the speed reaches zero inside this sample: resolve it finely
                i, w, th, play = _substeps(i, w, th, play, s_old, s_new, frac[p], pr, closed, S, c)
                continue
            i, w, th = ni, nw, nt
            if a > 0.0:
                play = _play(play, th / N, a)
        else:
            i, w, th, play = _substeps(i, w, th, play, s_old, s_new, frac[p], pr, closed, S, c)
    sse[p] = acc


# Two drivers with distinct code (numba's cache would otherwise hand the parallel
# dispatcher the serial build of a shared function). Threads pay off for a swarm; for
# the few rows of a finite-difference Jacobian the wake-up costs more than the work.
@numba.njit(parallel=True, cache=True)
def _kernel_par(s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w, out_th,
                out_i, store, wm, iw, tm, it, im, ii, sse):
    for p in numba.prange(prm.shape[0]):
        _candidate(p, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w,
                   out_th, out_i, store, wm, iw, tm, it, im, ii, sse)


@numba.njit(cache=True)
def _kernel_ser(s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w, out_th,
                out_i, store, wm, iw, tm, it, im, ii, sse):
    for p in range(prm.shape[0]):
        _candidate(p, s, m, frac, Ad, g_old, g_new, gf, prm, nonlinear, closed, S, c, out_w,
                   out_th, out_i, store, wm, iw, tm, it, im, ii, sse)


def _kernel(*args):
    return (_kernel_par if args[7].shape[0] >= 16 else _kernel_ser)(*args)
