"""Zenoh session configuration shared by the programs: endpoints, mutual TLS, access control.

With no endpoint given, the gateway listens on :data:`DEFAULT_ENDPOINT` and the emulators connect to it, so
that one cell finds itself on one machine over loopback only. Multicast scouting and gossip are off: peers
meet only where they are told to.

Every program of the cell runs with mutual TLS and the cell's access control (:mod:`hrc_runtime.access_control`)
by default: :func:`options_from_args` builds its :class:`SessionOptions` from its command line
(:func:`hrc_runtime.cli.add_zenoh_arguments`), and :func:`session_config` turns them into a Zenoh
configuration. Plain TCP, without authentication, encryption or access control, is for development only:
it needs ``--insecure-plain-tcp`` (or ``HRC_INSECURE_PLAIN_TCP=1`` in the environment, for test harnesses) in a
program, and is refused on any address but loopback, everywhere.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import zenoh

from hrc_contract.config import CellConfig, ConfigError
from hrc_runtime.access_control import CellPolicy, Ros2Policy, zenoh_access_control
from hrc_runtime.pki import LOOPBACK_HOSTS, CellPki, Identity, certificate_info, default_pki_dir

log = logging.getLogger("hrc.zenoh")

DEFAULT_ENDPOINT = "tls/127.0.0.1:7447"
PLAIN_TCP_ENV_VAR = "HRC_INSECURE_PLAIN_TCP"
"""Environment variable that, set to ``1``, allows plain TCP on loopback as ``--insecure-plain-tcp`` does."""
LEASE_MS = 1000
"""A frozen peer is seen gone after about a second instead of ten (field notes)."""

Mode = Literal["peer", "client", "router"]


class SecurityError(ConfigError):
    """A session would be less secure than allowed (plain TCP off loopback, mixed protocols). One line."""


@dataclass(frozen=True)
class MutualTls:
    """Mutual TLS with the cell CA, and the access control the session enforces on what it receives.

    Attributes:
        ca_certificate: the cell CA's certificate: only peers with a certificate it signed can connect.
        identity: this session's own certificate and key.
        policy: the cell's access control (default deny), or the ROS 2 session's; None for none (test tools only:
            an intruder).
    """

    ca_certificate: Path
    identity: Identity
    policy: CellPolicy | Ros2Policy | None


@dataclass(frozen=True)
class SessionOptions:
    """How a session joins the cell's Zenoh network, besides its endpoints.

    Attributes:
        mode: ``peer`` (default; programs meet directly), ``client`` (through a router, e.g. across hosts) or
            ``router`` (:mod:`hrc_tools.router.main`).
        tls: mutual TLS and access control; None for plain TCP on loopback (development and tests only).
    """

    mode: Mode = "peer"
    tls: MutualTls | None = None


PLAIN_TCP_LOOPBACK = SessionOptions()
"""Plain TCP, loopback only: what in-process test and benchmark sessions use unless given options."""


def endpoint_protocol(endpoint: str) -> str:
    """``tls`` of ``tls/127.0.0.1:7447``."""
    return endpoint.split("/", 1)[0] if "/" in endpoint else ""


def endpoint_host(endpoint: str) -> str:
    """The host of an endpoint (``127.0.0.1`` of ``tcp/127.0.0.1:7447#...``; ``::1`` of ``tcp/[::1]:7447``)."""
    address = endpoint.split("/", 1)[-1].split("?", 1)[0].split("#", 1)[0]
    if address.startswith("["):
        return address[1:].split("]", 1)[0]
    return address.rsplit(":", 1)[0]


def is_loopback(host: str) -> bool:
    """Whether ``host`` is ``localhost`` or a loopback address (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_endpoints(endpoints: Sequence[str], options: SessionOptions) -> None:
    """Refuse endpoints that do not fit the options: plain TCP only on loopback, TLS only with mutual TLS.

    Raises:
        SecurityError: an endpoint that is not allowed; the message names it and what is allowed.
    """
    for endpoint in endpoints:
        protocol = endpoint_protocol(endpoint)
        if not protocol:
            continue  # not an endpoint at all: Zenoh refuses it when the session opens, with its own reason
        if options.tls is not None:
            if protocol != "tls":
                raise SecurityError(
                    f"endpoint {endpoint!r} is not TLS; allowed with mutual TLS: tls/<host>:<port> endpoints only"
                )
        elif protocol != "tcp" or not is_loopback(endpoint_host(endpoint)):
            raise SecurityError(
                f"endpoint {endpoint!r} refused without TLS: plain TCP is allowed only on loopback "
                "(tcp/127.0.0.1:<port>) for development; use tls/ endpoints (the default) across hosts"
            )


def session_config(
    listen: Sequence[str] = (), connect: Sequence[str] = (), options: SessionOptions = PLAIN_TCP_LOOPBACK
) -> zenoh.Config:
    """A Zenoh configuration with explicit endpoints, no scouting, no shared memory, and the options' TLS and access
    control.

    Shared memory is off in every program: Zenoh (1.x) moves payloads above 3 kB (the gateway's status) through a
    16 MB pool of the sender, which a receiver maps and keeps, with its descriptors, for its own lifetime even after
    the sender exited (eclipse-zenoh/zenoh#2787): the soak's auditor grew by ~18 MB and 2 descriptors per gateway
    restart, the relays and emulators likewise. Copies over the link cost nothing worth that at these rates.

    Raises:
        SecurityError: see :func:`check_endpoints`.
    """
    check_endpoints([*listen, *connect], options)
    link: dict[str, Any] = {"tx": {"lease": LEASE_MS}}
    conf: dict[str, Any] = {
        "mode": options.mode,
        "listen": {"endpoints": list(listen)},
        "connect": {"endpoints": list(connect)},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": link, "shared_memory": {"enabled": False}},
    }
    if options.tls is None:
        link["protocols"] = ["tcp"]
    else:
        identity = options.tls.identity
        link["protocols"] = ["tls"]
        link["tls"] = {
            "root_ca_certificate": str(options.tls.ca_certificate),
            "enable_mtls": True,
            "listen_certificate": str(identity.certificate),
            "listen_private_key": str(identity.private_key),
            "connect_certificate": str(identity.certificate),
            "connect_private_key": str(identity.private_key),
            "verify_name_on_connect": True,
        }
        if options.tls.policy is not None:
            conf["access_control"] = zenoh_access_control(options.tls.policy)
    return zenoh.Config.from_json5(json.dumps(conf))


def mutual_tls(
    pki_dir: Path,
    common_name: str,
    policy: CellPolicy | Ros2Policy | None,
    hosts: Sequence[str] = (),
    *,
    create: bool = True,
) -> MutualTls:
    """Mutual TLS as ``common_name`` from the PKI folder; the identity is issued there if missing and ``create``.

    Args:
        pki_dir: the cell's PKI folder (:func:`hrc_runtime.pki.default_pki_dir`).
        common_name: this session's identity (:func:`hrc_runtime.pki.common_name`).
        policy: the access control to enforce; None for none.
        hosts: hosts this session listens on; an identity issued now names them, an existing one that does not
            is reported (peers connecting to such a host would refuse the certificate).
        create: issue a missing identity when the CA key is in ``pki_dir``.

    Raises:
        PkiError: the identity is missing and cannot be issued here, expired, or not from this CA.
    """
    pki = CellPki(pki_dir)
    extra_hosts = [h for h in dict.fromkeys(hosts) if h and h not in LOOPBACK_HOSTS and not _unspecified(h)]
    had_ca = pki.ca_certificate.exists()
    identity, issued = pki.identity(common_name, extra_hosts, create=create)
    if issued and not had_ca:
        log.warning(
            "created a new cell CA in %s: only programs with certificates of this CA can join; on a cell spread "
            "over hosts, copy ca.crt and this program's certificate from the CA's host instead (docs/security.md)",
            pki_dir,
        )
    if issued:
        log.info("issued a certificate for %r in %s (CA %s)", common_name, pki_dir, pki.ca_certificate)
    unnamed = [h for h in extra_hosts if h not in certificate_info(identity.certificate).hosts]
    if unnamed:
        log.warning(
            "certificate %s does not name %s: peers connecting there will refuse it; reissue it: "
            "hrc-cert issue --force --host %s ...",
            identity.certificate,
            ", ".join(unnamed),
            " --host ".join(unnamed),
        )
    return MutualTls(pki.ca_certificate, identity, policy)


def _unspecified(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_unspecified
    except ValueError:
        return False


def plain_tcp_allowed(args: argparse.Namespace) -> bool:
    """``--insecure-plain-tcp`` given, or ``HRC_INSECURE_PLAIN_TCP=1`` in the environment."""
    return bool(getattr(args, "insecure_plain_tcp", False)) or os.environ.get(PLAIN_TCP_ENV_VAR) == "1"


def options_from_args(
    args: argparse.Namespace,
    common_name: str,
    config: CellConfig,
    endpoints: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
) -> SessionOptions:
    """A program's session options from its command line (:func:`hrc_runtime.cli.add_zenoh_arguments`).

    TLS endpoints, or none (the default is TLS): mutual TLS as ``--tls-identity`` (default ``common_name``) from
    ``--pki-dir`` (issued there on first start when the CA key is there), with the cell's access control.
    Plain ``tcp/`` endpoints: only with ``--insecure-plain-tcp``, only on loopback, with a warning.

    Args:
        args: the parsed command line.
        common_name: the program's own identity, e.g. ``gateway`` or ``controller-ur5``.
        config: the cell (its name, robots and trackers make the access control).
        endpoints: the endpoints the session will use; default ``--zenoh-listen`` and ``--zenoh-connect``.
        listen: those it listens on (their hosts go into a certificate issued now); default ``--zenoh-listen``.

    Raises:
        SecurityError: plain TCP without the flag or off loopback, or TLS and other protocols mixed.
        PkiError: the identity cannot be had (see :func:`mutual_tls`).
        ConfigError: a tracker name the access control reserves.
    """
    mode: Mode = getattr(args, "zenoh_mode", "peer")
    if endpoints is None:
        endpoints = [*getattr(args, "zenoh_listen", []), *getattr(args, "zenoh_connect", [])]
    plain = [e for e in endpoints if endpoint_protocol(e) not in ("tls", "")]
    if plain:
        options = SessionOptions(mode)
        if any(endpoint_protocol(e) == "tls" for e in endpoints):
            raise SecurityError(f"TLS and non-TLS endpoints mixed ({', '.join(endpoints)}); allowed: one kind")
        if not plain_tcp_allowed(args):
            raise SecurityError(
                f"plain endpoint {plain[0]!r} refused: without TLS anyone who reaches it can command the robot; "
                "allowed: tls/ endpoints (the default), or tcp/ on loopback with --insecure-plain-tcp (development)"
            )
        check_endpoints(endpoints, options)
        # Loud whichever way it was asked for: an environment variable left in a service's environment must not
        # disable authentication silently.
        log.warning(
            "INSECURE (--insecure-plain-tcp or %s=1): plain TCP on %s: no authentication, no encryption, no access "
            "control; any local process can command the robot. Development only; refused off loopback.",
            PLAIN_TCP_ENV_VAR,
            ", ".join(endpoints),
        )
        return options
    pki_dir = Path(args.pki_dir) if getattr(args, "pki_dir", None) else default_pki_dir()
    if listen is None:
        listen = getattr(args, "zenoh_listen", [])
    identity = getattr(args, "tls_identity", None) or common_name
    tls = mutual_tls(pki_dir, identity, CellPolicy.from_config(config), [endpoint_host(e) for e in listen])
    return SessionOptions(mode, tls)
