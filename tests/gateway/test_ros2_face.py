"""The ROS 2 face's messages, from status documents, decoded back with rosbags."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.status_examples import STALE_TRACKER, gateway_status, near_robot_status, robot_status

from gateway import ros2_face as face
from hrc_contract.status_models import CapsuleStatus, GatewayStatus, HumanCapsuleStatus, PlanStatus
from hrc_devices.ros2.rmw_zenoh import Distro, deserialize, serialize

LINK = CapsuleStatus(name="tool", a_m=[0.0, 0.0, 1.0], b_m=[0.0, 0.3, 1.0], radius_m=0.07)


def _doc() -> GatewayStatus:
    doc = gateway_status(
        ur5=near_robot_status().model_copy(update={"links": [LINK]}), ur10=robot_status([STALE_TRACKER])
    )
    capsules = [
        HumanCapsuleStatus(human="front/h1", name="hand_r", a_m=[1.0, 0.0, 1.0], b_m=[1.0, 0.0, 1.0], radius_m=0.06),
        HumanCapsuleStatus(human="side/h2", name="torso", a_m=[3.0, 0.0, 0.9], b_m=[3.0, 0.0, 1.5], radius_m=0.2),
    ]
    return doc.model_copy(update={"human_capsules": capsules})


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_speed_override_is_delta_not_percent(distro: Distro) -> None:
    payload = serialize(distro, face.speed_override_message(distro, 0.62))
    assert deserialize(distro, payload, face.FLOAT64).data == pytest.approx(0.62)


def test_diagnostics_carry_zone_delta_and_faults_with_levels() -> None:
    array = deserialize(
        "jazzy", serialize("jazzy", face.diagnostics_message("jazzy", _doc(), "gw")), face.DIAGNOSTIC_ARRAY
    )
    by_robot = {s.hardware_id: s for s in array.status}
    assert by_robot["ur5"].level == face.LEVEL_WARN  # reduced speed
    assert by_robot["ur10"].level == face.LEVEL_ERROR  # a fault
    values = {kv.key: kv.value for kv in by_robot["ur10"].values}
    assert values["zone"] == "safety_exception"
    assert values["faults"] == "tracker_stale"
    assert values["fault/tracker_stale"] == STALE_TRACKER.reason
    assert {kv.key: kv.value for kv in by_robot["ur5"].values}["delta"] == "0.6200"


def test_markers_draw_every_capsule_coloured_by_zone() -> None:
    array = deserialize(
        "humble", serialize("humble", face.markers_message("humble", _doc(), "cell")), face.MARKER_ARRAY
    )
    first, *markers = array.markers
    assert first.action == face.DELETEALL
    robot = [m for m in markers if m.ns == "robot/ur5"]
    assert sorted(m.type for m in robot) == [face.SPHERE, face.SPHERE, face.CYLINDER]
    cylinder = next(m for m in robot if m.type == face.CYLINDER)
    assert (cylinder.scale.x, cylinder.scale.z) == pytest.approx((0.14, 0.3))
    assert (cylinder.pose.position.y, cylinder.color.r, cylinder.color.g) == pytest.approx((0.15, 1.0, 0.5))
    humans = [m for m in markers if m.ns == "human"]
    assert len(humans) == 1 + 3  # a point: one sphere; a segment: two spheres and a cylinder
    assert humans[0].color.g == pytest.approx(0.5)  # front/h1 holds ur5 at reduced speed: orange
    assert humans[1].color.b == pytest.approx(0.9)  # side/h2 holds nobody: blue
    assert all(m.header.frame_id == "cell" for m in markers)
    assert len({(m.ns, m.id) for m in markers}) == len(markers)


@pytest.mark.parametrize("u", [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0.6, 0.0, 0.8), (0.0, -0.6, -0.8)])
def test_cylinder_axis_points_along_the_capsule(u: tuple[float, float, float]) -> None:
    x, y, z, w = face.z_to_direction_quaternion(u)
    assert math.isclose(x * x + y * y + z * z + w * w, 1.0)
    rotated_z = (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))  # third column of R(q)
    assert np.allclose(rotated_z, u)


def test_ros_tokens_of_cell_names() -> None:
    assert [face.ros_token(n) for n in ("ur5", "arm-left", "5axis")] == ["ur5", "arm_left", "r_5axis"]


def test_an_open_robot_s_plan_is_a_line_strip_through_the_tool_s_path() -> None:
    path = [[0.5, 0.0, 1.2], [0.4, 0.3, 1.3], [0.0, 0.5, 1.3]]
    plan = PlanStatus(
        following=True, plan_time_s=0.2, plan_duration_s=1.5, path_waypoints=4, reason="horizon",
        requests={"horizon": 1}, adopted=1, rejected=0, failures={}, planning_last_s=0.1, path_tool_m=path,
    )  # fmt: skip
    doc = gateway_status(panda=robot_status(plan=plan, links=[LINK]))
    array = deserialize("jazzy", serialize("jazzy", face.markers_message("jazzy", doc, "cell")), face.MARKER_ARRAY)
    [line] = [m for m in array.markers if m.ns == "plan/panda"]
    assert line.type == face.LINE_STRIP
    assert [[p.x, p.y, p.z] for p in line.points] == path
    assert line.scale.x == pytest.approx(face.PLAN_LINE_WIDTH_M)
    on_program = gateway_status(panda=robot_status(links=[LINK]))
    array = deserialize(
        "jazzy", serialize("jazzy", face.markers_message("jazzy", on_program, "cell")), face.MARKER_ARRAY
    )
    assert not [m for m in array.markers if m.ns.startswith("plan/")]  # the DELETEALL removes an ended plan
