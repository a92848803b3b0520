"""The simulated rig: the bridge interface backed by the truth integrator.

Hidden effects, sensor noise, ADC/DAC quantisation, clipping and offsets come from
the rig file; everything random is seeded (the rig's noise seed plus a per-
experiment offset), so the same sweep is byte-identical every time.
"""
from __future__ import annotations

import zlib
from dataclasses import replace

import numpy as np

from labrig.core.errors import UserError
from labrig.model.effects import get_effect
from labrig.model.servo import ServoParams
from labrig.model.truth import simulate_truth
from labrig.bridge.base import Bridge, SampleBlock
from labrig.bridge.settings import board_law
from labrig.io.experiment import Experiment


def quantise(v: np.ndarray, bits: int, lo: float, hi: float) -> np.ndarray:
    """What an ADC/DAC of ``bits`` over [lo, hi] makes of ``v`` (clipped, mid-tread)."""
    q = (hi - lo) / 2 ** bits
    code = np.clip(np.round((np.asarray(v) - lo) / q), 0, 2 ** bits - 1)
    return lo + code * q


class SimRig(Bridge):
    """A simulated MS150 rig behind the bridge interface."""

    source = "sim"
    block = 100  # samples per block, like the board's batched frames

    def __init__(self, rig, seed: int | None = None, substeps: int = 20):
        self.rig = rig
        self.seed = rig.noise.seed if seed is None else seed
        self.substeps = substeps
        self.params = ServoParams.from_rig(rig)
        if rig.digital_loop:  # a PD on the position in axis units (RigConfig.digital_loop)
            self.params = replace(self.params, Kpot=1.0, Kt=1.0 / rig.gear_ratio)
        self.effects = [get_effect(n) for n in rig.effects]
        # by the effect's own name: a user effect is keyed "file.py:Class" in the rig file
        self._effect_params = {e.name: rig.effects[n] for e, n in zip(self.effects, rig.effects)}
        self._exp: Experiment | None = None
        self._data: dict | None = None
        self._pos = 0
        self._output_v = 0.0
        self._count = {"samples": 0, "experiments": 0, "run_samples": 0}
        #: how the simulated board ended the run on its own (a trip), None: it did not
        self.trip: dict | None = None

    def open(self) -> dict:
        return {"firmware": "labrig-sim", "capabilities": ["open", "closed", "square", "step",
                                                          "staircase", "constant", "pwl"]}

    def configure(self, exp: Experiment) -> None:
        limit = self.rig.bridge.output_limit_v
        if exp.peak_v() > limit + 1e-9:
            raise UserError(f"experiment '{exp.name}': peak {exp.peak_v():.3g} V exceeds the "
                            f"bridge output limit {limit:g} V (rig bridge.output_limit_v)")
        self._exp = exp
        self._data = None

    def start(self) -> None:
        if self._exp is None:
            raise UserError("start() before configure()")
        self._data = self._acquire(self._exp)
        self._pos = 0
        self.trip = self._tripped(self._exp, self._data)
        self._count["experiments"] += 1
        self._count["run_samples"] = 0   # the sidecar counts this run only

    def read(self, timeout: float = 2.0) -> SampleBlock | None:
        d = self._data
        if d is None or self._pos >= len(d["u"]):
            self._output_v = 0.0
            return None
        s = slice(self._pos, min(self._pos + self.block, len(d["u"])))
        self._pos = s.stop
        self._count["samples"] += s.stop - s.start
        self._count["run_samples"] += s.stop - s.start
        self._output_v = float(d["u"][s.stop - 1])
        part = {k: (d[k][s] if d[k] is not None else None)
                for k in ("tacho", "ref", "current", "drive")}
        return SampleBlock(index=np.arange(s.start, s.stop), u=d["u"][s], pos=d["pos"][s], **part)

    def stop(self) -> None:
        self._data = None
        self.zero()

    def zero(self) -> None:
        self._output_v = 0.0

    @property
    def output_v(self) -> float:
        """The voltage the bridge is applying now (0 V whenever idle)."""
        return self._output_v

    def counters(self) -> dict:
        """The current run's counters (a simulated link loses nothing; a tripped run's
        samples never taken are its lost tail)."""
        c = {"firmware": "labrig-sim", "dropped_samples": 0, "crc_errors": 0,
             "samples": self._count["run_samples"]}
        if self.trip is not None and self._exp is not None:
            c["dropped_samples"] = int(self._exp.n_samples) - (self.trip["after_sample"] + 1)
            c["trip"] = dict(self.trip)
        return c

    def _tripped(self, exp: Experiment, d: dict) -> dict | None:
        """The rig file's trips, checked on the simulated samples as the board checks its
        own (labrig.bridge.trips): the run is cut after the first sample past a limit."""
        from labrig.bridge import trips
        from labrig.bridge.settings import bridge_settings

        s = bridge_settings(self.rig)
        bounds = trips.limits(exp, self.rig, s)
        if bounds is None:
            return None
        if s.firmware == "hbridge":
            counts = d["pos"]
            speed = np.concatenate([[0.0], np.diff(counts)])
            position = counts
        else:
            speed = trips.adc_words(d["tacho"], "tacho", s) if d["tacho"] is not None else None
            position = trips.adc_words(d["pos"], "pos", s)
        hit = trips.first_trip(bounds, speed, position)
        if hit is None:
            return None
        k, why = hit
        for key in ("t", "u", "tacho", "pos", "ref", "current", "drive"):
            if d.get(key) is not None:
                d[key] = d[key][:k + 1]
        return {"fault": "TRIP", "text": trips.TEXTS[why], "after_sample": k}

    # -- the physics behind it ----------------------------------------------------
    def _acquire(self, exp: Experiment) -> dict:
        rig, br = self.rig, self.rig.bridge
        dt = 1.0 / exp.sample_rate_hz
        t = np.arange(exp.n_samples) * dt
        sampled = board_law(exp, rig)
        sensors = bool(sampled) and sampled.get("feedback") == "sensors"
        s = rig.sensors
        if sensors:   # the MS150 board's reference: a pot word, as output rad
            cpu, pz = sampled["counts_per_unit"], sampled["pos_zero"]
            u = (np.round(exp.waveform_at(t) / s.pos_v_per_rad * cpu + pz) - pz) / cpu
        elif sampled:   # the board's reference: whole counts, not a DAC's volts
            cpu = sampled["counts_per_unit"]
            u = np.round(exp.waveform_at(t) * cpu) / cpu
        else:
            u = quantise(exp.waveform_at(t), br.dac_bits, *br.dac_range_v)
        # one stream per experiment name: adding an experiment never changes the others
        rng = np.random.default_rng([self.seed, zlib.crc32(exp.name.encode())])
        lo, hi = br.adc_range_v
        # the noise streams are drawn in the same order whatever the rig has, so adding
        # a channel never changes the others
        n_tacho = rng.normal(0, rig.noise.tacho_v, len(t))
        n_pos = rng.normal(0, rig.noise.pos_v, len(t))
        q = (hi - lo) / 2 ** br.adc_bits
        sim = simulate_truth(self.params, u, dt, effects=self.effects,
                             effect_params=self._effect_params, loop=exp.loop,
                             kp=exp.position_gain, kv=exp.velocity_gain,
                             substeps=self.substeps, rail_v=rig.amplifier.output_limit_v,
                             sampled=sampled, sensor_noise=(n_tacho / q, n_pos / q))
        tacho = None
        if sensors:   # the words the board's loop read are the run's
            tacho, pos = lo + sim["tacho_word"] * q, lo + sim["pos_word"] * q
        elif s.encoder_counts_per_unit > 0:  # counts: exact edges, no analog noise
            pos = np.floor(sim["theta"] * s.encoder_counts_per_unit + 0.5)
        else:
            pos = quantise(s.pos_v_per_rad * sim["theta"] + s.pos_offset_v + n_pos,
                           br.adc_bits, lo, hi)
        if s.tacho_v_per_rad_s > 0 and not sensors:
            tacho = quantise(s.tacho_v_per_rad_s * sim["w"] + n_tacho, br.adc_bits, lo, hi)
        current = None
        if s.current_v_per_a > 0:
            n_cur = rng.normal(0, rig.noise.current_v, len(t))
            current = quantise(s.current_v_per_a * sim["i"] + n_cur, br.adc_bits, lo, hi)
        ref = quantise(u, br.adc_bits, lo, hi) if exp.loop == "closed" and not sampled else None
        return {"t": t, "u": u, "tacho": tacho, "pos": pos, "ref": ref, "current": current,
                "drive": sim.get("drive"), "truth": sim}

