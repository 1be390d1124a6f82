"""A line's certificates: one CA, one certificate per role, for Zenoh's mutual TLS.

The router (deploy/zenohd.json5) accepts only TLS links whose client certificate the line's CA
signed, and its access control matches each link's certificate common name to a role. A
certificate's common name *is* its role name (``learner``, ``tracker``, ...): the router
config lists them. Keys are ECDSA P-256 in PKCS#8 PEM, written owner-only (0600).

``cryptography`` is imported inside the functions: ``robocal --help`` stays fast.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
import re
from dataclasses import dataclass
from pathlib import Path

from kinematics.errors import ConfigError

#: The roles of a line. ``learner`` is the robocal daemon (window, learner, compensation,
#: recorder stages); ``dashboard`` a daemon that only watches; ``compensation`` a client that
#: queries ``compensate``; ``router`` the Zenoh router's own (server) certificate.
ROLES = ("robot", "tracker", "daq", "learner", "dashboard", "compensation", "router")
#: Names the router's certificate is valid for, besides the ``--hosts`` given.
LOOPBACK_HOSTS = ("localhost", "127.0.0.1")
_NAME = re.compile(r"[a-z]+(-[a-z0-9]+)*")


@dataclass(frozen=True)
class LineCerts:
    """Paths written by :func:`make_line_certs`: the CA and ``role -> (cert, key)``."""

    ca: Path
    ca_key: Path
    roles: dict[str, tuple[Path, Path]]


def parse_roles(text: str) -> tuple[str, ...]:
    """Certificate names from ``"learner,tracker,compensation-plc2"``: a role, or a role, a
    dash and a suffix (a second client of that role); ConfigError on anything else."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if not _NAME.fullmatch(n) or n.split("-")[0] not in ROLES]
    if not names or bad:
        raise ConfigError(
            f"roles must be a comma list of {', '.join(ROLES)} (or role-suffix); bad: {bad}"
        )
    if len(set(names)) != len(names):
        raise ConfigError(f"roles repeated in {text!r}")
    return names


def make_line_certs(
    out: str | Path,
    roles: tuple[str, ...] = ROLES,
    hosts: tuple[str, ...] = (),
    days: int = 825,
    line: str = "robocal line",
) -> LineCerts:
    """Write ``ca.pem``/``ca.key`` and ``<role>.pem``/``<role>.key`` into ``out``.

    An existing CA in ``out`` is reused (adding a role later keeps the line's other
    certificates valid); an existing role certificate is refused rather than overwritten.
    ``hosts`` (names or IP addresses) go into the router certificate's subject alternative
    names, with ``localhost`` and ``127.0.0.1``: clients verify the router's name.
    """
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    if days < 1:
        raise ConfigError(f"days must be >= 1, got {days}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    parse_roles(",".join(roles))
    taken = [r for r in roles if (out / f"{r}.pem").exists() or (out / f"{r}.key").exists()]
    if taken:
        raise ConfigError(f"{out}: certificates for {taken} exist already (never overwritten)")
    ca_pem, ca_key_path = out / "ca.pem", out / "ca.key"
    if ca_pem.exists() != ca_key_path.exists():
        raise ConfigError(f"{out}: ca.pem and ca.key must both exist or neither")
    if ca_pem.exists():
        ca = x509.load_pem_x509_certificate(ca_pem.read_bytes())
        ca_key = serialization.load_pem_private_key(ca_key_path.read_bytes(), None)
    else:
        ca_key = _new_key()
        ca = _certificate(f"{line} CA", ca_key.public_key(), ca_key, None, days, ca=True)
        _write_key(ca_key_path, ca_key)
        ca_pem.write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    written = {}
    for role in roles:
        key = _new_key()
        names = (*LOOPBACK_HOSTS, *hosts) if role.split("-")[0] == "router" else (role,)
        cert = _certificate(role, key.public_key(), ca_key, ca, days, san=names)
        _write_key(out / f"{role}.key", key)
        (out / f"{role}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        written[role] = (out / f"{role}.pem", out / f"{role}.key")
    return LineCerts(ca_pem, ca_key_path, written)


def certificate_name(path: str | Path) -> str:
    """The common name of a PEM certificate: its role name on the line's bus."""
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    cert = x509.load_pem_x509_certificate(Path(path).read_bytes())
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(names[0].value) if names else ""


def _new_key():
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _write_key(path: Path, key) -> None:
    """PKCS#8 PEM, created owner-only (0600) so no other user ever reads it."""
    from cryptography.hazmat.primitives import serialization

    data = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _certificate(cn, public_key, signer, issuer, days, *, ca=False, san=()):
    """An X.509 v3 certificate for ``cn`` signed by ``signer`` (self-signed when no issuer)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])
    now = dt.datetime.now(dt.UTC)
    builder = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject if issuer is None else issuer.subject)
        .public_key(public_key)
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(public_key), critical=False)
    )
    if issuer is not None:
        ski = issuer.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value
        builder = builder.add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(ski), critical=False
        )
    if ca:
        usage = dict(key_cert_sign=True, crl_sign=True, digital_signature=False)
    else:
        usage = dict(key_cert_sign=False, crl_sign=False, digital_signature=True)
        eku = [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
        builder = builder.add_extension(x509.ExtendedKeyUsage(eku), critical=False)
        builder = builder.add_extension(
            x509.SubjectAlternativeName([_general_name(n) for n in san]), critical=False
        )
    builder = builder.add_extension(
        x509.KeyUsage(
            content_commitment=False,
            key_encipherment=False,
            data_encipherment=False,
            key_agreement=False,
            encipher_only=False,
            decipher_only=False,
            **usage,
        ),
        critical=True,
    )
    return builder.sign(signer, hashes.SHA256())


def _general_name(name: str):
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(name))
    except ValueError:
        return x509.DNSName(name)
