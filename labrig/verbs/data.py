"""The lab's data as every verb reads it: runs, models, the catalogue, rig and plan files."""
from __future__ import annotations

from os import PathLike

from labrig.core.errors import UserError


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

    runs, _ = choose_way(runs_of(source), through)
    return runs


def runs_of(source) -> list:
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


def model_of(model):
    from labrig.model.model import Model

    if model is None or isinstance(model, Model):
        return model
    if isinstance(model, (str, PathLike)):
        return Model.load(model)
    if hasattr(model, "model") and callable(model.model):  # an Identification
        return model.model()
    raise UserError(f"model: {type(model).__name__} is not a Model, a model file or a fit")


def effects():
    """The effect catalogue: each effect's parameters, its physics, where it shows in the
    residuals and the experiment that confirms it. Returns a
    :class:`~labrig.model.catalogue.Catalogue`."""
    from labrig.model.catalogue import Catalogue

    return Catalogue.builtin()


def effect(name: str):
    """The catalogue's effect ``name`` (an instance; an unknown name fails with the
    catalogue listed)."""
    from labrig.model.effects import get_effect

    return get_effect(name)


def parse_effects(names):
    """Effects as ``--effects`` takes them (catalogue names, or ``FILE.py:Class`` of
    trusted code; a list or a comma-separated string) as an
    :class:`~labrig.model.effectset.EffectSet`; a bad name fails here, once."""
    from labrig.model.effectset import EffectSet

    return EffectSet.parse(names)


def load_model(path):
    """A model file (``identify -o``, ``diagnose -o``) as a :class:`~labrig.model.model.Model`."""
    from labrig.model.model import Model

    return Model.load(path)


def model_from_json(doc, what: str = "the model"):
    """A model's JSON document (``Model.to_json()``) as a :class:`~labrig.model.model.Model`;
    ``what`` names it in an error."""
    from labrig.model.model import Model

    return Model.from_json(doc, what)


def load_rig(path=None):
    """A rig file (TOML, or a ``.mystery`` file) as a :class:`~labrig.io.config.RigConfig`;
    default the MS150."""
    from labrig.io.config import load_rig as _load_rig

    return _load_rig(path)


def load_plan(path=None, rig=None):
    """A plan file's experiments, checked against ``rig``; default the lab's standard plan."""
    from labrig.io.config import load_plan as _load_plan

    return _load_plan(path, rig)


def plan_files() -> list:
    """The plans that come with labrig (``configs/plan_*.toml``)."""
    from labrig.io.config import CONFIG_DIR

    return sorted(CONFIG_DIR.glob("plan_*.toml"))


def check_plan(plan, rig) -> None:
    """Refuse a plan beyond the rig's output limit before anything moves."""
    from labrig.bridge.sweep import check_plan as _check

    _check(plan, rig)
