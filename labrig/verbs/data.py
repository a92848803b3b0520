"""The lab's data as every verb reads it: runs, models, the catalogue, rig and plan files."""
from __future__ import annotations

from os import PathLike

from labrig.core.errors import UserError


def read_runs(source, *, through: str | None = "auto"):
    """The runs of ``source``, as every verb reads them.

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        A folder of runs (``*.csv`` with their ``.json`` sidecars), a run file, or
        runs already read; a list may mix them.
    through : {"auto", "loop", "input"} or None
        Closed-loop runs: fit through the loop, or from the logged controller output as
        the input; ``auto`` (the default, as ``--through``) takes the input when logged;
        None: the runs as read and in the commands' order, no way chosen (the batch,
        the demo and the report fit what they read).

    Returns
    -------
    list of Run
        Sorted by name, as ``labrig`` commands read them.

    Raises
    ------
    UserError
        An empty ``source``, something that is not a folder, run file or Run, or a run
        file that cannot be read (the message names the file and the row).

    Examples
    --------
    >>> import labrig as lr
    >>> [r.name for r in lr.read_runs("data/sweep_default")]
    ['cl_sq_0.50V', 'cl_sq_0.60V', 'sq_1.20V', 'sq_1.50V', 'sq_2.00V', 'sq_2.50V']
    """
    from labrig.identification.closedloop import choose_way

    if through is None:
        return runs_of(source, natural=True)
    runs, _ = choose_way(runs_of(source), through)
    return runs


def runs_of(source, *, natural: bool = False) -> list:
    """The runs of ``source`` as read, no way chosen for closed loops: sorted by name, or
    with ``natural`` in the order ``labrig`` commands read a folder (numbers in names by
    value: ``sq_3.00V`` before ``sq_12.00V``)."""
    from labrig.io.runs import Run, natural_key, read_dataset

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
    return sorted(runs, key=(lambda r: natural_key(r.name)) if natural else (lambda r: r.name))


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
    residuals and the experiment that confirms it.

    Returns
    -------
    Catalogue
        Iterates over the effects' names; ``to_pandas()`` is the table, and a notebook
        shows it.

    Examples
    --------
    >>> import labrig as lr
    >>> list(lr.effects())[:3]
    ['deadband', 'coulomb_friction', 'saturation']
    """
    from labrig.model.catalogue import Catalogue

    return Catalogue.builtin()


def effect(name: str):
    """The catalogue's effect ``name`` (an instance; an unknown name fails with the
    catalogue listed)."""
    from labrig.model.effects import get_effect

    return get_effect(name)


def parse_effects(names, origin: str | None = None):
    """Effects as ``--effects`` takes them (catalogue names, or ``FILE.py:Class`` of
    trusted code; a list or a comma-separated string) as an
    :class:`~labrig.model.effectset.EffectSet`; a bad name fails here, once (``origin``
    names where the names came from)."""
    from labrig.model.effectset import EffectSet

    return EffectSet.parse(names) if origin is None else EffectSet.parse(names, origin=origin)


def load_model(path):
    """A model file (``identify -o``, ``diagnose -o``) as a Model.

    Parameters
    ----------
    path : str or Path
        The model's JSON file.

    Returns
    -------
    Model

    Raises
    ------
    UserError
        A file that is not a labrig model (the message names the file and the key), or
        one naming user effects from code not trusted (``trust_code``).

    Examples
    --------
    >>> import labrig as lr
    >>> m = lr.load_model("m1.json")  # doctest: +SKIP
    >>> m.names  # doctest: +SKIP
    ['coulomb_friction']
    """
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
    """A plan file's experiments, checked against ``rig``; default the rig family's plan
    (``configs/plan_default.toml`` for an MS150, ``configs/plan_arduino.toml`` for an
    H-bridge gear motor)."""
    from labrig.io.config import load_plan as _load_plan

    return _load_plan(path, rig)


def run_origins(folder) -> list:
    """Where each run in ``folder`` comes from, read from the sidecars alone.

    Parameters
    ----------
    folder : str or Path
        A folder of runs (each ``NAME.csv`` beside its ``NAME.json``).

    Returns
    -------
    Origins
        A list of RunOrigin, per run: ``name``, ``source`` ("sim", "serial", "import",
        ...), ``rig`` (the rig it was recorded on), ``imported_from``, ``drive``, ``axis``
        and ``position`` (its sensor in words); ``.describe()`` says them in a line,
        ``.not_played_by(rig_name)`` keeps the runs another rig played or that were
        imported.

    Raises
    ------
    RunFileError
        A sidecar that does not validate (exit 2, naming the file).

    Examples
    --------
    >>> import labrig.verbs as lv
    >>> sorted({o.source for o in lv.run_origins("data/sweep_default")})
    ['sim']
    """
    from labrig.io.origins import run_origins as _origins

    return _origins(folder)


def plan_files() -> list:
    """The plans that come with labrig (``configs/plan_*.toml``)."""
    from labrig.io.config import CONFIG_DIR

    return sorted(CONFIG_DIR.glob("plan_*.toml"))


def check_plan(plan, rig) -> None:
    """Refuse a plan beyond the rig's output limit before anything moves."""
    from labrig.bridge.sweep import check_plan as _check

    _check(plan, rig)


def runs_for_fit(source, through: str = "auto"):
    """The runs as they will be fitted and the way their closed loops are: ``(runs,
    way)``; ``way.why`` says it in words, ``way.told`` whether the runs said it."""
    from labrig.identification.closedloop import choose_way

    return choose_way(runs_of(source, natural=True), through)


def import_run(src, output, mapping: str, *, controller: str | None = None, warn=None,
               **settings):
    """A foreign CSV or MATLAB .mat file written as a labrig run in ``output`` (``labrig
    import``): ``mapping`` as ``--map`` (``"t=Time,u=CH1,speed=RPM"``), ``controller`` as
    ``--controller`` (``"pd:kp=2,kd=0.1"``), the other settings as the command's options;
    ``warn(line)`` hears what the import had to assume. Returns the CSV's path."""
    from labrig.io.importer import import_csv, parse_controller, parse_map

    return import_csv(src, output, parse_map(mapping), controller=parse_controller(controller),
                      warn=warn, **settings)


def load_identify_config(path):
    """An identify config (TOML: ``[bounds]``, ``[fixed]``, ``effects = [...]``) as a dict;
    None: empty."""
    from labrig.io.identify_config import load_identify_config as _load

    return _load(path)


def drive_units(model) -> dict:
    """How ``model``'s effect levels read on its drive: ``{"coulomb_friction.tc_v":
    ("coulomb_friction.tc_nm", factor, "N m")}`` for each input-volt parameter on a
    torque or force drive (value in the drive's unit = factor x value); empty on a
    voltage drive."""
    from labrig.model.drive_units import shown_keys

    m = model_of(model)
    return shown_keys(m.effects, m.plant, m.constants)
