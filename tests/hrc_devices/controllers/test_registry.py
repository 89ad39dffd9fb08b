"""The vendors' registry: every vendor is one folder and one registry line; a fake ``loopback`` vendor, registered
here only, drives the bridge's core and program and the launcher with no other file naming it."""

from __future__ import annotations

import pytest
from support.loopback_vendor import LOOPBACK, LoopbackExchange, LoopbackInterface, LoopbackInterfaceConfig
from support.paths import REPO_ROOT

from controller_bridge.bridge import Bridge
from controller_bridge.main import bridge_settings, make_interface, select_robot
from hrc_contract.config import CellConfig, ConfigError
from hrc_contract.messages import Override, to_payload
from hrc_devices.controllers.registry import VENDORS, bridged_kinds
from hrc_devices.robots.model import load_robot_model
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config
from hrc_tools.cell.launcher import bridge_environment, bridged_robots, program_commands, vendor_face_args
from hrc_tools.sim.bridged import default_interface
from hrc_tools.sim.cell import simulate
from hrc_tools.sim.exchanges import EXCHANGES
from hrc_tools.sim.links import LinkFaults
from tracker_emu.scenario import Scenario

ROBOT = "ur5"
WALL0, MONO0 = 1_790_000_000_000_000_000, 1_000_000_000


@pytest.fixture
def loopback(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(VENDORS, "loopback", LOOPBACK)
    monkeypatch.setitem(EXCHANGES, "loopback", LoopbackExchange)


def _loopback_cell() -> CellConfig:
    config = load_cell_config()
    robot = config.robots[ROBOT].model_copy(update={"interface": LoopbackInterfaceConfig()})
    return config.model_copy(update={"robots": {**config.robots, ROBOT: robot}})


def _at(t_s: float) -> Clocks:
    return Clocks(WALL0 + round(t_s * 1e9), MONO0 + round(t_s * 1e9))


def test_the_shipped_vendors_are_registered_by_their_config_kind() -> None:
    assert bridged_kinds() == ("ur_rtde", "abb_rws")
    for kind, vendor in VENDORS.items():
        assert vendor.kind == kind
        assert vendor.config.model_fields["kind"].annotation.__args__ == (kind,)  # type: ignore[attr-defined]
        assert default_interface(kind)["kind"] == kind


@pytest.mark.usefixtures("loopback")
def test_a_registered_vendor_drives_the_bridge_core_through_its_program() -> None:
    config = _loopback_cell()
    assert select_robot(config, None) == ROBOT
    model = load_robot_model(ROBOT, config.robots[ROBOT])
    settings = bridge_settings(config, ROBOT, model)
    assert settings.speed_input is LOOPBACK.speed_input
    assert settings.sample_jitter_s == 0.0
    interface = make_interface(config.robots[ROBOT].interface, model.n_joints, environ={})
    assert isinstance(interface, LoopbackInterface)
    interface.clock = lambda: _at(0.0)
    interface.connect()

    bridge = Bridge(settings)
    assert bridge.on_reading(interface.read(0.1)) is not None  # the controller's speed in force: 1
    interface.clock = lambda: _at(0.003)
    stamp_ns = _at(0.0).wall_ns
    payload = to_payload(Override(robot=ROBOT, seq=7, stamp_ns=stamp_ns, delta=0.4567))
    assert bridge.on_override(payload, _at(0.001)) is None
    value = bridge.next_write(_at(0.002))
    assert value is not None
    written = interface.write_speed_fraction(value)
    bridge.on_written(written, _at(0.002))
    state = bridge.on_reading(interface.read(0.1))
    assert state is not None
    assert written <= 0.4567
    assert state.override <= written  # the applied scaling, bounded from below over the rise time
    assert state.override_seq == 7  # confirmed by the read-back alone


@pytest.mark.usefixtures("loopback")
def test_a_registered_vendor_is_launched_with_its_face_and_environment() -> None:
    config = _loopback_cell()
    assert bridged_robots(config) == [ROBOT]
    assert vendor_face_args(config.robots[ROBOT]) == ["--loopback", "loop"]
    assert bridge_environment(config, {})["HRC_LOOPBACK"] == "loop"
    commands = program_commands(config, None, None, 8080, "tcp/127.0.0.1:7447", [])
    assert f"bridge-{ROBOT}" in commands
    assert commands[f"controller-{ROBOT}"][-2:] == ["--loopback", "loop"]
    assert default_interface("loopback") == {"kind": "loopback"}


def test_without_its_registry_line_the_vendor_is_unknown() -> None:
    config = _loopback_cell()
    with pytest.raises(ConfigError, match="no bridge"):
        select_robot(config, ROBOT)
    assert vendor_face_args(config.robots[ROBOT]) == []


UNBRIDGED_FOLDERS = {"abb_egm"}
"""Vendor folders with a codec (and an emulator face) but no bridge vendor yet (issue 34: EGM needs an open vendor
interface, docs/controllers.md)."""


def test_the_vendor_folders_hold_their_kind() -> None:
    root = REPO_ROOT / "hrc_devices" / "controllers"
    folders = {p.name for p in root.iterdir() if (p / "__init__.py").exists()}
    assert folders == set(bridged_kinds()) | UNBRIDGED_FOLDERS


@pytest.mark.usefixtures("loopback")
def test_a_registered_vendor_drives_the_simulated_cell_through_its_exchange() -> None:
    """The simulated cell puts the bridge and the loopback exchange between the gateway and the controller: with
    nobody in the cell the gateway learns the override path from the bridge's echo and the program runs."""
    config = _loopback_cell()
    robots = {name: load_robot_model(name, r) for name, r in config.robots.items()}
    empty = Scenario(description="nobody", duration_s=3.0, loop=False, humans=[])
    result = simulate(config, robots, empty, LinkFaults(), 3.0, seed=1)
    bridge = result.bridges[ROBOT]
    assert bridge["interface"] == "loopback"
    assert bridge["face_writes"] > 0
    assert bridge["published"] > 200  # a reading every 10 ms for 3 s, each published
    assert result.audit.violations == 0
    assert result.program_progress_cycles > 0.05  # δ > 0 reached the controller through the loopback link
