"""Declared schemas of every file a user hands in, validated once at the boundary.

One pydantic model per file kind: the rig TOML, the sweep-plan TOML, the model JSON and
the identify config (the run sidecar, ``*.json`` beside a run's CSV, is declared in
:mod:`labrig.core.sidecar_schema`). Types are strict (a number is a number, never the string ``"1.0"``; ``true`` is not 1), every
float is finite, and every value has its physical range. A failure becomes one line
naming the file, the key, what is wrong and the accepted range or type; inside
labrig the validated data is then trusted.

Nothing here runs code: effect names are plain strings until
:mod:`labrig.model.effects` decides whether a file may name a user effect.
"""
from __future__ import annotations

import difflib
import json
import re
import tomllib
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field,
                      ValidationError, model_validator)

from labrig.core.errors import ConfigError, UserError
from labrig.core.fileio import size_within

#: a JSON file a user hands in is small (a model, a sidecar); a bigger one is a mistake
MAX_JSON_BYTES = 8 * 1024 * 1024
#: run names: letters, digits and ``_ . + -``, not starting with a dot; they become file
#: names, so nothing that could climb out of the output folder (``/``, ``..``)
#: the longest run name (characters)
RUN_NAME_MAX = 100
RUN_NAME_RE = re.compile(r"[A-Za-z0-9_+\-][A-Za-z0-9_.+\-]{0,%d}" % (RUN_NAME_MAX - 1))
RUN_NAME_RULE = ("a run name uses letters, digits and _ . + - only, does not start with "
                 f"a dot and has at most {RUN_NAME_MAX} characters")


def check_run_name(name: Any, where: str = "run name") -> str:
    """``name`` if it is a safe run name, else a one-line :class:`UserError`."""
    if not isinstance(name, str) or not RUN_NAME_RE.fullmatch(name):
        raise UserError(f"{where}: {name!r} is not a valid run name; {RUN_NAME_RULE}")
    return name


def _safe_name(v: str) -> str:
    if not RUN_NAME_RE.fullmatch(v):
        raise ValueError(f"not a valid run name; {RUN_NAME_RULE}")
    return v


def Num(ge=None, le=None, gt=None, lt=None):
    """A strict, finite float with physical bounds."""
    return Annotated[float, Field(ge=ge, le=le, gt=gt, lt=lt, allow_inf_nan=False)]


def _nonzero_gain(v: float) -> float:
    if not 1e-9 <= abs(v) <= 1e6:
        raise ValueError("must be a nonzero gain with 1e-9 <= |value| <= 1e6")
    return v


def _range_pair(v: list) -> list:
    if len(v) != 2 or not v[0] < v[1]:
        raise ValueError("must be [low, high] with low < high")
    return v


Gain = Annotated[float, Field(allow_inf_nan=False), AfterValidator(_nonzero_gain)]
RangeV = Annotated[list[Num(-1e3, 1e3)], AfterValidator(_range_pair)]

RunName = Annotated[str, AfterValidator(_safe_name)]
Int32 = Annotated[int, Field(ge=0, le=2 ** 32 - 1)]


class ClosedModel(BaseModel):
    """Every key declared: a misspelt key is an error, never a silent default."""

    model_config = ConfigDict(extra="forbid", strict=True)


# -- rig TOML ---------------------------------------------------------------------------
# Sections only declare what may be written; the defaults live in labrig.io.config's
# dataclasses (one place), and a key left out keeps its default there.

class RigSection(ClosedModel):
    name: Optional[str] = None
    drive: Optional[Literal["voltage", "torque", "force"]] = None
    axis: Optional[Literal["rotary", "linear"]] = None
    gear_ratio: Num(0.01, 1e4) = None


class PlantSection(ClosedModel):
    R_ohm: Num(1e-3, 1e4) = None
    L_h: Num(1e-7, 10.0) = None
    J_kgm2: Num(1e-10, 10.0) = None
    B_nms_per_rad: Num(0.0, 10.0) = None
    K_nm_per_a: Num(1e-5, 100.0) = None
    M_kg: Num(1e-4, 1e5) = None
    Fv_ns_per_m: Num(0.0, 1e6) = None


class AmplifierSection(ClosedModel):
    gain: Num(1e-3, 1e3) = None
    output_limit_v: Num(0.01, 1e3) = None


