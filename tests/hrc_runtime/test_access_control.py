"""The cell's access control as a table: who may put on which key (pure; the sessions are in test_security_*)."""

from __future__ import annotations

import json

import pytest
import zenoh

from hrc_contract.config import CellConfig, ConfigError
from hrc_runtime.access_control import (
    CellPolicy,
    control_key,
    grants,
    may_put,
    program_common_names,
    zenoh_access_control,
)

POLICY = CellPolicy("demo", ("ur10", "ur5"), ("front", "side"))

OVERRIDE = "hrc/demo/robot/ur5/override"
STATE = "hrc/demo/robot/ur5/state"
TRUTH_STATE = "hrc/demo/truth/robot/ur5/state"
EMU_STATS = "hrc/demo/robot/ur5/emu_stats"
BRIDGE_STATS = "hrc/demo/robot/ur5/bridge_stats"
FRONT = "hrc/demo/tracker/front/humans"
SIDE = "hrc/demo/tracker/side/humans"
TRUTH_HUMANS = "hrc/demo/truth/humans"
STATUS = "hrc/demo/gateway/status"
UR10_OVERRIDE = "hrc/demo/robot/ur10/override"
EVERY_KEY = (OVERRIDE, UR10_OVERRIDE, STATE, TRUTH_STATE, EMU_STATS, BRIDGE_STATS, FRONT, SIDE, TRUTH_HUMANS, STATUS)

ALLOWED = {
    "gateway": set(EVERY_KEY),  # its own, and what it routes to its clients (checked on its ingress)
    "controller-ur5": {STATE, TRUTH_STATE, EMU_STATS, BRIDGE_STATS},  # the emulator's and the bridge's
    "tracker-front": {FRONT},
    "tracker-emu": {FRONT, SIDE, TRUTH_HUMANS},
    "observer-alice": set(),
    "router": set(EVERY_KEY),
    "relay": set(EVERY_KEY),
}


@pytest.mark.parametrize("cn", sorted(ALLOWED))
def test_each_role_may_put_exactly_its_keys(cn: str) -> None:
    allowed = {key for key in EVERY_KEY if may_put(POLICY, cn, key)}
    assert allowed == ALLOWED[cn]


def test_a_controller_cannot_speak_for_another_robot() -> None:
    assert may_put(POLICY, "controller-ur10", "hrc/demo/robot/ur10/state")
    assert not may_put(POLICY, "controller-ur10", STATE)
    assert not may_put(POLICY, "controller-ur5", OVERRIDE)


def test_nobody_but_the_gateway_and_forwarders_commands_the_robot() -> None:
    commanders = {g for grant in grants(POLICY) for g in grant.common_names if may_put(POLICY, g, OVERRIDE)}
    assert commanders == {"gateway", "router", "relay"}


def test_other_cells_and_unknown_names_get_nothing() -> None:
    assert not may_put(POLICY, "gateway", "hrc/other/robot/ur5/override")
    assert not may_put(POLICY, "tracker-lidar9", "hrc/demo/tracker/lidar9/humans")  # not in the cell
    assert not may_put(POLICY, "", OVERRIDE)


def test_relay_control_key_only_for_forwarders() -> None:
    key = control_key("demo")
    assert may_put(POLICY, "relay", key)
    assert not may_put(POLICY, "controller-ur5", key)
    assert not may_put(POLICY, "tracker-emu", key)


def test_tracker_named_emu_is_refused() -> None:
    with pytest.raises(ConfigError, match="reserved"):
        CellPolicy("demo", ("ur5",), ("front", "emu"))


def test_policy_from_the_shipped_cell(cell_config: CellConfig) -> None:
    policy = CellPolicy.from_config(cell_config)
    assert policy.cell == cell_config.cell
    assert set(policy.trackers) == set(cell_config.trackers)
    assert program_common_names(policy) == ("gateway", "controller-ur5", "tracker-emu", "observer-audit")


def test_zenoh_block_denies_by_default_and_loads() -> None:
    block = zenoh_access_control(POLICY)
    assert block["enabled"] is True
    assert block["default_permission"] == "deny"
    ids = [r["id"] for r in block["rules"]]
    assert len(ids) == len(set(ids))
    put_rules = [r for r in block["rules"] if "put" in r["messages"] and r["flows"] == ["ingress"]]
    assert {k for r in put_rules for k in r["key_exprs"]} >= set(EVERY_KEY)
    config = zenoh.Config.from_json5(json.dumps({"access_control": block}))
    assert json.loads(config.get_json("access_control/default_permission")) == "deny"


def test_only_the_operator_may_reset_a_lost_person() -> None:
    """A reset releases a lost person: no program but the operator station may put it (not even the gateway's
    peers' own roles); the operator may put nothing else."""
    from hrc_contract import keys as cell_keys
    from hrc_runtime.access_control import OPERATOR, CellPolicy, may_put

    policy = CellPolicy("demo", ("ur5",), ("front",))
    reset = cell_keys.operator_track_reset("demo")
    assert may_put(policy, OPERATOR, reset)
    for stranger in ("tracker-front", "controller-ur5", "tracker-emu", "observer-audit", "recorder"):
        assert not may_put(policy, stranger, reset), stranger
    assert not may_put(policy, OPERATOR, cell_keys.tracker_humans("demo", "front"))
    assert not may_put(policy, OPERATOR, cell_keys.robot_override("demo", "ur5"))
