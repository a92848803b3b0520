"""Rig and sweep-plan configuration: TOML files -> validated dataclasses.

Every key is checked: an unknown key or a value out of its physical range is a
``ConfigError`` naming the file and the key, so a typo never silently falls back
to a default.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .bridge.base import Experiment
from .errors import ConfigError

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"
DEFAULT_RIG = CONFIG_DIR / "rig_default.toml"
DEFAULT_PLAN = CONFIG_DIR / "plan_default.toml"


def _packaged(name: str) -> Path:
    """Configs ship inside the package too, so a wheel install finds them."""
    local = CONFIG_DIR / name
    if local.exists():
        return local
    return Path(__file__).resolve().parent / "configs" / name


# -- the rig --------------------------------------------------------------------

@dataclass
class Plant:
    R: float = 8.0
    L: float = 0.0085
    J: float = 5.2245e-5
    B: float = 1.0e-5
    K: float = 0.05

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class Amplifier:
    gain: float = 5.0
    output_limit_v: float = 13.0


@dataclass
class Sensors:
    tacho_v_per_rad_s: float = 0.026
    pos_v_per_rad: float = 0.5
    pos_offset_v: float = -4.0


@dataclass
class BridgeConfig:
    sample_rate_hz: float = 1000.0
    output_limit_v: float = 2.5
    dac_bits: int = 12
    dac_range_v: tuple = (-5.0, 5.0)
    adc_bits: int = 10
    adc_range_v: tuple = (-10.0, 10.0)
    watchdog_ms: float = 500.0
    calibration: dict = field(default_factory=dict)

    @property
    def adc_quantum_v(self) -> float:
        lo, hi = self.adc_range_v
        return (hi - lo) / 2 ** self.adc_bits


@dataclass
class Noise:
    tacho_v: float = 0.010
    pos_v: float = 0.004
    seed: int = 1


@dataclass
class RigConfig:
    """A whole rig: plant, amplifier, gear, sensors, bridge, noise and hidden effects."""

    name: str = "rig"
    gear_ratio: float = 30.0
    plant: Plant = field(default_factory=Plant)
    amplifier: Amplifier = field(default_factory=Amplifier)
    sensors: Sensors = field(default_factory=Sensors)
    bridge: BridgeConfig = field(default_factory=BridgeConfig)
    noise: Noise = field(default_factory=Noise)
    #: hidden effects of the simulated rig: catalogue name -> {param: value}
    effects: dict = field(default_factory=dict)
    source: str = ""

    def sensors_sidecar(self) -> dict:
        return dataclasses.asdict(self.sensors)

    def rig_sidecar(self) -> dict:
        return {"gear_ratio": self.gear_ratio, "amplifier_gain": self.amplifier.gain,
                "name": self.name}


# key -> (attribute, lower, upper); bounds are physical plausibility, not taste
_SCHEMA = {
    "rig": {"name": ("name", None, None), "gear_ratio": ("gear_ratio", 0.01, 1e4)},
    "plant": {"R_ohm": ("R", 1e-3, 1e4), "L_h": ("L", 1e-7, 10.0),
              "J_kgm2": ("J", 1e-10, 10.0), "B_nms_per_rad": ("B", 0.0, 10.0),
              "K_nm_per_a": ("K", 1e-5, 100.0)},
    "amplifier": {"gain": ("gain", 1e-3, 1e3), "output_limit_v": ("output_limit_v", 0.01, 1e3)},
    "sensors": {"tacho_v_per_rad_s": ("tacho_v_per_rad_s", 1e-6, 100.0),
                "pos_v_per_rad": ("pos_v_per_rad", 1e-6, 1e3),
                "pos_offset_v": ("pos_offset_v", -100.0, 100.0)},
    "bridge": {"sample_rate_hz": ("sample_rate_hz", 1.0, 1e5),
               "output_limit_v": ("output_limit_v", 0.0, 50.0),
               "dac_bits": ("dac_bits", 1, 24), "dac_range_v": ("dac_range_v", None, None),
               "adc_bits": ("adc_bits", 1, 24), "adc_range_v": ("adc_range_v", None, None),
               "watchdog_ms": ("watchdog_ms", 1.0, 60000.0),
               "calibration": ("calibration", None, None)},
    "noise": {"tacho_v": ("tacho_v", 0.0, 10.0), "pos_v": ("pos_v", 0.0, 10.0),
              "seed": ("seed", 0, 2 ** 32 - 1)},
}
_CALIBRATION_KEYS = {f"{ch}_{k}" for ch in ("dac", "tacho", "pos", "ref")
                     for k in ("gain", "offset_v")}


def _read_toml(path: Path | str, what: str) -> dict:
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: {what} file not found")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc}); fix the syntax") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text TOML file") from None


def _check_value(path, key, value, lo, hi):
    if lo is None:
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{path}: key '{key}' must be a number, got {value!r}")
    if not math.isfinite(value) or value < lo or value > hi:
        raise ConfigError(f"{path}: key '{key}' = {value} is out of range [{lo:g}, {hi:g}]")
    return value


def rig_from_dict(doc: dict, path: str = "<rig>") -> RigConfig:
    """Validate a parsed rig document and build the ``RigConfig``."""
    rig = RigConfig(source=str(path))
    sections = {"rig": rig, "plant": rig.plant, "amplifier": rig.amplifier,
                "sensors": rig.sensors, "bridge": rig.bridge, "noise": rig.noise}
    for sec, body in doc.items():
        if sec == "effects":
            rig.effects = _check_effects(path, body)
            continue
        if sec not in _SCHEMA:
            raise ConfigError(f"{path}: unknown section [{sec}]; expected one of "
                              f"{', '.join(sorted(list(_SCHEMA) + ['effects']))}")
        if not isinstance(body, dict):
            raise ConfigError(f"{path}: [{sec}] must be a table")
        for key, value in body.items():
            if key not in _SCHEMA[sec]:
                raise ConfigError(f"{path}: unknown key '{sec}.{key}'; expected one of "
                                  f"{', '.join(sorted(_SCHEMA[sec]))}")
            attr, lo, hi = _SCHEMA[sec][key]
            value = _check_value(path, f"{sec}.{key}", value, lo, hi)
            if key.endswith("range_v"):
                if (not isinstance(value, list) or len(value) != 2
                        or not all(isinstance(v, (int, float)) for v in value)
                        or value[0] >= value[1]):
                    raise ConfigError(f"{path}: key '{sec}.{key}' must be [low, high] volts "
                                      f"with low < high, got {value!r}")
                value = (float(value[0]), float(value[1]))
            if key == "calibration":
                bad = set(value) - _CALIBRATION_KEYS
                if bad:
                    raise ConfigError(f"{path}: unknown key 'bridge.calibration.{sorted(bad)[0]}';"
                                      f" expected one of {', '.join(sorted(_CALIBRATION_KEYS))}")
            setattr(sections[sec], attr, value)
    return rig


def _check_effects(path, body) -> dict:
    from .model.effects import get_effect  # late: the catalogue imports config-free code

    if not isinstance(body, dict):
        raise ConfigError(f"{path}: [effects] must be a table of effect tables")
    out = {}
    for name, params in body.items():
        try:
            eff = get_effect(name)
        except Exception as exc:
            raise ConfigError(f"{path}: [effects.{name}]: {exc}") from None
        params = dict(params or {})
        known = {p.name for p in eff.params}
        for k, v in params.items():
            if k not in known:
                raise ConfigError(f"{path}: unknown key 'effects.{name}.{k}'; "
                                  f"{name} has {', '.join(sorted(known))}")
            p = next(p for p in eff.params if p.name == k)
            _check_value(path, f"effects.{name}.{k}", v, p.lower, p.upper)
        missing = known - set(params)
        if missing:
            raise ConfigError(f"{path}: [effects.{name}] is missing '{sorted(missing)[0]}'")
        out[name] = {k: float(v) for k, v in params.items()}
    return out


def load_rig(path: Path | str | None = None) -> RigConfig:
    """Read and validate a rig TOML file (default: configs/rig_default.toml).

    A mystery rig (``*.mystery``, see ``labrig mystery``) is decoded transparently.
    """
    path = Path(path) if path is not None else _packaged("rig_default.toml")
    if path.suffix == ".mystery":
        from .mystery import read_mystery  # noqa: WPS433 (optional feature)

        return rig_from_dict(read_mystery(path), str(path))
    return rig_from_dict(_read_toml(path, "rig"), str(path))


# -- sweep plans ----------------------------------------------------------------

_EXP_KEYS = {f.name for f in dataclasses.fields(Experiment)} | {"amplitudes_v"}


def load_plan(path: Path | str | None = None, rig: RigConfig | None = None) -> list[Experiment]:
    """Read a sweep plan: ``[[experiment]]`` tables; ``amplitudes_v = [...]`` expands
    one table into one experiment per amplitude."""
    path = Path(path) if path is not None else _packaged("plan_default.toml")
    doc = _read_toml(path, "plan")
    defaults = doc.pop("defaults", {})
    exps = doc.pop("experiment", None)
    if doc:
        raise ConfigError(f"{path}: unknown key '{sorted(doc)[0]}'; a plan has "
                          "[defaults] and [[experiment]] tables")
    if not exps:
        raise ConfigError(f"{path}: no [[experiment]] tables; a plan needs at least one")
    rate = rig.bridge.sample_rate_hz if rig else 1000.0
    out: list[Experiment] = []
    for k, raw in enumerate(exps, 1):
        raw = {**defaults, **raw}
        for key in raw:
            if key not in _EXP_KEYS:
                raise ConfigError(f"{path}: experiment {k}: unknown key '{key}'; expected one "
                                  f"of {', '.join(sorted(_EXP_KEYS))}")
        amps = raw.pop("amplitudes_v", None)
        raw.setdefault("sample_rate_hz", rate)
        for amp in (amps if amps is not None else [raw.get("amplitude_v", 1.5)]):
            e = dict(raw, amplitude_v=amp)
            if "name" not in e or amps is not None:
                stem = {"square": "sq", "step": "step", "staircase": "stair",
                        "constant": "const"}.get(e.get("waveform", "square"), "exp")
                prefix = "cl_" if e.get("loop") == "closed" else ""
                e["name"] = f"{prefix}{stem}_{amp:+.2f}V".replace("+", "")
            out.append(_check_experiment(path, k, e))
    names = [e.name for e in out]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ConfigError(f"{path}: experiment name '{sorted(dup)[0]}' is used twice")
    return out


def _check_experiment(path, k, e) -> Experiment:
    where = f"{path}: experiment {k} ({e.get('name')})"
    if e.get("loop", "open") not in ("open", "closed"):
        raise ConfigError(f"{where}: key 'loop' must be 'open' or 'closed', got {e['loop']!r}")
    if e.get("waveform", "square") not in ("square", "step", "staircase", "constant"):
        raise ConfigError(f"{where}: key 'waveform' must be square, step, staircase or "
                          f"constant, got {e['waveform']!r}")
    for key, lo, hi in (("amplitude_v", -50, 50), ("frequency_hz", 1e-3, 1e3),
                        ("offset_v", -50, 50), ("lead_in_s", 0, 3600), ("periods", 0.01, 1e4),
                        ("step_s", 1e-3, 3600), ("sample_rate_hz", 1, 1e5),
                        ("position_gain", 0, 1e4), ("velocity_gain", 0, 1e4)):
        if key in e:
            _check_value(where, key, e[key], lo, hi)
    if e.get("duration_s") is not None:
        _check_value(where, "duration_s", e["duration_s"], 1e-3, 3600)
    if e.get("waveform") == "staircase" and not e.get("levels"):
        raise ConfigError(f"{where}: a staircase needs 'levels' (a list of volts)")
    return Experiment(**e)
