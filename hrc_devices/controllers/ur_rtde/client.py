"""The Universal Robots RTDE interface of the bridge: the speed slider out, the robot's state back (pure Python).

    interface = UrRtdeInterface("192.168.1.10", frequency_hz=125.0)
    interface.connect()                      # V (version 2), v, O (outputs at frequency_hz), I (slider), S
    interface.write_speed_fraction(0.4)      # U: speed_slider_mask 1, speed_slider_fraction 0.4
    reading = interface.read(timeout_s=0.1)  # the newest output package, checked
    interface.close()

The output recipe is :data:`OUTPUTS`; the input recipe ``speed_slider_mask, speed_slider_fraction``. The slider
is a double, so nothing is quantised: the value written is the value given. UR's slider has no floor (0.0 is
accepted and holds the robot at standstill with the program playing); which δ means stop is the bridge's policy.
The controller answers a slider another client holds with ``IN_USE``: :meth:`UrRtdeInterface.connect` then fails
with reason ``refused`` instead of sharing it.

Every value read is checked before it becomes a :class:`~hrc_devices.controllers.vendor.ControllerReading`: a package
of the wrong size, a non-finite number, a scaling outside [0, 1] or an unknown state code raises
:class:`~hrc_devices.controllers.vendor.VendorError` (``malformed``). ``running`` is true only while the program plays
(``runtime_state`` 2), the robot runs (``robot_mode`` 7) and safety is normal or reduced (``safety_mode`` 1, 2).
"""

from __future__ import annotations

import logging
import math
import select
import socket
import time
from collections.abc import Callable
from typing import TypeVar

from hrc_devices.controllers.ur_rtde import codec as rtde
from hrc_devices.controllers.ur_rtde.codec import MessageType, Recipe, RtdeError
from hrc_devices.controllers.vendor import ControllerReading, VendorError
from hrc_runtime.clocks import Clocks, read_clocks

log = logging.getLogger("hrc-bridge.ur_rtde")

_T = TypeVar("_T")

DEFAULT_PORT = 30004
OUTPUTS = (
    "timestamp",
    "actual_q",
    "actual_qd",
    "target_q",
    "target_qd",
    "speed_scaling",
    "target_speed_fraction",
    "runtime_state",
    "safety_mode",
    "robot_mode",
)
INPUTS = ("speed_slider_mask", "speed_slider_fraction")
MAX_FREQUENCY_HZ = 500.0
_RUNTIME_STATES = range(rtde.RUNTIME_STOPPING, rtde.RUNTIME_RESUMING + 1)
_SAFETY_MODES = range(1, 14)  # NORMAL … SYSTEM_THREE_POSITION_ENABLING_STOP (UR's safety_mode codes)
_ROBOT_MODES = range(-1, 10)  # NO_CONTROLLER … WAITING_CALIBRATION


def _finite_vector(name: str, value: object) -> tuple[float, ...]:
    if not isinstance(value, tuple) or len(value) != 6 or not all(math.isfinite(v) for v in value):
        raise VendorError("malformed", f"{name} = {value!r}; expected 6 finite numbers")
    return tuple(float(v) for v in value)


def _fraction(name: str, value: object) -> float:
    if not isinstance(value, float) or not 0.0 <= value <= 1.0:
        raise VendorError("malformed", f"{name} = {value!r}; allowed: a number in [0, 1]")
    return value


def _code(name: str, value: object, allowed: range) -> int:
    if not isinstance(value, int) or value not in allowed:
        raise VendorError("malformed", f"{name} = {value!r}; allowed: {allowed.start}..{allowed.stop - 1}")
    return value


def reading_from_values(values: dict[str, object], now: Clocks) -> ControllerReading:
    """Check one decoded output package and turn it into a reading.

    Args:
        values: the package's values by name (:data:`OUTPUTS`).
        now: the bridge's clocks when it arrived.

    Raises:
        VendorError: ``malformed`` for a missing, non-finite or out-of-range value.
    """
    timestamp_s = values["timestamp"]
    if not isinstance(timestamp_s, float) or not math.isfinite(timestamp_s) or timestamp_s < 0.0:
        raise VendorError("malformed", f"timestamp = {timestamp_s!r}; expected a finite time >= 0 s")
    runtime_state = _code("runtime_state", values["runtime_state"], _RUNTIME_STATES)
    safety_mode = _code("safety_mode", values["safety_mode"], _SAFETY_MODES)
    robot_mode = _code("robot_mode", values["robot_mode"], _ROBOT_MODES)
    _finite_vector("target_q", values["target_q"])
    running = (
        runtime_state == rtde.RUNTIME_PLAYING
        and robot_mode == rtde.ROBOT_MODE_RUNNING
        and safety_mode in (rtde.SAFETY_NORMAL, rtde.SAFETY_REDUCED)
    )
    return ControllerReading(
        received_wall_ns=now.wall_ns,
        received_mono_ns=now.mono_ns,
        q_rad=_finite_vector("actual_q", values["actual_q"]),
        qd_radps=_finite_vector("actual_qd", values["actual_qd"]),
        target_qd_radps=_finite_vector("target_qd", values["target_qd"]),
        speed_fraction=_fraction("target_speed_fraction", values["target_speed_fraction"]),
        speed_scaling=_fraction("speed_scaling", values["speed_scaling"]),
        running=running,
        state_text=f"runtime_state={runtime_state} safety_mode={safety_mode} robot_mode={robot_mode}",
        controller_time_s=timestamp_s,
    )


