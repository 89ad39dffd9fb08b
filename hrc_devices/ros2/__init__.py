"""ROS 2 over rmw_zenoh (:mod:`.rmw_zenoh`) and the vendored message definitions (``ros2_msgs/``)."""

__all__ = ["rmw_zenoh"]
