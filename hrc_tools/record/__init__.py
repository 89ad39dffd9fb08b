"""Recordings of the cell in MCAP and their replay through the gateway.

- :mod:`hrc_tools.record.cell`: ``hrc-record``, every cell topic as a Zenoh member with the ``recorder``
  certificate;
- :mod:`hrc_tools.record.scene`: ``foxglove.SceneUpdate`` capsules (Foxglove, Lichtblick 3D panel);
- :mod:`hrc_tools.record.ros2_cell`, :mod:`hrc_tools.record.ros2_mcap`: ``hrc-record --format ros2``, the same
  messages as a ROS 2 bag (rosbag2 folder, MCAP with CDR messages);
- :mod:`hrc_tools.record.replay`: ``hrc-replay``, a gateway recording fed through a new gateway node on its own
  clock.

The MCAP writer is :mod:`hrc_runtime.mcap_sink`; what ``hrc-gateway --record`` writes is :mod:`gateway.recording`.
"""

__all__ = [
    "cell",
    "replay",
    "ros2_cell",
    "ros2_mcap",
    "scene",
    "topics",
]
