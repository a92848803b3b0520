"""Rig and sweep-plan configuration: TOML files -> validated dataclasses.

Every key is checked: an unknown key or a value out of its physical range is a
``ConfigError`` naming the file and the key, so a typo never silently falls back
to a default.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

from labrig.io.board_pins import check_pins
from labrig.io.experiment import PWL_MAX_POINTS, Experiment
from labrig.core.errors import ConfigError, UserError
from labrig.core.schemas import PlanFile, RigFile, read_toml, validate
from labrig.model.plants import check_axis, plant_class
from labrig.io.mysteryfile import decode
from labrig.model.effects import CATALOGUE, catalogue_name

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
DEFAULT_RIG = CONFIG_DIR / "rig_default.toml"
DEFAULT_PLAN = CONFIG_DIR / "plan_default.toml"


def packaged_config(name: str) -> Path:
    """Configs ship inside the package too, so a wheel install finds them."""
    local = CONFIG_DIR / name
    if local.exists():
        return local
    return Path(__file__).resolve().parents[1] / "configs" / name


# -- the rig --------------------------------------------------------------------

@dataclass
class Plant:
    """Every plant's parameters; the rig's ``drive`` says which are used
    (labrig.model.plants): R..K (voltage), J, B (torque), M, Fv (force)."""

    R: float = 8.0
    L: float = 0.0085
    J: float = 5.2245e-5
    B: float = 1.0e-5
    K: float = 0.05
    M: float = 2.0
    Fv: float = 20.0

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    def values(self, drive: str = "voltage") -> dict:
        """The parameters of the plant ``drive`` names."""
        return {k: getattr(self, k) for k in plant_class(drive).names}


@dataclass
class Amplifier:
    gain: float = 5.0
    output_limit_v: float = 13.0


@dataclass
class Sensors:
    """Per axis unit: rad and rad/s on a rotary axis, m and m/s on a linear one."""

    tacho_v_per_rad_s: float = 0.026   # 0: no tacho
    pos_v_per_rad: float = 0.5
    pos_offset_v: float = -4.0
    #: an encoder instead of the pot: counts per rad (rotary) or per m (linear); 0: a pot
    encoder_counts_per_unit: float = 0.0
    #: a current-sense channel (V per A of armature current); 0: none
    current_v_per_a: float = 0.0
    #: the sense output at zero current: a bidirectional sense amplifier on a 0..5 V ADC
    #: (ACS712, INA240 with its reference at mid-supply) sits at 2.5 V
    current_zero_v: float = 0.0


@dataclass
class BridgeConfig:
    #: the hardware layer the board's firmware is built for: "ms150" (DAC + analog
    #: sensors) or "hbridge" (PWM into an H-bridge, a quadrature encoder)
    firmware: str = "ms150"
    #: H-bridge: PWM resolution (the output word is these bits and a sign), the bridge's
    #: inputs (PWM + DIR, or IN1/IN2), what the off phase does, the encoder's decoding
    #: (edges counted per quadrature cycle) and whether A0 senses the current
    pwm_bits: int = 8
    drive_mode: str = "pwm_dir"
    off_phase: str = "coast"
    decoding: int = 4
    current_sense: bool = False
    #: H-bridge: the counts from one index pulse to the next (a turn of the encoder's own
    #: shaft); 0: no index wired. Each run's pulses are checked against it (lost counts)
    index_counts: int = 0
    sample_rate_hz: float = 1000.0
    output_limit_v: float = 2.5
    dac_bits: int = 12
    dac_range_v: tuple = (-5.0, 5.0)
    adc_bits: int = 10
    adc_range_v: tuple = (-10.0, 10.0)
    watchdog_ms: float = 500.0
    #: a run that lost more than this share of its samples on the link is kept (the lost
    #: ones flagged as gaps) but the command exits 1 naming it
    max_lost_fraction: float = 0.001
    #: trips the board enforces (labrig.bridge.trips): the motor's speed beyond which it
    #: ends a run at 0 V (0: none), and a closed-loop run's position window (None: none)
    trip_speed: float = 0.0
    trip_position: tuple | None = None
    estop: bool = False
    #: the MS150's analog position loop as patched on the rig (the Kp and Kv attenuator
    #: settings): a closed-loop run's gains are these, whatever bridge plays it (None: not
    #: said; a board then refuses closed-loop runs, the simulated rig takes the plan's)
    loop_kp: float | None = None
    loop_kv: float | None = None
    calibration: dict = field(default_factory=dict)
    #: the board the bench is built on ("": not said) and the pins the rig file states it
    #: is wired to, checked against the firmware's map (labrig.io.board_pins)
    board: str = ""
    pins: dict = field(default_factory=dict)

    @property
    def adc_quantum_v(self) -> float:
        lo, hi = self.adc_range_v
        return (hi - lo) / 2 ** self.adc_bits


@dataclass
class Noise:
    tacho_v: float = 0.010
    pos_v: float = 0.004
    current_v: float = 0.005
    seed: int = 1


@dataclass
class RigConfig:
    """A whole rig: plant, amplifier, gear, sensors, bridge, noise and hidden effects."""

    name: str = "rig"
    #: what the input drives (labrig.model.plants) and the axis it moves
    drive: str = "voltage"
    axis: str = "rotary"
    gear_ratio: float = 30.0
    plant: Plant = field(default_factory=Plant)
    amplifier: Amplifier = field(default_factory=Amplifier)
    sensors: Sensors = field(default_factory=Sensors)
    bridge: BridgeConfig = field(default_factory=BridgeConfig)
    noise: Noise = field(default_factory=Noise)
    #: hidden effects of the simulated rig: catalogue name -> {param: value}
    effects: dict = field(default_factory=dict)
    source: str = ""

    @property
    def digital_loop(self) -> bool:
        """A closed loop of this rig is a digital PD on the position in axis units (an
        encoder or no tacho), not the MS150's analog loop on sensor volts."""
        return self.sensors.encoder_counts_per_unit > 0 or self.sensors.tacho_v_per_rad_s == 0

    def board_loop(self, exp) -> bool:
        """``exp`` is a closed loop the MS150 board closes itself, on its pot and tacho."""
        return exp.loop == "closed" and exp.closed_by == "board" and \
            self.bridge.firmware == "ms150" and not self.digital_loop

    def controller_sidecar(self, exp) -> dict | None:
        """The ``experiment.controller`` of a closed-loop run on a digital loop: in the axis's
        units (the MS150 board's loop, on sensor volts, as ``kp Kpot`` V per rad and ``kv Kt
        N`` V per rad/s of the axis)."""
        if exp.loop != "closed" or not (self.digital_loop or self.board_loop(exp)):
            return None
        kp, kd = float(exp.position_gain), float(exp.velocity_gain)
        if self.board_loop(exp):
            s = self.sensors
            kp, kd = kp * s.pos_v_per_rad, kd * s.tacho_v_per_rad_s * self.gear_ratio
        return {"kind": "pd", "kp": kp, "kd": kd, "ki": 0.0, "feedback": "position"}

    def sensors_sidecar(self) -> dict:
        s = self.sensors
        out = {"pos_v_per_rad": s.pos_v_per_rad, "pos_offset_v": s.pos_offset_v}
        if s.tacho_v_per_rad_s > 0:
            out["tacho_v_per_rad_s"] = s.tacho_v_per_rad_s
        if s.encoder_counts_per_unit > 0:  # the pos column holds counts
            out.update(pos_v_per_rad=s.encoder_counts_per_unit, pos_offset_v=0.0,
                       pos_kind="encoder", pos_quantum=1.0 / s.encoder_counts_per_unit)
        if s.current_v_per_a > 0:
            out["current_a_per_v"] = 1.0 / s.current_v_per_a
        return out

    def rig_sidecar(self) -> dict:
        out = {"gear_ratio": self.gear_ratio, "amplifier_gain": self.amplifier.gain,
               "name": self.name}
        if self.drive != "voltage" or self.axis != "rotary":
            out.update(drive=self.drive, axis=self.axis)
        if self.drive != "voltage":
            out["input_gain"] = self.amplifier.gain
        return out


