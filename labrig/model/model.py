"""One model object for a fitted or given model: the plant, its effects, the rig's known
constants and what the fit reported.

Every command reads and writes :class:`Model`; nothing else builds model dicts. The
plant is a registered class (:data:`PLANTS`): a new kind of plant (a torque- or
force-driven axis) is a new class there, not a branch in every command.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from labrig.core.errors import UserError
from labrig.core.fileio import write_json
from labrig.core.schemas import ModelFile, read_json, validate
from labrig.model import drive_units
from labrig.model.effects import Effect, catalogue_name
from labrig.model.effectset import EffectSet, param_key
from labrig.model.plants import PLANTS, VoltagePlant, plant_class
from labrig.model.servo import ServoParams
from labrig.model.start import parse_key, start_key
from labrig.core.tables import Table, fmt, table_html

FORMAT = "labrig-model/1"



#: what a fit reports and a model file carries along (never used to compute)
INFO_KEYS = ("method", "fitness", "rmse_over_noise", "fit_percent", "noise", "seed", "nfev",
             "identifiable", "dataset")


@dataclass(repr=False)
class Model:
    """A DC-servo model: plant parameters, effects and their parameters, constants.

    Attributes
    ----------
    params : dict
        Plant parameters in SI units (R, L, J, B, K for the voltage-driven servo; J, B
        for a torque-driven axis; M, Fv for a force-driven linear one).
    effects : EffectSet
    effect_params : dict
        ``{effect name: {param: value}}``.
    constants : dict
        The rig's known constants: Ka (the amplifier's gain, or a torque/force drive's
        gain kd), N, Kt, Kpot and the loop gains kp, kv.
    plant : str
        Plant kind, a key of :data:`PLANTS`.
    info : dict
        What the fit reported (method, fitness, rmse_over_noise, ...), carried along.
    starts : dict
        The fitted start of each run that does not start at rest (see below).

    Examples
    --------
    >>> import labrig as lr
    >>> m = lr.Model(params={"R": 8.0, "L": 0.01, "K": 0.05, "J": 1e-4, "B": 1e-5})
    >>> m.names
    []
    >>> m.with_value("K", 0.06).params["K"]
    0.06
    """

    params: dict
    effects: EffectSet = field(default_factory=EffectSet)
    effect_params: dict = field(default_factory=dict)
    constants: dict = field(default_factory=dict)
    plant: str = VoltagePlant.kind
    info: dict = field(default_factory=dict)
    #: the fitted start of each run that does not start at rest (labrig.model.start):
    #: ``{run name: {"w0": motor speed at the first sample, "i0": the armature current
    #: there (a measured current only), "dtheta": the output shaft's offset from where its
    #: first samples read, "gap0": where the motor sits in the gear's play (a model with
    #: backlash)}}``; a run not named starts at rest
    starts: dict = field(default_factory=dict)

    def __post_init__(self):
        self.effects = EffectSet.parse(self.effects) if not isinstance(self.effects, EffectSet) \
            else self.effects
        self.plant = plant_class(self.plant, "model structure").kind

    @property
    def plant_class(self):
        """The plant's class (:data:`PLANTS` ``[plant]``): its parameter names, units and
        simulator form."""
        return PLANTS[self.plant]

    # -- flat form -------------------------------------------------------------------------
    def flat(self) -> dict:
        """Every parameter in one dict: plant names, then ``effect.param``.

        Returns
        -------
        dict
            ``{name: float}`` in SI units: the plant's parameters (``"J"``), the effects'
            (``"deadband.d_v"``), then each run's fitted start (``"start[RUN].w0"``).
        """
        out = {k: float(self.params[k]) for k in self.plant_class.names}
        out.update(EffectSet.flatten(self.effect_params))
        out.update({start_key(run, what): float(v) for run, st in self.starts.items()
                    for what, v in st.items()})
        return out

    @classmethod
    def from_flat(cls, flat: dict, effects, constants: dict | None = None,
                  plant: str = VoltagePlant.kind, info: dict | None = None) -> "Model":
        """A model from the flat form :meth:`flat` gives (the inverse of :meth:`flat`).

        Parameters
        ----------
        flat : dict
            ``{name: value}`` in SI units: every plant parameter, every parameter of
            ``effects`` as ``"effect.param"``, and optionally runs' starts as
            ``"start[RUN].w0"``; other keys are ignored.
        effects : EffectSet, str or list of str
            The model's effects (``"deadband,coulomb_friction"`` or a list of names).
        constants : dict, optional
            The rig's known constants (Ka, N, Kt, Kpot, kp, kv); None: none.
        plant : str, default "voltage"
            Plant kind, a key of :data:`PLANTS`.
        info : dict, optional
            What the fit reported, carried along; None: nothing.

        Returns
        -------
        Model
            Its effects parsed and checked, its parameters as given.

        Raises
        ------
        UserError
            An unknown effect name, or effects that conflict.
        """
        effects = EffectSet.parse(effects)
        names = PLANTS[plant].names
        starts: dict = {}
        for key, v in flat.items():
            run_what = parse_key(key)
            if run_what:
                starts.setdefault(run_what[0], {})[run_what[1]] = float(v)
        return cls(params={k: float(flat[k]) for k in names}, effects=effects,
                   effect_params={e: {k: float(v) for k, v in ps.items()}
                                  for e, ps in effects.nest(flat).items()},
                   constants=dict(constants or {}), plant=plant, info=dict(info or {}),
                   starts=starts)

    def with_effect(self, effect: Effect, params: dict) -> "Model":
        """This model plus ``effect`` with its ``params`` (nothing re-fitted).

        Parameters
        ----------
        effect : Effect
            The effect to add (an effect object, not a name).
        params : dict
            ``{param: value}`` for ``effect``, in the units :attr:`effect_params` holds.

        Returns
        -------
        Model
            A new model; this one is unchanged and the fit record (``info``) is dropped.

        Raises
        ------
        UserError
            ``effect`` is already in the model or conflicts with one of its effects.
        """
        eps = {**self.effect_params, effect.name: dict(params)}
        return replace(self, effects=self.effects + [effect], effect_params=eps, info={})

    def with_params(self, effect: str, **params) -> "Model":
        """This model with some of ``effect``'s parameters set (nothing re-fitted; the
        fit record, which no longer describes it, dropped).

        Parameters
        ----------
        effect : str
            The name of one of the model's effects.
        **params : float
            The parameters to set, ``name=value`` in the units :attr:`effect_params`
            holds; the effect's other parameters keep their values.

        Returns
        -------
        Model
            A new model; this one is unchanged.

        Raises
        ------
        KeyError
            ``effect`` is not an effect of the model.
        """
        eps = {**self.effect_params, effect: {**self.effect_params[effect],
                                              **{k: float(v) for k, v in params.items()}}}
        return replace(self, effect_params=eps, info={})

    def with_value(self, key: str, value: float) -> "Model":
        """This model with one parameter set: a plant's (``"J"``) or an effect's
        (``"deadband.d_v"``); nothing re-fitted, the fit record dropped.

        Parameters
        ----------
        key : str
            A plant parameter (``"J"``) or ``"effect.param"`` (``"deadband.d_v"``).
        value : float
            Its new value, in SI units (an effect's in the units :attr:`effect_params`
            holds).

        Returns
        -------
        Model
            A new model with ``key`` at ``value``, the fit record dropped; this one is
            unchanged.

        Raises
        ------
        KeyError
            ``key`` is not a parameter of this model.
        """
        if "." in key:
            effect, name = key.split(".", 1)
            if effect not in self.effect_params or name not in self.effect_params[effect]:
                raise KeyError(f"{key}: not a parameter of this model")
            return self.with_params(effect, **{name: value})
        if key not in self.params:
            raise KeyError(f"{key}: not a parameter of this model")
        return replace(self, params={**self.params, key: float(value)}, info={})

    def values_from(self, other: "Model") -> "Model":
        """This model's structure with the values ``other`` holds for its parameters (the
        plant, its effects', the runs' starts): a model whose own parameters a larger
        model's fit moved.

        Parameters
        ----------
        other : Model
            The model to take values from; a parameter it lacks keeps this model's value.

        Returns
        -------
        Model
            A new model with this model's structure, constants and fit record.
        """
        theirs = other.flat()
        flat = {k: theirs.get(k, v) for k, v in self.flat().items()}
        return Model.from_flat(flat, self.effects, self.constants, plant=self.plant,
                               info=dict(self.info or {}))

    def effects_with(self, asked) -> EffectSet:
        """This model's effects and those of ``asked`` it lacks, in that order: what a fit
        warm-started from this model adds to (``identify --model``, ``lr.add_effect``).

        Parameters
        ----------
        asked : EffectSet, str or list of str
            The effects asked for (``"deadband,coulomb_friction"`` or a list of names).

        Returns
        -------
        EffectSet

        Raises
        ------
        UserError
            An unknown effect name, or an asked effect that conflicts with the model's.
        """
        return self.effects + [e for e in EffectSet.parse(asked) if e.name not in self.names]

    @property
    def names(self) -> list[str]:
        """The names of the model's effects, in order (``[]`` for the linear model)."""
        return self.effects.names

    def servo(self) -> ServoParams:
        """The plant's parameters and the rig's constants in the simulators' form.

        Returns
        -------
        ServoParams
            R, L, J, B, K in SI units (a torque or force drive: its J, B with no back-EMF)
            and Ka, N, Kt, Kpot (a default where a constant is missing).
        """
        return self.plant_class.servo(self.params, self.constants)

    # -- files ---------------------------------------------------------------------------
    def to_json(self) -> dict:
        """The model file's content (``labrig-model/1``)."""
        doc = {"format": FORMAT, "structure": self.plant, "method": self.info.get("method"),
               "effects": self.effects.specs, "params": dict(self.params),
               "effect_params": self.shown_effect_params(),
               "constants": dict(self.constants)}
        doc.update({k: self.info[k] for k in INFO_KEYS if k in self.info and k != "method"})
        if self.starts:
            doc["starts"] = {run: dict(st) for run, st in self.starts.items()}
        if doc["method"] is None:
            doc.pop("method")
        return doc

    @classmethod
    def from_json(cls, doc: dict, origin: str) -> "Model":
        """A validated model document -> Model; effects are loaded as names from a data
        file (a user effect only from a file trusted with ``--trust-code``)."""
        structure = doc.get("structure") or VoltagePlant.kind
        structure = plant_class(structure, f"{origin}: key 'structure'").kind
        missing = [k for k in PLANTS[structure].names if k not in doc["params"]]
        if missing:
            raise UserError(f"{origin}: key 'params.{missing[0]}' missing; a {structure} plant "
                            f"has {', '.join(PLANTS[structure].names)}")
        extra = [k for k in doc["params"] if k not in PLANTS[structure].names]
        if extra:  # R, L, K in a torque plant: the file and its structure disagree
            raise UserError(f"{origin}: key 'params.{extra[0]}' is not a parameter of a "
                            f"{structure} plant (it has {', '.join(PLANTS[structure].names)}); "
                            "remove it, or fix 'structure'")
        effects = EffectSet.parse(doc.get("effects", []), origin=f"{origin}: key 'effects'")
        # a hand-written file may spell a catalogue effect in any case ("Deadband")
        eps = {catalogue_name(k): v for k, v in (doc.get("effect_params") or {}).items()}
        # a torque or force drive's file names its levels in N m or N (drive_units)
        eps = drive_units.from_drive(effects, eps, structure, dict(doc.get("constants") or {}))
        shown = drive_units.shown_keys(effects, structure, dict(doc.get("constants") or {}))
        for e in effects:
            for p in e.params:
                if not isinstance((eps.get(e.name) or {}).get(p.name), (int, float)):
                    key = shown.get(f"{e.name}.{p.name}", (f"{e.name}.{p.name}",))[0]
                    raise UserError(f"{origin}: key 'effect_params.{key}' missing or not a "
                                    "number")
        info = {k: doc[k] for k in INFO_KEYS if k in doc}
        starts = {run: {k: float(v) for k, v in st.items()}
                  for run, st in (doc.get("starts") or {}).items()}
        return cls(starts=starts,
                   params={k: float(doc["params"][k]) for k in PLANTS[structure].names},
                   effects=effects,
                   effect_params={e.name: {p.name: float(eps[e.name][p.name]) for p in e.params}
                                  for e in effects},
                   constants=dict(doc.get("constants") or {}), plant=structure, info=info)

    @classmethod
    def load(cls, path: Path | str) -> "Model":
        """Read, validate and load a model file.

        Parameters
        ----------
        path : str or Path
            A ``labrig-model/1`` JSON file (what :meth:`save` writes).

        Returns
        -------
        Model
            The file's plant, effects, constants and fit record.

        Raises
        ------
        UserError
            The file is missing, too big, not JSON or not a labrig model, or a key is
            missing or wrong (one line naming the file and the key).
        """
        return cls.from_json(read_model_file(path), str(path))

    def save(self, path: Path | str) -> Path:
        """Write the model file atomically (the caller checks --force first).

        Parameters
        ----------
        path : str or Path
            Where to write; its folder is made if missing, an existing file replaced.

        Returns
        -------
        Path
            ``path``, as a :class:`~pathlib.Path`.
        """
        return write_json(path, self.to_json())

    # -- simulation ------------------------------------------------------------------------
    def simulate(self, runs) -> list[dict]:
        """Simulate this model on ``runs``, each with its fitted start (or from rest).

        Parameters
        ----------
        runs : list of Run
            The runs whose inputs drive the simulation (open or closed loop as each
            run's sidecar says).

        Returns
        -------
        list of dict
            Per run ``{"w": (n,), "theta": (n,), "i": (n,)}``: motor speed (rad/s or
            m/s), output position (rad or m) and the armature current (A; on a torque
            or force drive, the drive's torque or force).

        Raises
        ------
        UserError
            A user-written input or drive effect on a closed-loop run (it is simulated
            on open-loop runs only).
        """
        # the simulator brings numba (~0.12 s more to import); reading or writing a model
        # file never simulates
        from labrig.model.simulate import Simulator

        sim = Simulator(runs, self.effects, plant=self.plant_class)
        plant = np.array([[self.params[k] for k in self.plant_class.names]])
        starts = [self.starts.get(r.name) for r in sim.runs] if self.starts else None
        out = sim.simulate(plant, {e: {k: np.array([v]) for k, v in ps.items()}
                                   for e, ps in self.effect_params.items()}, starts)
        return [{"w": s["w"][0], "theta": s["theta"][0], "i": s["i"][0]} for s in out]

    def __repr__(self) -> str:
        return f"Model({self.plant}: {self.describe()})"

    def _repr_html_(self) -> str:
        t = Table(f"{' + '.join(['linear'] + self.names)} ({self.plant} plant)",
                  ["parameter", "value"], numeric=(1,))
        t.rows = [[k, fmt(v, ".4g")] for k, v in self.params.items()]
        t.rows += [[f"{e}.{k}", fmt(v, ".4g")] for e, ps in self.shown_effect_params().items()
                   for k, v in ps.items()]
        return table_html(t)

    def shown_effect_params(self) -> dict:
        """The effects' parameters as a user reads them: in the drive's units on a torque
        or force drive (``tc_nm``, ``tc_n``; :mod:`labrig.model.drive_units`), as they
        are on a voltage drive.

        Returns
        -------
        dict
            ``{effect name: {param: value}}``.
        """
        return drive_units.to_drive(self.effects, self.effect_params, self.plant, self.constants)

    def describe(self) -> str:
        """One line: the structure and its parameters.

        Returns
        -------
        str
            ``"linear + deadband (R = 8, ...; deadband: d_v = 0.3)"``: plant parameters
            in SI units, effects' as :meth:`shown_effect_params` gives them.
        """
        ps = ", ".join(f"{k} = {v:.4g}" for k, v in self.params.items())
        eff = "; ".join(f"{e}: " + ", ".join(f"{k} = {v:.3g}" for k, v in p.items())
                        for e, p in self.shown_effect_params().items())
        return f"{' + '.join(['linear'] + self.names)} ({ps}{'; ' + eff if eff else ''})"


def param_keys(model: Model) -> list[str]:
    """Flat names of every parameter of ``model``, plant first."""
    return list(model.plant_class.names) + [param_key(e.name, p.name)
                                            for e in model.effects for p in e.params]


def read_model_file(path: Path | str) -> dict:
    """A model file parsed and validated (schema :class:`labrig.core.schemas.ModelFile`), as a
    plain dict; nothing in it is loaded or run (``mystery check`` grades it as is)."""
    path = Path(path)
    doc = read_json(path, "model file", UserError,
                    f" (make one with `labrig identify DIR -o {path.name}`)")
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise UserError(f"{path}: key 'format' must be \"{FORMAT}\"; is this a labrig model?")
    return validate(ModelFile, doc, path, UserError).model_dump(exclude_unset=True)
