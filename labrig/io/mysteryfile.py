"""The mystery-rig file format: a rig document a student cannot read by opening it.

File format (``labrig-mystery/1``)::

    labrig-mystery/1
    salt <32 hex digits>
    <base64 text, 76 columns>

The payload is JSON -> zlib -> XOR with a SHA-256 counter keystream of a fixed key and
the salt -> base64. **This is obfuscation against casual reading (a student opening the
file in an editor, or grep), not security**: the key is in labrig/io/mysteryfile.py and anyone
who reads it can decode a mystery file. Do not use it to hide anything that matters.
A SHA-256 digest of the JSON inside the payload detects a damaged or edited file.
"""
from __future__ import annotations

import base64
import binascii
import hashlib
import json
import zlib
from pathlib import Path

from labrig.core.errors import ConfigError

HEADER = "labrig-mystery/1"
SUFFIX = ".mystery"
KEY = b"labrig mystery rig: obfuscation, not encryption"


def _keystream(salt: bytes, n: int) -> bytes:
    out = bytearray()
    counter = 0
    while len(out) < n:
        out += hashlib.sha256(KEY + salt + counter.to_bytes(8, "big")).digest()
        counter += 1
    return bytes(out[:n])


def _xor(data: bytes, salt: bytes) -> bytes:
    ks = _keystream(salt, len(data))
    return bytes(a ^ b for a, b in zip(data, ks))


def encode(content: dict) -> str:
    """``{"rig": doc, "seed": N}`` -> the text of a mystery file (no validation here)."""
    body = json.dumps(content, sort_keys=True).encode()
    payload = json.dumps({"sha256": hashlib.sha256(body).hexdigest(),
                          "body": body.decode()}).encode()
    salt = hashlib.sha256(KEY + body).digest()[:16]
    blob = base64.b64encode(_xor(zlib.compress(payload, 9), salt)).decode()
    lines = [HEADER, f"salt {salt.hex()}"] + [blob[i:i + 76] for i in range(0, len(blob), 76)]
    return "\n".join(lines) + "\n"


def decode(path: Path | str) -> dict:
    """A mystery file -> ``{"rig": doc, "seed": N | None}`` as stored (the rig is not
    validated here: see ``labrig.io.config.load_rig`` and ``labrig.io.mystery.load_mystery``);
    a damaged file is a ``ConfigError`` (exit 2) naming the file and what is wrong."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: mystery rig file not found")
    bad = f"{path}: not a valid mystery rig file"
    try:
        text = path.read_text(encoding="ascii")
    except (UnicodeDecodeError, OSError):
        raise ConfigError(f"{bad} (not text); ask for a fresh copy") from None
    lines = text.split("\n")
    if not lines or lines[0].strip() != HEADER:
        raise ConfigError(f"{bad} (first line is not '{HEADER}'); make one with "
                          "`labrig mystery new --seed N -o FILE.mystery`")
    try:
        tag, hexsalt = lines[1].split()
        if tag != "salt":
            raise ValueError
        salt = bytes.fromhex(hexsalt)
        blob = base64.b64decode("".join(s.strip() for s in lines[2:]), validate=True)
        payload = json.loads(zlib.decompress(_xor(blob, salt)))
        body = payload["body"].encode()
        if hashlib.sha256(body).hexdigest() != payload["sha256"]:
            raise ValueError("checksum")
        doc = json.loads(body)
        if not isinstance(doc.get("rig"), dict):
            raise ValueError("no rig")
    except (ValueError, IndexError, KeyError, TypeError, binascii.Error, zlib.error,
            UnicodeDecodeError, AttributeError, RecursionError, MemoryError):
        raise ConfigError(f"{bad} (damaged or edited: the contents do not decode); "
                          "ask for a fresh copy") from None
    seed = doc.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise ConfigError(f"{path}: key 'seed' must be an integer or null, got {seed!r}")
    return {"rig": doc["rig"], "seed": seed}
