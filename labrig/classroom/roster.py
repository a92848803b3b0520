"""A class file: the benches of one lab room, the people who use them, and how the room
is served.

Read once, at the boundary (:func:`read_class`): every key declared, every name one that
can become a folder name without leaving the class's folder, a mistake one line naming
the file, the key and the fix. Paths in it are relative to the class file.

Example (``class.toml``)::

    [class]
    name = "Servo lab, Tuesday"
    folder = "class_runs"         # each student's runs: class_runs/<student>/<bench>/
    booking_minutes = 45          # a seat ends by itself after this long
    watch = true                  # students may watch the other benches (read-only)

    [server]
    host = "0.0.0.0"              # the room's network (logins required)
    port = 5006

    [[bench]]
    name = "bench1"               # the simulated rig
    [[bench]]
    name = "bench2"
    rig = "emulate"               # the real firmware in simavr
    [[bench]]
    name = "bench3"
    rig = "board"                 # a board on this PC
    port = "/dev/ttyACM0"

    [people]
    students = ["ana", "ben"]
    instructors = ["kim"]
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Optional

from pydantic import AfterValidator, Field, model_validator

from labrig.core.errors import ConfigError
from labrig.core.schemas import ClosedModel, Num, read_toml, validate

#: a person's or a bench's name: it becomes a folder name and a word in the server's log,
#: so lower-case letters, digits, ``_`` and ``-`` only, starting with a letter
NAME_RE = re.compile(r"[a-z][a-z0-9_-]{0,31}")
NAME_RULE = ("a name of lower-case letters, digits, _ and - (at most 32), starting with "
             "a letter")


def _name(v: str) -> str:
    if not NAME_RE.fullmatch(v):
        raise ValueError(f"{v!r} is not {NAME_RULE}")
    return v


Name = Annotated[str, AfterValidator(_name)]


def _unique(v: list) -> list:
    seen = set()
    for x in v:
        if x in seen:
            raise ValueError(f"{x!r} is listed twice")
        seen.add(x)
    return v


class ClassSection(ClosedModel):
    name: Annotated[str, Field(min_length=1, max_length=80)] = "labrig class"
    folder: Annotated[str, Field(min_length=1, max_length=400)] = "class_runs"
    passwords: Annotated[str, Field(min_length=1, max_length=400)] = "class_passwords.json"
    booking_minutes: Num(gt=0, le=24 * 60) = 45.0
    watch: bool = True


class ServerSection(ClosedModel):
    host: Annotated[str, Field(min_length=1, max_length=255)] = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 5006
    #: how long a login lasts (the page asks for the password again after it)
    session_hours: Num(gt=0, le=24 * 7) = 8.0
    #: the server's own TLS (https://); or leave both out and put it behind a reverse proxy
    certfile: Optional[str] = None
    keyfile: Optional[str] = None
    #: the addresses students type (``host:port``) beyond this PC's own names: behind a
    #: reverse proxy, its public name (the page's websocket is refused from any other)
    origins: Annotated[list[Annotated[str, Field(min_length=1, max_length=255)]],
                       Field(max_length=20)] = []
    #: where bench PCs reach the class's Dask scheduler (TLS only; remote benches)
    dask_port: Annotated[int, Field(ge=1, le=65535)] = 8786
    #: the class's certificates (``labrig class certs``), relative to the class file
    certs: Annotated[str, Field(min_length=1, max_length=400)] = "certs"
    #: an HTTPS reverse proxy on this machine serves the class: the login cookie is sent
    #: over HTTPS only (``secure``), and the log names the client the proxy forwards
    #: (X-Real-IP, X-Forwarded-For), which only a server listening on this machine alone
    #: may believe
    behind_proxy: bool = False
    #: the server's cores the class's fits and grading share, first come first served:
    #: a booking's fit takes one (its numba and BLAS threads too), a grading two; default:
    #: every core of the server
    cores: Optional[Annotated[int, Field(ge=1, le=1024)]] = None

    @model_validator(mode="after")
    def _both_or_neither(self):
        if (self.certfile is None) != (self.keyfile is None):
            raise ValueError("give certfile and keyfile together (the server's TLS), or "
                             "neither (behind a reverse proxy, or this machine only)")
        if self.behind_proxy and self.certfile is not None:
            raise ValueError("behind_proxy: the proxy holds the TLS; remove certfile and "
                             "keyfile, or behind_proxy")
        if self.behind_proxy and self.host not in ("127.0.0.1", "localhost", "::1"):
            raise ValueError(f"behind_proxy: host = {self.host!r} lets anyone reach the "
                             "server past the proxy and forge the address it forwards; "
                             "listen on 127.0.0.1 where the proxy reaches it")
        return self


class BenchSection(ClosedModel):
    name: Name
    #: the simulated rig, the emulated board, a board on this PC, or a bench PC that
    #: serves its board to the class (``labrig class bench``)
    rig: Literal["sim", "emulate", "board", "remote"] = "sim"
    #: the serial device of a board on this PC (``rig = "board"``)
    port: Optional[Annotated[str, Field(min_length=1, max_length=255)]] = None
    #: the board's id (``labrig board id``): another board on the port is refused
    board_id: Optional[Annotated[int, Field(ge=0, le=2 ** 32 - 1)]] = None
    #: a rig file (TOML or mystery rig), relative to the class file; default the MS150
    rig_file: Optional[Annotated[str, Field(min_length=1, max_length=400)]] = None

    @model_validator(mode="after")
    def _port_for_a_board(self):
        if (self.rig == "board") != (self.port is not None):
            raise ValueError('a board on this PC needs its port (rig = "board", port = '
                             '"/dev/ttyACM0"); the simulated rig and the emulated board '
                             "take no port")
        return self


class PeopleSection(ClosedModel):
    students: Annotated[list[Name], Field(max_length=500), AfterValidator(_unique)] = []
    instructors: Annotated[list[Name], Field(min_length=1, max_length=50),
                           AfterValidator(_unique)]

    @model_validator(mode="after")
    def _one_role_each(self):
        both = sorted(set(self.students) & set(self.instructors))
        if both:
            raise ValueError(f"{both[0]!r} is both a student and an instructor; give one role")
        return self


class ClassFile(ClosedModel):
    """The class file's schema (TOML)."""

    class_: ClassSection = Field(default_factory=ClassSection, alias="class")
    server: ServerSection = Field(default_factory=ServerSection)
    bench: Annotated[list[BenchSection], Field(min_length=1, max_length=64)]
    people: PeopleSection

    @model_validator(mode="after")
    def _benches_named_once(self):
        _unique([b.name for b in self.bench])
        return self


