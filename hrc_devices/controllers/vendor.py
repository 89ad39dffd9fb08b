"""What the bridge needs from a controller's vendor interface, and nothing more: a *closed* controller's speed input
(UR RTDE, ABB RWS: :class:`VendorInterface`) or an *open* controller's joint references (ABB EGM:
:class:`OpenVendorInterface`).

    interface.connect()                        # handshake; raises VendorError naming what failed
    written = interface.write_speed_fraction(0.5)  # the value actually written (quantised, floored)
    reading = interface.read()                 # the next read-back (blocks at most timeout_s)
    interface.close()

    open_interface.connect()
    feedback = open_interface.read(timeout_s)  # the controller's joint feedback (an open controller speaks first)
    open_interface.send_reference(q_ref_rad, qd_ref_radps)   # answered to the controller last heard from
    open_interface.close()

An implementation does I/O only: no policy (echo, programmed velocity, watchdog) lives here; that is the bridge's
pure core. Every value read from the controller is hostile until checked: ``read`` raises :class:`VendorError`
for a malformed, non-finite or out-of-range answer instead of returning it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

from hrc_contract.errors import HrcError


class VendorError(HrcError):
    """The controller's interface failed or answered something invalid.

    Attributes:
        reason: a short machine-readable cause for counting (``connect``, ``timeout``, ``malformed``, ``refused``,
            ``closed``, ``auth``).
    """

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class ControllerReading:
    """One read-back from the controller, as received by the bridge.

    Attributes:
        received_wall_ns: the bridge's wall clock when the reading arrived [ns] (the joint state's stamp).
        received_mono_ns: the bridge's monotonic clock then [ns].
        q_rad: joint positions [rad].
        qd_radps: joint velocities [rad/s]; None when the interface offers none (the bridge differentiates q).
        target_qd_radps: the controller's target joint velocities [rad/s]; None when not offered.
        speed_fraction: the controller's read-back of the speed input, in [0, 1] (UR ``target_speed_fraction``,
            ABB speed ratio / 100).
        speed_scaling: a further scaling the controller applies, in [0, 1] (UR ``speed_scaling``); None when not
            offered.
        running: the program runs (not stopped, paused, or in a protective or emergency stop).
        state_text: the controller's state words, for the log and the status (e.g. ``runtime_state=2 safety_mode=1``).
        controller_time_s: the controller's own time of the reading (UR RTDE ``timestamp``) [s]; None when the
            interface offers none (the bridge then uses ``received_mono_ns``).
    """

    received_wall_ns: int
    received_mono_ns: int
    q_rad: tuple[float, ...]
    qd_radps: tuple[float, ...] | None
    target_qd_radps: tuple[float, ...] | None
    speed_fraction: float
    speed_scaling: float | None
    running: bool
    state_text: str
    controller_time_s: float | None = None


class VendorInterface(Protocol):
    """A controller's speed input and read-back (see the module docstring)."""

    kind: str
    """``ur_rtde`` or ``abb_rws``: the name the cell file and the status use."""

    def connect(self) -> None: ...

    def write_speed_fraction(self, fraction: float) -> float:
        """Write the speed input; ``fraction`` in [0, 1]. Returns the value written after quantisation (never more
        than ``fraction``).

        Raises:
            VendorError: the write failed.
        """
        ...

    def read(self, timeout_s: float) -> ControllerReading:
        """The next read-back, waiting at most ``timeout_s``.

        Raises:
            VendorError: timeout, a closed connection or an invalid answer.
        """
        ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class JointFeedback:
    """One joint feedback from an *open* controller, as received by the bridge.

    Attributes:
        received_wall_ns: the bridge's wall clock when it arrived [ns].
        received_mono_ns: the bridge's monotonic clock then [ns].
        q_rad: joint positions [rad], one per joint of the robot model.
        reference_rad: the reference the controller reports it converges on [rad] (EGM ``planned``); None when not
            offered.
        following: the controller follows the PC's references (EGM ``mciState`` RUNNING).
        running: motors on and the controller's program running (EGM ``motorState`` ON, ``rapidExecState``
            RUNNING).
        controller_time_s: the controller's own time of the feedback (EGM ``feedBack.time``) [s]; None when not
            offered.
        state_text: the controller's state words, for the log.
    """

    received_wall_ns: int
    received_mono_ns: int
    q_rad: tuple[float, ...]
    reference_rad: tuple[float, ...] | None
    following: bool
    running: bool
    controller_time_s: float | None
    state_text: str


class OpenVendorInterface(Protocol):
    """An open controller's joint references and feedback (see the module docstring). The controller speaks first:
    :meth:`send_reference` answers the controller last heard from."""

    kind: str
    """``abb_egm``: the name the cell file and the status use."""

    @property
    def refused(self) -> Mapping[str, int]:
        """Datagrams or messages the interface skipped before decoding a feedback, by reason."""
        ...

    def connect(self) -> None: ...

    def read(self, timeout_s: float) -> JointFeedback:
        """The next valid feedback, waiting at most ``timeout_s``.

        Raises:
            VendorError: timeout, a closed socket.
        """
        ...

    def send_reference(self, q_ref_rad: tuple[float, ...], qd_ref_radps: tuple[float, ...]) -> None:
        """Send a joint reference [rad] and its feed-forward velocity [rad/s].

        Raises:
            VendorError: not connected, nothing heard yet, not one finite value per joint, the send failed.
        """
        ...

    def close(self) -> None: ...