class SensorsSection(ClosedModel):
    tacho_v_per_rad_s: Num(0.0, 100.0) = None      # 0: no tacho
    pos_v_per_rad: Num(1e-6, 1e3) = None
    pos_offset_v: Num(-100.0, 100.0) = None
    encoder_counts_per_unit: Num(0.0, 1e9) = None   # 0: a pot
    current_v_per_a: Num(0.0, 1e3) = None           # 0: no current sense
    current_zero_v: Num(-100.0, 100.0) = None       # the sense output at zero current


class CalibrationSection(ClosedModel):
    dac_gain: Num(0.01, 100.0) = None
    dac_offset_v: Num(-50.0, 50.0) = None
    tacho_gain: Num(0.01, 100.0) = None
    tacho_offset_v: Num(-50.0, 50.0) = None
    pos_gain: Num(0.01, 100.0) = None
    pos_offset_v: Num(-50.0, 50.0) = None
    ref_gain: Num(0.01, 100.0) = None
    ref_offset_v: Num(-50.0, 50.0) = None


def _lower(v):
    """Keywords in any case ("Open", "SQUARE"), as names are on the command line."""
    return v.lower() if isinstance(v, str) else v


class BridgeSection(ClosedModel):
    #: the hardware layer: the MS150 bridge or an H-bridge board (labrig.bridge.hbridge)
    firmware: Annotated[Optional[Literal["ms150", "hbridge"]], BeforeValidator(_lower)] = None
    pwm_bits: Annotated[int, Field(ge=1, le=16)] = None
    drive_mode: Annotated[Optional[Literal["pwm_dir", "in1_in2"]], BeforeValidator(_lower)] = None
    off_phase: Annotated[Optional[Literal["coast", "brake"]], BeforeValidator(_lower)] = None
    decoding: Optional[Literal[1, 2, 4]] = None
    current_sense: Optional[bool] = None
    #: counts from one index pulse to the next (a turn of its shaft); 0 or left out: none
    index_counts: Annotated[int, Field(ge=0, le=10_000_000)] = None
    sample_rate_hz: Num(1.0, 1e5) = None
    output_limit_v: Num(0.0, 50.0) = None
    dac_bits: Annotated[int, Field(ge=1, le=24)] = None
    dac_range_v: RangeV = None
    adc_bits: Annotated[int, Field(ge=1, le=24)] = None
    adc_range_v: RangeV = None
    watchdog_ms: Num(1.0, 2000.0) = None            # host silence: the board stops within it
    max_lost_fraction: Num(0.0, 1.0) = None          # a run losing more exits 1
    #: trips the board enforces (labrig.bridge.trips): the motor's speed (0: none), a
    #: closed-loop run's position window, an E-stop wired to D7
    trip_speed: Num(0.0, 1e6) = None
    trip_position: RangeV = None
    estop: Optional[bool] = None
    loop_kp: Num(0.0, 1e4) = None   # the MS150's analog loop as patched (labrig.io.config)
    loop_kv: Num(0.0, 1e4) = None
    calibration: CalibrationSection = None
    #: the board the bench is built on, and the pins it is wired to (checked against the
    #: firmware's map: labrig.io.board_pins); a board that greets as another is refused
    board: Annotated[Optional[Literal["uno", "nano", "mega"]], BeforeValidator(_lower)] = None
    pins: Annotated[dict[Annotated[str, Field(max_length=16)],
                         Union[int, Annotated[str, Field(max_length=8)]]],
                    Field(max_length=16)] = None


class NoiseSection(ClosedModel):
    tacho_v: Num(0.0, 10.0) = None
    pos_v: Num(0.0, 10.0) = None
    current_v: Num(0.0, 10.0) = None
    seed: Int32 = None


class RigFile(ClosedModel):
    rig: Optional[RigSection] = None
    plant: Optional[PlantSection] = None
    amplifier: Optional[AmplifierSection] = None
    sensors: Optional[SensorsSection] = None
    bridge: Optional[BridgeSection] = None
    noise: Optional[NoiseSection] = None
    #: effect name -> {param: value}; names and ranges are checked against the catalogue
    effects: dict[str, dict[str, Num(-1e6, 1e6)]] = {}


# -- sweep plan -------------------------------------------------------------------------

