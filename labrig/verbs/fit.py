"""Fits: the analyser, the identifiers, a model compared with the runs, the ladder."""
from __future__ import annotations

from labrig.core.defaults import METHOD, SEED
from labrig.core.errors import UserError
from labrig.core.progress import Event, both
from labrig.verbs.data import model_of, read_runs


def analyse(source, *, tolerance: float | None = None):
    """Deadband, Km and tau_m from open-loop runs (``labrig analyse``).

    ``source`` as in :func:`read_runs`, or a steady-state table CSV (like the seed
    paper's Table 1). Returns an :class:`~labrig.analysis.result.AnalysisResult`.
    """
    from labrig.analysis.dataset import analyse as _analyse
    from labrig.analysis.result import GAIN_TOLERANCE

    if not isinstance(source, (list, tuple)):
        source = [source]
    return _analyse(list(source), tolerance=GAIN_TOLERANCE if tolerance is None else tolerance)


def identify(source, method: str = METHOD, effects=(), *, model=None, seed: int | None = SEED,
             fixed: dict | None = None, bounds: dict | None = None,
             through: str | None = "auto", progress=None, **options):
    """Fit the plant and effects (``labrig identify``).

    Parameters
    ----------
    source : see :func:`read_runs`
    method : {"co", "jfo", "pso"}
        Default ``"co"``, as the command line's ``--method``.
    effects : list of str
        Catalogue names (``lr.effects()`` lists them) or ``FILE.py:Class`` of trusted code.
    model : Model, model file or Identification, optional
        Start from this model (its effects are kept and ``effects`` added), as ``--model``.
    seed : int or None
        Default 0, as the command line: the same files give the same fit. None draws a
        fresh seed, recorded in the result (``result.seed``) to repeat it.
    fixed, bounds : dict, optional
        ``{"R": 8.2}`` and ``{"R": (1, 20)}``, as ``--fix`` and ``--bounds``.
    progress : callable(Event), optional
        Hears each iteration (JFO, PSO) or start (CO) with the best fitness so far
        (:class:`labrig.core.progress.Event`, kind ``iteration``).
    **options
        ``pop``, ``iters``, ``starts``, ``polish``, ``p``, ``q``, ``c`` (channel weights)
        as in :func:`labrig.identification.engine.identify`.

    Returns
    -------
    Identification
        ``.model()`` is the fitted :class:`~labrig.model.model.Model`.
    """
    from labrig.identification.engine import identify as _identify
    from labrig.model.effectset import EffectSet

    runs = read_runs(source, through=through)
    asked = EffectSet.parse(list(effects) if not isinstance(effects, str) else effects)
    start_model, start = model_of(model), None
    if start_model is not None:
        start = start_model.flat()
        asked = start_model.effects_with(asked)
    if progress is not None:
        total = options.get("starts", 8) if method == "co" else options.get("iters", 200)
        options["callback"] = both(options.get("callback"), lambda it, best: progress(
            Event("identify", "iteration", it, total, f"best fitness {best:.4g}", best)))
    return _identify(runs, method, asked, seed=seed, fixed=fixed, bounds=bounds, start=start,
                     **options)


def add_effect(source, model, effect, *, method: str = "co", seed: int | None = SEED,
               through: str | None = "auto", progress=None, **options):
    """``model`` with ``effect`` (a catalogue name, or several) added, fitted from where
    ``model`` was fitted: the warm-started add of the loop (``labrig identify --model M
    --effects E``; the demo, the report and the lab page add this way). ``options`` as
    :func:`identify` (``starts=1``: one start, from the model). Returns an
    :class:`~labrig.identification.engine.Identification`."""
    names = [effect] if isinstance(effect, str) else list(effect)
    return identify(source, method, names, model=model, seed=seed, through=through,
                    progress=progress, **options)


def try_effect(source, model, effect: str):
    """``model`` with ``effect`` added at the size a fit would start from, nothing
    re-fitted: to see what the effect does to the curves before any fit says (the lab's
    *Try an effect*; its sliders then set the size by hand)."""
    from labrig.model.effects import get_effect

    runs, m = read_runs(source), model_of(model)
    eff = get_effect(effect)
    if eff.name in m.names:
        raise UserError(f"{eff.name}: the model has it already")
    return m.with_effect(eff, eff.initial_guess(runs, m.servo()))


def set_by_hand(source, model, values: dict):
    """``model`` with parameters set by hand, nothing re-fitted (the lab's sliders;
    ``labrig compare --set``): ``values`` maps a plant parameter (``"J"``) or an
    effect's (``"coulomb_friction.tc_v"``, in the units :func:`effect` lists) to its
    value. An effect the model lacks is added first, as :func:`try_effect` adds it.
    A value outside the parameter's range is refused, naming the range."""
    from labrig.model.effects import get_effect

    m = model_of(model)
    for key, value in values.items():
        name, dot, par = key.partition(".")
        if dot and name not in m.names:
            get_effect(name)   # an unknown name fails here, with the catalogue listed
            m = try_effect(source, m, name)
        if dot:
            eff = next(e for e in m.effects if e.name == name)
            p = next((q for q in eff.params if q.name == par), None)
            bounds = (p.lower, p.upper) if p is not None else None
        else:
            bounds = m.plant_class.bounds.get(key) if key in m.params else None
        if bounds is None:
            known = list(m.params) + [f"{e.name}.{q.name}" for e in m.effects for q in e.params]
            raise UserError(f"{key}: not a parameter of the model; its parameters: "
                            + ", ".join(known))
        if not bounds[0] <= value <= bounds[1]:
            raise UserError(f"{key}={value:g}: outside its range {bounds[0]:g} to "
                            f"{bounds[1]:g}; give a value inside it")
        m = m.with_value(key, float(value))
    return m


def remove_effect(model, name: str):
    """``model`` without its effect ``name`` (its other values kept, nothing re-fitted)."""
    from labrig.diagnosis.refit import without

    return without(model_of(model), name)


def compare(source, model, *, through: str | None = "auto", detail: bool = True):
    """The model simulated on the runs: fit %, rmse/noise by run and regime, residuals
    (``labrig compare``). Returns an :class:`~labrig.diagnosis.evaluation.Evaluation`; its
    ``plot()`` overlays model and measurement with the residual and its noise band.
    ``detail=False``: the residuals, fit % and rmse/noise only, the same numbers in a
    third of the time (no regimes, stretches or correlations: what a slider redraws)."""
    from labrig.diagnosis.evaluation import evaluate

    return evaluate(read_runs(source, through=through), model_of(model), detail=detail)


def ladder(source, models, *, through: str | None = "auto"):
    """The error after each added effect, against the noise floor (``labrig ladder``).

    ``models``: a list of Models, model files or fits, simplest first (a file's rung
    names it). Returns a :class:`~labrig.diagnosis.ladder.Ladder`.
    """
    from os import PathLike

    from labrig.diagnosis.ladder import evaluate_ladder

    return evaluate_ladder(read_runs(source, through=through),
                           [m if isinstance(m, (str, PathLike)) else model_of(m) for m in models])
