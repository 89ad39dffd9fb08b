"""The bridge's open vendor interface for ABB EGM: :class:`~hrc_devices.controllers.abb_egm.pc.EgmPc` as an
:class:`~hrc_devices.controllers.vendor.OpenVendorInterface` (feedback in radians, references answered to the
controller last heard from).

    interface = EgmInterface("0.0.0.0", 6510, n_joints=9)
    interface.connect()                                  # binds the UDP port
    feedback = interface.read(timeout_s=0.1)            # JointFeedback of the next valid EgmRobot
    interface.send_reference(q_ref_rad, qd_ref_radps)   # EgmSensor: planned [deg], speedRef [deg/s]
    interface.close()
"""

from __future__ import annotations

from collections.abc import Mapping

from hrc_devices.controllers.abb_egm.pc import EgmPc
from hrc_devices.controllers.vendor import JointFeedback

__all__ = ["EgmInterface"]

US_PER_S = 1e6


class EgmInterface:
    """ABB EGM's PC side for the bridge (see the module docstring).

    Args:
        host: the address to listen on.
        port: the UDP port the controller sends to (0: ephemeral, :attr:`port` after :meth:`connect`).
        n_joints: the robot model's joint count.
        controller_host: the controller's IPv4 address (datagrams from others are skipped and counted); None: any.
    """

    kind = "abb_egm"

    def __init__(self, host: str, port: int, n_joints: int, controller_host: str | None = None) -> None:
        self._pc = EgmPc(host, port, n_joints, controller_host)

    @property
    def port(self) -> int:
        """The bound UDP port."""
        return self._pc.port

    @property
    def refused(self) -> Mapping[str, int]:
        """Datagrams skipped (undecodable, wrong joint count, a foreign sender), by reason."""
        return self._pc.refused

    def connect(self) -> None:
        """Bind the UDP socket (the controller speaks first: nothing is sent).

        Raises:
            VendorError: ``connect``: the address cannot be bound.
        """
        self._pc.close()
        self._pc.open()

    def read(self, timeout_s: float) -> JointFeedback:
        """The next valid ``EgmRobot`` as joint feedback.

        Raises:
            VendorError: ``timeout``, ``closed``.
        """
        feedback = self._pc.receive(timeout_s)
        time_us = feedback.controller_time_us
        return JointFeedback(
            received_wall_ns=feedback.received_wall_ns,
            received_mono_ns=feedback.received_mono_ns,
            q_rad=tuple(float(v) for v in feedback.q_rad),
            reference_rad=None if feedback.planned_rad is None else tuple(float(v) for v in feedback.planned_rad),
            following=feedback.following,
            running=feedback.motors_on and feedback.rapid_running,
            controller_time_s=None if time_us is None else time_us / US_PER_S,
            state_text=(
                f"seqno={feedback.seqno} mci={'RUNNING' if feedback.following else 'not running'} "
                f"motors={'ON' if feedback.motors_on else 'OFF'} "
                f"rapid={'RUNNING' if feedback.rapid_running else 'STOPPED'}"
            ),
        )

    def send_reference(self, q_ref_rad: tuple[float, ...], qd_ref_radps: tuple[float, ...]) -> None:
        """Answer the controller with an ``EgmSensor`` (reference [rad] → [deg], feed-forward [rad/s] → [deg/s]).

        Raises:
            VendorError: ``closed`` (nothing heard yet, not open), ``malformed`` (not one finite value per joint).
        """
        self._pc.send(q_ref_rad, qd_ref_radps)

    def close(self) -> None:
        """Close the socket (idempotent)."""
        self._pc.close()
