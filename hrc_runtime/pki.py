"""The cell's public-key infrastructure: one CA, one certificate per program and role, in a state folder.

Zenoh's mutual TLS authenticates each end of a link by a certificate signed by the cell CA; its access control
then grants rights by the certificate's common name (CN), which names a role (:mod:`hrc_runtime.access_control`):

=============  =====================  ===========================================================
role           CN                     may put (everything else: read only)
=============  =====================  ===========================================================
gateway        ``gateway``            overrides, joint commands, gateway status; forwards to its clients what it let in
controller     ``controller-<robot>`` that robot's joint state, ground truth and emulator stats
tracker        ``tracker-<name>``     that tracker's humans
tracker-emu    ``tracker-emu``        every tracker's humans and the humans' ground truth
observer       ``observer-<name>``    nothing (auditor, dashboards, tests)
recorder       ``recorder``           nothing: subscribes to every cell topic (``hrc-record``)
operator       ``operator``           only ``hrc/<cell>/operator/track_reset``: an operator's reset of a lost person
router         ``router``             forwards what its own access control let in
relay          ``relay``              forwards (fault injection); controls itself
ros2           ``ros2``               on the ROS 2 session only: the topics of the gateway's ROS 2 face
=============  =====================  ===========================================================

On the gateway's ROS 2 session (``[ros2]``), a ``tracker-<name>`` certificate may put only that tracker's ROS 2
topic, ``tracker-emu`` every ROS 2 tracker's, and no other role anything (:class:`access_control.Ros2Policy`).

Layout of the folder (default ``$HRC_STATE_DIR/pki``, else ``<repo>/.state/pki``; mode 0700)::

    ca.crt  ca.key            the cell CA (the key signs certificates: keep it on one host only)
    <cn>.crt  <cn>.key        one identity per common name; every private key is mode 0600
    .lock                     serialises creation by several processes starting at once

Keys are ECDSA P-256; the CA is valid :data:`CA_VALIDITY_DAYS`, a certificate :data:`CERT_VALIDITY_DAYS`.
Every certificate names ``localhost`` and ``127.0.0.1`` (and any ``hosts`` given) in its subject alternative
names, since a Zenoh peer that connects to ``tls/<host>:<port>`` checks that the certificate it gets names
``<host>``.
"""

from __future__ import annotations

import datetime
import fcntl
import ipaddress
import os
import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, get_args

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from hrc_contract.config import ConfigError
from hrc_runtime.locate import find_state_dir

"""Environment variable naming the state folder (outside git); the PKI lives in its ``pki`` sub-folder."""
CA_VALIDITY_DAYS = 3650
CERT_VALIDITY_DAYS = 730
EXPIRY_WARNING_DAYS = 30
LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "::1")

Role = Literal[
    "gateway", "controller", "tracker", "tracker-emu", "observer", "recorder", "operator", "router", "relay", "ros2"
]
ROLES: tuple[Role, ...] = get_args(Role)
NAMED_ROLES: tuple[Role, ...] = ("controller", "tracker", "observer")
"""Roles whose common name carries a name: ``<role>-<name>``; the others are the role alone."""

_NAME = re.compile(r"[a-z0-9_]+(?:-[a-z0-9_]+)*")
_CA_CN_PREFIX = "hrc cell CA"


class PkiError(ConfigError):
    """The PKI cannot provide an identity (no CA, no certificate, bad role or name). The message is one line."""


@dataclass(frozen=True)
class Identity:
    """A certificate and its private key, signed by the cell CA.

    Attributes:
        common_name: the certificate's CN, e.g. ``controller-ur5``.
        certificate: path of the PEM certificate.
        private_key: path of the PEM private key (mode 0600).
    """

    common_name: str
    certificate: Path
    private_key: Path


@dataclass(frozen=True)
class CertificateInfo:
    """What a certificate says, for listings and checks.

    Attributes:
        common_name: the CN.
        hosts: DNS names and IP addresses of the subject alternative names.
        not_after: end of validity (UTC).
        issuer: the issuer's CN.
    """

    common_name: str
    hosts: tuple[str, ...]
    not_after: datetime.datetime
    issuer: str


def default_pki_dir(environ: dict[str, str] | None = None) -> Path:
    """``pki/`` in the state folder: ``$HRC_STATE_DIR/pki``, else the checkout's ``.state/pki``.

    Raises:
        NotFoundError: no state folder (:func:`hrc_runtime.locate.find_state_dir`).
    """
    return find_state_dir(environ) / "pki"