@dataclass(frozen=True)
class ClassRoom:
    """A class file read and checked: its paths resolved against the file's folder."""

    path: Path
    name: str
    folder: Path
    passwords: Path
    booking_minutes: float
    watch: bool
    server: ServerSection
    benches: tuple[BenchSection, ...]
    students: tuple[str, ...]
    instructors: tuple[str, ...]

    def role(self, user: str | None) -> str | None:
        """``"student"``, ``"instructor"`` or None (not in this class)."""
        if user in self.instructors:
            return "instructor"
        return "student" if user in self.students else None

    def bench(self, name: str) -> BenchSection:
        for b in self.benches:
            if b.name == name:
                return b
        raise KeyError(f"no bench {name!r} in {self.path}")

    def seat_folder(self, student: str, bench: str) -> Path:
        """Where a student's runs on a bench go: ``<folder>/<student>/<bench>/`` (both
        names checked by the class file's rule, so the folder stays inside the class's)."""
        return self.folder / _name(student) / _name(bench)

    def resolve(self, relative: str | None) -> Path | None:
        return None if relative is None else (self.path.parent / relative)


def read_class(path: Path | str) -> ClassRoom:
    """Read and check a class file.

    Parameters
    ----------
    path : path
        The class file (TOML).

    Returns
    -------
    ClassRoom

    Raises
    ------
    ConfigError
        Not found, not TOML, or a key missing, unknown or out of range (one line naming
        the file and the key).
    """
    path = Path(path)
    doc = read_toml(path, "class")
    checked = validate(ClassFile, doc, path, ConfigError, section_word=True)
    c = checked.class_
    base = path.parent
    return ClassRoom(path=path, name=c.name, folder=base / c.folder,
                     passwords=base / c.passwords, booking_minutes=c.booking_minutes,
                     watch=c.watch, server=checked.server, benches=tuple(checked.bench),
                     students=tuple(checked.people.students),
                     instructors=tuple(checked.people.instructors))
