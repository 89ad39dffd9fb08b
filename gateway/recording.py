"""The gateway's recording of itself (``hrc-gateway --record PATH``): what it needs to be rebuilt and replayed.

Channels of the MCAP file, one JSON message per record, each with the JSON Schema of its model:

- ``/gateway/config`` (``hrc.cell_config``): once, the effective :class:`CellConfig` (replay builds the node
  from it);
- ``/gateway/input`` (``hrc.gateway_input``): each message the node was given: key, payload bytes (base64),
  arrival on both clocks;
- ``/gateway/internal_error`` (``hrc.gateway_internal_error``): an exception while handling a message (the
  node counted it and faulted the topic);
- ``/gateway/cycle`` (``hrc.gateway_cycle``): each decision: ``now`` on both clocks, ``period_s``, the override
  seq and δ per robot.

The messages' MCAP ``sequence`` is the order in which the node saw them (:class:`gateway.node.GatewayNode`
takes it under its order lock), which is what a replay follows; ``log_time`` is the wall clock of the arrival
or decision, for viewers. :class:`GatewayRecorder` is the node's recorder: it only queues (the encoding to
JSON runs on the sink's thread).
"""

from __future__ import annotations

import base64
import functools
import itertools
import json
import logging
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader
from pydantic import BaseModel, ConfigDict, ValidationError

from gateway.node import GatewayCycle
from hrc_contract.config import CellConfig
from hrc_runtime.clocks import Clocks
from hrc_runtime.mcap_sink import (
    DEFAULT_MAX_QUEUED,
    SUMMARY_METADATA,
    McapSink,
    RecordingError,
    RecordingSummary,
    model_channel,
)
from hrc_runtime.realtime import use_realtime_scheduling

log = logging.getLogger("hrc-gateway.recording")

CONFIG_TOPIC = "/gateway/config"
INPUT_TOPIC = "/gateway/input"
INTERNAL_ERROR_TOPIC = "/gateway/internal_error"
CYCLE_TOPIC = "/gateway/cycle"
FORMAT_METADATA = "hrc.gateway_recording"
"""Metadata naming the format (``version``), the cell and its configuration hash."""
FORMAT_VERSION = "1"


