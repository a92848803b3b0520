"""The base classes of every effect: a parameter, the effect, and one abstract class per
stage of the servo where an effect acts. The catalogue (``labrig.model.effects``) and a
user's own effects derive from these.
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass

STAGES = ("input", "drive", "friction", "output", "delay")


@dataclass(frozen=True)
class Param:
    """One effect parameter: name, unit, physical bounds and a description.

    Parameters
    ----------
    name : str
        The parameter's name in the effect (``effect.name`` in a model: ``deadband.d_v``).
    unit : str
        Its unit, as tables and figures print it ("V", "s", "rad").
    lower, upper : float
        The physical range a fit searches (finite, ``lower < upper``).
    doc : str
        One line: what the parameter is in the rig.
    log : bool
        Search it in log space (positive values spanning decades); False for a value
        that may be zero or negative (an offset).

    Examples
    --------
    >>> import labrig as lr
    >>> p = lr.Param("tc_v", "V", 1e-3, 2.0, "friction as the voltage that balances it")
    >>> p.name, p.unit, p.upper
    ('tc_v', 'V', 2.0)
    """

    name: str
    unit: str
    lower: float
    upper: float
    doc: str = ""
    log: bool = True  # search in log space (positive, spans decades)


class Effect(abc.ABC):
    """Base of every effect. Subclasses set ``name``, ``params`` and implement the hook
    of their stage; the catalogue's effects derive from the stage classes below
    (:class:`InputEffect`, :class:`DriveEffect`, :class:`FrictionEffect`,
    :class:`OutputEffect`, :class:`DelayEffect`), which declare the hook abstract.

    - ``input``/``drive``: ``apply(v, **p) -> v'`` (elementwise on arrays)
    - ``friction``: ``friction(plant, **p) -> (kinetic, breakaway)`` torque levels >= 0
      (``plant`` has R, K, Ka, maybe arrays over candidates); the simulator applies
      the Karnopp stick-slip rule with them
    - ``output``: ``output(state, x, **p) -> (state', y)`` a stateful map of the
      output-shaft angle x (the play operator for backlash)
    - ``delay``: ``delay_s(**p) -> seconds``

    ``initial_guess(runs, plant)`` returns a starting value for every parameter
    from data (``plant`` is a ``ServoParams`` with helper methods).

    A user effect may subclass ``Effect`` directly with ``stage`` set (the small
    interface of the first exercise sheets) or a stage class.

    Attributes
    ----------
    name : str
        The effect's name in a model and on the command line (``--effects NAME``).
    stage : {"input", "drive", "friction", "output", "delay"}
        Where it acts in the servo: the hook a subclass implements.
    params : tuple of Param
        Its parameters, with their units and the ranges a fit searches.
    summary, signature, experiment : str
        What it is in the rig, where it shows in the residuals of a model without it,
        and the experiment that confirms it (the catalogue's words).

    Examples
    --------
    A dry friction of one's own, as sheet 3 asks (``labrig identify --effects
    my_friction.py:MyCoulomb`` loads such a file):

    >>> import labrig as lr
    >>> class MyCoulomb(lr.Effect):
    ...     'Dry friction: a constant torque against the motion.'
    ...     name = "my_coulomb"
    ...     stage = "friction"
    ...     params = (lr.Param("tc_v", "V", 1e-3, 2.0, "friction as a voltage"),)
    ...     def friction(self, plant, tc_v):
    ...         t = tc_v * plant.Ka * plant.K / plant.R   # the stall torque of tc_v volts
    ...         return t, t                               # (kinetic, breakaway)
    ...     def initial_guess(self, runs, plant):
    ...         return {"tc_v": 0.1}
    >>> MyCoulomb().stage, [p.name for p in MyCoulomb.params]
    ('friction', ['tc_v'])
    """

    name: str = "effect"
    stage: str = "input"
    params: tuple = ()
    #: one line: what the effect is in the rig
    summary: str = ""
    #: where it shows in the residuals of a model that lacks it
    signature: str = ""
    #: the experiment that would confirm it
    experiment: str = ""
    #: parameter -> column of the fast simulator's kernel that holds it (built-in
    #: input, drive and output effects); empty: the simulator's general path
    kernel_columns: dict = {}
    #: effects of one family are alternatives: a model holds at most one of them
    #: (empty: the effect's own name)
    family: str = ""

    # -- what the loop knows about the effect (a user's effect may set these too) --
    #: the parameter that sets where the effect acts (a proposal varies it over what
    #: the data allow); empty: none
    threshold: str = ""
    #: the parameter that says how large the effect is, zero when it is absent (a dead
    #: zone's width, a delay, an offset): ``diagnose`` supports the effect only when the
    #: data resolve it (:mod:`labrig.diagnosis.evidence.resolution`); empty: not checked
    size: str = ""
    #: a member of the family with fewer parameters, tried in its place by the search
    simpler: str = ""
    #: fitted effects this one is tried in place of, starting from their values
    #: (:meth:`from_simpler`): an open-ended refinement only ever added to what the data
    #: already pin (the friction curve's Stribeck peak)
    extends: tuple = ()
    #: effects whose residuals look like this one's, in the order the search tries to
    #: swap them in for it
    look_alikes: tuple = ()
    #: its usual look-alike: what ``labrig propose`` separates it from by default
    rival: str = ""
    #: the effect a proposal tests in its place (the symmetric form of an asymmetric one)
    proposed_as: str = ""
    #: how it responds to each kind of input a proposal can play
    #: (:data:`labrig.design.inputs.KINDS`), in plain words
    responses: dict = {}
    #: the effect sets how much drive it takes to move (a dead zone, an offset, a friction
    #: level): when no single effect earns its parameters, the search fits pairs of such
    #: effects together, in this rank's order (None: not one of them). A user's effect
    #: with a rank joins the pairs like a built-in one
    pair_rank: int | None = None
    #: an open-ended effect (a curve, not one named mechanism): ``diagnose`` offers it only
    #: where :meth:`offered` says the data show what it adds, and a named effect that
    #: explains as well wins on parsimony
    open_ended: bool = False

    def offered(self, evaluation, runs) -> bool:
        """Whether ``diagnose`` tries this effect on a model whose evaluation (per run
        residuals, :class:`labrig.diagnosis.evidence.evaluation.Evaluation`) is ``evaluation``; a named
        effect always is."""
        return True

    def from_simpler(self, name: str, params: dict, runs) -> list[dict]:
        """Starts for this effect's re-fit in place of the fitted effect ``name`` (one of
        :attr:`extends`, with ``params``): the first reproduces it exactly, the others
        add some of what this effect adds; empty: it cannot, or not on these ``runs``."""
        return []

    def as_member(self, name: str, params: dict) -> list[dict]:
        """Starts for this effect's parameters standing where a fitted member of its family
        (``name``, its :attr:`simpler` or one whose simpler it is) stood with ``params``:
        the first reproduces it as closely as this effect can. ``diagnose`` fits each of a
        nested pair from the other's result too, so the richer one never explains the runs
        worse than the one it contains, and neither is left in a basin the other left.
        Empty: not a member it can stand for."""
        return []

    def inert(self) -> dict:
        """Parameter values that switch the effect off (``diagnose`` checks that the
        effect itself carries a candidate's gain); empty: unknown."""
        return {self.size: 0.0} if self.size else {}

    @property
    def family_name(self) -> str:
        return self.family or self.name

    def data_bounds(self, reach) -> dict:
        """``{param: (lower, upper)}`` from what the data can see
        (:class:`labrig.model.reach.Reach`); default: the catalogue's bounds."""
        return {}

    def scan_grid(self, reach) -> dict:
        """``{param: values}`` (arrays of one length): points to try before a local fit,
        so a threshold never starts where no gradient reaches it; default: none."""
        return {}

    def param_names(self) -> list[str]:
        return [p.name for p in self.params]

    def initial_guess(self, runs, plant) -> dict:
        return {p.name: math.sqrt(p.lower * p.upper) if p.log and p.lower > 0
                else 0.5 * (p.lower + p.upper) for p in self.params}

    def to_kernel(self, kernel, p: dict, plant) -> bool:
        """Write this effect into the fast kernel's parameter table.

        ``kernel.set(column, values)`` / ``kernel.add(column, values)`` act on the
        columns named in :data:`labrig.model.simulate.KERNEL_COLUMNS`; ``p`` maps
        each parameter to an array over candidates. Returns False when the kernel
        cannot represent the effect (the simulator then takes its general path).
        """
        if self.kernel_columns:
            for param, column in self.kernel_columns.items():
                kernel.set(column, p[param])
            return True
        base = STAGE_BASES.get(self.stage)
        if base is not None and not isinstance(self, base) \
                and base.to_kernel is not Effect.to_kernel:
            return base.to_kernel(self, kernel, p, plant)  # a plain Effect with stage set
        return False

    def explain_params(self, params: dict, context: dict) -> str:
        """The fitted parameters in plain words with units (``context``: the rig's
        constants ``Ka`` and the smallest open-loop amplitude ``amin``)."""
        units = {q.name: q.unit for q in self.params}
        return ", ".join(f"{k} = {v:.3g} {units.get(k, '')}".rstrip() for k, v in params.items())

    def describe(self) -> str:
        ps = ", ".join(f"{p.name} [{p.unit}]" for p in self.params)
        return f"{self.name} ({self.stage}; {ps}): {self.summary}"

    def __repr__(self):
        return f"<effect {self.name}>"


class InputEffect(Effect):
    """Maps the bridge voltage before the amplifier (dead zone, offset, asymmetry)."""

    stage = "input"

    @abc.abstractmethod
    def apply(self, v, **p):
        """The mapped input voltage (elementwise)."""


class DriveEffect(Effect):
    """Maps the armature voltage ``Ka u`` (the amplifier's rail)."""

    stage = "drive"

    @abc.abstractmethod
    def apply(self, v, **p):
        """The mapped armature voltage (elementwise)."""


class FrictionEffect(Effect):
    """A friction torque level; the simulators apply the Karnopp stick-slip rule."""

    stage = "friction"

    @abc.abstractmethod
    def friction(self, plant, **p):
        """``(kinetic, breakaway)`` torque levels >= 0."""

    def to_kernel(self, kernel, p, plant) -> bool:
        tc, ts = self.friction(plant, **p)
        kernel.add("tc", tc)
        kernel.add("ts", ts)
        return True


class OutputEffect(Effect):
    """A stateful map of the output-shaft angle seen by the pot (gear play)."""

    stage = "output"

    @abc.abstractmethod
    def output(self, state, x, **p):
        """``(state', y)``: the new state and the angle the pot sees."""


class DelayEffect(Effect):
    """A transport delay between the bridge output and the motor."""

    stage = "delay"

    @abc.abstractmethod
    def delay_s(self, **p):
        """The delay in seconds."""

    def to_kernel(self, kernel, p, plant) -> bool:
        kernel.add("td", self.delay_s(**p))
        return True


#: the stage classes, for user effects that subclass ``Effect`` with ``stage`` set
STAGE_BASES = {"input": InputEffect, "drive": DriveEffect, "friction": FrictionEffect,
               "output": OutputEffect, "delay": DelayEffect}
