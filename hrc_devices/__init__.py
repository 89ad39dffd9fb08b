"""What two or more programs know about the cell's devices: the robots (model, link motion, segments, effective
mass, the program), the controllers (the vendor base, one folder per vendor, the registry), the body trackers (people
frames, one module per format, the registry) and ROS 2 (rmw_zenoh and the vendored message definitions).

The layer between the programs and the runtime: imports hrc_runtime and hrc_contract of the project; no device
module imports a program, and vendor folders and tracker formats do not import each other.
"""

__all__ = ["controllers", "robots", "ros2", "trackers"]
