"""Whether an effect's fitted size is one the data resolve.

A fit always returns a number. An input offset of 2 mV behind a PWM bridge whose steps
are 47 mV, a delay of a tenth of a sample, or a dead zone whose value swings from fold
to fold lowers the in-sample error by fitting noise, not physics; ``diagnose`` does not
call such an effect supported. The rule, for the effect's *size* (``Effect.size``: the
parameter that is zero when the effect is absent, a dead zone's width, a delay, an
offset):

1. **above the input's resolution**: a size in volts acting at the input, the drive or
   as friction (a relative input gain: times the largest input) must be at least one
   step of the input (:func:`input_quantum`: the bridge's DAC step its runs record, or
   an imported run's ``experiment.input_step_v``);
2. **above a fraction of a sample**: a delay must be at least :data:`MIN_SAMPLES` of the
   sample period; **above the position's resolution**: a size in the axis's position
   unit at the output (a gear's play) must span at least one count of an encoder
   (``Run.pos_quantum``): a play inside one count moves no count;
3. **resolved by the folds**: the size must exceed :data:`Z` standard errors from the
   grouped jackknife over the cross-validation folds (each fold's fit, on the data it
   saw), so an interval of ``Z`` standard errors excludes zero.
"""
from __future__ import annotations

import numpy as np

#: a delay shorter than this fraction of a sample is not resolved
MIN_SAMPLES = 0.25
#: the size must exceed this many jackknife standard errors
Z = 3.0
#: the input shows its lattice when it takes at least this many distinct values (a PWM
#: duty cycle or a ramp on a DAC does; a staircase of a few dozen levels does not)
MIN_LEVELS = 64


def input_quantum(runs) -> float:
    """The input's step (V): as the runs' sidecars state it (the bridge's DAC step), else
    the smallest gap between the input's distinct values when it takes at least
    :data:`MIN_LEVELS` of them (a PWM or DAC lattice); 0 when unknown."""
    declared = [r.input_step for r in runs if getattr(r, "input_step", 0.0)]
    if declared:
        return max(declared)
    gaps = []
    for r in runs:
        v = np.unique(np.round(np.asarray(r.u, float), 9))
        if len(v) >= MIN_LEVELS:
            d = np.diff(v)
            d = d[d > 1e-9]
            if len(d):
                gaps.append(float(np.min(d)))
    return max(gaps) if gaps else 0.0


def jackknife_se(values) -> float:
    """Grouped-jackknife standard error of an estimate from its fold fits."""
    v = np.asarray([x for x in values if np.isfinite(x)], float)
    k = len(v)
    if k < 2:
        return 0.0
    return float(np.sqrt((k - 1) / k * np.sum((v - v.mean()) ** 2)))


def _all_below_step(effect, params: dict, runs) -> str | None:
    """An effect without one size whose every input-volt parameter is below one step of
    the input (an asymmetric dead zone of a millivolt each way behind a PWM)."""
    if effect.stage not in ("input", "drive", "friction"):
        return None
    volts = {p.name: abs(float(params[p.name])) for p in effect.params
             if p.unit == "V" and p.name in params}
    if not volts:
        return None
    q = input_quantum(runs)
    if q > 0 and max(volts.values()) < q:
        said = ", ".join(f"{effect.name}.{k} = {v * 1e3:.3g} mV" for k, v in volts.items())
        return f"{said}: all below one step of the input ({q * 1e3:.3g} mV)"
    return None


def unresolved(effect, params: dict, runs, fold_values=()) -> str | None:
    """Why the fitted size of ``effect`` is not resolved by these data, in words; None
    when it is."""
    name = effect.size
    if not name:   # several sizes (a dead zone each way): none resolved, none is there
        return _all_below_step(effect, params, runs)
    if name not in params:
        return None
    value = float(params[name])
    unit = next((p.unit for p in effect.params if p.name == name), "")
    dt = float(np.median([r.dt for r in runs]))
    volts = None
    if unit == "V" and effect.stage in ("input", "drive", "friction"):
        volts = abs(value)
    elif unit == "-" and effect.stage == "input":   # a relative gain, at the largest input
        volts = abs(value) * max(float(np.max(np.abs(r.u))) for r in runs)
    q = input_quantum(runs) if volts is not None else 0.0
    if q > 0 and volts < q:
        return (f"{effect.name}.{name} = {value:.3g} {unit} moves the input by "
                f"{volts * 1e3:.3g} mV, below one step of the input ({q * 1e3:.3g} mV)")
    pq = max((getattr(r, "pos_quantum", 0.0) for r in runs), default=0.0)
    if effect.stage == "output" and unit in ("rad", "m") and pq > 0 and 2 * abs(value) < pq:
        return (f"{effect.name}.{name} = {value:.3g} {unit}: a play of {2 * abs(value):.3g} "
                f"{unit}, inside one count of the encoder ({pq:.3g} {unit})")
    if effect.stage == "delay" and unit == "s" and abs(value) < MIN_SAMPLES * dt:
        return (f"{effect.name}.{name} = {value * 1e3:.3g} ms is below {MIN_SAMPLES:g} of a "
                f"sample ({dt * 1e3:.3g} ms)")
    se = jackknife_se(fold_values)
    if se > 0 and abs(value) < Z * se:
        return (f"{effect.name}.{name} = {value:.3g} {unit} is within {Z:g} standard errors "
                f"({se:.2g} {unit}, from the folds' fits) of zero")
    return None
