"""Where each run starts: at rest where its first samples say, or in motion, with its
initial state fitted as nuisance parameters beside the model.

A kit's recordings often start in motion (PRBS around an operating point, a step from a
running speed). Simulated from rest, such a run begins with a start-up transient the motor
never had, and the fit spends the model's parameters (or a delay, or a pole) on it. And an
encoder's count says where the shaft is only to within one count: the model started at
the first count is off by up to half a count for the whole run.

So, per run and decided from the data (:func:`run_starts`):

- **speed at the first sample** (``w0``, motor rad/s or m/s) is fitted when the first
  samples show motion: their mean speed (or, without a speed channel, the slope of the
  position) is more than :data:`MOVING_SIGMAS` standard errors from zero;
- **the armature current at the first sample** (``i0``, A) is fitted beside it when the
  model has the current as an output and the run measured it (a voltage drive with a
  current channel). Without a current channel it starts in equilibrium with the first
  sample's drive and speed, ``i0 = (v0 - Ke w0) / R`` (:func:`initial_current`): what the
  speed alone cannot tell apart, as the electrical lag settles within a few ms, well
  inside a sample on every rig here;
- **a position offset** (``dtheta``, at the output shaft, against the position the first
  samples read) is fitted when the run starts in motion (the first samples' mean is not
  where the shaft was at the first one) or the position is an encoder's count (its start
  is unknown within a count);
- **where the motor sits in the gear's play** (``gap0``, a fraction of the half gap from
  -1 to 1, the motor's angle less the output's) when the model has backlash and the run
  starts in motion: the motor leads, the teeth pressed on the side it moves to (``gap0``
  = the sign of its speed; the model's play operator puts them there after any travel),
  held at that value, not fitted. A model started with the gap centred is off by the half
  gap for the whole run (an emulated board's sweep on a busy machine, each run starting
  in the slow coast of the one before, ended with rmse/noise 9 for this alone). A run
  that starts at rest starts centred: where the last reversal left the teeth is unknown,
  and fitting it per run gave a model without backlash a way to absorb other errors.

A run that starts at rest is simulated from rest as before: nothing is fitted and the
fused kernels run as they did. ``mode`` overrides the decision: ``"rest"`` fits nothing,
``"estimate"`` fits both for every run.

The parameters ride in the optimiser's vector as ``start[RUN].w0``, ``start[RUN].i0`` and
``start[RUN].dtheta`` (:func:`start_key`) within a range about the data's own estimate,
``start[RUN].gap0`` held at the data's value, and a model records them per run
(``Model.starts``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from labrig.core.errors import UserError

#: a run is moving at its start when its first samples' mean speed is this many standard
#: errors (of that mean, from the channel's noise floor) away from zero
MOVING_SIGMAS = 5.0
#: the first samples looked at: this long, at least MIN_FIRST samples
FIRST_S = 0.02
MIN_FIRST = 4
#: a position without a speed channel is looked at over the input's first level, up to
#: this long: an encoder's shaft still coasting from the run before moves a count or two
#: in FIRST_S, which its quantisation hides (an emulated board's sweep on a busy machine:
#: 160 counts/s at the start, 5 standard errors over 4 samples, 20 over 20)
FIRST_POS_S = 0.1
#: how a run's start is decided (``--start``)
MODES = ("auto", "rest", "estimate")
#: the parameters of a run's start, in the order of the optimiser's vector
WHAT = ("w0", "i0", "dtheta", "gap0")


def start_key(run: str, what: str) -> str:
    """The flat name of a run's start parameter: ``start[RUN].w0``."""
    return f"start[{run}].{what}"


def parse_key(key: str) -> tuple[str, str] | None:
    """``start[RUN].w0`` -> ``("RUN", "w0")``; None for any other key."""
    if not key.startswith("start[") or "]." not in key:
        return None
    run, what = key[len("start["):].rsplit("].", 1)
    return (run, what) if what in WHAT else None


def is_start_key(key: str) -> bool:
    return parse_key(key) is not None