class _Record(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class InputRecord(_Record):
    """A message given to the node: its key, its payload exactly as received, its arrival [ns]."""

    key: str
    payload_base64: str
    received_wall_ns: int
    received_mono_ns: int

    @property
    def payload(self) -> bytes:
        return base64.b64decode(self.payload_base64)

    @property
    def received(self) -> Clocks:
        return Clocks(self.received_wall_ns, self.received_mono_ns)


class InternalErrorRecord(_Record):
    """Handling the message on ``key`` raised; the node counted it and faulted the topic."""

    key: str
    received_wall_ns: int
    received_mono_ns: int

    @property
    def received(self) -> Clocks:
        return Clocks(self.received_wall_ns, self.received_mono_ns)


class CycleRecord(_Record):
    """One decision: when [ns], the period it assumed [s], the override seq and δ per robot."""

    seq: int
    now_wall_ns: int
    now_mono_ns: int
    period_s: float
    deltas: dict[str, float]

    @property
    def now(self) -> Clocks:
        return Clocks(self.now_wall_ns, self.now_mono_ns)


Step = InputRecord | InternalErrorRecord | CycleRecord

CONFIG = model_channel("hrc.cell_config", CellConfig)
INPUT = model_channel("hrc.gateway_input", InputRecord)
INTERNAL_ERROR = model_channel("hrc.gateway_internal_error", InternalErrorRecord)
CYCLE = model_channel("hrc.gateway_cycle", CycleRecord)
_STEP_MODELS: dict[str, type[Step]] = {
    INPUT_TOPIC: InputRecord,
    INTERNAL_ERROR_TOPIC: InternalErrorRecord,
    CYCLE_TOPIC: CycleRecord,
}


# -- encoders (run on the sink's thread) -------------------------------------------------------------


def _encode_config(config: CellConfig) -> bytes:
    return config.model_dump_json().encode()


def _encode_input(value: tuple[str, bytes, Clocks]) -> bytes:
    key, payload, received = value
    record = {
        "key": key,
        "payload_base64": base64.b64encode(payload).decode("ascii"),
        "received_wall_ns": received.wall_ns,
        "received_mono_ns": received.mono_ns,
    }
    return json.dumps(record).encode()


def _encode_internal_error(value: tuple[str, Clocks]) -> bytes:
    key, received = value
    return json.dumps({"key": key, "received_wall_ns": received.wall_ns, "received_mono_ns": received.mono_ns}).encode()


def _encode_cycle(value: tuple[Clocks, float, GatewayCycle]) -> bytes:
    now, period_s, cycle = value
    record = {
        "seq": cycle.seq,
        "now_wall_ns": now.wall_ns,
        "now_mono_ns": now.mono_ns,
        "period_s": period_s,  # json writes the shortest repr: read back to the same float
        "deltas": {name: override.delta for name, override in cycle.overrides.items()},
    }
    return json.dumps(record).encode()


class GatewayRecorder:
    """The node's recorder (:class:`gateway.node.NodeRecorder`) writing :data:`CONFIG` … :data:`CYCLE` to ``path``.

    A context manager: the file is complete (footer, summary) when it exits.

    Raises:
        RecordingError: the file cannot be created.
    """

    def __init__(
        self, path: Path, config: CellConfig, max_queued: int = DEFAULT_MAX_QUEUED, realtime_priority: int = 0
    ) -> None:
        metadata = {FORMAT_METADATA: {"version": FORMAT_VERSION, "cell": config.cell, "config_sha256": config.sha256()}}
        # Its writer takes the interpreter lock: at normal scheduling another program can deschedule it while it
        # holds the lock, and the loop waits (the 60-minute soak: 622 of 625 'blocked' stalls had it waiting for a CPU).
        on_start = (
            functools.partial(use_realtime_scheduling, realtime_priority, "the recorder's writer", log)
            if realtime_priority
            else None
        )
        self.sink = McapSink(path, max_queued, metadata, on_start)
        for topic, channel in ((INPUT_TOPIC, INPUT), (INTERNAL_ERROR_TOPIC, INTERNAL_ERROR), (CYCLE_TOPIC, CYCLE)):
            self.sink.declare(topic, channel)
        self.sink.offer(CONFIG_TOPIC, CONFIG, time.time_ns(), _encode_config, config)
        self.sink.start()

    def __enter__(self) -> GatewayRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> RecordingSummary:
        return self.sink.close()

    def on_input(self, key: str, payload: bytes, received: Clocks) -> None:
        self.sink.offer(INPUT_TOPIC, INPUT, received.wall_ns, _encode_input, (key, payload, received))

    def on_internal_error(self, key: str, received: Clocks) -> None:
        self.sink.offer(INTERNAL_ERROR_TOPIC, INTERNAL_ERROR, received.wall_ns, _encode_internal_error, (key, received))

    def on_cycle(self, now: Clocks, period_s: float, cycle: GatewayCycle) -> None:
        self.sink.offer(CYCLE_TOPIC, CYCLE, now.wall_ns, _encode_cycle, (now, period_s, cycle))


# -- reading back ----------------------------------------------------------------------------------------


class GatewayRecording(NamedTuple):
    """A gateway recording as read back.

    Attributes:
        config: the configuration the gateway ran with.
        steps: inputs, internal errors and cycles in the order the node saw them.
        dropped: messages the gateway could not write (0 for a complete recording).
        missing_after: the sequence numbers after which messages are missing (a replay is exact up to the
            first one only).
        truncated: why the file ends before its footer (the gateway did not close it, e.g. it was killed); the
            messages of every chunk before the cut are there.
    """

    config: CellConfig
    steps: list[Step]
    dropped: int
    missing_after: list[int]
    truncated: str | None = None

    @property
    def complete(self) -> bool:
        return self.dropped == 0 and not self.missing_after and self.truncated is None


class _Truncated(NamedTuple):
    """The file ends before its footer (the gateway was killed): what came before was read."""

    reason: str


def _messages(path: Path) -> Iterator[tuple[str, int, bytes] | _Truncated]:
    """(topic, sequence, data) of every message in file order, the metadata as messages of topic ``#<name>``;
    a :class:`_Truncated` last if the file ends early (every chunk before the cut is still read).

    Raises:
        RecordingError: the file cannot be read or is not MCAP.
    """
    topics: dict[int, str] = {}
    try:
        with path.open("rb") as f:
            records = StreamReader(f).records
            try:
                for record in records:
                    if isinstance(record, Channel):
                        topics[record.id] = record.topic
                    elif isinstance(record, Message):
                        yield topics.get(record.channel_id, "?"), record.sequence, record.data
                    elif isinstance(record, Metadata):
                        yield f"#{record.name}", -1, json.dumps(record.metadata).encode()
            except (McapError, ValueError, EOFError, struct.error) as exc:
                if not topics:
                    raise
                yield _Truncated(str(exc) or type(exc).__name__)
    except OSError as exc:
        raise RecordingError(f"cannot read the recording {path}: {exc.strerror or exc}") from None
    except (McapError, ValueError, EOFError, struct.error) as exc:
        raise RecordingError(f"{path} is not an MCAP file ({exc or type(exc).__name__})") from None


def read_gateway_recording(path: Path) -> GatewayRecording:
    """Read what :class:`GatewayRecorder` wrote.

    Raises:
        RecordingError: the file cannot be read, is not a gateway recording, or a message does not parse.
    """
    config: CellConfig | None = None
    numbered: list[tuple[int, Step]] = []
    metadata: dict[str, dict[str, Any]] = {}
    truncated: str | None = None
    try:
        for item in _messages(path):
            if isinstance(item, _Truncated):
                truncated = item.reason
                break
            topic, sequence, data = item
            if topic.startswith("#"):
                metadata[topic[1:]] = json.loads(data)
            elif topic == CONFIG_TOPIC:
                config = CellConfig.model_validate_json(data)
            elif topic in _STEP_MODELS:
                numbered.append((sequence, _STEP_MODELS[topic].model_validate_json(data)))
    except ValidationError as exc:
        raise RecordingError(f"{path}: a message does not match its schema: {exc.errors()[0]['msg']}") from None
    if config is None or FORMAT_METADATA not in metadata:
        raise RecordingError(f"{path} is not a gateway recording (no {CONFIG_TOPIC}); record one: hrc-gateway --record")
    numbered.sort(key=lambda item: item[0])
    sequences = [0, *(s for s, _ in numbered)]  # the config is message 0
    missing_after = [a for a, b in itertools.pairwise(sequences) if b != a + 1]
    dropped = int(metadata.get(SUMMARY_METADATA, {}).get("dropped", "0"))
    return GatewayRecording(config, [step for _, step in numbered], dropped, missing_after, truncated)
