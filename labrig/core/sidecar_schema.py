"""The run sidecar's schema (``*.json`` beside a run's CSV): every key declared, each
value with its physical range (the rules of :mod:`labrig.core.schemas`)."""
from __future__ import annotations

from typing import Annotated, Any, Literal, Optional

from pydantic import Field

from labrig.core.schemas import Gain, Num, ClosedModel

class SampledPD(ClosedModel):
    """A board's own PD, sample by sample, as it computes it: ``out = floor((kp_q e - kd_q
    v) / 256)`` output counts, clamped to ``limits``, held to the next sample; one output
    count is ``volts_per_count`` of input. ``feedback = "count"`` (an H-bridge board): ``e``
    the reference less the encoder's count and ``v`` the count's change over one sample,
    both in counts from the run's start (``counts_per_unit`` of the axis). ``"sensors"``
    (the MS150 board's loop): ``e`` the reference less the pot's ADC word (``counts_per_unit``
    words per unit, ``pos_zero`` the word at 0) and ``v`` the tacho's word less
    ``tacho_zero_word`` (``tacho_counts_per_unit_s`` words per unit/s of the motor,
    ``tacho_zero`` the word at rest), words of ``word_max + 1`` codes."""

    kp_q: Annotated[int, Field(ge=0, le=0xFFFF)]
    kd_q: Annotated[int, Field(ge=0, le=0xFFFF)]
    counts_per_unit: Num(gt=0, le=1e9)
    volts_per_count: Num(gt=0, le=1e3)
    limits: Annotated[list[Annotated[int, Field(ge=-0xFFFF, le=0xFFFF)]],
                      Field(min_length=2, max_length=2)]
    feedback: Literal["count", "sensors"] = "count"
    pos_zero: Num(-1e6, 1e6) = 0.0
    tacho_counts_per_unit_s: Num(0, 1e6) = 0.0
    tacho_zero: Num(-1e6, 1e6) = 0.0
    tacho_zero_word: Annotated[int, Field(ge=0, le=0xFFFF)] = 0
    word_max: Annotated[int, Field(ge=1, le=0xFFFF)] = 0xFFFF


class Controller(ClosedModel):
    """The controller of a closed-loop run: ``drive = kp (ref - x) - kd x' + ki int(ref - x)``
    in input volts, x the fed-back position (derivative on the measurement)."""

    kind: Literal["pd", "pid"]
    kp: Num(0, 1e9)
    kd: Num(0, 1e9) = 0.0
    ki: Num(0, 1e9) = 0.0
    feedback: Literal["position"] = "position"
    output_limit_v: Optional[Num(gt=0, le=1e4)] = None
    #: the board's arithmetic, when the run was played by a board's loop (an H-bridge
    #: board's, or the MS150 board's own): the model then runs that law, not a continuous PD
    sampled: Optional[SampledPD] = None


class SidecarExperiment(ClosedModel):
    loop: Literal["open", "closed"]
    #: the MS150's closed loop: its analog loop (the patch panel) or the board's own
    closed_by: Optional[Literal["analog", "board"]] = None
    waveform: Optional[str] = None
    amplitude_v: Num(-1e3, 1e3) = None
    frequency_hz: Num(gt=0, le=1e5) = None
    offset_v: Num(-1e3, 1e3) = None
    lead_in_s: Num(0, 1e5) = None
    periods: Num(gt=0, le=1e6) = None
    duration_s: Num(gt=0, le=1e6) = None
    step_s: Num(gt=0, le=1e5) = None
    levels: list[Num(-1e3, 1e3)] = None
    points: list[Annotated[list[Num(-1e5, 1e5)], Field(min_length=2, max_length=2)]] = None
    between: list[Annotated[str, Field(max_length=300)]] = None
    sample_rate_hz: Num(gt=0, le=1e6) = None
    position_gain: Num(0, 1e6) = None
    velocity_gain: Num(0, 1e6) = None
    controller: Optional[Controller] = None
    #: one step of the input (V), when the bridge's resolution is known (a PWM's step)
    input_step_v: Num(0.0, 10.0) = None
    #: how the run starts, when its owner knows (labrig import --start): at rest, or in
    #: motion (its initial state fitted); absent: decided from the data (labrig.model.start)
    start: Optional[Literal["rest", "moving"]] = None


class SidecarSensors(ClosedModel):
    tacho_v_per_rad_s: Gain = None
    #: the unit of a ``speed`` column (physical speed, no tacho): the axis's SI unit
    speed_unit: Optional[Literal["rad/s", "m/s"]] = None
    pos_v_per_rad: Gain = None
    pos_offset_v: Num(-1e3, 1e3) = None
    #: the position sensor's quantum in the axis's unit (an encoder's count)
    pos_quantum: Num(gt=0, le=1e3) = None
    pos_kind: Optional[Literal["pot", "encoder"]] = None
    current_a_per_v: Gain = None
    #: the speed is the travel over this window divided by it (a moving window of
    #: encoder counts, as a sketch computes it): a sensor filter, modelled, not fitted
    speed_window_s: Num(gt=0, le=10.0) = None
    #: the window was not declared: the import found the speed to be whole counts that
    #: stand at zero when still, and took it as counted over the sample before
    speed_window_found: Optional[bool] = None


class SidecarRig(ClosedModel):
    gear_ratio: Num(gt=0, le=1e5) = None
    amplifier_gain: Num(gt=0, le=1e5) = None
    #: the plant (labrig.model.plants) and the axis it moves
    drive: Optional[Literal["voltage", "torque", "force"]] = None
    axis: Optional[Literal["rotary", "linear"]] = None
    #: a torque/force drive's gain kd (N m or N per input volt)
    input_gain: Num(gt=0, le=1e6) = None
    #: the input is the drive's command ("command", default) or a measured torque or
    #: force, a current channel times its constant ("measured"): nothing at the
    #: amplifier's input acts on it (labrig.model.effects.input_can_have)
    input: Optional[Literal["command", "measured"]] = None
    name: Optional[str] = None


class Sidecar(ClosedModel):
    """A run's sidecar: every key declared, so a misspelt one (``brige``,
    ``experiment.amplitud_v``) is an error that names the labrig spelling, never a
    silently missing value."""

    format: str
    sample_rate_hz: Num(gt=0, le=1e6)
    experiment: SidecarExperiment
    sensors: SidecarSensors
    rig: SidecarRig
    source: Optional[str] = None
    created: Optional[str] = None
    #: the bridge's own record of the run (firmware, counters, DAC step): reported as is
    bridge: Optional[dict[str, Any]] = None
    #: the file a run was imported from (``labrig import``)
    imported_from: Optional[str] = None
    #: free text for the user's own notes, never read by labrig
    notes: Optional[Any] = None
