"""A run as a rig would record an input candidate: the model's prediction through the
template run's sensors, with seeded noise; and a closed-loop input's gains as a plan
states them."""
from __future__ import annotations

import copy

import numpy as np
import pandas as pd

from labrig.design.inputs import InputCandidate
from labrig.io.runs import Run

#: the rest before a proposed input starts (s)
LEAD_IN_S = 0.5


def loop_keys(cand: InputCandidate, fs: float | None = None) -> dict:
    """A closed-loop input's gains, as a plan states them; with ``fs`` (a run's sidecar)
    a board's own loop adds its controller and law at that rate, as labrig sweep records
    them (labrig.bridge.settings.sampled_pd)."""
    g = cand.gains
    if g is None:
        return {}
    out = {"position_gain": float(g["kp"]), "velocity_gain": float(g["kv"])}
    if fs is not None and "board" in g:
        b = g["board"]
        per = 256.0 / (b["volts_per_count"] * b["counts_per_unit"])   # Q8.8 per V/unit
        out["controller"] = {"kind": "pd", "kp": float(g["kp"]), "kd": float(g["kv"]),
                             "ki": 0.0, "feedback": "position",
                             "sampled": {**b, "kp_q": int(round(g["kp"] * per)),
                                         "kd_q": int(round(g["kv"] * fs * per))}}
    return out


def synthetic_run(template: Run, cand: InputCandidate, name: str, sim: dict | None = None,
                  noise: dict | None = None, rng=None) -> Run:
    """A run of ``cand`` as ``template``'s rig would record it: volts through the same
    sensors, the model's prediction ``sim`` (``w``, ``theta``) plus seeded noise."""
    fs = template.fs
    u = cand.values(fs, LEAD_IN_S)
    n = len(u)
    cols = {"t": np.arange(n) / fs, "u": u}
    w = np.zeros(n) if sim is None else sim["w"]
    th = np.zeros(n) if sim is None else sim["theta"]
    if noise is not None:
        w = w + rng.normal(0.0, noise.get("speed", 0.0), n)
        th = th + rng.normal(0.0, noise.get("position", 0.0), n)
    if template.has_tacho:
        cols["tacho"] = w * template.kt
    elif template.has_speed:  # imported speed: stored as speed, as the template's is
        cols["speed"] = w
    if template.has_pos:
        cols["pos"] = th * template.kpot + template.pos_offset
    meta = copy.deepcopy(template.meta)
    meta["experiment"] = {"loop": cand.loop, "waveform": "pwl", "lead_in_s": LEAD_IN_S,
                          "points": cand.points, **loop_keys(cand, fs)}
    if cand.gains is not None:   # the reference, as the bridge records it
        cols["ref"] = u
    return Run(name=name, data=pd.DataFrame(cols), meta=meta)
