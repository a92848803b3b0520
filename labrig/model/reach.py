"""What the data can see: the input amplitudes, the drive levels, speeds and angles the
runs reach. Threshold effects (a dead zone, a rail, a friction level, a gear gap) have
no gradient while their threshold lies outside this range, so their bounds and their
initial scans come from it (``Effect.data_bounds``, ``Effect.scan_grid``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Reach:
    """The range of every signal a threshold effect acts on.

    Attributes
    ----------
    amin, amax : float
        Smallest open-loop amplitude and largest input the amplifier can see in any
        run (V at the bridge; in closed loop kp times a reference step).
    Ka : float
        Amplifier gain (armature V per bridge V).
    drive_max : float
        Largest armature voltage the input reaches through the model's input effects
        (V); a rail above it is never met.
    speed_max : float
        Largest |speed| measured (rad/s, motor side).
    theta_span : float
        Travel of the output shaft (rad).
    dt : float
        Smallest sample period (s).
    duration : float
        Shortest run (s).
    """

    amin: float
    amax: float
    Ka: float
    drive_max: float
    speed_max: float
    theta_span: float
    dt: float
    duration: float

    @classmethod
    def of(cls, runs, model=None) -> "Reach":
        """From runs (``labrig.io.runs.Run``) and the model the new effect would join."""
        open_amps = [r.amplitude for r in runs if r.loop == "open" and r.amplitude > 0]
        # the amplifier's input: u in open loop; in closed loop the error kp (r - theta),
        # up to kp times a reference step of 2A
        amax = max(float(np.max(np.abs(r.u))) * (1.0 if r.loop == "open" else
                                                  2.0 * (r.gains or {}).get("kp", 1.0))
                   for r in runs)
        amax = max(amax, 1e-3)
        Ka = float(runs[0].constants["Ka"])
        drive = np.array([amax])
        if model is not None:  # the input chain in front of the amplifier
            for e in model.effects:
                if e.stage == "input":
                    p = {k: np.asarray(v, float) for k, v in model.effect_params[e.name].items()}
                    drive = np.maximum(np.abs(e.apply(np.array([amax, -amax]), **p)), 0.0)
                    drive = np.array([float(np.max(drive))])
        speeds = [np.max(np.abs(r.speed)) for r in runs if r.speed is not None]
        if not speeds:
            speeds = [np.max(np.abs(np.gradient(r.position, r.dt))) * r.constants["N"]
                      for r in runs if r.position is not None]
        spans = [np.ptp(r.position) for r in runs if r.position is not None]
        return cls(amin=min(open_amps) if open_amps else amax, amax=amax, Ka=Ka,
                   drive_max=max(float(drive[0]) * Ka, 1e-3),
                   speed_max=float(max(speeds)) if speeds else 1.0,
                   theta_span=float(max(spans)) if spans else 1.0,
                   dt=float(min(r.dt for r in runs)),
                   duration=float(min(len(r.u) * r.dt for r in runs)))
