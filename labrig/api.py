"""The public verbs: what ``import labrig as lr`` gives a notebook or a script.

Every verb takes its data the same way — a folder of runs, a run file, a list of them,
or runs already read (:func:`read_runs`) — and has the command line's defaults, so
``lr.identify("runs")`` is ``labrig identify runs``. Each returns the result object the
command prints: it shows a one-screen summary as text, its tables and its figure in a
notebook, and has ``to_json()`` (the command's ``--json``), ``to_pandas()`` and
``plot(ax=None)``.

The loop in five lines::

    import labrig as lr
    runs = lr.read_runs("data/sweep_default")
    fit = lr.identify(runs)                     # the linear model (CO)
    diag = lr.diagnose(runs, fit.model())       # which effect is missing?
    better = lr.identify(runs, effects=[diag.recommendation], model=fit.model())
"""
from __future__ import annotations

from os import PathLike

from labrig.core.defaults import METHOD, SEED
from labrig.core.errors import UserError

__all__ = ["sweep", "read_runs", "analyse", "identify", "diagnose", "auto", "propose", "compare",
           "ladder", "effects", "load_model"]


def sweep(output, plan=None, rig=None, *, port: str | None = None, seed: int | None = None,
          resume: bool = False, on_progress=None):
    """Play a plan on the simulated rig (default) or the board at ``port`` and write one
    run per experiment to ``output`` (``labrig sweep``); returns the runs read back.

    Parameters
    ----------
    output : str or Path
        Folder for the runs; an existing run there is refused unless ``resume``.
    plan, rig : str or Path, optional
        Plan and rig files (TOML; a rig may be a ``.mystery`` file); default the lab's
        standard plan and the MS150 rig.
    port : str, optional
        Serial device of the bridge; without it the simulated rig plays the plan.
    seed : int, optional
        Noise seed of the simulated rig (default: the rig file's).
    on_progress : callable(n_samples), optional
        Called as samples arrive.
    """
    from labrig.bridge.sweep import sweep as _sweep
    from labrig.io.config import load_plan, load_rig

    rig_cfg = load_rig(rig)
    experiments = load_plan(plan, rig_cfg)
    if port:
        from labrig.bridge.serial import SerialBridge

        bridge = SerialBridge(port, rig_cfg)
    else:
        from labrig.bridge.sim import SimRig

        bridge = SimRig(rig_cfg, seed=seed)
    written = _sweep(bridge, experiments, rig_cfg, output, resume=resume,
                     on_progress=on_progress)
    return _runs([str(p) for p in written]) if written else _runs(output)


def read_runs(source, *, through: str = "auto"):
    """The runs of ``source``, as every verb reads them.

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        A folder of runs (``*.csv`` with their ``.json`` sidecars), a run file, or
        runs already read; a list may mix them.
    through : {"auto", "loop", "input"}
        Closed-loop runs: fit through the loop, or from the logged controller output as
        the input; ``auto`` (the default, as ``--through``) takes the input when logged.

    Returns
    -------
    list of Run
        Sorted by name, as ``labrig`` commands read them.
    """
    from labrig.identification.closedloop import choose_way

    runs, _ = choose_way(_runs(source), through)
    return runs


def _runs(source) -> list:
    from labrig.io.runs import Run, read_dataset

    items = list(source) if isinstance(source, (list, tuple)) else [source]
    if not items:
        raise UserError("source: empty; give a folder of runs, run files or Run objects")
    runs, paths = [], []
    for x in items:
        if isinstance(x, Run):
            runs.append(x)
        elif isinstance(x, (str, PathLike)):
            paths.append(x)
        else:
            raise UserError(f"source: {type(x).__name__} is not a folder, a run file or a Run")
    if paths:
        runs += read_dataset(paths)
    return sorted(runs, key=lambda r: r.name)


def _model(model):
    from labrig.model.model import Model

    if model is None or isinstance(model, Model):
        return model
    if isinstance(model, (str, PathLike)):
        return Model.load(model)
    if hasattr(model, "model") and callable(model.model):  # an Identification
        return model.model()
    raise UserError(f"model: {type(model).__name__} is not a Model, a model file or a fit")


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
             fixed: dict | None = None, bounds: dict | None = None, through: str = "auto",
             **options):
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
    start_model, start = _model(model), None
    if start_model is not None:
        start = start_model.flat()
        asked = start_model.effects + [e for e in asked if e.name not in start_model.names]
    return _identify(runs, method, asked, seed=seed, fixed=fixed, bounds=bounds, start=start,
                     **options)


