"""A ROS 2 bag (rosbag2, MCAP storage) written by a background thread from a bounded queue: offering never blocks.

    any thread ──offer(log_time_ns, build, value)──▶ bounded queue ──writer thread: build → CDR──▶ <bag>/<bag>.mcap

What ``ros2 bag record -s mcap`` leaves, written by ``rosbags``' rosbag2 writer (:class:`rosbags.rosbag2.Writer`,
MCAP storage plugin), so that ROS tools and ``rosbags`` read it as a bag:

- a folder ``<bag>/`` holding ``<bag>.mcap`` and ``metadata.yaml`` (rosbag2 metadata version 8 for Humble and Jazzy,
  9 for Kilted; ``rosbags.rosbag2.Reader`` needs the YAML, an MCAP reader only the file);
- in the MCAP file: profile ``ros2``; one schema per message type, encoding ``ros2msg``, its data the concatenated
  ``.msg`` definitions (the type's own, then each nested type after a ``====…`` line and ``MSG: <pkg>/<Type>``, as
  rosbag2 stores them, from the distro's type store :func:`hrc_devices.ros2.rmw_zenoh.typestore`); one channel per
  topic, message encoding ``cdr``, with its ``offered_qos_profiles``; chunks compressed with zstd; the rosbag2 metadata
  record.

The caller hands over a value and a ``build`` function turning it into ``(topic, message)`` pairs; building and CDR
serialisation run on the writer thread, so a Zenoh callback only pays for one ``put_nowait``. A full queue drops the
offer and counts it (never waits); the bag's ``custom_data`` then says it is incomplete (``hrc.complete``).
Unlike the JSON recording (:class:`hrc_runtime.mcap_sink.McapSink`), an existing bag is never replaced (as
``ros2 bag record``); and messages reach the file in 1 MiB chunks (rosbags' chunk size), so a SIGKILL loses up to the
last chunk.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, NamedTuple

from rosbags.interfaces import (
    Connection,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer, WriterError
from ruamel.yaml import YAML

from hrc_devices.ros2.rmw_zenoh import Distro, serialize, typestore
from hrc_runtime.mcap_sink import DEFAULT_MAX_QUEUED, QueuedWriter, RecordingError

log = logging.getLogger("hrc-recorder.ros2")

BAG_VERSION: dict[Distro, Literal[8, 9]] = {"humble": 8, "jazzy": 8, "kilted": 9}
"""rosbag2 metadata version written per distro (``rosbags`` writes 8 or 9; Jazzy's rosbag2 writes 8)."""
PROFILE = "ros2"
"""The MCAP header's profile (rosbags' MCAP storage writes it)."""
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
SUMMARY_PREFIX = "hrc."
"""``custom_data`` keys of ``metadata.yaml`` written at close: ``hrc.records``, ``hrc.dropped``, ``hrc.complete``,
``hrc.error``, besides those given at start."""

_DEFAULT_TIME = QosTime(0, 0)


def qos(*, depth: int = 10, transient_local: bool = False) -> Qos:
    """The QoS a topic is said to have been offered with: reliable, keep last ``depth``, volatile unless
    ``transient_local`` (``/tf_static``); deadline, lifespan and lease at the defaults (0)."""
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=depth,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        deadline=_DEFAULT_TIME,
        lifespan=_DEFAULT_TIME,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=_DEFAULT_TIME,
        avoid_ros_namespace_conventions=False,
    )


DEFAULT_QOS = qos()
"""What the gateway's ROS 2 face offers (reliable, volatile, keep last 10:
``hrc_devices.ros2.rmw_zenoh.DEFAULT_QOS``)."""


class Ros2Topic(NamedTuple):
    """A channel of the bag.

    Attributes:
        name: the fully qualified ROS name, ``/ur5/joint_states``.
        msgtype: the ROS type, ``sensor_msgs/msg/JointState``.
        qos: the offered QoS written with it (``ros2 bag play`` publishes with it).
    """

    name: str
    msgtype: str
    qos: Qos = DEFAULT_QOS


Build = Callable[[Any], Sequence[tuple[Ros2Topic, Any]]]
"""Turns an offered value into ROS 2 messages (of the sink's distro), each with its topic."""
_Item = tuple[int, Build, Any]


def bag_file(path: Path) -> Path:
    """The MCAP file inside the bag folder ``path`` (``<bag>/<bag>.mcap``, rosbags' name for it)."""
    return path / f"{path.name}.mcap"


