"""An MCAP file written by a background thread from a bounded queue: offering a message never blocks.

    any thread ──offer(topic, channel, log_time_ns, encode, value)──▶ bounded queue ──writer thread──▶ file.mcap

The thread, the queue and the counting of what is dropped are :class:`QueuedWriter`'s, shared with the ROS 2 bag
(:class:`hrc_tools.record.ros2_mcap.Ros2BagSink`).

Every message is JSON (``message_encoding="json"``) on a channel whose schema is a JSON Schema
(``jsonschema``) generated from a pydantic model by :func:`hrc_contract.contract.schema_of`, so a reader (the
``mcap`` library, Foxglove, Lichtblick) knows what each field means. The caller hands over the value and how
to encode it; the encoding runs on the writer thread, so the caller (e.g. the gateway's safety loop) only
pays for one ``put_nowait``. When the queue is full the message is dropped and counted, never waited for:
the file then says it is incomplete (metadata ``hrc.recording``), and the gap in the messages' ``sequence``
numbers says where.
"""

from __future__ import annotations

import abc
import contextlib
import itertools
import logging
import queue
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO, Any, Generic, NamedTuple, Self, TypeVar

from mcap.writer import CompressionType, Writer
from pydantic import BaseModel

from hrc_contract.contract import render, schema_of
from hrc_contract.errors import HrcError

log = logging.getLogger("hrc-recorder")

DEFAULT_MAX_QUEUED = 100_000
"""Messages waiting for the writer thread beyond this are dropped (about 2 min of a gateway at 250 Hz)."""
CHUNK_BYTES = 256 * 1024
"""MCAP chunk size: small chunks keep each compression short on the writer thread [bytes]."""
SUMMARY_METADATA = "hrc.recording"
"""Name of the metadata record written at close: ``records``, ``dropped``, ``complete``, ``error``."""
PROFILE = "hrc"
"""The MCAP header's profile: JSON messages of this project's contract."""


class RecordingError(HrcError):
    """A recording cannot be written or read (path, format, missing records). The message says which file."""


class ChannelSpec(NamedTuple):
    """What a channel carries: the schema's name (``hrc.joint_state``, ``foxglove.SceneUpdate``) and JSON Schema."""

    schema_name: str
    schema: Mapping[str, Any]


def model_channel(schema_name: str, model: type[BaseModel]) -> ChannelSpec:
    """A channel of JSON messages of ``model``, its schema generated as the contract's (``docs/schemas``)."""
    return ChannelSpec(schema_name, schema_of(schema_name, model))


class RecordingSummary(NamedTuple):
    """What a closed recording holds.

    Attributes:
        path: the file.
        records: messages written.
        dropped: messages offered but not written (queue full, or after a write error).
        error: the write error that stopped the recording, if any.
    """

    path: Path
    records: int
    dropped: int
    error: str | None

    @property
    def complete(self) -> bool:
        return self.dropped == 0 and self.error is None

    def as_metadata(self) -> dict[str, str]:
        """``records``, ``dropped``, ``complete`` (``true``/``false``) and ``error`` (empty if none), as strings."""
        return {
            "records": str(self.records),
            "dropped": str(self.dropped),
            "complete": "true" if self.complete else "false",
            "error": self.error or "",
        }


def identity(payload: bytes) -> bytes:
    """The encoder of a payload that already is the JSON message (e.g. bytes received on Zenoh)."""
    return payload


Encoder = Callable[[Any], bytes]
_Item = tuple[int, str, ChannelSpec, int, Encoder, Any]
ItemT = TypeVar("ItemT")


class QueuedWriter(abc.ABC, Generic[ItemT]):
    """A recording written by its own thread from a bounded queue (a context manager: started on entry, closed on exit).

    Queuing (:meth:`_put`) never blocks: on a full queue the item is dropped and counted. The writer thread hands
    each item to :meth:`_write`; once that has set ``_error`` (a write error), later items are dropped and counted
    instead. :meth:`close` drains the queue, then :meth:`_finish` ends the file on the caller's thread.

    Args:
        path: the recording (its summary names it).
        max_queued: items waiting beyond this are dropped and counted.
        thread_name: the writer thread's name.
        on_start: called first on the writer thread (e.g. to set its scheduling); None: nothing.
    """

    def __init__(
        self, path: Path, max_queued: int, thread_name: str, on_start: Callable[[], object] | None = None
    ) -> None:
        self.path = path
        self._on_start = on_start
        self._queue: queue.Queue[ItemT | None] = queue.Queue(max_queued)
        self._drop_lock = threading.Lock()
        self._dropped = 0
        self._records = 0
        self._error: str | None = None
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)
        self._started = False
        self._closed = False

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- any thread ---------------------------------------------------------------------------------

    def _put(self, item: ItemT) -> bool:
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self._count_drop()
            return False
        return True

    def _count_drop(self) -> None:
        with self._drop_lock:
            self._dropped += 1

    @property
    def dropped(self) -> int:
        with self._drop_lock:
            return self._dropped

    def summary(self) -> RecordingSummary:
        """What was written and dropped so far."""
        return RecordingSummary(self.path, self._records, self.dropped, self._error)

    # -- lifetime ------------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the writer thread (what was queued before is kept, up to ``max_queued``)."""
        if not self._started:
            self._started = True
            self._thread.start()

    def close(self, timeout_s: float = 30.0) -> RecordingSummary:
        """Write what is queued, then finish the file (:meth:`_finish`: summary and footer); idempotent."""
        if not self._closed:
            self._closed = True
            self.start()
            with contextlib.suppress(queue.Full):  # the writer drains the queue, so this wait is short
                self._queue.put(None, timeout=timeout_s)
            self._thread.join(timeout_s)
            self._finish()
        return self.summary()

    @abc.abstractmethod
    def _finish(self) -> None:
        """Write the summary and the footer, close the file (after the writer thread ended)."""

    # -- the writer thread ----------------------------------------------------------------------------

    def _run(self) -> None:
        if self._on_start is not None:
            self._on_start()
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self._error is None:
                self._write(item)
            elif self._counts(item):
                self._count_drop()
            time.sleep(0)  # hand the GIL over after each item: a backlog here never holds up the caller's threads

    @abc.abstractmethod
    def _write(self, item: ItemT) -> None:
        """Write one item; on a write error set ``_error`` (later items are dropped) and count the drop."""

    def _counts(self, item: ItemT) -> bool:
        """Whether ``item``, dropped after a write error, counts as a dropped message (all do, unless overridden)."""
        return True