class UrRtdeInterface:
    """The speed slider of a UR controller over RTDE (see the module docstring).

    Args:
        host: the controller's address.
        port: 30004 on a real controller.
        frequency_hz: output frequency, in (0, 500] (125 Hz is a CB3's maximum, 500 Hz an e-Series').
        connect_timeout_s: how long each handshake step may take [s].
        clock: the clocks a reading is stamped with.

    Raises:
        ValueError: a frequency outside (0, 500] Hz.
    """

    kind = "ur_rtde"

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        frequency_hz: float = 125.0,
        connect_timeout_s: float = 2.0,
        clock: Callable[[], Clocks] = read_clocks,
    ) -> None:
        if not 0.0 < frequency_hz <= MAX_FREQUENCY_HZ:
            raise ValueError(f"frequency_hz = {frequency_hz}; allowed: (0, {MAX_FREQUENCY_HZ}] Hz")
        self.host = host
        self.port = port
        self.frequency_hz = frequency_hz
        self.connect_timeout_s = connect_timeout_s
        self._clock = clock
        self._sock: socket.socket | None = None
        self._buffer = bytearray()
        self._output: Recipe | None = None
        self._input: Recipe | None = None
        self.controller_version: tuple[int, int, int, int] | None = None

    # -- handshake ----------------------------------------------------------------------------------------------------

    def connect(self) -> None:
        """Connect and set up the recipes (protocol version 2).

        Raises:
            VendorError: ``connect`` (no connection), ``refused`` (version, recipe or start refused, or the slider
                ``IN_USE``), ``malformed`` (an answer that does not decode or has the wrong types), ``timeout``.
        """
        self.close()
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
        except OSError as exc:
            raise VendorError("connect", f"RTDE {self.host}:{self.port}: {exc}") from None
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._buffer.clear()
        try:
            self._handshake()
        except VendorError:
            self.close()
            raise

    def _handshake(self) -> None:
        reply = self._request(MessageType.REQUEST_PROTOCOL_VERSION, rtde.encode_version_request(rtde.PROTOCOL_VERSION))
        if not self._decode(rtde.decode_accepted, reply):
            raise VendorError("refused", f"RTDE {self.host}: protocol version {rtde.PROTOCOL_VERSION} refused")
        reply = self._request(MessageType.GET_URCONTROL_VERSION)
        self.controller_version = self._decode(rtde.decode_controller_version, reply)
        reply = self._request(
            MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS, rtde.encode_output_setup(self.frequency_hz, OUTPUTS)
        )
        self._output = self._recipe(reply, OUTPUTS, "output")
        reply = self._request(MessageType.CONTROL_PACKAGE_SETUP_INPUTS, rtde.encode_input_setup(INPUTS))
        self._input = self._recipe(reply, INPUTS, "input")
        reply = self._request(MessageType.CONTROL_PACKAGE_START)
        if not self._decode(rtde.decode_accepted, reply):
            raise VendorError("refused", f"RTDE {self.host}: start refused")
        log.info(
            "RTDE %s: controller %s, outputs at %.0f Hz, slider recipe %d",
            self.host,
            ".".join(map(str, self.controller_version)),
            self.frequency_hz,
            self._input.recipe_id,
        )

    def _recipe(self, payload: bytes, names: tuple[str, ...], what: str) -> Recipe:
        recipe_id, types = self._decode(rtde.decode_setup_reply, payload)
        if rtde.IN_USE in types or rtde.NOT_FOUND in types or recipe_id == 0:
            refused = [f"{n}={t}" for n, t in zip(names, types, strict=False) if t in (rtde.IN_USE, rtde.NOT_FOUND)]
            detail = ", ".join(refused) or "no variable refused"
            raise VendorError("refused", f"RTDE {self.host}: {what} setup refused (recipe {recipe_id}; {detail})")
        expected = tuple(rtde.OUTPUT_TYPES[n] if what == "output" else rtde.SLIDER_INPUT_TYPES[n] for n in names)
        if types != expected:
            raise VendorError("malformed", f"RTDE {self.host}: {what} types {types}; expected {expected}")
        return Recipe(recipe_id, names, types)

    @staticmethod
    def _decode(decoder: Callable[[bytes], _T], payload: bytes) -> _T:
        try:
            return decoder(payload)
        except RtdeError as exc:
            raise VendorError("malformed", str(exc)) from None

    def _request(self, message_type: MessageType, payload: bytes = b"") -> bytes:
        """Send one request and return the payload of its reply (other messages before it are skipped)."""
        self._send(rtde.pack_message(message_type, payload))
        deadline_s = time.monotonic() + self.connect_timeout_s
        while True:
            message = self._next_message(deadline_s, f"reply to {message_type.name}")
            if message.type_code == message_type:
                return message.payload

    # -- the vendor interface ---------------------------------------------------------------------------------------

    def write_speed_fraction(self, fraction: float) -> float:
        """Write the slider: mask 1, ``fraction`` in [0, 1]. Returns ``fraction`` (a double is not quantised).

        Raises:
            ValueError: ``fraction`` non-finite or outside [0, 1] (a programming error in the caller).
            VendorError: ``closed`` if not connected or the send fails.
        """
        if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
            raise ValueError(f"speed fraction {fraction}; allowed: [0, 1]")
        if self._input is None:
            raise VendorError("closed", f"RTDE {self.host}: not connected")
        payload = rtde.encode_data(self._input, (1, float(fraction)))
        self._send(rtde.pack_message(MessageType.DATA_PACKAGE, payload))
        return fraction

    def read(self, timeout_s: float) -> ControllerReading:
        """The newest output package, waiting at most ``timeout_s`` for one; older buffered packages are skipped.

        Raises:
            VendorError: ``timeout``, ``closed``, ``malformed`` or ``refused`` (the controller's error message).
        """
        recipe = self._output
        if recipe is None:
            raise VendorError("closed", f"RTDE {self.host}: not connected")
        deadline_s = time.monotonic() + timeout_s
        newest: bytes | None = None
        while newest is None or self._has_whole_message():
            message = self._next_message(deadline_s, "output package")
            if message.type_code == MessageType.DATA_PACKAGE:
                newest = message.payload
        now = self._clock()
        values = self._decode(lambda payload: rtde.decode_data(recipe, payload), newest)
        return reading_from_values(dict(zip(OUTPUTS, values, strict=True)), now)

    def close(self) -> None:
        """Close the connection (the controller releases the slider)."""
        if self._sock is not None:
            self._sock.close()
        self._sock = None
        self._output = self._input = None

    # -- bytes --------------------------------------------------------------------------------------------------------

    def _send(self, data: bytes) -> None:
        if self._sock is None:
            raise VendorError("closed", f"RTDE {self.host}: not connected")
        try:
            self._sock.sendall(data)
        except OSError as exc:
            self.close()
            raise VendorError("closed", f"RTDE {self.host}: send failed: {exc}") from None

    def _has_whole_message(self) -> bool:
        if len(self._buffer) < rtde.HEADER_SIZE:
            self._fill(0.0)
        return len(self._buffer) >= rtde.HEADER_SIZE and len(self._buffer) >= int.from_bytes(self._buffer[:2], "big")

    def _next_message(self, deadline_s: float, what: str) -> rtde.Message:
        """The next whole message; text messages are logged, an error one raises ``refused``."""
        while True:
            try:
                messages = rtde.take_messages(self._buffer, rtde.MAX_MESSAGE_BYTES)
            except RtdeError as exc:
                self.close()
                raise VendorError("malformed", f"RTDE {self.host}: {exc}") from None
            if messages:
                message = messages[0]
                # Put the rest back in front: take_messages consumed them.
                self._buffer[:0] = b"".join(rtde.pack_message(m.type_code, m.payload) for m in messages[1:])
                if message.type_code != MessageType.TEXT_MESSAGE:
                    return message
                self._on_text(message.payload)
                continue
            remaining_s = deadline_s - time.monotonic()
            if remaining_s <= 0.0:
                raise VendorError("timeout", f"RTDE {self.host}: no {what} within the timeout")
            self._fill(remaining_s)

    def _on_text(self, payload: bytes) -> None:
        text, source, level = self._decode(rtde.decode_text, payload)
        if level in (rtde.TextLevel.EXCEPTION, rtde.TextLevel.ERROR):
            raise VendorError("refused", f"RTDE {self.host} ({source}): {text}")
        log.warning("RTDE %s (%s): %s", self.host, source, text)

    def _fill(self, timeout_s: float) -> None:
        """Read what has arrived, waiting at most ``timeout_s``."""
        if self._sock is None:
            raise VendorError("closed", f"RTDE {self.host}: not connected")
        readable, _, _ = select.select([self._sock], [], [], max(timeout_s, 0.0))
        if not readable:
            return
        try:
            data = self._sock.recv(65536)
        except OSError as exc:
            self.close()
            raise VendorError("closed", f"RTDE {self.host}: {exc}") from None
        if not data:
            self.close()
            raise VendorError("closed", f"RTDE {self.host}: the controller closed the connection")
        self._buffer += data