#: TOML key -> dataclass attribute, per section (the TOML names carry the units)
_ATTRS = {
    "rig": {"name": "name", "gear_ratio": "gear_ratio", "drive": "drive", "axis": "axis"},
    "plant": {"R_ohm": "R", "L_h": "L", "J_kgm2": "J", "B_nms_per_rad": "B",
              "K_nm_per_a": "K", "M_kg": "M", "Fv_ns_per_m": "Fv"},
}


def rig_from_dict(doc: dict, path: str = "<rig>") -> RigConfig:
    """Validate a parsed rig document (schema :class:`labrig.core.schemas.RigFile`) and
    build the ``RigConfig``; keys left out keep the dataclass defaults."""
    checked = validate(RigFile, doc, path, ConfigError, section_word=True)
    rig = RigConfig(source=str(path))
    targets = {"rig": rig, "plant": rig.plant, "amplifier": rig.amplifier,
               "sensors": rig.sensors, "bridge": rig.bridge, "noise": rig.noise}
    for sec, obj in targets.items():
        body = getattr(checked, sec)
        if body is None:
            continue
        for key, value in body.model_dump(exclude_unset=True).items():
            if key.endswith("range_v") or key == "trip_position":
                value = (float(value[0]), float(value[1]))
            setattr(obj, _ATTRS.get(sec, {}).get(key, key), value)
    rig.effects = _check_effects(path, checked.effects, rig.bridge.output_limit_v)
    _check_plant(path, rig, checked)
    rig.bridge.pins = check_pins(rig.bridge.firmware, rig.bridge.board, rig.bridge.pins, path)
    if rig.bridge.index_counts and rig.bridge.firmware != "hbridge":
        raise ConfigError(f"{path}: key 'bridge.index_counts': the {rig.bridge.firmware} bridge "
                          "reads no encoder (an index is the H-bridge board's, firmware = "
                          "\"hbridge\"); remove the key")
    _check_rail(path, rig)
    _check_patched_loop(path, rig)
    if rig.bridge.firmware == "hbridge":
        from labrig.io.hbridge_rig import check_rig
        check_rig(rig, path, given=checked.bridge.model_dump(exclude_unset=True)
                  if checked.bridge else {})
    return rig


