"""The class's certificates: an authority of its own, a certificate for the class server
(its Dask scheduler and client) and one per bench PC, made with :mod:`cryptography`.

Dask's TLS then admits only a connection whose certificate this authority signed, and
encrypts it: a stranger on the network can neither reach the scheduler (which runs any
code a client sends) nor read the samples. Keys are written readable by their owner
only; nothing is overwritten without ``force``. The authority's key signs new bench
certificates; keep it on the class server.
"""
from __future__ import annotations

import datetime as dt
import ipaddress
from pathlib import Path

from labrig.core.errors import UserError
from labrig.core.fileio import atomic_write

#: how long the certificates last (a school year and a little)
DAYS = 400


def _key():
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _name(cn: str):
    from cryptography.x509.oid import NameOID
    from cryptography import x509

    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "labrig class"),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _cert(subject: str, key, issuer: str, issuer_key, *, ca: bool, hosts=()):
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes

    now = dt.datetime.now(dt.timezone.utc)
    b = (x509.CertificateBuilder().subject_name(_name(subject)).issuer_name(_name(issuer))
         .public_key(key.public_key()).serial_number(x509.random_serial_number())
         .not_valid_before(now - dt.timedelta(minutes=5))
         .not_valid_after(now + dt.timedelta(days=DAYS))
         .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
    if hosts:
        names = []
        for h in hosts:
            try:
                names.append(x509.IPAddress(ipaddress.ip_address(h)))
            except ValueError:
                names.append(x509.DNSName(h))
        b = b.add_extension(x509.SubjectAlternativeName(names), critical=False)
    return b.sign(issuer_key, hashes.SHA256())


def _write(path: Path, data: bytes, secret: bool) -> None:
    # a key is 0600 from its creation, never readable for a moment; written whole or not
    atomic_write(path, data, mode=0o600 if secret else 0o644)


def _pem(cert=None, key=None) -> bytes:
    from cryptography.hazmat.primitives import serialization

    if cert is not None:
        return cert.public_bytes(serialization.Encoding.PEM)
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def make_certs(folder: Path | str, benches, hosts, *, force: bool = False) -> list[Path]:
    """An authority, the server's certificate (for ``hosts``) and one per bench.

    Parameters
    ----------
    folder : path
        Where they go: ``ca.pem``, ``ca.key``, ``server.pem``, ``server.key``,
        ``<bench>.pem``, ``<bench>.key``.
    benches : list of str
        The benches on other PCs.
    hosts : list of str
        The names and addresses the class server is reached by.
    force : bool
        Replace certificates already there.

    Returns
    -------
    list of Path
        The files written.
    """
    folder = Path(folder)
    names = ["ca", "server", *benches]
    files = [folder / f"{n}.{ext}" for n in names for ext in ("pem", "key")]
    there = [f for f in files if f.exists()]
    if there and not force:
        raise UserError(f"{there[0]}: exists; give `force` to make the class's "
                        "certificates again (every bench then needs its new one)")
    folder.mkdir(parents=True, exist_ok=True)
    ca_key = _key()
    ca = _cert("labrig class authority", ca_key, "labrig class authority", ca_key, ca=True)
    _write(folder / "ca.pem", _pem(ca), False)
    _write(folder / "ca.key", _pem(key=ca_key), True)
    for n in names[1:]:
        key = _key()
        cert = _cert(n, key, "labrig class authority", ca_key, ca=False,
                     hosts=list(hosts) if n == "server" else [])
        _write(folder / f"{n}.pem", _pem(cert), False)
        _write(folder / f"{n}.key", _pem(key=key), True)
    return files


def security(folder: Path | str, who: str):
    """Dask's TLS settings for ``who`` (``server`` or a bench): its certificate and key,
    the class's authority, encryption required.

    Raises
    ------
    UserError
        A file missing.
    """
    from distributed.security import Security

    folder = Path(folder)
    need = [folder / "ca.pem", folder / f"{who}.pem", folder / f"{who}.key"]
    for f in need:
        if not f.exists():
            raise UserError(f"{f}: not found; make the class's certificates with labrig "
                            "class certs CLASS.toml, and copy the bench's own to its PC")
    ca, cert, key = map(str, need)
    return Security(tls_ca_file=ca, tls_scheduler_cert=cert, tls_scheduler_key=key,
                    tls_worker_cert=cert, tls_worker_key=key, tls_client_cert=cert,
                    tls_client_key=key, require_encryption=True)