def common_name(role: str, name: str | None = None) -> str:
    """The CN of a role: ``<role>-<name>`` for the named roles, else the role itself.

    Raises:
        PkiError: unknown role, a named role without a name (or a name for another role), or a name outside
            ``[a-z0-9_-]+``.
    """
    if role not in ROLES:
        raise PkiError(f"unknown role {role!r}; allowed: {', '.join(ROLES)}")
    if role in NAMED_ROLES:
        if not name or not _NAME.fullmatch(name) or len(name) > 64:
            raise PkiError(f"role {role!r} needs --name made of [a-z0-9_-] (at most 64), not {name!r}")
        return f"{role}-{name}"
    if name:
        raise PkiError(f"role {role!r} takes no name (got {name!r}); named roles: {', '.join(NAMED_ROLES)}")
    return role


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.UTC)


def _write_private(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` with mode 0600 from the first byte on, atomically (temp file + rename)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)


def _write_public(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(data)
    tmp.chmod(0o644)
    os.replace(tmp, path)


def _san(hosts: Sequence[str]) -> x509.SubjectAlternativeName:
    names: list[x509.GeneralName] = []
    for host in dict.fromkeys(hosts):  # keep order, drop repeats
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return x509.SubjectAlternativeName(names)


def certificate_info(path: Path) -> CertificateInfo:
    """Read a PEM certificate.

    Raises:
        PkiError: the file is missing or not a PEM certificate.
    """
    try:
        cert = x509.load_pem_x509_certificate(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise PkiError(f"{path}: not a readable PEM certificate ({exc})") from None
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        hosts = tuple(san.get_values_for_type(x509.DNSName)) + tuple(
            str(ip) for ip in san.get_values_for_type(x509.IPAddress)
        )
    except x509.ExtensionNotFound:
        hosts = ()
    return CertificateInfo(_cn(cert.subject), hosts, cert.not_valid_after_utc, _cn(cert.issuer))


def _cn(name: x509.Name) -> str:
    attrs = name.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(attrs[0].value) if attrs else ""


class CellPki:
    """The PKI folder of a cell: its CA and the identities signed by it.

    Creation is idempotent and serialised by a lock file, so that several programs starting at once on a fresh
    machine create one CA, not several.
    """

    def __init__(self, root: Path) -> None:
        self.root = root

    @property
    def ca_certificate(self) -> Path:
        return self.root / "ca.crt"

    @property
    def ca_key(self) -> Path:
        return self.root / "ca.key"

    def identity_paths(self, cn: str) -> Identity:
        """Where the identity ``cn`` lives (whether or not it exists)."""
        return Identity(cn, self.root / f"{cn}.crt", self.root / f"{cn}.key")

    @contextmanager
    def _locked(self) -> Iterator[None]:
        self.root.mkdir(parents=True, exist_ok=True, mode=0o700)
        with (self.root / ".lock").open("a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)

    def ensure_ca(self) -> bool:
        """Create the CA if the folder has none. Returns True if it was created now.

        Raises:
            PkiError: the folder has a CA certificate without its key or the other way round.
        """
        with self._locked():
            return self._ensure_ca()

    def _ensure_ca(self) -> bool:
        have_cert, have_key = self.ca_certificate.exists(), self.ca_key.exists()
        if have_cert and have_key:
            return False
        if have_cert or have_key:
            missing = self.ca_key if have_cert else self.ca_certificate
            raise PkiError(f"{missing} is missing while the rest of the CA is there; restore it or remove {self.root}")
        key = ec.generate_private_key(ec.SECP256R1())
        name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"{_CA_CN_PREFIX} {os.urandom(4).hex()}")])
        now = _now()
        cert = (
            x509.CertificateBuilder()
            .subject_name(name)
            .issuer_name(name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=CA_VALIDITY_DAYS))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(
                x509.KeyUsage(
                    digital_signature=False,
                    content_commitment=False,
                    key_encipherment=False,
                    data_encipherment=False,
                    key_agreement=False,
                    key_cert_sign=True,
                    crl_sign=True,
                    encipher_only=False,
                    decipher_only=False,
                ),
                critical=True,
            )
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256())
        )
        _write_private(self.ca_key, _key_pem(key))
        _write_public(self.ca_certificate, cert.public_bytes(serialization.Encoding.PEM))
        return True

    def issue(self, cn: str, hosts: Sequence[str] = (), *, replace: bool = False) -> Identity:
        """Sign a new certificate for ``cn`` (creating the CA first if needed) and write it with its key.

        Args:
            cn: the common name, from :func:`common_name`.
            hosts: DNS names or IP addresses others use to reach this identity's listener, besides loopback.
            replace: overwrite an existing identity; without it an existing one is kept and returned.

        Raises:
            PkiError: the CA key is not in this folder (issue on the CA's host), or a half-present CA.
        """
        with self._locked():
            return self._issue(cn, hosts, replace)

    def _issue(self, cn: str, hosts: Sequence[str], replace: bool) -> Identity:
        identity = self.identity_paths(cn)
        if not replace and identity.certificate.exists() and identity.private_key.exists():
            return identity
        if self.ca_certificate.exists() and not self.ca_key.exists():
            raise PkiError(
                f"no CA key in {self.root} to sign {cn!r}: issue it where the CA key is "
                f"(hrc-cert issue ...) and copy {cn}.crt and {cn}.key here"
            )
        self._ensure_ca()
        ca_key = serialization.load_pem_private_key(self.ca_key.read_bytes(), password=None)
        if not isinstance(ca_key, ec.EllipticCurvePrivateKey):
            raise PkiError(f"{self.ca_key}: not an EC private key")
        ca_cert = x509.load_pem_x509_certificate(self.ca_certificate.read_bytes())
        key = ec.generate_private_key(ec.SECP256R1())
        now = _now()
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)]))
            .issuer_name(ca_cert.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=CERT_VALIDITY_DAYS))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(
                x509.KeyUsage(
                    digital_signature=True,
                    content_commitment=False,
                    key_encipherment=False,
                    data_encipherment=False,
                    key_agreement=False,
                    key_cert_sign=False,
                    crl_sign=False,
                    encipher_only=False,
                    decipher_only=False,
                ),
                critical=True,
            )
            .add_extension(
                x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                critical=False,
            )
            .add_extension(_san([*LOOPBACK_HOSTS, *hosts]), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256())
        )
        _write_private(identity.private_key, _key_pem(key))
        _write_public(identity.certificate, cert.public_bytes(serialization.Encoding.PEM))
        return identity

    def identity(self, cn: str, hosts: Sequence[str] = (), *, create: bool = True) -> tuple[Identity, bool]:
        """The identity ``cn``, issued now if missing and ``create`` (and the CA key is here).

        Returns:
            The identity and whether it was issued by this call.

        Raises:
            PkiError: missing and cannot be issued here; or its certificate is expired or not signed by this CA.
        """
        with self._locked():
            identity = self.identity_paths(cn)
            issued = False
            if not (identity.certificate.exists() and identity.private_key.exists()):
                if not create:
                    raise PkiError(
                        f"no certificate for {cn!r} in {self.root}; issue one: hrc-cert issue --pki-dir {self.root} "
                        f"--role ... (see docs/security.md)"
                    )
                identity, issued = self._issue(cn, hosts, replace=False), True
            if not self.ca_certificate.exists():
                raise PkiError(f"no CA certificate {self.ca_certificate}; copy it from the CA's host")
        self.check(identity)
        return identity, issued

    def check(self, identity: Identity) -> CertificateInfo:
        """Check that an identity is usable: CN as named, issued by this CA, not expired.

        Raises:
            PkiError: it is not.
        """
        info = certificate_info(identity.certificate)
        if info.common_name != identity.common_name:
            raise PkiError(f"{identity.certificate}: CN {info.common_name!r}, expected {identity.common_name!r}")
        cert = x509.load_pem_x509_certificate(identity.certificate.read_bytes())
        ca_cert = x509.load_pem_x509_certificate(self.ca_certificate.read_bytes())
        try:
            cert.verify_directly_issued_by(ca_cert)
        except (ValueError, TypeError, InvalidSignature):
            raise PkiError(
                f"{identity.certificate}: not signed by this cell's CA {_cn(ca_cert.subject)!r} "
                f"(issued by {info.issuer!r})"
            ) from None
        if info.not_after <= _now():
            raise PkiError(f"{identity.certificate}: expired on {info.not_after:%Y-%m-%d}; reissue it (hrc-cert issue)")
        if not os.access(identity.private_key, os.R_OK):
            raise PkiError(f"{identity.private_key}: not readable by this user")
        return info

    def identities(self) -> list[CertificateInfo]:
        """Every certificate in the folder but the CA's, by CN."""
        certs = sorted(p for p in self.root.glob("*.crt") if p != self.ca_certificate)
        return [certificate_info(p) for p in certs]


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    encoding, key_format = serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8
    return key.private_bytes(encoding, key_format, serialization.NoEncryption())
