"""The PC's side of ABB EGM (joint mode): a UDP server that reads ``EgmRobot`` and answers with ``EgmSensor``.

    with EgmPc("0.0.0.0", 6510, n_joints=7) as pc:
        feedback = pc.receive(timeout_s=0.1)         # the next EgmRobot, in radians; its sender becomes the robot
        pc.send(q_ref_rad, qd_ref_radps)             # EgmSensor to that sender: reference [deg], speedRef [deg/s]

The controller speaks first (every 4 ms); the PC answers the address the last valid ``EgmRobot`` came from, as
abb-robot-client does. I/O only, no policy: what to send and when to stop is the caller's (a bridge's core). Every
datagram is hostile until decoded: :meth:`EgmPc.receive` raises :class:`VendorError` (``timeout``, ``malformed``,
``closed``) instead of returning a bad reading; a datagram that does not decode or has the wrong joint count is
counted and skipped, and the wait goes on until the timeout.
"""

from __future__ import annotations

import socket
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType, TracebackType

import numpy as np
import numpy.typing as npt

from hrc_devices.controllers.abb_egm.codec import (
    MAX_DATAGRAM_BYTES,
    EgmSensor,
    MciState,
    MotorState,
    RapidState,
    decode_robot,
    encode_sensor,
    joints_deg,
    joints_rad,
)
from hrc_devices.controllers.abb_egm.wire import EgmError
from hrc_devices.controllers.vendor import VendorError