def diagnose(source, model=None, *, candidates=None, seed: int = SEED,
             fixed: dict | None = None, through: str = "auto"):
    """Where the model fails and which catalogue effect is missing (``labrig diagnose``).

    ``model`` (a Model, a model file or an Identification) defaults to the linear model
    fitted here. Returns a :class:`~labrig.diagnosis.ranking.Diagnosis`; its
    ``recommended_model()`` is the re-fitted model with the recommended effect.
    """
    from labrig.diagnosis.diagnose import diagnose as _diagnose
    from labrig.model.effects import get_effect

    for c in candidates or ():
        get_effect(c)  # an unknown name fails here, with the catalogue listed
    return _diagnose(read_runs(source, through=through), _model(model), seed=seed,
                     fixed=fixed, candidates=list(candidates) if candidates else None)


def auto(source, model=None, *, max_rounds: int = 3, seed: int = SEED,
         fixed: dict | None = None, through: str = "auto", log=None, on_step=None):
    """The loop run to the end: add, pair, swap and remove effects while the
    cross-validated error falls (``labrig diagnose --auto``). Returns an
    :class:`~labrig.diagnosis.auto.AutoDiagnosis` with the final model and its ladder;
    ``log(line)`` receives the rounds' summaries and ``on_step(k, model)`` every rung as
    the search climbs the ladder."""
    from labrig.diagnosis.auto import auto_diagnose

    if max_rounds < 1:
        raise UserError(f"max_rounds: {max_rounds} adds nothing; give 1 or more")
    return auto_diagnose(read_runs(source, through=through), _model(model),
                         max_rounds=max_rounds, seed=seed, fixed=fixed, log=log,
                         on_step=on_step)


def propose(source, model, between: str | None = None, *, budget_s: float = 20.0,
            seed: int = SEED, rig=None, through: str = "auto"):
    """The experiment that best tells two explanations apart (``labrig propose``).

    ``between`` is ``"a,b"`` (default: the model's effect and its usual look-alike);
    ``rig`` a rig file or :class:`~labrig.io.config.RigConfig` whose limits bound the
    input. Returns a :class:`~labrig.diagnosis.proposal.Proposal`; ``to_toml()`` is the plan.
    """
    from labrig.io.config import RigConfig, load_rig
    from labrig.diagnosis.propose import propose as _propose

    amax = None
    if rig is not None:
        rig = rig if isinstance(rig, RigConfig) else load_rig(rig)
        amax = min(rig.bridge.output_limit_v, rig.amplifier.output_limit_v / rig.amplifier.gain)
    return _propose(read_runs(source, through=through), _model(model), between,
                    budget_s=budget_s, amax=amax, seed=seed, rig=rig)


def compare(source, model, *, through: str = "auto"):
    """The model simulated on the runs: fit %, rmse/noise by run and regime, residuals
    (``labrig compare``). Returns an :class:`~labrig.diagnosis.evaluation.Evaluation`; its
    ``plot()`` overlays model and measurement with the residual and its noise band."""
    from labrig.diagnosis.evaluation import evaluate

    return evaluate(read_runs(source, through=through), _model(model))


def ladder(source, models, *, through: str = "auto"):
    """The error after each added effect, against the noise floor (``labrig ladder``).

    ``models``: a list of Models, model files or fits, simplest first. Returns a
    :class:`~labrig.diagnosis.ladder.Ladder`.
    """
    from labrig.diagnosis.ladder import evaluate_ladder

    return evaluate_ladder(read_runs(source, through=through), [_model(m) for m in models])


def effects():
    """The effect catalogue: each effect's parameters, its physics, where it shows in the
    residuals and the experiment that confirms it. Returns a
    :class:`~labrig.model.catalogue.Catalogue`."""
    from labrig.model.catalogue import Catalogue

    return Catalogue.builtin()


def load_model(path):
    """A model file (``identify -o``, ``diagnose -o``) as a :class:`~labrig.model.model.Model`."""
    from labrig.model.model import Model

    return Model.load(path)