def bag_custom_data(path: Path) -> dict[str, str]:
    """``custom_data`` of the bag folder ``path``'s ``metadata.yaml`` (the cell, its config hash, the summary).

    Raises:
        RecordingError: no readable ``metadata.yaml`` (the bag was not closed, or is not a bag).
    """
    try:
        metadata = YAML(typ="safe").load((path / "metadata.yaml").read_text())
        custom = metadata["rosbag2_bagfile_information"].get("custom_data") or {}
    except (OSError, KeyError, TypeError, AttributeError, ValueError) as exc:
        raise RecordingError(f"{path} is not a closed ROS 2 bag: {exc}") from None
    return {str(k): str(v) for k, v in custom.items()}


class Ros2BagSink(QueuedWriter[_Item]):
    """One ROS 2 bag, written by its own thread (a context manager: ``with Ros2BagSink(path, "jazzy") as sink``).

    Its summary (:meth:`close`) counts as ``records`` the ROS 2 messages written, as ``dropped`` the offers not
    written; :meth:`close` writes it into ``custom_data``, then the MCAP summary and ``metadata.yaml``.

    Args:
        path: the bag folder to create; it must not exist (its parent is created).
        distro: whose message definitions and hashes the bag carries.
        max_queued: offers waiting beyond this are dropped and counted.
        custom_data: ``custom_data`` of ``metadata.yaml`` (string → string), e.g. the cell and its config hash.

    Raises:
        RecordingError: the folder exists or cannot be created.
        ConfigError: an unknown distro.
    """

    def __init__(
        self,
        path: Path,
        distro: Distro,
        max_queued: int = DEFAULT_MAX_QUEUED,
        custom_data: Mapping[str, str] | None = None,
    ) -> None:
        super().__init__(path, max_queued, "ros2-bag-writer")
        self.distro: Distro = distro
        store = typestore(distro)
        if path.exists():
            raise RecordingError(f"the ROS 2 bag {path} exists already; allowed: a new folder (never overwritten)")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._bag = Writer(path, version=BAG_VERSION[distro], storage_plugin=StoragePlugin.MCAP)
            self._bag.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            for key, value in (custom_data or {}).items():
                self._bag.set_custom_data(key, value)
            self._bag.open()
        except (OSError, WriterError) as exc:
            raise RecordingError(f"cannot create the ROS 2 bag {path}: {exc}") from None
        self._store = store
        self._connections: dict[str, Connection] = {}

    # -- any thread ---------------------------------------------------------------------------------

    def offer(self, log_time_ns: int, build: Build, value: Any) -> bool:
        """Queue ``value``; ``build(value)`` runs on the writer thread, each message written at ``log_time_ns``.

        Returns:
            False if it was dropped (queue full).
        """
        return self._put((log_time_ns, build, value))

    # -- lifetime ------------------------------------------------------------------------------------

    def _finish(self) -> None:
        for key, value in self.summary().as_metadata().items():
            self._bag.set_custom_data(SUMMARY_PREFIX + key, value)
        try:
            self._bag.close()
        except (OSError, WriterError) as exc:
            self._error = self._error or f"cannot finish {self.path}: {exc}"
            log.error("ROS 2 bag %s: %s", self.path, self._error)
            with contextlib.suppress(Exception):
                self._bag.abort()

    # -- the writer thread ----------------------------------------------------------------------------

    def _write(self, item: _Item) -> None:
        log_time_ns, build, value = item
        try:
            encoded = [(self._connection(topic), serialize(self.distro, message)) for topic, message in build(value)]
        except Exception:  # a value that cannot be translated is dropped, not the whole recording
            log.exception("ROS 2 bag %s: cannot build the messages of %s; dropped", self.path, type(value).__name__)
            self._count_drop()
            return
        try:
            for connection, data in encoded:
                self._bag.write(connection, log_time_ns, data)
                self._records += 1
        except (OSError, WriterError) as exc:
            self._error = f"cannot write {self.path}: {exc}"
            log.error("ROS 2 bag %s: %s; later messages are dropped", self.path, self._error)
            self._count_drop()

    def _connection(self, topic: Ros2Topic) -> Connection:
        connection = self._connections.get(topic.name)
        if connection is None:
            connection = self._bag.add_connection(
                topic.name, topic.msgtype, typestore=self._store, offered_qos_profiles=[topic.qos]
            )
            self._connections[topic.name] = connection
        elif connection.msgtype != topic.msgtype:  # a programming error: this message is dropped, not the bag
            raise ValueError(f"topic {topic.name} is {connection.msgtype}, not {topic.msgtype}")
        return connection
