"""The simulated cell through the ROS 2 adapter: capsules → ZED keypoints → CDR → the gateway's adapter → capsules.

What reaches the door covers every capsule end the sensor measured (the adapter never shrinks a person); a tracker
without a ROS 2 input is passed unchanged; a frame the adapter refuses is counted and reaches no link.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from hrc_contract.config import CellConfig
from hrc_contract.messages import Capsule, Human, Humans, to_payload
from hrc_runtime.clocks import Clocks
from hrc_tools.sim.ros2_adapter import ZedRoundTrip, with_zed_trackers
from tracker_emu.body import BodyPose, body_capsules

NOW = 1_790_000_000_000_000_000


def frame(tracker: str, x_m: float = 2.5, stamp_ns: int = NOW) -> Humans:
    capsules = [
        Capsule(name=c.name, a=tuple(c.a), b=tuple(c.b), radius=c.radius_m)
        for c in body_capsules(BodyPose(x_m, 0.5, 3.0, reach=0.5))
    ]
    return Humans(tracker=tracker, seq=1, stamp_ns=stamp_ns, humans=[Human(id="h1", capsules=capsules)])


def covered(doc: dict[str, object], point: np.ndarray) -> bool:
    for human in doc["humans"]:  # type: ignore[attr-defined]
        for c in human["capsules"]:
            a, b = np.asarray(c["a"]), np.asarray(c["b"])
            axis = b - a
            t = np.clip((point - a) @ axis / max(float(axis @ axis), 1e-12), 0.0, 1.0)
            if np.linalg.norm(point - (a + t * axis)) <= c["radius"] + 1e-6:
                return True
    return False


@pytest.fixture
def zed_cell(cell_config: CellConfig) -> CellConfig:
    return with_zed_trackers(cell_config)


def test_every_tracker_becomes_a_zed_and_ros2_is_enabled(cell_config: CellConfig, zed_cell: CellConfig) -> None:
    assert all(t.ros2 is None for t in cell_config.trackers.values())
    assert zed_cell.ros2.enabled
    for name, tracker in zed_cell.trackers.items():
        assert tracker.ros2 is not None
        assert tracker.ros2.format == "zed_objects"
        assert zed_cell.tracker_plausibility(name).max_capsule_radius_m == tracker.ros2.max_capsule_radius_m


def test_what_reaches_the_door_covers_every_measured_capsule_end(zed_cell: CellConfig) -> None:
    refused: list[str] = []
    trip = ZedRoundTrip(zed_cell, lambda topic, reason, received: refused.append(reason))
    message = frame("front")
    payload = trip.frame("front", message, ["h1"], Clocks(NOW + 30_000_000, 0))
    assert payload is not None
    assert refused == []
    doc = json.loads(payload)
    assert doc["tracker"] == "front"
    assert doc["seq"] == 1  # the attachment's sequence number
    assert doc["stamp_ns"] == NOW  # the capture time, from the header
    for capsule in message.humans[0].capsules:
        for end in (capsule.a, capsule.b):
            assert covered(doc, np.asarray(end)), (capsule.name, end)


def test_a_tracker_without_a_ros2_input_is_passed_unchanged(cell_config: CellConfig) -> None:
    trip = ZedRoundTrip(cell_config, lambda topic, reason, received: None)
    message = frame("front")
    assert trip.frame("front", message, ["h1"], Clocks(NOW, 0)) == to_payload(message)


def test_a_frame_the_adapter_refuses_is_counted_and_goes_nowhere(zed_cell: CellConfig) -> None:
    refused: list[tuple[str, str]] = []
    trip = ZedRoundTrip(zed_cell, lambda topic, reason, received: refused.append((topic, reason)))
    absurd = frame("front", x_m=150.0)  # keypoints beyond any cell
    assert trip.frame("front", absurd, ["h1"], Clocks(NOW, 0)) is None
    assert refused == [("tracker/front", "absurd_keypoint")]


def test_body_fitting_reaches_every_added_camera(cell_config: CellConfig) -> None:
    """--zed-body-fitting: each camera the sweep adds fits hidden keypoints; by default none does (the wrapper's)."""
    fitted = with_zed_trackers(cell_config, body_fitting=True)
    assert all(t.ros2 is not None and t.ros2.enable_body_fitting for t in fitted.trackers.values())
    plain = with_zed_trackers(cell_config)
    assert not any(t.ros2 is not None and t.ros2.enable_body_fitting for t in plain.trackers.values())
