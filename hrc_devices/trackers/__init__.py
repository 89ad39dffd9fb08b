"""The body trackers: skeletons to capsules (:mod:`.skeletons`), people frames of ROS 2 trackers (ZED, Azure Kinect:
:mod:`.ros2_people`), ROS4HRI bodies (:mod:`.ros4hri_body`) and the formats' registry (:data:`.registry.FORMATS`)."""

__all__ = ["registry", "ros2_people", "ros4hri_body", "skeletons"]