__all__ = ["EgmFeedback", "EgmPc"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class EgmFeedback:
    """One ``EgmRobot`` as the PC received it.

    Attributes:
        received_wall_ns, received_mono_ns: the PC's clocks when it arrived [ns].
        seqno: the controller's sequence number.
        q_rad: ``feedBack`` joints (then external joints) [rad], one per joint of the robot.
        planned_rad: ``planned`` joints [rad]; None when the controller sent none.
        following: ``mciState`` RUNNING (EGM's motion follows the sensor).
        motors_on: ``motorState`` ON.
        rapid_running: ``rapidExecState`` RUNNING.
        controller_time_us: ``feedBack.time`` [µs]; None when absent.
    """

    received_wall_ns: int
    received_mono_ns: int
    seqno: int
    q_rad: FloatArray
    planned_rad: FloatArray | None
    following: bool
    motors_on: bool
    rapid_running: bool
    controller_time_us: int | None


class EgmPc:
    """The PC's UDP server for one robot (see the module docstring).

    Args:
        host: the address to listen on ("" or 0.0.0.0: every one).
        port: the UDP port the controller sends to (0: an ephemeral one, :attr:`port` after :meth:`open`).
        n_joints: the robot model's joint count (a seventh and further ride in ``externalJoints``).
        controller_host: the controller's IPv4 address: datagrams from any other host are counted
            (``foreign_sender``) and skipped, so that nobody else's ``EgmRobot`` is taken for the robot's feedback or
            answered; None: any sender (the last valid one is answered).
    """

    def __init__(self, host: str, port: int, n_joints: int, controller_host: str | None = None) -> None:
        self.host, self._port, self.n_joints = host, port, n_joints
        self.controller_host = controller_host
        self._sock: socket.socket | None = None
        self._robot: tuple[str, int] | None = None
        self._seqno = 0
        self._refused: Counter[str] = Counter()

    @property
    def port(self) -> int:
        """The bound port (after :meth:`open`)."""
        return self._port if self._sock is None else int(self._sock.getsockname()[1])

    @property
    def refused(self) -> Mapping[str, int]:
        """Datagrams skipped, by :class:`EgmError` reason."""
        return MappingProxyType(dict(sorted(self._refused.items())))

    def open(self) -> None:
        """Bind the socket.

        Raises:
            VendorError: ``connect``: the address cannot be bound.
        """
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((self.host, self._port))
        except OSError as exc:
            sock.close()
            raise VendorError("connect", f"EGM: cannot listen on UDP {self.host}:{self._port}: {exc}") from None
        self._sock = sock

    def receive(self, timeout_s: float) -> EgmFeedback:
        """The next valid ``EgmRobot``, waiting at most ``timeout_s``; its sender is answered by :meth:`send`.

        Raises:
            VendorError: ``timeout`` (none valid in time), ``closed`` (not open).
        """
        sock = self._sock
        if sock is None:
            raise VendorError("closed", "EGM: receive() before open()")
        deadline = time.monotonic() + timeout_s
        while True:
            left_s = deadline - time.monotonic()
            if left_s <= 0.0:
                raise VendorError("timeout", f"EGM: no valid EgmRobot within {timeout_s} s")
            sock.settimeout(left_s)
            try:
                data, sender = sock.recvfrom(MAX_DATAGRAM_BYTES + 1)
            except TimeoutError:
                continue
            except OSError as exc:
                raise VendorError("closed", f"EGM: receive failed: {exc}") from None
            mono_ns = time.monotonic_ns()
            wall_ns = time.time_ns()
            if self.controller_host is not None and str(sender[0]) != self.controller_host:
                self._refused["foreign_sender"] += 1
                continue
            try:
                feedback = self._feedback(data, wall_ns, mono_ns)
            except EgmError as exc:
                self._refused[exc.reason] += 1
                continue
            self._robot = (str(sender[0]), int(sender[1]))
            return feedback

    def _feedback(self, data: bytes, wall_ns: int, mono_ns: int) -> EgmFeedback:
        robot = decode_robot(data)
        planned = None
        if robot.planned_deg:
            planned = joints_rad(robot.planned_deg, robot.planned_external_deg, self.n_joints)
        return EgmFeedback(
            received_wall_ns=wall_ns,
            received_mono_ns=mono_ns,
            seqno=robot.seqno,
            q_rad=joints_rad(robot.feedback_deg, robot.feedback_external_deg, self.n_joints),
            planned_rad=planned,
            following=robot.mci == MciState.RUNNING,
            motors_on=robot.motors == MotorState.ON,
            rapid_running=robot.rapid == RapidState.RUNNING,
            controller_time_us=robot.feedback_time_us,
        )

    def send(self, q_ref_rad: npt.ArrayLike, qd_ref_radps: npt.ArrayLike) -> None:
        """Send the reference [rad] and its speed [rad/s] to the controller last heard from.

        Raises:
            VendorError: ``closed`` (not open, or no ``EgmRobot`` received yet), ``malformed`` (not one finite value
                per joint).
        """
        q = np.asarray(q_ref_rad, dtype=float)
        qd = np.asarray(qd_ref_radps, dtype=float)
        if q.shape != (self.n_joints,) or qd.shape != (self.n_joints,) or not np.all(np.isfinite(q) & np.isfinite(qd)):
            raise VendorError(
                "malformed", f"EGM: reference {q.tolist()}, speed {qd.tolist()}; allowed: {self.n_joints} finite each"
            )
        if self._sock is None or self._robot is None:
            raise VendorError("closed", "EGM: nothing to answer yet (the controller speaks first)")
        self._seqno += 1
        joints, external = joints_deg(q)
        speed, speed_external = joints_deg(qd)
        data = encode_sensor(
            EgmSensor(
                seqno=self._seqno & 0xFFFF_FFFF,
                tm_ms=(time.monotonic_ns() // 1_000_000) & 0xFFFF_FFFF,
                planned_deg=joints,
                planned_external_deg=external,
                speed_ref_degps=speed,
                speed_ref_external_degps=speed_external,
            )
        )
        try:
            self._sock.sendto(data, self._robot)
        except OSError as exc:
            raise VendorError("closed", f"EGM: send to {self._robot[0]}:{self._robot[1]} failed: {exc}") from None

    def close(self) -> None:
        """Close the socket (idempotent)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> EgmPc:
        self.open()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
