"""The simulated cell through the ROS 2 adapter: each tracker frame as the ZED camera it is, and back to capsules.

    emulator frame (hrc.humans/1: the capsules a sensor measured)
        ──ZedSensor.objects (tracker_emu.ros2_zed: BODY_38 or fitted BODY_34, tracking states)──▶ ObjectsStamped CDR
        ──TrackerSubscription.on_sample (gateway.ros2_trackers: judge, decode, skeleton capsules)──▶ hrc.humans/1
        ──▶ the tracker's simulated link ──▶ the gateway's door

The very objects the running cell uses on both sides (``hrc-tracker-emu --publish zed`` and the gateway's ROS 2
trackers), without a Zenoh session: the sweep then measures what the adapter changes (keypoints instead of
capsules, reach spheres for hidden parts, SEARCHING people kept as lost), on the same seeds. A refusal of the
adapter is counted by the gateway and faults the tracker, as in the cell.

Differences to the running cell: the conversion happens before the link instead of after it, and takes no
simulated time (its cost on the gateway's host is measured in docs/ros2.md); the frames' attachment carries the
adapter's own sequence number, from 1 per tracker, as a ZED publisher's does.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from gateway.ros2_trackers import Rejection, TrackerSubscription, tracker_subscriptions, tracker_wires
from hrc_contract.config import CellConfig, ConfigError, Pose
from hrc_contract.messages import Humans, to_payload
from hrc_devices.ros2.rmw_zenoh import Attachment, encode_attachment, topic_key
from hrc_runtime.clocks import Clocks
from tracker_emu.ros2_zed import ZedSensor

GID = bytes(16)
"""The simulated publishers' GID (the adapter never reads it)."""
ROS2_ENDPOINT = "tcp/127.0.0.1:7449"
"""The endpoint :func:`with_zed_trackers` writes into ``[ros2]`` (never opened: the simulation has no sessions)."""


def with_zed_trackers(config: CellConfig, uncertainty_m: float = 0.05, body_fitting: bool = False) -> CellConfig:
    """``config`` with every tracker that has no ROS 2 input read as a ZED camera (``zed_objects``) at its position
    (axes of the world: the pose only moves the keypoints to the sensor's frame and back), ``[ros2]`` enabled.

    Args:
        config: the cell (a sweep case's, with its trackers).
        uncertainty_m: the stated keypoint uncertainty of the added inputs [m] (configs/cell_ros2_zed.toml's).
        body_fitting: the cameras' ``enable_body_fitting`` (off, the ZED wrapper's default: BODY_38, a hidden
            keypoint NaN; on: BODY_34, a hidden keypoint fitted; docs/ros2.md "ZED body fitting").

    Raises:
        ConfigError: (ValidationError) the changed cell does not validate.
    """
    raw: dict[str, Any] = config.model_dump()
    for name, tracker in raw["trackers"].items():
        if tracker.get("ros2") is None:
            xyz = tuple(tracker.get("position_m") or (0.0, 0.0, 0.0))
            tracker["ros2"] = {
                "format": "zed_objects",
                "topic": f"/{name.replace('-', '_')}/zed_node/body_trk/skeletons",
                "frame_id": f"{name}_left_camera_frame",
                "sensor_pose_world": Pose(xyz=xyz).model_dump(),
                "uncertainty_m": uncertainty_m,
                "enable_body_fitting": body_fitting,
            }
    if not raw["ros2"]["enabled"]:
        raw["ros2"] |= {"enabled": True, "listen": [ROS2_ENDPOINT]}
    return CellConfig.model_validate(raw)


class ZedRoundTrip:
    """Every ROS 2 tracker of a cell played as a ZED and read back by the gateway's own ROS 2 tracker subscription.

    Args:
        config: the cell; its trackers with a ``zed_objects`` ROS 2 input go through the adapter.
        reject: where a refusal goes (the gateway's ``InputStore.count_rejection``): counted, the tracker faulted.

    Raises:
        ConfigError: a ROS 2 tracker of another format (only ZED is emulated).
    """

    def __init__(self, config: CellConfig, reject: Rejection) -> None:
        others = [n for n, t in config.trackers.items() if t.ros2 is not None and t.ros2.format != "zed_objects"]
        if others:
            raise ConfigError(f"tracker(s) {', '.join(others)}: only zed_objects ROS 2 inputs are simulated")
        self._out: bytes | None = None
        self.subscriptions: dict[str, TrackerSubscription] = tracker_subscriptions(config, self._door, reject)
        self._sensors: dict[str, ZedSensor] = {}
        self._keys: dict[str, str] = {}
        self._sequences: dict[str, int] = {}
        wires = tracker_wires(config)
        for name, subscription in self.subscriptions.items():
            source = subscription.adapter.source
            self._sensors[name] = ZedSensor(source, config.trackers[name].noise_std_m, config.ros2.distro)
            fq_name, wire = wires[name]
            self._keys[name] = topic_key(config.ros2.domain_id, fq_name, wire)
            self._sequences[name] = 0

    def _door(self, key: str, payload: bytes, received: Clocks) -> None:
        self._out = payload

    def frame(self, tracker: str, message: Humans, present_ids: Iterable[str], now: Clocks) -> bytes | None:
        """The payload the gateway's door gets for one measured frame of ``tracker``: through the adapter for a ROS 2
        tracker (None when the adapter refused it: already counted), the frame itself for any other."""
        subscription = self.subscriptions.get(tracker)
        if subscription is None:
            return to_payload(message)
        cdr = self._sensors[tracker].objects(message, present_ids)
        self._sequences[tracker] += 1
        attachment = encode_attachment(Attachment(self._sequences[tracker], message.stamp_ns, GID))
        self._out = None
        subscription.clock = lambda: now
        subscription.on_sample(self._keys[tracker], cdr, attachment)
        return self._out