def _check_rail(path, rig: RigConfig) -> None:
    """The bridge's output limit times the amplifier's gain stays at or below the
    amplifier's rail (an H-bridge's: its supply): a plan at the limit never asks the
    amplifier for more than it can give, where it would clip unseen."""
    b, a = rig.bridge, rig.amplifier
    if b.output_limit_v * a.gain > a.output_limit_v * (1 + 1e-9):
        raise ConfigError(
            f"{path}: key 'bridge.output_limit_v' = {b.output_limit_v:g} V: times the "
            f"amplifier's gain {a.gain:g} it asks {b.output_limit_v * a.gain:g} V of an "
            f"amplifier whose rail is {a.output_limit_v:g} V (amplifier.output_limit_v); set "
            f"it at or below {a.output_limit_v / a.gain:.4g} V")


def _check_patched_loop(path, rig: RigConfig) -> None:
    """The analog loop's gains: the MS150's only (an H-bridge board closes its loop from the
    plan's gains), both or neither."""
    b = rig.bridge
    given = [k for k in ("loop_kp", "loop_kv") if getattr(b, k) is not None]
    if given and b.firmware != "ms150":
        raise ConfigError(f"{path}: key 'bridge.{given[0]}': the {b.firmware} board closes its "
                          "loop itself, from the plan's position_gain and velocity_gain; "
                          "remove the key")
    if len(given) == 1:
        missing = ({"loop_kp", "loop_kv"} - set(given)).pop()
        raise ConfigError(f"{path}: key 'bridge.{given[0]}' without 'bridge.{missing}': the "
                          "patched loop has both gains; add it")


def patched_gains(rig: RigConfig) -> tuple[float, float] | None:
    """The MS150's analog loop gains as patched (``[bridge] loop_kp, loop_kv``), or None."""
    b = rig.bridge
    return None if b.loop_kp is None else (float(b.loop_kp), float(b.loop_kv))


