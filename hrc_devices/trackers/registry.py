"""The ROS 2 body tracker formats by the cell file's ``[trackers.<name>.ros2] format``: the one place that lists them.

fmt = FORMATS[tracker.ros2.format]
wire = topic_type(distro, fmt.msgtype)       # the configured topic's message type
frame = fmt.decode(payload, store)           # one message → a people frame (None: a format of several streams)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from rosbags.typesys.store import Typestore

from hrc_devices.trackers import ros2_people

__all__ = ["FORMATS", "TrackerFormat", "register_format"]


class TrackerFormat(NamedTuple):
    """What the programs know of one tracker format.

    Attributes:
        name: the cell file's ``format``.
        msgtype: the ROS 2 message type of its configured topic.
        decode: one message of the topic → a people frame; None for a format whose people come from several
            streams (ROS4HRI: the tracked list, per body joint states and /tf), which the reader assembles.
    """

    name: str
    msgtype: str
    decode: Callable[[bytes, Typestore], ros2_people.PeopleFrame] | None


FORMATS: dict[str, TrackerFormat] = {}
"""Every tracker format, by name."""


def register_format(fmt: TrackerFormat) -> None:
    """Add ``fmt``; a name replaces one of the same name."""
    FORMATS[fmt.name] = fmt


register_format(TrackerFormat("zed_objects", ros2_people.ZED_OBJECTS, ros2_people.decode_zed_objects))
register_format(TrackerFormat("k4abt_markers", ros2_people.MARKER_ARRAY, ros2_people.decode_k4abt_markers))
register_format(TrackerFormat("ros4hri_bodies", ros2_people.IDS_LIST, None))
