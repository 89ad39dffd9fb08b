"""The emulated open controller's ABB EGM face (Externally Guided Motion, joint mode), for a PC that drives it.

    face = EgmFace(node, "127.0.0.1", 6510)   # the PC's UDP address (EGM's "remote address" and port)
    face.start()                              # a UDP socket on an ephemeral port; a receiver thread
    face.on_cycle(output)                     # every emulator cycle: one EgmRobot to the PC
    face.close()

**The exchange** (as an IRC5 running ``EGMActJoint`` / ``EGMRunJoint``): the controller speaks first. Every cycle
(``controller.cycle_s``, 4 ms) it sends an ``EgmRobot`` to the PC's address: header ``seqno`` (consecutive from 1)
and ``tm`` [ms since the face started], ``feedBack`` (the joint angles [deg] and the wall-clock time), ``planned``
(the reference it is converging on; its position where it has none), ``motorState`` ON, ``rapidExecState`` RUNNING,
``mciState`` RUNNING while it follows and STOPPED otherwise, ``mciConvergenceMet`` (every joint within
:data:`CONVERGENCE_DEG` of the reference). The PC answers the sender's address with an ``EgmSensor``: ``planned``
joints [deg] are the reference, ``speedRef`` joints [deg/s] the feed-forward (absent: 0; absent for the external
joints only: 0 for those). Joints beyond the sixth
ride in ``externalJoints`` in the model's order (a 7-axis arm's arm angle first; the Panda's fingers after it):
:mod:`hrc_devices.controllers.abb_egm.codec`.

Each ``EgmSensor`` becomes one joint command of the open node (:meth:`OpenControllerNode.on_message`), stamped with
its arrival on the emulator's wall clock (EGM's ``tm`` is the sender's, and abb-robot-client sends 0) and numbered by
this face; the PC's sequence numbers are not checked (abb-robot-client's go 1, 3, 5, …). The follower runs in EGM's
**position mode** (``on_silence = "hold_reference"``): between datagrams it converges on the last reference and holds
it; when none has come for the controller's ``watchdog_s`` (EGM's ``\\CommTimeout``, 1 s in ABB's Add-In; the cell
file's, 0.1 s by default) it stops at its acceleration bound (a protective stop: RAPID would get ``ERR_UDPUC_COMM``)
and resumes from where it stands on the next valid datagram (as a RAPID error handler that restarts ``EGMRunJoint``).

Only datagrams from the PC's address are taken (its port, and its host or any loopback host when the PC is on
loopback: a reply to 127.0.0.x comes from 127.0.0.1); others, undecodable ones and those with the wrong joint count
are counted and dropped. Not emulated: Cartesian (pose) mode and ``EgmSensorPathCorr``, ``\\MaxSpeedDeviation``,
EGM's low-pass filter and ramps (``\\LpFilter``, ``\\RampInTime``, ``\\RampOutTime``), the condition time
(``\\CondTime``), ``RAPIDtoRobot`` / ``RAPIDfromRobot``, measured force, velocity mode (``PosCorrGain`` 0).
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import threading
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType, TracebackType

import numpy as np

from controller_emu.open_node import OpenControllerNode, OpenControllerOutput
from hrc_contract.messages import JointCommand
from hrc_devices.controllers.abb_egm.codec import (
    MAX_DATAGRAM_BYTES,
    ROBOT_AXES,
    EgmRobot,
    MciState,
    MotorState,
    RapidState,
    decode_sensor,
    encode_robot,
    joints_deg,
    joints_rad,
)
from hrc_devices.controllers.abb_egm.wire import EgmError
from hrc_runtime.clocks import Clocks, read_clocks

log = logging.getLogger("hrc-controller-emu.egm")

CONVERGENCE_DEG = 1.0
"""``mciConvergenceMet`` when every joint is within this of the reference [deg] (this emulator's criterion)."""

RECEIVE_POLL_S = 0.2
"""The receiver thread's socket timeout: how soon it notices :meth:`EgmFace.close` [s]."""


@dataclass(frozen=True)
class EgmFaceStats:
    """What the face sent, took and dropped.

    Attributes:
        sent: ``EgmRobot`` datagrams sent.
        received: datagrams received (from anyone).
        accepted: ``EgmSensor`` references the node accepted.
        refused: the others, by reason (``foreign_sender``, an :class:`EgmError` reason, a node's rejection).
    """

    sent: int
    received: int
    accepted: int
    refused: Mapping[str, int]


def sender_is_pc(sender: tuple[str, int], pc: tuple[str, int]) -> bool:
    """Whether a datagram from ``sender`` (host, port) comes from the PC at ``pc`` (an IPv4 address and port).

    The ports must match; the hosts too, except that every loopback address stands for every other (a PC bound to
    all addresses answers 127.0.0.5's datagram from 127.0.0.1).
    """
    if sender[1] != pc[1]:
        return False
    if sender[0] == pc[0]:
        return True
    try:
        return ipaddress.ip_address(sender[0]).is_loopback and ipaddress.ip_address(pc[0]).is_loopback
    except ValueError:
        return False


def robot_message(output: OpenControllerOutput, seqno: int, tm_ms: int) -> EgmRobot:
    """The ``EgmRobot`` of one emulator cycle (the module docstring says what each field reports)."""
    state = output.state
    planned_rad = state.q_rad if state.q_ref_rad is None else state.q_ref_rad
    feedback, feedback_external = joints_deg(state.q_rad)
    planned, planned_external = joints_deg(planned_rad)
    following = state.mode == "running"
    converged = bool(np.all(np.abs(np.degrees(planned_rad - state.q_rad)) <= CONVERGENCE_DEG))
    return EgmRobot(
        seqno=seqno & 0xFFFF_FFFF,
        tm_ms=tm_ms & 0xFFFF_FFFF,
        feedback_deg=feedback,
        feedback_external_deg=feedback_external,
        feedback_time_us=output.joint_state.stamp_ns // 1000,
        planned_deg=planned,
        planned_external_deg=planned_external,
        motors=MotorState.ON,
        mci=MciState.RUNNING if following else MciState.STOPPED,
        mci_convergence_met=following and converged,
        rapid=RapidState.RUNNING,
    )


def sensor_command(data: bytes, robot: str, n_joints: int, seq: int, stamp_ns: int) -> JointCommand:
    """The open node's joint command of one ``EgmSensor`` datagram (reference and feed-forward in radians).

    Raises:
        EgmError: not a valid ``EgmSensor``, or not one reference per joint (a speed reference, when present, too).
    """
    sensor = decode_sensor(data)
    q_rad = joints_rad(sensor.planned_deg, sensor.planned_external_deg, n_joints)
    if sensor.speed_ref_degps or sensor.speed_ref_external_degps:
        # external joints without a speed reference get none (send_to_robot's external_joints_speed is optional)
        external_degps = sensor.speed_ref_external_degps or (0.0,) * max(n_joints - ROBOT_AXES, 0)
        qd_radps = joints_rad(sensor.speed_ref_degps, external_degps, n_joints)
    else:
        qd_radps = np.zeros(n_joints)
    return JointCommand(robot=robot, seq=seq, stamp_ns=stamp_ns, q=q_rad.tolist(), qd=qd_radps.tolist(), delta=1.0)


class EgmFace:
    """The controller's side of EGM for ``node`` (see the module docstring).

    Args:
        node: the open controller (its limits should hold the reference on silence: EGM's position mode).
        pc_host: the PC's address (a name is resolved to IPv4 at :meth:`start`).
        pc_port: the PC's UDP port.
        bind_host: the local address to send from (an ephemeral port).
    """

    def __init__(self, node: OpenControllerNode, pc_host: str, pc_port: int, *, bind_host: str = "0.0.0.0") -> None:
        self.node = node
        self.pc_host = pc_host
        self.pc_port = pc_port
        self.bind_host = bind_host
        self._pc: tuple[str, int] | None = None
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()
        self._lock = threading.Lock()
        self._sent = 0
        self._received = 0
        self._accepted = 0
        self._refused: Counter[str] = Counter()
        self._seq = 0
        self._newest_stamp_ns = -1
        self._start_mono_ns = time.monotonic_ns()

    @property
    def local_address(self) -> tuple[str, int]:
        """The (host, port) the face sends from (after :meth:`start`)."""
        if self._sock is None:
            raise RuntimeError("EgmFace.local_address before start()")
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    def start(self) -> None:
        """Resolve the PC's address, open the socket and start receiving.

        Raises:
            OSError: the PC's host does not resolve, or the socket cannot be bound.
        """
        self._pc = (socket.gethostbyname(self.pc_host), self.pc_port)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((self.bind_host, 0))
            sock.settimeout(RECEIVE_POLL_S)
        except OSError:
            sock.close()
            raise
        self._sock = sock
        self._start_mono_ns = time.monotonic_ns()
        self._thread = threading.Thread(target=self._receive_loop, name="egm-face", daemon=True)
        self._thread.start()

    def on_cycle(self, output: OpenControllerOutput) -> None:
        """Send this cycle's ``EgmRobot`` to the PC (a send error is counted, never raised: the loop goes on)."""
        if self._sock is None or self._pc is None:
            return
        tm_ms = (output.cycle_mono_ns - self._start_mono_ns) // 1_000_000
        data = encode_robot(robot_message(output, self._sent + 1, tm_ms))
        try:
            self._sock.sendto(data, self._pc)
        except OSError as exc:  # e.g. ECONNREFUSED from an earlier datagram to a closed port: EGM keeps sending
            with self._lock:
                self._refused["send_error"] += 1
            log.debug("EgmRobot not sent: %s", exc)
            return
        with self._lock:
            self._sent += 1

    def on_datagram(self, data: bytes, sender: tuple[str, int], now: Clocks) -> str | None:
        """Take one datagram received at ``now``: None if the node accepted its reference, else why not (counted)."""
        with self._lock:
            self._received += 1
        reason: str | None
        if self._pc is None or not sender_is_pc(sender, self._pc):
            reason = "foreign_sender"
        else:
            stamp_ns = max(now.wall_ns, self._newest_stamp_ns + 1)  # a wall-clock step back must not refuse the PC
            try:
                command = sensor_command(data, self.node.robot, self.node.limits.n_joints, self._seq, stamp_ns)
            except EgmError as exc:
                reason = exc.reason
            else:
                self._seq += 1
                reason = self.node.on_message(command, now)
                if reason is None:
                    self._newest_stamp_ns = stamp_ns
        with self._lock:
            if reason is None:
                self._accepted += 1
            else:
                self._refused[reason] += 1
        return reason

    def _receive_loop(self) -> None:
        sock = self._sock
        if sock is None:
            return
        while not self._closing.is_set():
            try:
                data, sender = sock.recvfrom(MAX_DATAGRAM_BYTES + 1)
            except TimeoutError:
                continue
            except OSError as exc:
                if self._closing.is_set():
                    return
                # ICMP port unreachable from an earlier send (the PC is not listening yet): keep receiving
                log.debug("EGM receive: %s", exc)
                continue
            try:
                reason = self.on_datagram(data, (str(sender[0]), int(sender[1])), read_clocks())
            except Exception:  # the receiver must never die: count it, the watchdog stops the robot
                log.exception("error while handling an EgmSensor")
                with self._lock:
                    self._refused["internal_error"] += 1
                continue
            if reason is not None:
                log.debug("EgmSensor refused: %s", reason)

    def progress(self) -> str:
        """For the emulator's progress line."""
        stats = self.stats()
        return f"egm_sent={stats.sent} egm_received={stats.received} egm_refused={dict(stats.refused)}"

    def stats(self) -> EgmFaceStats:
        """The current figures (safe to call from any thread)."""
        with self._lock:
            return EgmFaceStats(
                sent=self._sent,
                received=self._received,
                accepted=self._accepted,
                refused=MappingProxyType(dict(sorted(self._refused.items()))),
            )

    def close(self) -> None:
        """Stop receiving and close the socket (idempotent)."""
        self._closing.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> EgmFace:
        self.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