def _patched_plan(where: str, e: dict, rig: RigConfig | None) -> None:
    """A closed-loop experiment on a rig whose loop is patched takes the patch's gains; a
    plan that asks for others is refused: nothing on the rig would apply them. A loop the
    board closes takes the plan's; ``closed_by`` is the MS150's choice."""
    by = e.get("closed_by")
    if by is not None and e.get("loop") != "closed":
        raise ConfigError(f"{where}: closed_by = {by!r} belongs to a closed-loop experiment "
                          "(loop = \"closed\"); remove it")
    if by == "analog" and rig is not None and rig.bridge.firmware != "ms150":
        raise ConfigError(f"{where}: closed_by = \"analog\", but the {rig.bridge.firmware} "
                          "board closes its loop itself; remove the key or write \"board\"")
    gains = patched_gains(rig) if rig is not None else None
    if gains is None or e.get("loop") != "closed" or by == "board":
        return
    for key, patched, knob in (("position_gain", gains[0], "loop_kp"),
                               ("velocity_gain", gains[1], "loop_kv")):
        if key in e and abs(float(e[key]) - patched) > 1e-9:
            raise ConfigError(
                f"{where}: {key} = {float(e[key]):g}, but the rig's loop is patched at "
                f"{patched:g} ([bridge] {knob} in the rig file): the board does not apply a "
                f"plan's gains; turn the patch panel's knob and write {knob} = "
                f"{float(e[key]):g} in the rig file, or leave {key} out of the plan")
        e[key] = patched


def _check_plant(path, rig: RigConfig, checked) -> None:
    """The drive and axis agree, a linear or torque axis has no gear unless stated, and
    only a voltage plant has an armature current to sense."""
    section = checked.rig.model_dump(exclude_unset=True) if checked.rig else {}
    if "axis" not in section:
        rig.axis = "linear" if rig.drive == "force" else "rotary"
    try:
        check_axis(rig.drive, rig.axis, f"{path}: key 'rig.axis'")
    except UserError as exc:
        raise ConfigError(str(exc)) from None
    if rig.drive != "voltage" and "gear_ratio" not in section:
        rig.gear_ratio = 1.0
    if rig.axis == "linear" and rig.gear_ratio != 1.0:
        raise ConfigError(f"{path}: key 'rig.gear_ratio' = {rig.gear_ratio:g}, but a linear axis "
                          "has none (the position is the carriage's, in m); remove it")
    if rig.sensors.current_v_per_a > 0 and rig.drive != "voltage":
        raise ConfigError(f"{path}: key 'sensors.current_v_per_a': a {rig.drive}-driven plant's "
                          "current is its command, not a measurement labrig fits; remove it")
    if rig.sensors.tacho_v_per_rad_s == 0 and rig.sensors.encoder_counts_per_unit == 0 \
            and rig.sensors.pos_v_per_rad == 0:
        raise ConfigError(f"{path}: [sensors] has neither a tacho nor a position sensor")


def rig_to_doc(rig: RigConfig) -> dict:
    """The rig as the full TOML document (every key, defaults filled in)."""
    inverse = {sec: {attr: key for key, attr in m.items()} for sec, m in _ATTRS.items()}
    doc = {"rig": {"name": rig.name, "drive": rig.drive, "axis": rig.axis,
                   "gear_ratio": rig.gear_ratio}}
    for sec in ("plant", "amplifier", "sensors", "bridge", "noise"):
        body = dataclasses.asdict(getattr(rig, sec))
        if sec == "plant":  # only the parameters of the rig's plant
            body = rig.plant.values(rig.drive)
        doc[sec] = {inverse.get(sec, {}).get(k, k): (list(v) if isinstance(v, tuple) else v)
                    for k, v in body.items()
                    if not (k in ("calibration", "board", "pins", "index_counts", "trip_speed",
                                  "trip_position", "estop", "loop_kp", "loop_kv") and not v)}
    doc["effects"] = {k: dict(v) for k, v in rig.effects.items()}
    return doc