@dataclass(frozen=True)
class RunStart:
    """A run's start as the data show it, and what is fitted of it.

    ``w0``, ``i0`` and ``dtheta`` are the data's estimates (the middle of their search
    ranges); ``w_span``, ``i_span`` and ``th_span`` the ranges' half widths;
    ``fit_w0``/``fit_i0``/``fit_dtheta`` say which are fitted. ``why`` says it in words."""

    run: str
    moving: bool
    fit_w0: bool
    fit_dtheta: bool
    w0: float = 0.0
    w_span: float = 0.0
    dtheta: float = 0.0
    th_span: float = 0.0
    why: str = ""
    fit_i0: bool = False
    i0: float = 0.0
    i_span: float = 0.0
    #: the motor's place in the gear's play (a fraction of the half gap): held at
    #: ``gap0`` (in the space's names, fixed: :meth:`held`)
    hold_gap0: bool = False
    gap0: float = 0.0

    @property
    def fitted(self) -> bool:
        return self.fit_w0 or self.fit_dtheta

    def params(self) -> list[tuple[str, float, float, float]]:
        """``(key, estimate, lower, upper)`` of each fitted parameter."""
        out = []
        if self.fit_w0:
            out.append((start_key(self.run, "w0"), self.w0, self.w0 - self.w_span,
                        self.w0 + self.w_span))
        if self.fit_i0:
            out.append((start_key(self.run, "i0"), self.i0, self.i0 - self.i_span,
                        self.i0 + self.i_span))
        if self.fit_dtheta:
            out.append((start_key(self.run, "dtheta"), self.dtheta, self.dtheta - self.th_span,
                        self.dtheta + self.th_span))
        if self.hold_gap0:
            out.append((start_key(self.run, "gap0"), self.gap0, -1.0, 1.0))
        return out

    def held(self) -> dict:
        """``{key: value}`` of the start parameters held at the data's value (fixed)."""
        return {start_key(self.run, "gap0"): self.gap0} if self.hold_gap0 else {}


