"""A class's passwords, stored as scrypt hashes (the standard library's
:func:`hashlib.scrypt`), never in clear.

The file (JSON, written atomically, readable by its owner only) maps each person's
name to ``scrypt$N$r$p$<salt>$<hash>`` (salt and hash in base64). A password is checked
in constant time against its hash; a name without a hash costs the same work as one
with, so a login's timing does not tell who is in the class.
"""
from __future__ import annotations

import base64
import hashlib
import hmac
import os
from pathlib import Path
from typing import Annotated

from pydantic import Field, RootModel

from labrig.core.errors import ConfigError, UserError
from labrig.core.fileio import atomic_write, dumps
from labrig.core.schemas import read_json, validate
from labrig.classroom.roster import Name

#: scrypt's cost: N = 2**14, r = 8, p = 1 (16 MiB and ~50 ms a check: a guess costs as
#: much; the parameters are stored with each hash, so raising them later keeps old ones)
N, R, P = 2 ** 14, 8, 1
#: the shortest password the class file's tool accepts
MIN_LENGTH = 8
_HASH_RE = r"scrypt\$\d{1,8}\$\d{1,3}\$\d{1,3}\$[A-Za-z0-9+/=]{8,100}\$[A-Za-z0-9+/=]{8,200}"


class PasswordFile(RootModel):
    root: Annotated[dict[Name, Annotated[str, Field(pattern=_HASH_RE)]],
                    Field(max_length=1000)]


def _scrypt(password: str, salt: bytes, n: int, r: int, p: int) -> bytes:
    return hashlib.scrypt(password.encode("utf-8"), salt=salt, n=n, r=r, p=p,
                          maxmem=256 * 1024 * 1024, dklen=32)


def hash_password(password: str) -> str:
    """A fresh salt and ``password``'s scrypt hash, in the file's form."""
    salt = os.urandom(16)
    digest = _scrypt(password, salt, N, R, P)
    b64 = lambda b: base64.b64encode(b).decode("ascii")   # noqa: E731
    return f"scrypt${N}${R}${P}${b64(salt)}${b64(digest)}"


#: checked against when a name has no hash (the same work, then False)
_NOBODY = hash_password(os.urandom(12).hex())


def check_password(password: str, stored: str | None) -> bool:
    """True when ``password`` hashes to ``stored`` (compared in constant time)."""
    _, n, r, p, salt, digest = (stored or _NOBODY).split("$")
    got = _scrypt(password, base64.b64decode(salt), int(n), int(r), int(p))
    return hmac.compare_digest(got, base64.b64decode(digest)) and stored is not None


def read_passwords(path: Path | str) -> dict[str, str]:
    """The hashes in ``path`` (an empty class when the file does not exist yet)."""
    path = Path(path)
    if not path.exists():
        return {}
    doc = read_json(path, "password file", ConfigError)
    return dict(validate(PasswordFile, doc, path, ConfigError).root)


def set_password(path: Path | str, user: str, password: str, *, force: bool = False) -> Path:
    """Store ``user``'s password (its hash) in the password file ``path``.

    Parameters
    ----------
    path : path
        The class's password file (made if missing; only its owner may read it).
    user : str
        A name of the class file.
    password : str
        At least :data:`MIN_LENGTH` characters.
    force : bool
        Replace a password ``user`` already has.

    Raises
    ------
    UserError
        A short password, or a user who has one already without ``force``.
    """
    path = Path(path)
    if len(password) < MIN_LENGTH:
        raise UserError(f"a password of {len(password)} characters is too short; give at "
                        f"least {MIN_LENGTH}")
    hashes = read_passwords(path)
    if user in hashes and not force:
        raise UserError(f"{path}: {user} has a password already; give `force` to replace it")
    hashes[user] = hash_password(password)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, dumps(dict(sorted(hashes.items()))), mode=0o600)   # never readable by others
    return path
