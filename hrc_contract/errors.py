"""The project's exception tree: one root, :class:`HrcError`, for every error the project raises on purpose.

A leaf module (it imports nothing of the project), so that the wire messages can use it and stay a leaf.

    HrcError
    ├── ConfigError        (hrc_contract.config)           a configuration that cannot load or is unsafe: refuse
    │   │                                                  to start
    │   ├── NotFoundError  (hrc_runtime.locate)            no cell file or state folder given nor found
    │   ├── ProgramModelError (controller_bridge.program_model) a recorded program model that cannot be made,
    │   │                                                  loaded or used for this robot
    │   ├── PkiError       (hrc_runtime.pki)               the cell's PKI is missing, invalid or expired
    │   └── SecurityError  (hrc_runtime.zenoh_session)     a Zenoh session cannot be secured as asked
    ├── MessageError       (hrc_contract.messages)         a payload that is not a valid message: count it, fail
    │   │                                                  closed
    │   ├── SkeletonError  (hrc_devices.trackers.skeletons)   keypoints that cannot describe a person
    │   ├── Ros2MessageError (hrc_devices.trackers.ros2_people) a ROS 2 tracker message that does not decode
    │   │                                                  or is absurd
    │   └── Ros2TrackerError (gateway.ros2_trackers)       a ROS 2 tracker sample refused before it is decoded
    ├── DigestError        (hrc_devices.controllers.abb_rws.http_digest) an HTTP Digest header that does not
    │                                                      parse: refuse it (401)
    ├── EgmError           (hrc_devices.controllers.abb_egm.wire) bytes that are not a valid ABB EGM message
    ├── AttachmentError    (hrc_devices.ros2.rmw_zenoh)    an rmw_zenoh sample attachment that rmw_zenoh would drop
    ├── RecordingError     (hrc_runtime.mcap_sink)         a recording cannot be written or read
    ├── RtdeError          (hrc_devices.controllers.ur_rtde.codec) bytes that are not a valid RTDE package
    ├── RuleError          (hrc_tools.faultinject.rules)   a fault-injection rule that does not parse
    ├── RelayError         (hrc_tools.faultinject.relay)   the fault relay cannot run
    ├── VendorError        (hrc_devices.controllers.vendor) a controller's vendor interface failed or answered
    │                                                      something invalid
    └── BenchError         (hrc_tools.cell.procs)          a benchmark or process test could not run
        └── StartupError   (hrc_tools.cell.procs)          a program did not start

Every message says what was given and what is allowed.
"""

from __future__ import annotations


class HrcError(Exception):
    """Root of the errors raised by hrc-gateway's programs and libraries."""
