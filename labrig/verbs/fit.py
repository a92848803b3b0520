"""Fits: the analyser, the identifiers, a model compared with the runs, the ladder."""
from __future__ import annotations

from labrig.core.defaults import METHOD, SEED
from labrig.core.errors import UserError
from labrig.core.progress import Event, both
from labrig.verbs.data import model_of, read_runs


def analyse(source, *, tolerance: float | None = None):
    """Deadband, Km and tau_m from open-loop runs (``labrig analyse``).

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        Runs as :func:`read_runs` reads them, or a steady-state table CSV (a column of
        input volts and one of steady speeds, like the seed paper's Table 1).
    tolerance : float, optional
        How far (relative) the gain of each amplitude may stray from the others' before
        the result calls the gain amplitude-dependent; default the analyser's own.

    Returns
    -------
    AnalysisResult
        ``km``, ``deadband_v``, ``tau_s`` and the per-amplitude ``levels``; ``plot()``
        draws the steady speeds against the input, ``to_pandas()`` the table.

    Raises
    ------
    UserError
        A source that cannot be read, or runs with no step to analyse (the message
        names the file and what to give instead).

    Examples
    --------
    >>> import labrig as lr
    >>> res = lr.analyse("data/sweep_default")
    >>> round(res.km)
    97
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
    through : {"auto", "loop", "input"} or None
        Closed-loop runs, as :func:`read_runs`'s.
    progress : callable(Event), optional
        Hears each iteration (JFO, PSO) or start (CO) with the best fitness so far
        (:class:`labrig.core.progress.Event`, kind ``iteration``).
    **options
        ``pop``, ``iters``, ``starts``, ``polish``, ``p``, ``q``, ``c`` (channel weights)
        as in :func:`labrig.identification.engine.identify`.

    Returns
    -------
    Identification
        ``.model()`` is the fitted :class:`~labrig.model.model.Model`; ``fitness``, the
        parameters with their intervals where the data resolve them, and the bounds a
        parameter ended at.

    Raises
    ------
    UserError
        An unknown method or effect name, a source that cannot be read, bounds outside
        a parameter's range (the message names the argument).
    FitDiverged
        Every start's simulation overflowed: start from a model nearer the data.

    Examples
    --------
    >>> import labrig as lr
    >>> fit = lr.identify("data/sweep_default", effects=["deadband"])  # doctest: +SKIP
    >>> round(fit.model().effect_params["deadband"]["d_v"], 2)  # doctest: +SKIP
    0.13
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
    """``model`` with ``effect`` added, fitted from where ``model`` was fitted: the
    warm-started add of the loop (``labrig identify --model M --effects E``; the demo,
    the report and the lab page add this way).

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        The runs, as :func:`read_runs` reads them.
    model : Model, model file or Identification
        The model to add to; its effects are kept.
    effect : str or list of str
        A catalogue name (``lr.effects()`` lists them), or several.
    method, seed, through, progress, **options
        As :func:`identify`'s (``starts=1``: one start, from the model).

    Returns
    -------
    Identification
        The fit with the effect; ``.model()`` is the new model.

    Raises
    ------
    UserError
        An unknown effect name, or one the model holds already.

    Examples
    --------
    >>> import labrig as lr
    >>> m0 = lr.identify("data/sweep_default").model()  # doctest: +SKIP
    >>> m1 = lr.add_effect("data/sweep_default", m0, "deadband").model()  # doctest: +SKIP
    """
    names = [effect] if isinstance(effect, str) else list(effect)
    return identify(source, method, names, model=model, seed=seed, through=through,
                    progress=progress, **options)


def try_effect(source, model, effect: str):
    """``model`` with ``effect`` added at the size a fit would start from, nothing
    re-fitted: to see what the effect does to the curves before any fit says (the lab's
    *Try an effect*; its sliders then set the size by hand).

    Parameters
    ----------
    source : folder, file, list of them, or runs
        The runs the effect's starting size is guessed from.
    model : Model, model file or fit
        The model to add it to.
    effect : str
        A catalogue name (:func:`effects`) or ``FILE.py:Class`` of code you trust.

    Returns
    -------
    Model
        The model with the effect at its guessed size; compare it with
        :func:`compare` before fitting it with :func:`identify`.

    Raises
    ------
    UserError
        An unknown effect (the catalogue listed), or one the model has already.

    Examples
    --------
    >>> import labrig as lr
    >>> m = lr.Model(params={"R": 8.0, "L": 0.01, "K": 0.05, "J": 1e-4, "B": 1e-5})
    >>> t = lr.try_effect("data/sweep_default", m, "deadband")
    >>> t.names, round(t.effect_params["deadband"]["d_v"], 3)
    (['deadband'], 0.06)
    """
    from labrig.model.effects import get_effect

    runs, m = read_runs(source), model_of(model)
    eff = get_effect(effect)
    if eff.name in m.names:
        raise UserError(f"{eff.name}: the model has it already")
    return m.with_effect(eff, eff.initial_guess(runs, m.servo()))


def set_by_hand(source, model, values: dict):
    """``model`` with parameters set by hand, nothing re-fitted (the lab's sliders;
    ``labrig compare --set``).

    Parameters
    ----------
    source : folder, file, list of them, or runs
        The runs an added effect's other parameters are guessed from.
    model : Model, model file or fit
        The model to change.
    values : dict
        A plant parameter (``"J"``) or an effect's (``"coulomb_friction.tc_v"``, in the
        units :func:`effect` lists) to its value. An effect the model lacks is added
        first, as :func:`try_effect` adds it.

    Returns
    -------
    Model
        The model with those values; :func:`compare` shows it on the runs, and
        ``identify(..., model=it, starts=1)`` fits from there.

    Raises
    ------
    UserError
        A name that is not a parameter (its parameters listed), or a value outside the
        parameter's range (the range named).

    Examples
    --------
    >>> import labrig as lr
    >>> m = lr.Model(params={"R": 8.0, "L": 0.01, "K": 0.05, "J": 1e-4, "B": 1e-5})
    >>> h = lr.set_by_hand("data/sweep_default", m, {"coulomb_friction.tc_v": 0.13, "J": 2e-4})
    >>> h.names, h.effect_params["coulomb_friction"], h.params["J"]
    (['coulomb_friction'], {'tc_v': 0.13}, 0.0002)
    """
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
    """``model`` without its effect ``name``, its other values kept, nothing re-fitted.

    Parameters
    ----------
    model : Model, model file or Identification
    name : str
        The effect to take out.

    Returns
    -------
    Model

    Raises
    ------
    UserError
        ``name`` is not one of the model's effects.

    Examples
    --------
    >>> import labrig as lr
    >>> m1 = lr.identify("data/sweep_default", effects=["deadband"]).model()  # doctest: +SKIP
    >>> lr.remove_effect(m1, "deadband").names  # doctest: +SKIP
    []
    """
    from labrig.diagnosis.loop.refit import without

    m = model_of(model)
    if name not in m.names:
        raise UserError(f"name: {name!r} is not an effect of the model; its effects: "
                        + (", ".join(m.names) or "none"))
    return without(m, name)


def compare(source, model, *, through: str | None = "auto", detail: bool = True):
    """The model simulated on the runs, against the measurements (``labrig compare``).

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        The runs, as :func:`read_runs` reads them.
    model : Model, model file or Identification
    through : {"auto", "loop", "input"} or None
        Closed-loop runs, as :func:`read_runs`'s.
    detail : bool
        False: the residuals, fit % and rmse/noise only, the same numbers without the
        regimes, stretches and correlations (what a slider redraws).

    Returns
    -------
    Evaluation
        Fit %, rmse/noise by run and regime, the residuals; ``plot()`` overlays model
        and measurement with the residual and its noise band.

    Raises
    ------
    UserError
        A run folder or model file that cannot be read, a model whose plant is not the
        runs' (one line naming the file and the fix).

    Examples
    --------
    >>> import labrig as lr
    >>> m = lr.identify("data/sweep_default").model()  # doctest: +SKIP
    >>> round(lr.compare("data/sweep_default", m).rmse)  # doctest: +SKIP
    8
    """
    from labrig.diagnosis.evidence.evaluation import evaluate

    return evaluate(read_runs(source, through=through), model_of(model), detail=detail)


def ladder(source, models, *, through: str | None = "auto"):
    """The error after each added effect, against the noise floor (``labrig ladder``).

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        The runs, as :func:`read_runs` reads them.
    models : list of Model, model file or Identification
        Simplest first; a file's rung is named after it.
    through : {"auto", "loop", "input"} or None
        Closed-loop runs, as :func:`read_runs`'s.

    Returns
    -------
    Ladder
        One rung a model: in-sample and held-out rmse/noise; ``plot()`` draws the ladder.

    Raises
    ------
    UserError
        A run folder or model file that cannot be read, or no model given.

    Examples
    --------
    >>> import labrig as lr
    >>> lad = lr.ladder("data/sweep_default", ["m0.json", "m1.json"])  # doctest: +SKIP
    >>> [round(s.rmse_over_noise["overall"]) for s in lad.steps]  # doctest: +SKIP
    [8, 1]
    """
    from os import PathLike

    from labrig.diagnosis.results.ladder import evaluate_ladder

    return evaluate_ladder(read_runs(source, through=through),
                           [m if isinstance(m, (str, PathLike)) else model_of(m) for m in models])
