"""The cell PKI: CA and identities created once, private keys 0600, names checked, foreign certificates refused."""

from __future__ import annotations

import stat
import threading
from pathlib import Path

import pytest

from hrc_runtime.locate import STATE_DIR_ENV_VAR
from hrc_runtime.pki import NAMED_ROLES, ROLES, CellPki, PkiError, certificate_info, common_name, default_pki_dir


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_ca_is_created_once_with_private_files(tmp_path: Path) -> None:
    pki = CellPki(tmp_path / "pki")
    assert pki.ensure_ca() is True
    ca_bytes = pki.ca_certificate.read_bytes()
    assert pki.ensure_ca() is False  # kept, not replaced
    assert pki.ca_certificate.read_bytes() == ca_bytes
    assert _mode(pki.ca_key) == 0o600
    assert _mode(pki.root) == 0o700
    assert certificate_info(pki.ca_certificate).common_name.startswith("hrc cell CA")


def test_identity_is_issued_by_the_ca_with_loopback_and_given_hosts(tmp_path: Path) -> None:
    pki = CellPki(tmp_path / "pki")
    identity, issued = pki.identity("router", ["10.0.0.1", "cell-router.local"])
    assert issued
    info = pki.check(identity)
    assert info.common_name == "router"
    assert set(info.hosts) >= {"localhost", "127.0.0.1", "::1", "10.0.0.1", "cell-router.local"}
    assert info.issuer == certificate_info(pki.ca_certificate).common_name
    assert _mode(identity.private_key) == 0o600
    again, issued_again = pki.identity("router")
    assert not issued_again
    assert again.certificate.read_bytes() == identity.certificate.read_bytes()


def test_replace_issues_a_new_key(tmp_path: Path) -> None:
    pki = CellPki(tmp_path / "pki")
    first = pki.issue("gateway")
    key_before = first.private_key.read_bytes()
    assert pki.issue("gateway").private_key.read_bytes() == key_before  # kept without replace
    assert pki.issue("gateway", replace=True).private_key.read_bytes() != key_before


@pytest.mark.parametrize(
    ("role", "name", "expected"),
    [
        ("gateway", None, "gateway"),
        ("controller", "ur5", "controller-ur5"),
        ("tracker", "lidar2", "tracker-lidar2"),
        ("observer", "audit", "observer-audit"),
        ("tracker-emu", None, "tracker-emu"),
        ("router", None, "router"),
        ("relay", None, "relay"),
    ],
)
def test_common_name_of_each_role(role: str, name: str | None, expected: str) -> None:
    assert common_name(role, name) == expected


@pytest.mark.parametrize(
    ("role", "name", "says"),
    [
        ("admin", None, ", ".join(ROLES)),
        ("tracker", None, "needs --name"),
        ("controller", "UR5", "needs --name"),
        ("observer", "a/b", "needs --name"),
        ("gateway", "two", "takes no name"),
    ],
)
def test_common_name_errors_say_what_is_allowed(role: str, name: str | None, says: str) -> None:
    with pytest.raises(PkiError, match=r"allowed|needs|takes") as info:
        common_name(role, name)
    assert says in str(info.value)


def test_named_roles_are_roles() -> None:
    assert set(NAMED_ROLES) <= set(ROLES)


def test_missing_identity_without_create_names_the_command(tmp_path: Path) -> None:
    pki = CellPki(tmp_path / "pki")
    pki.ensure_ca()
    with pytest.raises(PkiError, match="hrc-cert issue"):
        pki.identity("tracker-lidar2", create=False)


def test_host_without_ca_key_uses_copied_identities_but_cannot_issue(tmp_path: Path) -> None:
    """A second host gets ca.crt and its own certificate and key, never ca.key."""
    ca_host = CellPki(tmp_path / "ca-host")
    issued = ca_host.issue("controller-ur5")
    other = CellPki(tmp_path / "robot-host")
    other.root.mkdir()
    for src in (ca_host.ca_certificate, issued.certificate, issued.private_key):
        (other.root / src.name).write_bytes(src.read_bytes())
    identity, created = other.identity("controller-ur5")
    assert not created
    other.check(identity)
    with pytest.raises(PkiError, match="no CA key"):
        other.identity("gateway")


def test_certificate_of_another_ca_is_refused(tmp_path: Path) -> None:
    ours, theirs = CellPki(tmp_path / "ours"), CellPki(tmp_path / "theirs")
    ours.ensure_ca()
    forged = theirs.issue("gateway")  # same CN, other CA
    target = ours.identity_paths("gateway")
    target.certificate.write_bytes(forged.certificate.read_bytes())
    target.private_key.write_bytes(forged.private_key.read_bytes())
    with pytest.raises(PkiError, match="not signed by this cell's CA"):
        ours.identity("gateway")


def test_half_a_ca_is_an_error(tmp_path: Path) -> None:
    pki = CellPki(tmp_path / "pki")
    pki.ensure_ca()
    pki.ca_key.unlink()
    pki.ca_certificate.rename(pki.root / "kept.pem")
    pki.ca_key.write_text("not a key")
    with pytest.raises(PkiError, match="missing while the rest of the CA is there"):
        pki.ensure_ca()


def test_programs_starting_at_once_share_one_ca(tmp_path: Path) -> None:
    """The lock file serialises creation: four starters, one CA, every identity signed by it."""
    root = tmp_path / "pki"
    barrier = threading.Barrier(4)
    errors: list[BaseException] = []

    def start(cn: str) -> None:
        barrier.wait()
        try:
            CellPki(root).identity(cn)
        except BaseException as exc:  # collected for the assertion below
            errors.append(exc)

    threads = [
        threading.Thread(target=start, args=(cn,)) for cn in ("gateway", "controller-ur5", "tracker-emu", "observer-a")
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors
    pki = CellPki(root)
    for cn in ("gateway", "controller-ur5", "tracker-emu", "observer-a"):
        pki.check(pki.identity_paths(cn))  # raises if signed by another CA


def test_default_pki_dir_follows_the_state_dir(tmp_path: Path) -> None:
    assert default_pki_dir({STATE_DIR_ENV_VAR: str(tmp_path)}) == tmp_path / "pki"
    assert default_pki_dir({}).name == "pki"
    assert default_pki_dir({}).parent.name == ".state"
