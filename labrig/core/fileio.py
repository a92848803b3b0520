"""Writing files the way every labrig output is written: atomically, with the user's
umask, and as strict JSON (no inf/NaN); and what a data file must be before it is read."""
from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Callable

import stat

import numpy as np

from labrig.core.errors import WriteError


def not_regular(path: Path | str) -> str | None:
    """What ``path`` is when it is not a regular file a reader can finish ("a folder", "a
    FIFO (named pipe)", "a device", ...), following symlinks; None for a regular file or
    a path that does not exist. A FIFO would block a reader forever and /dev/zero never
    ends: both are refused before anything opens them."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return None
    except OSError as e:   # a name too long, a loop of symlinks, no permission
        return f"unreadable ({e.strerror})"
    if stat.S_ISREG(mode):
        return None
    for test, what in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return what
    return "not a regular file"


def size_within(path: Path, limit: int, error: Callable[[str], Exception], missing: str,
                too_big: Callable[[int], str]) -> int:
    """The size in bytes of the file at ``path``, checked before anything reads it.

    Parameters
    ----------
    path : Path
    limit : int
        The most bytes the reader takes.
    error : callable
        The exception to raise, given the line ``"PATH: ..."``.
    missing : str
        What the line says when there is no file at ``path``.
    too_big : callable
        What the line says for a size over ``limit``, given the size.

    Returns
    -------
    int
    """
    if not path.is_file():
        raise error(f"{path}: {missing}")
    size = path.stat().st_size
    if size > limit:
        raise error(f"{path}: {too_big(size)}")
    return size


def _umask() -> int:
    old = os.umask(0o022)
    os.umask(old)
    return old


def atomic_write(path: Path | str, text: str | bytes, mode: int | None = None) -> None:
    """Write ``text`` (or bytes) to ``path`` via a temporary file and a rename: a reader
    never sees a half-written file, and a crash leaves only a ``.NAME.*.tmp`` behind.
    ``mode`` (0o600 for a secret) is the file's from its creation, before its first byte;
    None follows the umask."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise _cannot_write(path, exc) from exc
    try:
        # mkstemp makes 0600; a run or model on a shared lab drive must be readable
        # like any other file the user writes, so follow the umask (a secret stays 0600)
        os.fchmod(fd, 0o666 & ~_umask() if mode is None else mode)
        binary = isinstance(text, bytes)
        with os.fdopen(fd, "wb" if binary else "w", **({} if binary else
                                                       {"encoding": "utf-8", "newline": ""})) as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and not isinstance(exc, WriteError):
            raise _cannot_write(path, exc) from exc
        raise


def _cannot_write(path: Path, exc: OSError) -> WriteError:
    """A failed write as one line: the file, the system's reason, what to do."""
    return WriteError(f"{path}: cannot be written ({exc.strerror or exc}): free some space "
                      "or write it elsewhere; nothing half-written was left")


def json_default(o):
    """``json.dumps(default=...)`` for numpy scalars, arrays and tuples."""
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, tuple):
        return list(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _as_is(x: Any) -> Any:
    return x


def finite_json(value: Any, *, key: Callable[[Any], Any] = _as_is,
                other: Callable[[Any], Any] = _as_is) -> Any:
    """``value`` with every non-finite float replaced by ``None``, at any depth.

    Python floats, numpy scalars and arrays inside dicts, lists and tuples are
    converted; dict keys and any other object are left as they are (``json``'s
    ``default`` deals with those). Strict JSON has no ``inf``/``nan``, and an
    unbounded interval or a diverged candidate's rmse must not end a command in
    an internal error.

    Parameters
    ----------
    value : Any
    key : callable, optional
        Applied to every dict key (by default the keys are kept).
    other : callable, optional
        Applied to every object of another type (by default it is kept): the
        identifier's results make a nested result its dict this way.

    Returns
    -------
    Any
    """
    def convert(v):
        if isinstance(v, dict):
            return {key(k): convert(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [convert(x) for x in v]
        if isinstance(v, np.ndarray):
            return convert(v.tolist())
        if isinstance(v, (bool, np.bool_)):
            return bool(v)
        if isinstance(v, np.integer):
            return int(v)
        if isinstance(v, (float, np.floating)):
            v = float(v)
            return v if math.isfinite(v) else None
        return other(v)

    return convert(value)


def dumps(obj: Any) -> str:
    """Strict, indented JSON of ``obj`` (non-finite numbers become null)."""
    return json.dumps(finite_json(obj), indent=2, allow_nan=False,
                      default=lambda o: finite_json(json_default(o))) + "\n"


def write_json(path: Path | str, obj: Any) -> Path:
    """``obj`` as strict JSON in ``path``, atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, dumps(obj))
    return path
