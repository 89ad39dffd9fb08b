"""What ``hrc-record`` records: the cell's keys, the model and channel of each, and how a received payload is judged
(a valid message of its key, or a rejected payload kept with why); the JSON and the ROS 2 recordings share it."""

from __future__ import annotations

import base64
from typing import NamedTuple

from pydantic import BaseModel, ConfigDict, ValidationError

from hrc_contract import keys
from hrc_contract.messages import MAX_PAYLOAD_BYTES, Humans, JointState, MessageError, Override, parse_message
from hrc_contract.status_models import Event, GatewayStatus
from hrc_runtime.mcap_sink import ChannelSpec, model_channel
from hrc_tools.record import scene

JOINT_STATE = model_channel("hrc.joint_state", JointState)
OVERRIDE = model_channel("hrc.override", Override)
HUMANS = model_channel("hrc.humans", Humans)
STATUS = model_channel("hrc.gateway_status", GatewayStatus)
EVENT = model_channel("hrc.event", Event)
SCENE = ChannelSpec(scene.SCHEMA_NAME, scene.foxglove_schema())


class RejectedPayload(BaseModel):
    """A payload that is not a valid message of its key: kept as received, with why."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    key: str
    reason: str
    payload_base64: str


REJECTED = model_channel("hrc.rejected", RejectedPayload)


class Topic(NamedTuple):
    """How a key of the cell is recorded: its model (to validate), its channel, and its scene builder."""

    model: type[BaseModel]
    channel: ChannelSpec
    scene_topic: str | None


def topic_of(cell: str, key: str) -> Topic | None:
    """What ``key`` carries in cell ``cell``, None for a key this recorder does not know."""
    parts = key.split("/")
    if len(parts) < 4 or parts[0] != "hrc" or parts[1] != cell:
        return None
    kind = parts[2:]
    if len(kind) == 3 and kind[0] == "robot" and kind[2] == "state":
        return Topic(JointState, JOINT_STATE, None)
    if len(kind) == 3 and kind[0] == "robot" and kind[2] == "override":
        return Topic(Override, OVERRIDE, None)
    if len(kind) == 3 and kind[0] == "tracker" and kind[2] == "humans":
        return Topic(Humans, HUMANS, f"/scene/humans/{kind[1]}")
    if kind == ["gateway", "status"]:
        return Topic(GatewayStatus, STATUS, "/scene/robots")
    if len(kind) == 4 and kind[:2] == ["truth", "robot"] and kind[3] == "state":
        return Topic(JointState, JOINT_STATE, None)
    if kind == ["truth", "humans"]:
        return Topic(Humans, HUMANS, "/scene/truth")
    return None


def subscriptions(cell: str) -> list[str]:
    """The key expressions recorded: the contract's topics of the cell and the ground truth."""
    return [
        keys.robot_state(cell, "*"),
        keys.robot_override(cell, "*"),
        keys.tracker_humans(cell, "*"),
        keys.gateway_status(cell),
        f"hrc/{cell}/truth/**",
    ]


def parse_payload(payload: bytes, model: type[BaseModel]) -> BaseModel:
    """The message, by the contract's parser for wire messages (``schema`` checked), by the model otherwise."""
    if "schema_" in model.model_fields:
        return parse_message(payload, model)
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise MessageError("too_large", f"{len(payload)} bytes")
    try:
        return model.model_validate_json(payload)
    except ValidationError as exc:
        raise MessageError("invalid", str(exc.errors()[0]["msg"])) from None


class Received(NamedTuple):
    """A valid message received on a known key: how the key is recorded, and the message."""

    topic: Topic
    message: BaseModel


def receive(cell: str, key: str, payload: bytes) -> Received | RejectedPayload | None:
    """What a payload received on ``key`` is: a valid message of its key, a rejected payload (kept with why), or
    None for a key this recorder does not know (the JSON and the ROS 2 recordings validate alike)."""
    topic = topic_of(cell, key)
    if topic is None:
        return None
    try:
        return Received(topic, parse_payload(payload, topic.model))
    except MessageError as exc:
        return RejectedPayload(key=key, reason=exc.reason, payload_base64=base64.b64encode(payload).decode())