class McapSink(QueuedWriter[_Item]):
    """One MCAP file, written by its own thread (a context manager: ``with McapSink(path) as sink: ...``).

    Args:
        path: the file to create (its folder too); an existing file is replaced.
        max_queued: messages waiting beyond this are dropped and counted.
        metadata: MCAP metadata records written at start (name → string map), e.g. the cell and its config hash.
        on_start: called first on the writer thread (:class:`QueuedWriter`).

    Raises:
        RecordingError: the file cannot be created.
    """

    def __init__(
        self,
        path: Path,
        max_queued: int = DEFAULT_MAX_QUEUED,
        metadata: Mapping[str, Mapping[str, str]] | None = None,
        on_start: Callable[[], object] | None = None,
    ) -> None:
        super().__init__(path, max_queued, "mcap-writer", on_start)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file: IO[bytes] = path.open("wb")
        except OSError as exc:
            raise RecordingError(f"cannot create the recording {path}: {exc.strerror or exc}") from None
        self._writer = Writer(self._file, chunk_size=CHUNK_BYTES, compression=CompressionType.LZ4)
        self._writer.start(profile=PROFILE, library="hrc-gateway recorder")
        for name, data in (metadata or {}).items():
            self._writer.add_metadata(name, dict(data))
        self._sequence = itertools.count()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}

    # -- any thread ---------------------------------------------------------------------------------

    def declare(self, topic: str, channel: ChannelSpec) -> None:
        """Register ``topic`` now (on the writer thread), so the file lists it even if no message comes."""
        self._put((-1, topic, channel, 0, identity, None))

    def offer(self, topic: str, channel: ChannelSpec, log_time_ns: int, encode: Encoder, value: Any) -> bool:
        """Queue one message for ``topic`` (registered on first use); ``encode(value)`` runs on the writer thread.

        Returns:
            False if the message was dropped (queue full, or the recording failed).
        """
        return self._put((next(self._sequence), topic, channel, log_time_ns, encode, value))

    # -- lifetime ------------------------------------------------------------------------------------

    def _finish(self) -> None:
        try:
            self._writer.add_metadata(SUMMARY_METADATA, self.summary().as_metadata())
            self._writer.finish()  # type: ignore[no-untyped-call]  # mcap stub
        except OSError as exc:
            self._error = self._error or f"cannot finish {self.path}: {exc.strerror or exc}"
            log.error("recording %s: %s", self.path, self._error)
        finally:
            self._file.close()

    # -- the writer thread ----------------------------------------------------------------------------

    def _counts(self, item: _Item) -> bool:
        return item[0] >= 0  # a declaration is no message

    def _write(self, item: _Item) -> None:
        sequence, topic, channel, log_time_ns, encode, value = item
        try:
            data = b"" if sequence < 0 else encode(value)
        except Exception:  # a value that cannot be encoded is dropped, not the whole recording
            log.exception("recording %s: cannot encode a message on %s; dropped", self.path, topic)
            self._count_drop()
            return
        try:
            channel_id = self._channel_id(topic, channel)
            if sequence < 0:
                return
            self._writer.add_message(channel_id, log_time_ns, data, log_time_ns, sequence)
            self._records += 1
        except OSError as exc:
            self._error = f"cannot write {self.path}: {exc.strerror or exc}"
            log.error("recording %s: %s; later messages are dropped", self.path, self._error)
            self._count_drop()

    def _channel_id(self, topic: str, channel: ChannelSpec) -> int:
        channel_id = self._channels.get(topic)
        if channel_id is None:
            schema_id = self._schemas.get(channel.schema_name)
            if schema_id is None:
                data = render(channel.schema).encode()
                schema_id = self._writer.register_schema(channel.schema_name, "jsonschema", data)
                self._schemas[channel.schema_name] = schema_id
            channel_id = self._writer.register_channel(topic, "json", schema_id)
            self._channels[topic] = channel_id
        return channel_id
