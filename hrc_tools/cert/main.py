"""``hrc-cert``: the cell's CA and certificates (mutual TLS identities for Zenoh).

    hrc-cert init  [--config PATH] [--pki-dir DIR]          CA + the identities of the cell's programs
    hrc-cert issue --role ROLE [--name NAME] [--host H]... [--force] [--pki-dir DIR]
    hrc-cert list  [--pki-dir DIR]

Roles and what each may do: :mod:`hrc_runtime.pki`, :mod:`hrc_runtime.access_control`. ``issue`` prints where the
certificate and key are: copy them with ``ca.crt`` (never ``ca.key``) to the host that needs them, and give
that program ``--pki-dir`` (and ``--tls-identity`` if its CN is not its default). Exits 2 with a one-line reason
on an invalid request.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hrc_contract.config import ConfigError
from hrc_runtime.access_control import CellPolicy, program_common_names
from hrc_runtime.config import load_cell_config
from hrc_runtime.pki import ROLES, CellPki, Identity, certificate_info, common_name, default_pki_dir

PROG = "hrc-cert"


def provision_cell(pki: CellPki, policy: CellPolicy) -> list[str]:
    """Create the CA if needed and issue every identity the cell's programs use that is missing.

    Returns:
        The CNs issued by this call (none when all were there).

    Raises:
        PkiError: the CA key is not in the folder, or an identity there is unusable.
    """
    issued = []
    for cn in program_common_names(policy):
        _, created = pki.identity(cn)
        if created:
            issued.append(cn)
    return issued


def _grant_note(role: str, name: str | None, config_path: str | None) -> str | None:
    """A warning when a named controller or tracker is not in the cell configuration (its puts would be denied)."""
    if role not in ("controller", "tracker") or name is None:
        return None
    try:
        config = load_cell_config(config_path)
    except ConfigError:
        return None
    names = config.robots if role == "controller" else config.trackers
    if name in names:
        return None
    kind = "robots" if role == "controller" else "trackers"
    return (
        f"note: {name!r} is not among the {kind} of cell {config.cell!r} ({', '.join(sorted(names))}): its puts are "
        f"denied until [{kind}.{name}] is added to the cell configuration"
    )


def _describe(identity: Identity) -> str:
    info = certificate_info(identity.certificate)
    return (
        f"{identity.common_name}: certificate {identity.certificate}\n"
        f"  private key {identity.private_key} (0600), valid until {info.not_after:%Y-%m-%d}, "
        f"hosts {', '.join(info.hosts)}"
    )


def main(args: argparse.Namespace) -> int:
    """Run one command. Returns the exit code.

    Raises:
        ConfigError: (and PkiError) an invalid role, name, configuration or PKI folder.
    """
    pki = CellPki(Path(args.pki_dir) if args.pki_dir else default_pki_dir())
    if args.command == "init":
        created_ca = pki.ensure_ca()
        issued = provision_cell(pki, CellPolicy.from_config(load_cell_config(args.config)))
        print(f"CA {pki.ca_certificate} ({'created' if created_ca else 'kept'}); issued: {', '.join(issued) or 'none'}")
    elif args.command == "issue":
        cn = common_name(args.role, args.name)
        identity = pki.identity_paths(cn)
        if identity.certificate.exists() and not args.force:
            print(f"{cn} exists (use --force to replace it):\n{_describe(identity)}")
            return 0
        identity = pki.issue(cn, args.host, replace=args.force)
        print(_describe(identity))
        print(f"  CA certificate {pki.ca_certificate}")
        note = _grant_note(args.role, args.name, args.config)
        if note:
            print(note)
    else:
        for info in pki.identities():
            print(f"{info.common_name:24} until {info.not_after:%Y-%m-%d}  hosts {', '.join(info.hosts)}")
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description="The cell's CA and mutual-TLS certificates")
    parser.add_argument("--pki-dir", default=None, metavar="DIR", help="default $HRC_STATE_DIR/pki, else .state/pki")
    commands = parser.add_subparsers(dest="command", required=True)
    init = commands.add_parser("init", help="create the CA and the identities of the cell's programs")
    init.add_argument("--config", default=None, metavar="PATH", help="cell configuration (default configs/cell.toml)")
    issue = commands.add_parser("issue", help="issue a certificate for a role")
    issue.add_argument("--role", required=True, choices=ROLES)
    issue.add_argument("--name", default=None, help="robot, tracker or observer name (controller, tracker, observer)")
    issue.add_argument(
        "--host", action="append", default=[], metavar="HOST", help="DNS name or IP others connect to (repeatable)"
    )
    issue.add_argument("--force", action="store_true", help="replace an existing certificate and key")
    issue.add_argument("--config", default=None, metavar="PATH", help="cell configuration, to check the name")
    commands.add_parser("list", help="list the certificates")
    return parser


def cli(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    try:
        code = main(args)
    except ConfigError as exc:
        sys.stderr.write(f"{PROG}: {' '.join(str(exc).split())}\n")
        sys.exit(2)
    sys.exit(code)


if __name__ == "__main__":
    cli()
