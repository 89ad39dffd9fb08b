"""The emulator's vendor faces come from one registry: its options, the launcher's and the vendors' agree, a face of
the other kind of controller is refused, and a face that cannot start closes those started before it."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import pytest
from support.paths import REPO_ROOT

from controller_emu.faces import FACES, Face, start_faces
from controller_emu.main import _check_faces_serve
from hrc_contract.config import ConfigError
from hrc_devices.controllers.registry import VENDORS


def test_every_face_is_an_option_of_the_emulator() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "controller_emu", "--help"], capture_output=True, cwd=REPO_ROOT, timeout=60, check=True
    )
    text = result.stdout.decode()
    for face in FACES.values():
        assert face.option in text, face.kind


def test_every_bridged_vendor_is_served_by_the_face_its_emulator_args_name() -> None:
    assert set(FACES) >= set(VENDORS)
    options = {face.option: face for face in FACES.values()}
    for kind, vendor in VENDORS.items():
        args = vendor.emulator_args(vendor.config.model_validate(vendor.sim_interface))
        assert args[0] in options, kind
        face = options[args[0]]
        assert face.kind == kind
        assert face.control == "closed"  # a bridge writes a closed controller's speed input
        face.address(args[1])  # the address the launcher gives parses


def test_a_face_of_the_other_kind_of_controller_is_refused() -> None:
    _check_faces_serve("ur5", "closed", {"ur_rtde": "127.0.0.2"})
    _check_faces_serve("panda", "open", {"abb_egm": ("127.0.0.1", 6510)})
    allowed = r"--rtde serves a closed one; allowed with control = 'open': --egm"
    with pytest.raises(ConfigError, match=r"has an open controller \(control = 'open'\): " + allowed):
        _check_faces_serve("panda", "open", {"ur_rtde": "127.0.0.2"})
    with pytest.raises(ConfigError, match=r"has a closed controller \(control = 'closed'\): --egm serves an open one"):
        _check_faces_serve("ur5", "closed", {"abb_egm": ("127.0.0.1", 6510)})


class _Fake:
    def __init__(self, log: list[str], name: str, fails: bool) -> None:
        self.log, self.name, self.fails = log, name, fails

    def start(self) -> None:
        if self.fails:
            raise OSError("address in use")
        self.log.append(f"start {self.name}")

    def on_cycle(self, output: Any) -> None:
        pass

    def close(self) -> None:
        self.log.append(f"close {self.name}")

    def progress(self) -> str:
        return ""


def _fake(kind: str, log: list[str], fails: bool = False) -> Face:
    return Face(
        kind=kind,
        option=f"--{kind}",
        metavar="ADDR",
        help="a test's face",
        control="closed",
        address=str,
        serve=lambda node, model, address: _Fake(log, address, fails),
        describe=lambda address: f"{kind} at {address}",
    )


def test_a_face_that_cannot_start_closes_those_started_before_it() -> None:
    log: list[str] = []
    faces = {"one": _fake("one", log), "two": _fake("two", log, fails=True)}
    model: Any = None
    with pytest.raises(ConfigError, match="two at b: cannot be served: address in use"):
        start_faces(faces, {"one": "a", "two": "b"}, node=None, model=model)
    assert log == ["start a", "close a"]
    assert [type(f).__name__ for f in start_faces(faces, {"one": "a"}, node=None, model=model)] == ["_Fake"]
