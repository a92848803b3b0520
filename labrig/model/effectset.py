"""A model's effects as one object (pysindy's ``ConcatLibrary`` is the pattern).

:class:`EffectSet` owns what used to be spread over the identifiers, the diagnosis and
the model file: the canonical order every simulator applies effects in, the rule of
one friction law, one output map and one delay per model, the ``"effect.param"``
naming of flat parameters, and the conversion between flat dicts, nested dicts and
columns of a candidate matrix.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from labrig.core.errors import UserError
from labrig.model.effects import Effect, get_effect, ordered

#: stages of which a model holds at most one effect (they do not compose)
SINGLE_STAGES = ("friction", "output", "delay")


def param_key(effect: str, param: str) -> str:
    """The flat name of an effect parameter, e.g. ``deadband.d_v``."""
    return f"{effect}.{param}"


class EffectSet(Sequence):
    """An ordered, checked collection of effects.

    Parameters
    ----------
    effects : iterable of Effect
    where : str
        Who gave them (an option or a file), for the error message.
    """

    def __init__(self, effects: Iterable[Effect] = (), where: str = "`effects`"):
        effects = list(effects)
        names = [e.name for e in effects]
        for n in names:
            if names.count(n) > 1:
                raise UserError(f"{where}: '{n}' given twice")
        for stage in SINGLE_STAGES:
            same = [e.name for e in effects if e.stage == stage]
            if len(same) > 1:
                raise UserError(f"{where}: {' and '.join(same)} both act as {stage}; pick one")
        families = [e.family_name for e in effects]
        for e in effects:
            if families.count(e.family_name) > 1:
                same = [x.name for x in effects if x.family_name == e.family_name]
                raise UserError(f"{where}: {' and '.join(same)} are both a {e.family_name}; "
                                "pick one")
        self._effects = ordered(effects)

    @classmethod
    def parse(cls, text, origin: str | None = None) -> "EffectSet":
        """``"deadband,coulomb_friction"`` or a list of names -> an EffectSet.

        ``origin``: the data file the names come from (``None``: the command line);
        a data file may name a user effect only from a trusted file.
        """
        if isinstance(text, EffectSet):
            return text
        if not text:
            return cls()
        items = text.split(",") if isinstance(text, str) else list(text)
        # effect objects pass through; names are looked up (and checked for trust)
        return cls([s if isinstance(s, Effect) else get_effect(s.strip(), origin)
                    for s in items if isinstance(s, Effect) or s.strip()],
                   where=origin or "`effects`")

    # -- sequence ----------------------------------------------------------------------
    def __getitem__(self, i):
        return self._effects[i]

    def __len__(self) -> int:
        return len(self._effects)

    def __add__(self, other) -> "EffectSet":
        return EffectSet(list(self._effects) + list(other))

    def __radd__(self, other) -> "EffectSet":
        return EffectSet(list(other) + list(self._effects))

    def __repr__(self) -> str:
        return f"EffectSet({', '.join(self.names) or 'linear'})"

    # -- naming --------------------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        return [e.name for e in self._effects]

    @property
    def specs(self) -> list[str]:
        """What a model file stores: the catalogue name, or FILE.py:Class for a user's."""
        return [getattr(e, "spec", e.name) for e in self._effects]

    def by_name(self, name: str) -> Effect:
        for e in self._effects:
            if e.name == name:
                return e
        raise KeyError(name)

    def stages(self) -> set[str]:
        return {e.stage for e in self._effects}

    def keys(self) -> list[str]:
        """Flat parameter names in order: ``effect.param`` for every effect."""
        return [param_key(e.name, p.name) for e in self._effects for p in e.params]

    # -- conversions -----------------------------------------------------------------------
    def nest(self, flat: dict) -> dict:
        """``{"deadband.d_v": x, "R": ...}`` -> ``{"deadband": {"d_v": x}}`` (plant keys ignored)."""
        return {e.name: {p.name: flat[param_key(e.name, p.name)] for p in e.params}
                for e in self._effects}

    @staticmethod
    def flatten(nested: dict) -> dict:
        """``{"deadband": {"d_v": x}}`` -> ``{"deadband.d_v": x}``."""
        return {param_key(e, k): v for e, ps in (nested or {}).items() for k, v in ps.items()}

    def split(self, phys: np.ndarray, offset: int) -> dict:
        """Columns ``offset:`` of a (P, D) candidate matrix -> ``{effect: {param: (P,)}}``."""
        out, k = {}, offset
        for e in self._effects:
            out[e.name] = {}
            for p in e.params:
                out[e.name][p.name] = phys[:, k]
                k += 1
        return out

    def units(self) -> list[tuple[str, object]]:
        """``(key, Param)`` of every parameter, in order."""
        return [(param_key(e.name, p.name), p) for e in self._effects for p in e.params]

    def bounds(self) -> list[tuple[str, float, float, bool]]:
        """``(key, lower, upper, log)`` of every parameter, from the catalogue (``log``:
        the parameter may be searched in log space when its lower bound is positive)."""
        return [(param_key(e.name, p.name), p.lower, p.upper, bool(p.log))
                for e in self._effects for p in e.params]

    def initial_guess(self, runs, plant) -> dict:
        """Every effect's data-driven starting point, flat."""
        out = {}
        for e in self._effects:
            guess = e.initial_guess(runs, plant)
            out.update({param_key(e.name, p.name): float(guess[p.name]) for p in e.params})
        return out