class ExperimentSpec(ClosedModel):
    name: RunName = None
    loop: Annotated[Optional[Literal["open", "closed"]], BeforeValidator(_lower)] = None
    #: who closes an MS150's loop: its analog loop as patched, or the board on its sensors
    closed_by: Annotated[Optional[Literal["analog", "board"]], BeforeValidator(_lower)] = None
    waveform: Annotated[Optional[Literal["square", "step", "staircase", "constant", "pwl"]],
                        BeforeValidator(_lower)] = None
    amplitude_v: Num(-50, 50) = None
    amplitudes_v: Annotated[list[Num(-50, 50)], Field(min_length=1, max_length=1000)] = None
    frequency_hz: Num(1e-3, 1e3) = None
    offset_v: Num(-50, 50) = None
    lead_in_s: Num(0, 3600) = None
    periods: Num(0.01, 1e4) = None
    duration_s: Num(1e-3, 3600) = None
    levels: Annotated[list[Num(-50, 50)], Field(max_length=10000)] = None
    step_s: Num(1e-3, 3600) = None
    sample_rate_hz: Num(1, 1e5) = None
    position_gain: Num(0, 1e4) = None
    velocity_gain: Num(0, 1e4) = None
    #: the two effects a proposed experiment tells apart (labrig propose): catalogue names
    between: Annotated[list[Annotated[str, Field(pattern=r"^[A-Za-z_]{1,40}$")]],
                       Field(min_length=2, max_length=2)] = None
    #: pwl breakpoints [[t_s, u_v], ...] (labrig.io.config checks order and count)
    points: Annotated[list[Annotated[list[Num(-3600, 3600)], Field(min_length=2, max_length=2)]],
                      Field(max_length=1000)] = None


class PlanFile(ClosedModel):
    defaults: Optional[ExperimentSpec] = None
    experiment: Annotated[list[ExperimentSpec], Field(min_length=1, max_length=1000)]


# -- model JSON -------------------------------------------------------------------------

class PlantParams(ClosedModel):
    """Every plant's parameters; which are required depends on the model's structure."""

    R: Num(gt=0, le=1e6) = None
    L: Num(gt=0, le=1e3) = None
    J: Num(gt=0, le=1e3) = None
    B: Num(gt=0, le=1e3) = None
    K: Num(gt=0, le=1e3) = None
    M: Num(gt=0, le=1e6) = None
    Fv: Num(gt=0, le=1e7) = None


class ModelConstants(ClosedModel):
    Ka: Num(gt=0, le=1e5) = None
    N: Num(gt=0, le=1e5) = None
    Kt: Gain = None
    Kpot: Gain = None
    kp: Num(0, 1e6) = None
    kv: Num(0, 1e6) = None


EffectName = Annotated[str, Field(min_length=1, max_length=300)]


class ModelFile(ClosedModel):
    """A model file: every key declared (a misspelt ``efects`` is an error, not a model
    without effects)."""

    format: str
    structure: Optional[str] = None
    method: Optional[str] = None
    effects: Annotated[list[EffectName], Field(max_length=50)] = []
    params: PlantParams
    effect_params: dict[EffectName, dict[str, Num(-1e9, 1e9)]] = {}
    #: each run's fitted start (labrig.model.start): its motor speed at the first sample
    #: and its output shaft's offset
    starts: Annotated[dict[RunName,
                           dict[Literal["w0", "i0", "dtheta", "gap0"], Num(-1e9, 1e9)]],
                      Field(max_length=10000)] = {}
    constants: Optional[ModelConstants] = None
    # what the fit reported: shown, never computed with; NaN is allowed (a failed fit)
    fitness: Optional[float] = None
    rmse_over_noise: Optional[float | dict[str, Optional[float]]] = None
    fit_percent: Optional[float | dict[str, Any]] = None
    noise: Optional[dict[str, Any]] = None
    seed: Optional[Any] = None
    nfev: Optional[Any] = None
    identifiable: Optional[Any] = None
    dataset: Optional[Any] = None
    #: free text for the user's own notes, never read by labrig
    notes: Optional[Any] = None

    @model_validator(mode="after")
    def _params_for_named_effects(self):
        named = {e.lower() for e in self.effects}  # effect names in any case
        for name in self.effect_params:
            if name.lower() not in named and not any(":" in e for e in self.effects):
                raise ValueError(f"effect_params names '{name}', which is not in 'effects'")
        return self


class IdentifyConfig(ClosedModel):
    bounds: dict[str, Annotated[list[Num(-1e9, 1e9)], AfterValidator(_range_pair)]] = {}
    fixed: dict[str, Num(-1e9, 1e9)] = {}
    effects: Annotated[list[EffectName], Field(max_length=50)] = []


# -- reading and reporting ----------------------------------------------------------------

