"""A result declared once: its dataclass is its JSON form.

A result mixes in :class:`Record`; its dataclass fields, and the typed properties it marks
with :func:`pydantic.computed_field`, are the keys of its JSON. pydantic derives from that
one declaration the JSON (:meth:`Record.to_json`), the schema (:meth:`Record.json_schema`)
and the reading back (:meth:`Record.from_json`), so there is no hand-written writer and no
second document to keep in line with it. A field's JSON name, when it differs from its
Python name, is its pydantic ``alias``; a field the JSON does not keep has
``exclude=True``; a key written only when it says something has ``exclude_if``.

Examples
--------
>>> from dataclasses import dataclass
>>> @dataclass
... class Level(Record):
...     v: float
...     speed: Annotated[float, Field(alias="speed_rad_s")]
...
...     @computed_field
...     @property
...     def km(self) -> float:
...         return self.speed / self.v
>>> Level(2.0, 30.0).to_json()
{'v': 2.0, 'speed_rad_s': 30.0, 'km': 15.0}
>>> Level.from_json({"v": 2.0, "speed_rad_s": 30.0, "km": 15.0})
Level(v=2.0, speed=30.0)
>>> sorted(Level.json_schema()["properties"])
['km', 'speed_rad_s', 'v']
"""
from __future__ import annotations

from functools import cache
from typing import Annotated, Any, ClassVar, Optional

from pydantic import (BeforeValidator, ConfigDict, Field, PlainSerializer, TypeAdapter,
                      computed_field, with_config)

from labrig.core.fileio import finite_json

# (Field and computed_field are what a result's declaration uses; given here too, with
# Annotated, so a declaration's words are found in one place)
__all__ = ["Record", "AsJson", "AsList", "NoneIfEmpty", "TupleOf", "Num", "Live",
           "keeps_extra_keys", "unset", "empty", "Annotated", "Field", "computed_field"]

#: a number the JSON may hold as null
Num = Optional[float]
#: a field the JSON does not keep (a live object, or the flags behind a derived key)
Live = Field(exclude=True)
#: a nested record's TypedDict shape that carries keys beyond those it declares, as they are
keeps_extra_keys = with_config(ConfigDict(extra="allow"))


@cache
def _adapter(cls) -> TypeAdapter:
    return TypeAdapter(cls)


class Record:
    """Mixin for a result dataclass whose fields are its JSON form (module docstring).

    A subclass may set ``finite_json = True``: its JSON then has NaN and inf as None
    (:func:`labrig.core.fileio.finite_json`), for results whose JSON has always said so
    in Python too; and ``readable = False`` when its JSON is a summary that cannot give
    the result back (the live objects it was computed from are not in it).
    """

    # (arbitrary types: a field may hold a Model or an array; its annotation says how
    # it is written, e.g. :data:`AsJson`)
    __pydantic_config__ = ConfigDict(arbitrary_types_allowed=True, populate_by_name=True)
    finite_json: ClassVar[bool] = False
    readable: ClassVar[bool] = True

    def to_json(self) -> dict:
        """The result's JSON form (the keys its command's ``--json`` prints).

        Returns
        -------
        dict
            Every field and computed key under its JSON name; what the JSON does not
            keep is left out.
        """
        out = _adapter(type(self)).dump_python(self, mode="python", by_alias=True)
        return finite_json(out, key=str) if self.finite_json else out

    @classmethod
    def json_schema(cls) -> dict:
        """The JSON schema of :meth:`to_json`'s form, derived from the declaration.

        Returns
        -------
        dict
            A JSON Schema (draft 2020-12) object.
        """
        return _adapter(cls).json_schema(mode="serialization", by_alias=True)

    @classmethod
    def from_json(cls, doc: dict):
        """The result a JSON record was written from, less what the JSON does not keep.

        Parameters
        ----------
        doc : dict
            A record as :meth:`to_json` wrote it (read from a file, say).

        Returns
        -------
        Record
            An instance of ``cls``.

        Raises
        ------
        pydantic.ValidationError
            When ``doc`` lacks a key the result needs or holds a value of the wrong kind.
        TypeError
            When the result's JSON is a summary that cannot give it back (``readable``).
        """
        if not cls.readable:
            raise TypeError(f"{cls.__name__}'s JSON is a summary of live objects it does "
                            "not hold: it is not read back")
        return _adapter(cls).validate_python(doc, by_alias=True, by_name=True)


def _json_of(value) -> Any:
    return value.to_json() if value is not None else None


#: a field holding an object with its own ``to_json`` (a Model): written as that JSON
AsJson = PlainSerializer(_json_of)


def unset(value) -> bool:
    """For ``exclude_if``: the key is written only when its value is not None."""
    return value is None


def empty(value) -> bool:
    """For ``exclude_if``: the key is written only when its value says something (not
    None, 0, "", [] or {})."""
    return not value


#: an empty value (0, "", [], {}) written as null
NoneIfEmpty = PlainSerializer(lambda v: v or None)
#: a tuple written as a JSON list
AsList = PlainSerializer(list)
#: ... and read back as a tuple
TupleOf = Annotated[tuple, AsList, BeforeValidator(tuple)]