def run_start(run, sigma_w: float | None, sigma_theta: float | None,
              mode: str = "auto", sigma_i: float | None = None, play: bool = False) -> RunStart:
    """Decide one run's start (a :class:`labrig.model.simulate.RunData`): ``mode`` "auto"
    follows the run file (``experiment.start``, labrig import --start) and else the data;
    "rest" and "estimate" override both. ``sigma_i``: the current's noise floor when the
    model has the current as an output (None: the current is not fitted). ``play``: the
    model has backlash (a run in motion starts with the teeth pressed on its side)."""
    declared = getattr(run, "start", "auto")
    if mode == "auto" and declared in ("rest", "moving"):
        mode = "rest" if declared == "rest" else "estimate"
    n_first = max(MIN_FIRST, int(round(FIRST_S / run.dt)))
    idx = np.flatnonzero(run.keep())[:n_first]   # (a lost sample says nothing)
    if mode == "rest" or len(idx) < 2:
        return RunStart(run.name, False, False, False, why="simulated from rest")
    motor = run.N if run.axis == "rotary" else 1.0   # the speed channel is the motor's
    w_est, moving, why = 0.0, False, ""
    if run.w is not None and sigma_w:
        w = run.w[idx]
        se = sigma_w / np.sqrt(len(w))
        moving = abs(np.mean(w)) > MOVING_SIGMAS * se
        w_est = float(np.mean(w[:2]))   # where it starts (the input may switch at once)
        why = (f"the first {len(w)} samples' mean speed is {abs(np.mean(w)) / se:.0f} standard "
               "errors from zero")
    elif run.theta is not None and sigma_theta:
        def slope_of(ix):   # the position's slope over samples ix, and its standard error
            t = ix * run.dt
            slope = float(np.polyfit(t, run.theta[ix], 1)[0])
            return slope, sigma_theta * np.sqrt(12.0 / len(ix)) / max(t[-1] - t[0], run.dt)

        slope, se = slope_of(idx)
        w_est = slope * motor
        moving = abs(slope) > MOVING_SIGMAS * se
        why = f"first {len(idx)} samples' position slope ({abs(slope) / se:.0f} standard errors)"
        changes = np.flatnonzero(np.diff(run.u) != 0.0)   # the input's first level lasts this
        n_pos = min(changes[0] + 1 if len(changes) else len(run.u),
                    int(round(FIRST_POS_S / run.dt)))
        if not moving and n_pos > len(idx):   # a slow coast, seen over the first level
            ix = np.flatnonzero(run.keep())[:n_pos]
            s_long, se_long = slope_of(ix)
            if abs(s_long) > MOVING_SIGMAS * se_long:
                moving = True
                # the first samples' slope says where it starts (a coast slows), the longer
                # one that it moves: the range covers both
                w_est = (slope if abs(slope) > abs(s_long) else s_long) * motor
                why = (f"first {len(ix)} samples' position slope, the input held "
                       f"({abs(s_long) / se_long:.0f} standard errors)")
    if mode == "estimate":
        moving = True
    th = run.theta
    dth, th_span = 0.0, 0.0
    fit_th = th is not None and (moving or run.pos_q > 0)
    if fit_th:
        # the model starts at the first samples' mean (RunData.theta0); a moving shaft was
        # short of it at the first sample by the travel over half the window
        k = max(1, min(20, len(th) // 50))   # as RunData.theta0 averages them
        dth = -float(w_est / motor * run.dt * (k - 1) / 2.0) if moving else 0.0
        th_span = max(run.pos_q, 5.0 * (sigma_theta or 0.0), abs(dth))
    # from standstill to twice the estimate: room for a filtered or quantised first reading
    w_span = max(abs(w_est), 10.0 * (sigma_w or 0.0), 1e-3 * motor) if moving else 0.0
    fit_i = moving and sigma_i is not None and getattr(run, "current", None) is not None
    i_est = float(np.mean(run.current[idx[:2]])) if fit_i else 0.0
    # a reading's worth either side, and room for a current still settling
    i_span = max(abs(i_est), 10.0 * (sigma_i or 0.0)) if fit_i else 0.0
    if moving:
        what = ", ".join(w for w, on in (("speed", True), ("current", fit_i),
                                         ("position", fit_th)) if on)
        text = f"starts in motion ({why}): its {what} at the first sample fitted"
    elif fit_th:
        text = "starts at rest; the encoder's start within a count fitted as a position offset"
    else:
        text = "starts at rest" + (f" ({why})" if why else "")
    # a shaft in motion has the teeth pressed on its side (the motor leads the output)
    hold_gap = bool(play and moving and th is not None and w_est != 0.0)
    if hold_gap:
        text += "; the gear's teeth pressed on the side it moves to"
    return RunStart(run.name, moving, moving, fit_th, w0=w_est if moving else 0.0,
                    w_span=w_span, dtheta=dth, th_span=th_span, why=text, fit_i0=fit_i,
                    i0=i_est, i_span=i_span, hold_gap0=hold_gap,
                    gap0=float(np.sign(w_est)) if hold_gap else 0.0)


def run_starts(runs, sigma_w: float | None, sigma_theta: float | None,
               mode: str = "auto", sigma_i: float | None = None,
               play: bool = False) -> list[RunStart]:
    """Every run's start (prepared runs, the channels' noise floors; ``play``: the model
    has backlash)."""
    if mode not in MODES:
        raise UserError(f"`start_state`: unknown mode '{mode}'; choose {', '.join(MODES)}")
    return [run_start(r, sigma_w, sigma_theta, mode, sigma_i, play) for r in runs]


def initial_current(v0, w0, prm_R, prm_Ke):
    """The armature current in equilibrium with the first sample's drive ``v0`` at the
    speed ``w0`` (arrays over candidates)."""
    return (v0 - prm_Ke * w0) / prm_R


def start_report(starts, values: dict) -> dict:
    """``{run: {"start": "moving" | "rest", "w0": ..., "i0": ..., "dtheta": ..., "why": ...}}`` of
    the runs whose start is fitted, with the fitted values (``values``: flat)."""
    out = {}
    for st in starts:
        if not st.fitted:
            continue
        entry = {"start": "moving" if st.moving else "rest"}
        for what in WHAT:
            key = start_key(st.run, what)
            if key in values:
                entry[what] = float(values[key])
        entry["why"] = st.why
        out[st.run] = entry
    return out


def describe_starts(report: dict, speed_unit: str, position_unit: str) -> str:
    """One line on the runs' fitted starts (``start_report``)."""
    moving = [f"{run} at {e['w0']:.3g} {speed_unit}"
              + (f", {e['i0']:.3g} A" if "i0" in e else "") for run, e in report.items()
              if e.get("start") == "moving" and "w0" in e]
    offset = [run for run, e in report.items() if e.get("start") == "rest" and "dtheta" in e]
    parts = []
    if moving:
        parts.append("runs that start in motion, their state at the first sample fitted: "
                     + ", ".join(moving))
    if offset:
        parts.append(f"{len(offset)} run(s) at rest whose encoder start within a count is "
                     f"fitted as a position offset ({position_unit})")
    return "; ".join(parts) + " (labrig import --start rest, or identify --start rest, " \
        "simulates from rest)"