def _check_effects(path, body: dict, volts_limit: float = 0.0) -> dict:
    """Hidden effects by catalogue name, every parameter given and within its bounds.

    A threshold in input volts may reach the bridge's own output limit ``volts_limit``
    (a 12 V H-bridge's dead zone is volts wide, an MS150 bridge's a fraction of one).

    A rig file is data: it may name a user effect (FILE.py:Class) only when the user
    trusted that file on the command line (``--trust-code``), because loading it runs it.
    """
    from labrig.model.effects import catalogue_name, get_effect  # late: the catalogue imports config-free code

    out = {}
    for name, params in body.items():
        try:
            eff = get_effect(name, origin=f"{path}: [effects.{name}]")
        except UserError as exc:
            raise ConfigError(str(exc)) from None
        known = {p.name: p for p in eff.params}
        for k, v in params.items():
            if k not in known:
                raise ConfigError(f"{path}: unknown key 'effects.{name}.{k}'; "
                                  f"{name} has {', '.join(sorted(known))}")
            p = known[k]
            upper = max(p.upper, volts_limit) if p.unit == "V" else p.upper
            if not p.lower <= v <= upper:
                raise ConfigError(f"{path}: key 'effects.{name}.{k}' = {v:g} is out of range "
                                  f"[{p.lower:g}, {upper:g}] {p.unit}")
        missing = set(known) - set(params)
        if missing:
            raise ConfigError(f"{path}: [effects.{name}] is missing '{sorted(missing)[0]}'")
        # the catalogue's spelling: the simulator looks the parameters up by it
        out[catalogue_name(name)] = {k: float(v) for k, v in params.items()}
    return out


def load_rig(path: Path | str | None = None) -> RigConfig:
    """Read and validate a rig TOML file (default: configs/rig_default.toml).

    A mystery rig (``*.mystery``, see ``labrig mystery``) is decoded transparently.
    """
    path = Path(path) if path is not None else packaged_config("rig_default.toml")
    if path.suffix == ".mystery":
        return rig_from_dict(decode(path)["rig"], str(path))
    return rig_from_dict(read_toml(path, "rig"), str(path))


# -- sweep plans ----------------------------------------------------------------

#: a plan that asks for more samples than this is a typo (3600 s at 100 kHz would
#: allocate gigabytes and run for minutes): refused before anything moves
MAX_PLAN_SAMPLES = 20_000_000
_STEMS = {"square": "sq", "step": "step", "staircase": "stair", "constant": "const",
          "pwl": "pwl"}


#: each rig family's default plan (``rig.bridge.firmware`` -> a packaged plan): the MS150's
#: is the seed paper's squares and closed-loop steps; an H-bridge gear motor's drives its
#: supply's range at the sketch's 200 Hz (the MS150's +-2.5 V at 1 kHz would barely pass
#: its dead zone, and its closed loops feed back a tacho such a rig does not have)
DEFAULT_PLANS = {"ms150": "plan_default.toml", "hbridge": "plan_arduino.toml"}


def default_plan(rig: RigConfig | None = None) -> Path:
    """The plan a sweep plays when none is given: ``rig``'s family's
    (:data:`DEFAULT_PLANS`); the MS150's without a rig."""
    family = rig.bridge.firmware if rig is not None else "ms150"
    return packaged_config(DEFAULT_PLANS.get(family, DEFAULT_PLANS["ms150"]))


def load_plan(path: Path | str | None = None, rig: RigConfig | None = None) -> list[Experiment]:
    """Read a sweep plan: ``[[experiment]]`` tables; ``amplitudes_v = [...]`` expands
    one table into one experiment per amplitude (schema :class:`labrig.core.schemas.PlanFile`).
    Without ``path``, the rig family's default plan (:func:`default_plan`)."""
    path = Path(path) if path is not None else default_plan(rig)
    doc = read_toml(path, "plan")
    if "experiment" not in doc:
        raise ConfigError(f"{path}: no [[experiment]] tables; a plan needs at least one")
    plan = validate(PlanFile, doc, path, ConfigError)
    defaults = plan.defaults.model_dump(exclude_unset=True) if plan.defaults else {}
    rate = rig.bridge.sample_rate_hz if rig else 1000.0
    out: list[Experiment] = []
    for k, spec in enumerate(plan.experiment, 1):
        own = spec.model_dump(exclude_unset=True)
        raw = {**defaults, **own}
        if raw.get("loop") != "closed" and "closed_by" not in own:
            raw.pop("closed_by", None)   # a default for the plan's closed loops
        amps = raw.pop("amplitudes_v", None)
        raw.setdefault("sample_rate_hz", rate)
        for amp in (amps if amps is not None else [raw.get("amplitude_v", 1.5)]):
            e = dict(raw, amplitude_v=amp)
            if e.get("waveform") == "pwl":
                e["points"] = [list(p) for p in e.get("points") or []]
            if "name" not in e or amps is not None:
                stem = _STEMS[e.get("waveform", "square")]
                prefix = "cl_" if e.get("loop") == "closed" else ""
                e["name"] = f"{prefix}{stem}_{amp:+.2f}V".replace("+", "")
            _patched_plan(f"{path}: experiment {k} ({e['name']})", e, rig)
            out.append(_check_experiment(path, k, e))
    names = [e.name for e in out]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ConfigError(f"{path}: experiment name '{sorted(dup)[0]}' is used twice")
    total = sum(e.n_samples for e in out)
    if total > MAX_PLAN_SAMPLES:
        raise ConfigError(f"{path}: the plan asks for {total:,} samples in all, more than "
                          f"labrig records in one sweep ({MAX_PLAN_SAMPLES:,}); shorten the "
                          "experiments or lower sample_rate_hz")
    return out


