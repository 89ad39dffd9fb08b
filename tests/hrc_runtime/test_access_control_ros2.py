"""The ROS 2 session's access control as a table (pure): the face, each ROS 2 tracker's own topic, the emulator."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh

from hrc_contract.config import ConfigError
from hrc_runtime.access_control import (
    ROS2_FACE,
    Ros2Policy,
    Ros2Rights,
    may_declare_token,
    may_put,
    ros2_grants,
    zenoh_access_control,
)
from hrc_runtime.pki import certificate_info, common_name
from hrc_tools.cert.main import cli as cert_cli

SPEED = "0/cell/ur5/speed_override/std_msgs::msg::dds_::Float64_/RIHS01_aa"
FRONT = "0/front/body/zed_msgs::msg::dds_::ObjectsStamped_/RIHS01_bb"
FRONT_HUMBLE = "0/front/body/zed_msgs::msg::dds_::ObjectsStamped_/TypeHashNotSupported"
SIDE = "0/side/body/zed_msgs::msg::dds_::ObjectsStamped_/RIHS01_bb"
EVERY_KEY = (SPEED, FRONT, FRONT_HUMBLE, SIDE)
FRONT_TOKEN = "@ros2_lv/0/*/*/*/MP/*/*/*/%front%body/*/*/*"
NODE_TOKEN = "@ros2_lv/0/*/*/*/NN/*/*/*"
POLICY = Ros2Policy(
    read=("0/**", "@ros2_lv/0/**"),
    face=Ros2Rights((SPEED,), ("@ros2_lv/0/*/*/*/NN/%/%cell/hrc_gateway",)),
    trackers=(
        ("front", Ros2Rights(("0/front/body/*/*",), (NODE_TOKEN, FRONT_TOKEN))),
        ("side", Ros2Rights(("0/side/body/*/*",), (NODE_TOKEN, "@ros2_lv/0/*/*/*/MP/*/*/*/%side%body/*/*/*"))),
    ),
)
ALLOWED = {
    ROS2_FACE: {SPEED},
    "tracker-front": {FRONT, FRONT_HUMBLE},  # any type or hash on its own topic: a wrong one is counted by the door
    "tracker-side": {SIDE},
    "tracker-emu": {FRONT, FRONT_HUMBLE, SIDE},
    "gateway": set(),  # the cell's roles have no right here
    "controller-ur5": set(),
    "router": set(),  # nobody forwards on the ROS 2 session
    "relay": set(),
    "observer-rviz": set(),
}


@pytest.mark.parametrize("cn", sorted(ALLOWED))
def test_each_role_may_put_exactly_its_keys(cn: str) -> None:
    assert {key for key in EVERY_KEY if may_put(POLICY, cn, key)} == ALLOWED[cn]


def test_a_tracker_declares_only_its_own_publisher_and_a_node() -> None:
    token = (
        "@ros2_lv/0/0a1b/0/3/MP/%/%front/zed_node/%front%body/zed_msgs::msg::dds_::ObjectsStamped_/RIHS01_bb/"
        "2:2:1,5:,:,:,,"
    )
    node = "@ros2_lv/0/0a1b/0/0/NN/%/%front/zed_node"
    assert may_declare_token(POLICY, "tracker-front", token)
    assert may_declare_token(POLICY, "tracker-front", node)
    assert not may_declare_token(POLICY, "tracker-side", token)
    assert not may_declare_token(POLICY, "controller-ur5", node)
    assert not may_declare_token(POLICY, "tracker-front", "@ros2_lv/0/0a1b/0/0/NN/%/%cell/hrc_gateway/extra")


def test_without_ros2_trackers_only_the_face_has_rights() -> None:
    policy = Ros2Policy(POLICY.read, POLICY.face, ())
    assert [g.common_names for g in ros2_grants(policy)] == [(ROS2_FACE,)]


def test_a_ros2_tracker_named_emu_is_refused() -> None:
    with pytest.raises(ConfigError, match="reserved"):
        Ros2Policy(POLICY.read, POLICY.face, (("emu", Ros2Rights(("0/x/*/*",), (NODE_TOKEN,))),))


def test_zenoh_block_denies_by_default_and_reads_only_the_domain() -> None:
    block = zenoh_access_control(POLICY)
    assert block["default_permission"] == "deny"
    read = [r for r in block["rules"] if r["id"] == "members-read"]
    assert read[0]["key_exprs"] == ["0/**", "@ros2_lv/0/**"]
    config = zenoh.Config.from_json5(json.dumps({"access_control": block}))
    assert json.loads(config.get_json("access_control/enabled")) is True


def test_hrc_cert_issues_the_ros2_role(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert common_name("ros2") == ROS2_FACE
    with pytest.raises(SystemExit) as exited:
        cert_cli(["--pki-dir", str(tmp_path), "issue", "--role", "ros2"])
    assert exited.value.code == 0
    assert certificate_info(tmp_path / "ros2.crt").common_name == ROS2_FACE
    assert "ros2: certificate" in capsys.readouterr().out
