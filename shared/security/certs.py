"""Make a local certificate authority and one TLS certificate per identity (``racestack certs``).

What is made (``make_bundle``, pure: keys and certificates in memory):

* a CA: ECDSA P-256 key, self-signed, ``CN = racestack local CA``, basic constraints CA:true
  (path length 0), key usage keyCertSign + cRLSign;
* per identity: an ECDSA P-256 key and a certificate signed by the CA with ``CN = identity``
  (what the hub's ``access_control`` matches, ``cert_common_names``), SAN ``DNS:localhost,
  IP:127.0.0.1`` plus any extra hosts (every session can be a TLS server, e.g. the hub),
  extended key usage serverAuth + clientAuth (mutual TLS), valid ``days`` days.

``write_bundle`` writes it as PEM files (``shared.security.identities`` names them): keys with
mode 0600, certificates 0644; it refuses to overwrite an existing file unless ``force``.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from shared.security.identities import CA_CERT, CA_KEY, IDENTITIES, identity_files

#: Common name of the local CA.
CA_NAME = "racestack local CA"
#: Default validity of every certificate [days].
DEFAULT_DAYS = 825
#: Hosts every certificate is valid for (the loopback hub).
DEFAULT_HOSTS: tuple[str, ...] = ("localhost", "127.0.0.1")


class CertsError(ValueError):
    """The certificates cannot be made or written; one line saying why."""


@dataclass(frozen=True)
class PemPair:
    """One certificate and its private key, PEM-encoded."""

    cert_pem: bytes
    key_pem: bytes


@dataclass(frozen=True)
class Bundle:
    """A CA and the certificates it signed, by identity."""

    ca: PemPair
    identities: dict[str, PemPair]


def _san(hosts: Iterable[str]) -> x509.SubjectAlternativeName:
    names: list[x509.GeneralName] = []
    for h in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            names.append(x509.DNSName(h))
    return x509.SubjectAlternativeName(names)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def make_bundle(
    identities: Sequence[str] = IDENTITIES,
    *,
    hosts: Sequence[str] = DEFAULT_HOSTS,
    days: int = DEFAULT_DAYS,
    now: dt.datetime | None = None,
) -> Bundle:
    """A fresh CA and one certificate per identity (see the module docstring).

    Args:
        identities: the common names, ``[A-Za-z0-9_-]+`` each, no duplicates.
        hosts: DNS names / IP addresses in every certificate's SAN.
        days: validity [days] from `now` (> 0).
        now: the start of validity (None: the current UTC time minus 5 minutes of clock
            skew).
    """
    from shared.keys import check_chunk

    if days <= 0:
        raise CertsError(f"days must be > 0, not {days}")
    if len(set(identities)) != len(identities) or not identities:
        raise CertsError(f"identities must be distinct and not empty: {list(identities)}")
    for name in identities:
        try:
            check_chunk(name, "identity")
        except ValueError as exc:
            raise CertsError(str(exc)) from None
    start = now or (dt.datetime.now(dt.UTC) - dt.timedelta(minutes=5))
    end = start + dt.timedelta(days=days)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, CA_NAME)])
    ca_cert = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True, content_commitment=False, key_encipherment=False,
                data_encipherment=False, key_agreement=False, key_cert_sign=True,
                crl_sign=True, encipher_only=False, decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), False)
        .sign(ca_key, hashes.SHA256())
    )
    ca_ski = ca_cert.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value
    out: dict[str, PemPair] = {}
    for name in identities:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(start)
            .not_valid_after(end)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(
                x509.KeyUsage(
                    digital_signature=True, content_commitment=False, key_encipherment=False,
                    data_encipherment=False, key_agreement=True, key_cert_sign=False,
                    crl_sign=False, encipher_only=False, decipher_only=False,
                ),
                critical=True,
            )
            .add_extension(
                x509.ExtendedKeyUsage(
                    [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
                ),
                critical=False,
            )
            .add_extension(_san(hosts), critical=False)
            .add_extension(
                x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(ca_ski), False
            )
            .sign(ca_key, hashes.SHA256())
        )
        out[name] = PemPair(cert.public_bytes(serialization.Encoding.PEM), _key_pem(key))
    ca = PemPair(ca_cert.public_bytes(serialization.Encoding.PEM), _key_pem(ca_key))
    return Bundle(ca, out)


def bundle_files(out_dir: Path, bundle: Bundle) -> dict[Path, tuple[bytes, int]]:
    """Path -> (content, file mode) of every file of `bundle` in `out_dir` (pure)."""
    files = {
        out_dir / CA_CERT: (bundle.ca.cert_pem, 0o644),
        out_dir / CA_KEY: (bundle.ca.key_pem, 0o600),
    }
    for name, pair in bundle.identities.items():
        paths = identity_files(out_dir, name)
        files[paths.cert] = (pair.cert_pem, 0o644)
        files[paths.key] = (pair.key_pem, 0o600)
    return files


def write_bundle(out_dir: Path, bundle: Bundle, *, force: bool = False) -> list[Path]:
    """Write `bundle` into `out_dir` (created if needed); the paths written.

    Raises:
        CertsError: the folder is unusable, or a file exists and not `force` (nothing is
            written then).
    """
    from shared.outdir import writable_dir_problem

    problem = writable_dir_problem(out_dir)
    if problem is not None:
        raise CertsError(problem)
    files = bundle_files(out_dir, bundle)
    existing = sorted(str(p.name) for p in files if p.exists())
    if existing and not force:
        raise CertsError(
            f"{out_dir} already holds {', '.join(existing[:4])}"
            f"{' ...' if len(existing) > 4 else ''}; use --force to replace them"
        )
    written: list[Path] = []
    try:
        for path, (data, mode) in files.items():
            tmp = path.with_name(path.name + ".tmp")
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
            try:
                os.write(fd, data)
            finally:
                os.close(fd)
            os.chmod(tmp, mode)  # the umask may have taken bits off
            os.replace(tmp, path)
            written.append(path)
    except OSError as exc:
        raise CertsError(f"cannot write {out_dir}: {exc.strerror or exc}") from None
    return written


def make_certs(
    out_dir: Path,
    identities: Sequence[str] = IDENTITIES,
    *,
    hosts: Sequence[str] = DEFAULT_HOSTS,
    days: int = DEFAULT_DAYS,
    force: bool = False,
) -> list[Path]:
    """``make_bundle`` then ``write_bundle``: the whole ``racestack certs`` job."""
    return write_bundle(out_dir, make_bundle(identities, hosts=hosts, days=days), force=force)