def read_toml(path: Path | str, what: str) -> dict:
    """Parse a user's TOML file, or raise one line: not found, too big, not TOML."""
    path = Path(path)
    size_within(path, 1_000_000, ConfigError, f"{what} file not found",
                lambda size: f"too big for a {what} file (over 1 MB); is this the right file?")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc}); fix the syntax") from None
    except (UnicodeDecodeError, RecursionError):
        raise ConfigError(f"{path}: not a text TOML file") from None


def read_json(path: Path | str, what: str, error: type[UserError] = UserError,
              hint: str = "") -> Any:
    """Parse a user's JSON file, or raise one line: not found, too big, not JSON,
    nested too deep."""
    path = Path(path)
    size_within(path, MAX_JSON_BYTES, error, f"{what} not found{hint}",
                lambda size: f"{size / 1e6:.1f} MB is too big for a {what} "
                             f"(limit {MAX_JSON_BYTES / 1e6:.0f} MB); is this the right file?")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{path}: {what} is not valid JSON ({exc})") from None
    except RecursionError:
        raise error(f"{path}: {what} is nested too deeply to be a labrig file") from None


def validate(cls: type[BaseModel], data: Any, path: Path | str,
             error: type[UserError] = UserError, *, section_word: bool = False) -> BaseModel:
    """``cls.model_validate(data)`` or one line naming the file, the key and the fix.

    ``section_word``: an unknown top-level key is an unknown TOML *section*.
    """
    try:
        return cls.model_validate(data)
    except ValidationError as exc:
        raise error(f"{path}: {describe(cls, exc, section_word)}") from None
    except RecursionError:
        raise error(f"{path}: nested too deeply to be a labrig file") from None


def _short(value: Any) -> str:
    text = json.dumps(value) if value is None or isinstance(value, bool) else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def describe(cls: type[BaseModel], exc: ValidationError, section_word: bool = False) -> str:
    """The first validation error as ``key 'a.b' ...: what is wrong (got X)``."""
    err = exc.errors(include_url=False)[0]
    loc = list(err["loc"])
    where, item = "", ""
    ints = [i for i, p in enumerate(loc) if isinstance(p, int)]
    if ints:  # ('experiment', 0, 'amplitude') -> "experiment 1: unknown key 'amplitude'"
        i = ints[0]
        if loc[i + 1:]:
            where = f"{'.'.join(map(str, loc[:i]))} {loc[i] + 1}: "
            loc = loc[i + 1:]
        else:
            item = f" (item {loc[i] + 1})"
            loc = loc[:i]
    key = ".".join(map(str, loc))
    kind = err["type"]
    return where + _what(cls, err, kind, key, item, section_word)


def _what(cls, err, kind, key, item, section_word) -> str:
    if kind == "extra_forbidden":
        allowed = sorted(_fields_at(cls, [p for p in err["loc"][:-1]]))
        if section_word and "." not in key and not item:
            return (f"unknown section [{key}]; expected one of "
                    f"{', '.join(f'[{a}]' for a in allowed)}")

        close = difflib.get_close_matches(str(err["loc"][-1]), allowed, n=1, cutoff=0.6)
        hint = (f"; did you mean '{close[0]}'?" if close else
                f"; expected one of {', '.join(allowed)}" if allowed else "")
        return f"unknown key '{key}'{hint}"
    if kind == "missing":
        return f"key '{key}' missing"
    msg = err["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    msg = msg[0].lower() + msg[1:]
    if not key:
        return f"{msg}"
    return f"key '{key}'{item} = {_short(err.get('input'))}: {msg}"


def _fields_at(cls, loc) -> set[str]:
    """The keys a (nested) model declares at ``loc``, for 'expected one of' hints."""
    for part in loc:
        if isinstance(part, int):
            continue
        fields = getattr(cls, "model_fields", None)
        if not fields or part not in fields:
            return set()
        cls = _model_in(fields[part].annotation)
        if cls is None:
            return set()
    return set(getattr(cls, "model_fields", {}) or {})


def _model_in(annotation):
    """The BaseModel class inside ``Optional[...]`` / ``list[...]``, if any."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _model_in(arg)
        if found is not None:
            return found
    return None


class JsonDoc(BaseModel):
    """Base of the documents of labrig's own JSON outputs (``--json``, the artefacts the
    report reads): declared keys are typed; any other key is carried along (newer
    writers), and a test checks that labrig's own writers declare every key they write."""

    model_config = ConfigDict(extra="allow")
