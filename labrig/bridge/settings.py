"""The bridge's units: the rig's ``[bridge]`` section, DAC/ADC words <-> volts, and an
experiment as the CONFIGURE body the board runs.

Pure functions of the configuration (no link, no board), so the conversions that decide
what reaches the motor are checked without hardware and shared by every caller.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from labrig.bridge import protocol as P
from labrig.io.experiment import Experiment
from labrig.core.errors import UserError

if TYPE_CHECKING:   # annotation only: labrig.io.config imports the bridge package
    from labrig.io.config import RigConfig

TIMER_HZ = 2_000_000   # Timer1 count rate: only rates dividing it are exact

#: channels with a calibration gain and offset (``<channel>_gain``, ``<channel>_offset_v``)
CAL_CHANNELS = ("dac", "tacho", "pos", "ref")


@dataclass(frozen=True)
class BridgeSettings:
    """The rig's ``[bridge]`` section as the host uses it, calibration filled in.

    Gains default to 1 and offsets to 0 V for every channel of :data:`CAL_CHANNELS`
    that the calibration leaves out.
    """

    sample_rate_hz: float
    output_limit_v: float
    dac_bits: int
    dac_range_v: tuple[float, float]
    adc_bits: int
    adc_range_v: tuple[float, float]
    watchdog_ms: int
    firmware: str = "ms150"
    current_sense: bool = False
    #: the current-sense output at zero current (V at the board's A0)
    current_zero_v: float = 0.0
    #: the encoder's counts per unit of the axis (an H-bridge rig's closed loop works in them)
    counts_per_unit: float = 0.0
    #: the sensors the MS150 board's own loop reads: the pot's volts per unit of the axis
    #: and at 0, the tacho's volts per unit/s of the motor (the rig's ``[sensors]``)
    pos_v_per_unit: float = 0.0
    pos_zero_v: float = 0.0
    tacho_v_per_unit_s: float = 0.0
    dac_gain: float = 1.0
    dac_offset_v: float = 0.0
    tacho_gain: float = 1.0
    tacho_offset_v: float = 0.0
    pos_gain: float = 1.0
    pos_offset_v: float = 0.0
    ref_gain: float = 1.0
    ref_offset_v: float = 0.0


def bridge_settings(rig: RigConfig) -> BridgeSettings:
    """Read ``rig.bridge``: the one place the bridge's settings come from.

    Parameters
    ----------
    rig : labrig.io.config.RigConfig
        The rig; ``RigConfig()`` is the default rig, whose ``bridge`` holds the defaults
        of ``configs/rig_default.toml``.

    Returns
    -------
    BridgeSettings
        The same fields as floats/ints/tuples, with calibration gains and offsets filled in.
    """
    b = rig.bridge
    cal = dict(b.calibration or {})
    return BridgeSettings(
        sample_rate_hz=float(b.sample_rate_hz), output_limit_v=float(b.output_limit_v),
        dac_bits=int(b.dac_bits), dac_range_v=tuple(float(v) for v in b.dac_range_v),
        adc_bits=int(b.adc_bits), adc_range_v=tuple(float(v) for v in b.adc_range_v),
        watchdog_ms=int(b.watchdog_ms), firmware=b.firmware, current_sense=bool(b.current_sense),
        counts_per_unit=float(rig.sensors.encoder_counts_per_unit),
        pos_v_per_unit=float(rig.sensors.pos_v_per_rad), pos_zero_v=float(rig.sensors.pos_offset_v),
        tacho_v_per_unit_s=float(rig.sensors.tacho_v_per_rad_s),
        current_zero_v=float(rig.sensors.current_zero_v),
        **{f"{k}_gain": float(cal.get(f"{k}_gain", 1.0)) for k in CAL_CHANNELS},
        **{f"{k}_offset_v": float(cal.get(f"{k}_offset_v", 0.0)) for k in CAL_CHANNELS})


def dac_word_to_volts(words, s: BridgeSettings) -> np.ndarray:
    """Bridge output volts for DAC words: nominal from the range, then the calibration."""
    lo, hi = s.dac_range_v
    nominal = lo + np.asarray(words, dtype=float) * (hi - lo) / 2 ** s.dac_bits
    return s.dac_gain * nominal + s.dac_offset_v


def volts_to_dac_word(v: float, s: BridgeSettings) -> int:
    """DAC word whose calibrated output is closest to ``v`` volts (clipped to the DAC)."""
    lo, hi = s.dac_range_v
    nominal = (v - s.dac_offset_v) / s.dac_gain
    w = int(round((nominal - lo) * 2 ** s.dac_bits / (hi - lo)))
    # an H-bridge word is a sign and the PWM's counts: the same most either way
    least = 1 if s.firmware == "hbridge" else 0
    return min(max(w, least), 2 ** s.dac_bits - 1)


def adc_counts_to_volts(counts, channel: str, s: BridgeSettings) -> np.ndarray:
    """Sensor volts for ADC counts of ``channel`` (``tacho``, ``pos`` or ``ref``)."""
    lo, hi = s.adc_range_v
    nominal = lo + np.asarray(counts, dtype=float) * (hi - lo) / 2 ** s.adc_bits
    return getattr(s, f"{channel}_gain") * nominal + getattr(s, f"{channel}_offset_v")


#: a digital loop's reference word for the run's starting count
REF_ZERO = 32768


def pd_gain_words(exp: Experiment, s: BridgeSettings) -> tuple[int, int]:
    """An H-bridge board's PD gains in its own units: Q8.8 output counts per count of
    error, and per count of change per sample. The board applies, at every sample,
    ``out = floor((kp_q (ref - x) - kd_q (x - x_prev)) / 256)`` output counts (see
    :func:`pd_output`).

    Raises
    ------
    UserError
        A gain the board's 16 bits cannot hold.
    """
    per_volt = 2 ** (s.dac_bits - 1) / s.dac_range_v[1]   # output counts per volt
    kp_q = int(round(exp.position_gain * per_volt / s.counts_per_unit * 256))
    kd_q = int(round(exp.velocity_gain * exp.sample_rate_hz * per_volt / s.counts_per_unit * 256))
    if not (0 <= kp_q <= 0xFFFF and 0 <= kd_q <= 0xFFFF):
        raise UserError(f"experiment {exp.name!r}: loop gains kp {exp.position_gain:g}, kd "
                        f"{exp.velocity_gain:g} do not fit the board's PD (at most "
                        f"{0xFFFF / 256 / per_volt * s.counts_per_unit:.3g} V/rad and "
                        f"{0xFFFF / 256 / per_volt * s.counts_per_unit / exp.sample_rate_hz:.3g} "
                        "V per rad/s, none negative)")
    return kp_q, kd_q


def pd_output(kp_q: int, kd_q: int, ref: np.ndarray, x: np.ndarray) -> np.ndarray:
    """What an H-bridge board's PD outputs (counts around zero, before the limits) for
    references ``ref`` and counts ``x`` (both from the run's start), sample by sample."""
    e = np.clip(np.asarray(ref, dtype=np.int64) - x, -32767, 32767)
    v = np.clip(np.diff(np.asarray(x, dtype=np.int64), prepend=0), -32767, 32767)
    return (kp_q * e - kd_q * v) >> 8


def is_board_loop(exp: Experiment, s: BridgeSettings) -> bool:
    """``exp`` is a closed loop the MS150 board closes itself (``closed_by = "board"``)."""
    return exp.loop == "closed" and exp.closed_by == "board" and s.firmware == "ms150"


def sensor_words(s: BridgeSettings) -> dict:
    """The MS150 board's sensors as its ADC sees them: the pot's words per unit of the axis
    (``counts_per_unit``) and its word at 0 (``pos_zero``), the tacho's words per unit/s of
    the motor and its word at rest (``tacho_zero``, and the whole word the board subtracts,
    ``tacho_zero_word``), the largest word; fractional words where the physics puts them
    (a word is ``round`` of them, as the ADC codes a voltage)."""
    lo, hi = s.adc_range_v
    per_v = 2 ** s.adc_bits / (hi - lo)   # words per volt at the ADC's range
    tz = ((0.0 - s.tacho_offset_v) / s.tacho_gain - lo) * per_v
    return {"counts_per_unit": s.pos_v_per_unit / s.pos_gain * per_v,
            "pos_zero": ((s.pos_zero_v - s.pos_offset_v) / s.pos_gain - lo) * per_v,
            "tacho_counts_per_unit_s": s.tacho_v_per_unit_s / s.tacho_gain * per_v,
            "tacho_zero": tz, "tacho_zero_word": int(round(tz)), "word_max": 2 ** s.adc_bits - 1}


def sensor_gain_words(exp: Experiment, s: BridgeSettings) -> tuple[int, int]:
    """The MS150 board's loop gains in its own units: Q8.8 DAC counts per pot word of
    error and per tacho word, so that its output is ``position_gain (ref - pot) -
    velocity_gain tacho`` in sensor volts, as the analog loop's is.

    Raises
    ------
    UserError
        A gain the board's 16 bits cannot hold, or a sensor whose sign would turn the
        board's loop into positive feedback.
    """
    if s.pos_v_per_unit <= 0 or s.tacho_v_per_unit_s <= 0:
        raise UserError(f"experiment {exp.name!r}: the board closes its loop on the pot and "
                        "the tacho, and needs both to rise with the forward drive (the rig "
                        "file's sensors.pos_v_per_rad and sensors.tacho_v_per_rad_s above 0; "
                        "a negative one is a sensor wired the other way round: swap its wires)")
    lo, hi = s.adc_range_v
    volts_per_word = (hi - lo) / 2 ** s.adc_bits
    per_volt = 2 ** s.dac_bits / (s.dac_range_v[1] - s.dac_range_v[0]) / s.dac_gain
    kp_q = int(round(exp.position_gain * s.pos_gain * volts_per_word * per_volt * 256))
    kd_q = int(round(exp.velocity_gain * s.tacho_gain * volts_per_word * per_volt * 256))
    if not (0 <= kp_q <= 0xFFFF and 0 <= kd_q <= 0xFFFF):
        top = 0xFFFF / 256 / (volts_per_word * per_volt)
        raise UserError(f"experiment {exp.name!r}: loop gains position_gain "
                        f"{exp.position_gain:g}, velocity_gain {exp.velocity_gain:g} do not fit "
                        f"the board's loop (at most {top / s.pos_gain:.3g} and "
                        f"{top / s.tacho_gain:.3g} V per V, none negative)")
    return kp_q, kd_q


def board_reference_words(exp: Experiment, s: BridgeSettings, levels_v) -> list[int]:
    """The pot words the MS150 board's loop aims at for reference ``levels_v`` (volts of
    the pot about its 0, as the analog loop reads them)."""
    w = sensor_words(s)
    words = [int(round(v / s.pos_v_per_unit * w["counts_per_unit"] + w["pos_zero"]))
             for v in levels_v]
    if any(not 0 <= x <= w["word_max"] for x in words):
        raise UserError(f"experiment {exp.name!r}: a reference beyond the pot's range (the "
                        "board's loop aims at a pot word its ADC can read)")
    return words


def sensor_pd(exp: Experiment, s: BridgeSettings, hello: dict | None = None) -> dict:
    """How the MS150 board closes ``exp``'s loop, for the run's sidecar
    (``experiment.controller.sampled``, ``feedback = "sensors"``): its Q8.8 gains, its
    sensors' words (:func:`sensor_words`), the input volts of one DAC count and the
    output's limits in counts about zero, so that the model runs the board's own law."""
    kp_q, kd_q = sensor_gain_words(exp, s)
    zero = volts_to_dac_word(0.0, s)
    wmin, wmax = output_words(s, hello or {})
    return {"kp_q": kp_q, "kd_q": kd_q, "feedback": "sensors", **sensor_words(s),
            "volts_per_count": float((s.dac_range_v[1] - s.dac_range_v[0]) / 2 ** s.dac_bits
                                     * s.dac_gain),
            "limits": [int(wmin - zero), int(wmax - zero)]}


def output_words(s: BridgeSettings, hello: dict) -> tuple[int, int]:
    """The output words a run may use: the rig's output limit either way, within the
    firmware's own limits (HELLO's ``fw_dac_min``/``fw_dac_max``; missing: the DAC's)."""
    limit = s.output_limit_v
    wmin, wmax = sorted((volts_to_dac_word(-limit, s), volts_to_dac_word(limit, s)))
    return (max(wmin, hello.get("fw_dac_min", 0)),
            min(wmax, hello.get("fw_dac_max", 2 ** s.dac_bits - 1)))


def sampled_pd(exp: Experiment, s: BridgeSettings, hello: dict | None = None) -> dict:
    """How an H-bridge board runs ``exp``'s loop, for the run's sidecar
    (``experiment.controller.sampled``): its Q8.8 gains, the counts per position unit, the
    input volts of one output count and the output's limits in counts about zero (the
    rig's output limit within the firmware's words), so that the model runs the board's
    own law on its own count (:mod:`labrig.simulation.sampled_kernel`)."""
    kp_q, kd_q = pd_gain_words(exp, s)
    zero = volts_to_dac_word(0.0, s)
    wmin, wmax = output_words(s, hello or {})
    return {"kp_q": kp_q, "kd_q": kd_q, "counts_per_unit": float(s.counts_per_unit),
            "volts_per_count": float(s.dac_range_v[1] / 2 ** (s.dac_bits - 1)),
            "limits": [int(wmin - zero), int(wmax - zero)]}


def board_law(exp: Experiment, rig, hello: dict | None = None) -> dict | None:
    """The law a board closes ``exp``'s loop by (an H-bridge board's :func:`sampled_pd`, the
    MS150 board's own loop's :func:`sensor_pd`), or None: an open-loop run, or a loop that
    is not the board's."""
    if exp.loop != "closed":
        return None
    s = bridge_settings(rig)
    if rig.board_loop(exp):
        return sensor_pd(exp, s, hello)
    return sampled_pd(exp, s, hello) if rig.bridge.firmware == "hbridge" else None


def waveform_levels(exp: Experiment) -> list[float]:
    """The output levels (bridge volts) the board cycles through for ``exp``."""
    if exp.waveform == "square":
        return [exp.offset_v + exp.amplitude_v, exp.offset_v - exp.amplitude_v]
    if exp.waveform in ("step", "constant"):
        return [exp.amplitude_v + exp.offset_v]
    if exp.waveform == "staircase":
        if not exp.levels:
            raise UserError(f"experiment {exp.name!r}: a staircase needs levels")
        return [v + exp.offset_v for v in exp.levels]
    if exp.waveform == "pwl":
        return [u + exp.offset_v for _, u in exp.points]
    raise UserError(f"experiment {exp.name!r}: the board cannot generate a {exp.waveform!r} waveform "
                    "(square, step, staircase, constant or pwl)")


def experiment_body(exp: Experiment, s: BridgeSettings, hello: dict) -> bytes:
    """The CONFIGURE body of ``exp`` in DAC words, checked against every limit first.

    Parameters
    ----------
    exp : Experiment
    s : BridgeSettings
    hello : dict
        The board's HELLO fields (its maximum rate and firmware DAC limits); missing
        fields mean no limit beyond the DAC's own and 1000 Hz.

    Raises
    ------
    UserError
        The experiment is beyond the output limit, the board's rates, its level count or
        the firmware's DAC limits, or has an unknown loop or waveform.
    """
    limit = s.output_limit_v
    peak = exp.peak_v()
    if peak > limit + 1e-9:
        raise UserError(f"experiment {exp.name!r} peaks at {peak:.3g} V, beyond the bridge output "
                        f"limit of {limit:.3g} V ([bridge] output_limit_v)")
    if exp.loop not in P.LOOPS:
        raise UserError(f"experiment {exp.name!r}: loop must be 'open' or 'closed'")
    rate = int(round(exp.sample_rate_hz))
    max_rate = hello.get("max_rate_hz", 1000)
    min_rate = hello.get("min_rate_hz", 50)
    clock = hello.get("timer_hz", TIMER_HZ)   # the board's sample clock: exact rates divide it
    if abs(rate - exp.sample_rate_hz) > 1e-9 or clock % rate or not min_rate <= rate <= max_rate:
        examples = ", ".join(str(r) for r in (100, 200, 250, 500, 1000, 2000)
                             if min_rate <= r <= max_rate and clock % r == 0)
        raise UserError(f"experiment {exp.name!r}: sample rate {exp.sample_rate_hz:g} Hz is not "
                        f"available; the board runs {min_rate}..{max_rate} Hz at divisors of "
                        f"{clock:g} Hz (e.g. {examples})")
    levels_v = waveform_levels(exp)
    most = min(P.MAX_LEVELS, hello.get("max_levels", P.MAX_LEVELS))
    if len(levels_v) > most:
        what = "pwl breakpoints (the board's table)" if exp.waveform == "pwl" else \
            "staircase levels"
        raise UserError(f"experiment {exp.name!r}: the board holds at most {most} "
                        f"{what}, the plan has {len(levels_v)}")
    pieces = None
    if exp.waveform == "pwl":
        if not hello.get("capabilities", P.CAP_PWL) & P.CAP_PWL:
            raise UserError(f"experiment {exp.name!r}: this board's firmware does not play pwl "
                            "waveforms; update it (`labrig flash --board BOARD`)")
        ks = [int(round(t * rate)) for t, _ in exp.points]
        pieces = [b - a for a, b in zip(ks, ks[1:])]
        if not all(1 <= L <= P.MAX_PIECE for L in pieces):
            raise UserError(f"experiment {exp.name!r}: pwl breakpoints must lie 1 to "
                            f"{P.MAX_PIECE} samples apart at {rate} Hz")
    digital = s.firmware == "hbridge" and exp.loop == "closed"
    board = is_board_loop(exp, s)
    if board and not hello.get("capabilities", 0) & P.CAP_BOARD_LOOP:
        raise UserError(f"experiment {exp.name!r}: this board's firmware does not close the "
                        "loop itself (closed_by = \"board\"); update it (`labrig flash "
                        "--board BOARD`)")
    if board:   # the board's loop on its sensors: its references are pot words
        levels = board_reference_words(exp, s, levels_v)
    elif digital:   # the board's PD on the count: its references are counts
        levels = [REF_ZERO + int(round(v * s.counts_per_unit)) for v in levels_v]
        if any(not 0 <= w <= 0xFFFF for w in levels):
            raise UserError(f"experiment {exp.name!r}: a reference beyond +-32767 counts "
                            f"(+-{32767 / s.counts_per_unit:.3g} rad) of the run's start")
    else:
        levels = [volts_to_dac_word(v, s) for v in levels_v]
    zero = volts_to_dac_word(0.0, s)
    wmin, wmax = output_words(s, hello)
    if any(not wmin <= w <= wmax for w in ([] if digital or board else levels) + [zero]):
        lo_v, hi_v = dac_word_to_volts([hello.get("fw_dac_min", 0),
                                        hello.get("fw_dac_max", 2 ** s.dac_bits - 1)], s)
        raise UserError(f"experiment {exp.name!r} needs DAC words beyond the firmware limit "
                        f"({lo_v:.3g}..{hi_v:.3g} V with this calibration)")
    if exp.waveform == "square":
        segment = int(round(rate / (2.0 * exp.frequency_hz)))
    elif exp.waveform == "staircase":
        segment = int(round(exp.step_s * rate))
    else:
        segment = 0
    closed = exp.loop == "closed"
    gain_words = pd_gain_words(exp, s) if digital else sensor_gain_words(exp, s) if board else None
    tail = None
    if board:   # the lead-in holds the shaft at the pot's 0, as the analog loop's 0 V does
        w = sensor_words(s)
        tail = (int(round(w["pos_zero"])), w["tacho_zero_word"])
    return P.configure_body(gain_words=gain_words, board_loop=tail,
        loop="board" if board else exp.loop, waveform=exp.waveform, sample_rate_hz=rate, n_samples=int(exp.n_samples),
        lead_in_samples=int(round(exp.lead_in_s * rate)), segment_samples=segment,
        dac_zero=zero, dac_min=wmin, dac_max=wmax, watchdog_ms=s.watchdog_ms, levels=levels,
        position_gain=exp.position_gain if closed else 0.0,
        velocity_gain=exp.velocity_gain if closed else 0.0, pieces=pieces)