def _check_points(where, points, fs) -> None:
    """A pwl waveform's breakpoints: 2..64 of them, times from 0 and rising by at least a
    sample (the firmware's table holds whole samples)."""
    if not points or len(points) < 2:
        raise ConfigError(f"{where}: a pwl waveform needs 'points' = [[t_s, u_v], ...], at "
                          "least two")
    if len(points) > PWL_MAX_POINTS:
        raise ConfigError(f"{where}: {len(points)} breakpoints; a pwl waveform holds at most "
                          f"{PWL_MAX_POINTS}")
    if points[0][0] != 0:
        raise ConfigError(f"{where}: the first breakpoint must be at t = 0 (after the "
                          f"lead-in), got {points[0][0]:g} s")
    for i in range(1, len(points)):
        if points[i][0] - points[i - 1][0] < 1.0 / fs:
            raise ConfigError(f"{where}: breakpoint {i + 1} at {points[i][0]:g} s is not at "
                              f"least one sample after the one before ({points[i - 1][0]:g} "
                              "s); times must rise")


def _check_experiment(path, k, e) -> Experiment:
    """What one key cannot say alone: the waveform's needs and the sampling theorem."""
    where = f"{path}: experiment {k} ({e.get('name')})"
    wave = e.get("waveform", "square")
    if wave == "square" and not e["amplitude_v"] > 0:
        raise ConfigError(f"{where}: a square wave needs amplitude_v > 0, got "
                          f"{e['amplitude_v']:g} (it swings +-amplitude; use offset_v to "
                          "shift it; a step may be negative)")
    if wave == "square":
        f, fs = e.get("frequency_hz", 0.25), e["sample_rate_hz"]
        if f > fs / 10:
            raise ConfigError(f"{where}: frequency_hz = {f:g} is above a tenth of the sample "
                              f"rate ({fs:g} Hz): each half period needs at least 5 samples; "
                              "lower the frequency or raise sample_rate_hz")
    if wave == "staircase" and not e.get("levels"):
        raise ConfigError(f"{where}: a staircase needs 'levels' (a list of volts)")
    if wave == "pwl":
        _check_points(where, e.get("points"), e["sample_rate_hz"])
    elif e.get("points"):
        raise ConfigError(f"{where}: 'points' belong to waveform = \"pwl\"; remove them or "
                          "set the waveform")
    if e.get("between"):
        e["between"] = [catalogue_name(n) for n in e["between"]]  # names in any case
        for name in e["between"]:
            if name not in CATALOGUE:
                raise ConfigError(f"{where}: 'between' names {name!r}, not a catalogue "
                                  f"effect; use {', '.join(sorted(CATALOGUE))}")
    exp = Experiment(**e)
    if exp.n_samples > MAX_PLAN_SAMPLES:
        raise ConfigError(f"{where}: {exp.n_samples:,} samples is more than labrig records "
                          f"in one run ({MAX_PLAN_SAMPLES:,}); shorten it or lower "
                          "sample_rate_hz")
    if exp.n_samples < 2:
        raise ConfigError(f"{where}: lasts {exp.total_s:g} s, under two samples; make it "
                          "longer")
    return exp
