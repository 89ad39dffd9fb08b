"""The emulated controller's Universal Robots RTDE face: the speed slider in, the robot's state out, on TCP 30004.

    face = RtdeFace(node, "127.0.0.2", model=robot_model)   # port 30004, fixed like the real controller's
    face.start()                             # binds; raises ConfigError naming the address
    face.on_cycle(output)                    # the emulator's loop, every cycle: stores the latest state
    face.close()

What a client sees is what an e-Series controller (software 5.11, :data:`CONTROLLER_VERSION`) shows its RTDE
clients: protocol version 2 only; every output variable of UR's RTDE guide that this software has
(:func:`hrc_devices.controllers.ur_rtde.codec.output_type`; their values: :mod:`controller_emu.rtde_outputs`, from the
controller's cycle and the robot's model where the emulator has one, stated constants where it has none), so
ur-rtde's receive interface works with its default recipe; output setups at 0 < f <= 500 Hz (a frequency outside that
gets recipe id 0 and the start is refused); names the controller does not have are answered ``NOT_FOUND`` in the type
list, as the real controller does (ur-rtde then raises naming them); input recipes numbered 1, 2, 3… per connection
in arrival order (ur-rtde's IO interface sets up 16 and writes the slider with id 4). Inputs: a writable input set up
by one connection is ``IN_USE`` for every other connection until the first one disconnects (UR's RTDE guide: an input
controlled by another client or a fieldbus is ``IN_USE``; ur-rtde raises on it), so a second client cannot take the
slider from the bridge. Of the inputs, **only the speed slider has an effect**: registers are accepted and read back
in the outputs (``input_int_register_23`` and the like; no program reads them), and a write that drives a digital or
analog output (a non-zero mask) is ignored and counted as ``io_ignored``: the emulator has no I/O. They are set up
rather than answered ``IN_USE`` because ur-rtde's IO interface raises on any ``IN_USE`` and would never reach its
slider recipe.

A slider write (``speed_slider_mask`` 1, ``speed_slider_fraction`` in [0, 1]) becomes an override of the node,
stamped with the emulator's wall clock (``seq`` counts per face). The node's watchdog then stops the robot when
slider writes stop arriving for ``watchdog_s``: this emulates URScript
``rtde_set_watchdog("speed_slider_fraction", min_frequency, "pause")``, which the robot's program must call on a
real robot (the README says so). A non-finite or out-of-range fraction is not applied (counted ``slider_value``):
the robot keeps its last value until the watchdog stops it, never a value the client did not mean.

Outputs, at each output period, of the latest controller cycle (:meth:`RtdeFace.on_cycle`) that this client has not
had yet: every package is one cycle's data stamped with that cycle's time, as on the real controller, whose
packages each carry one control cycle. The emulator's cycle is its own (``cycle_s``, 4 ms by default): at 500 Hz an
output tick without a new cycle sends nothing, so a client gets one package per cycle; a cycle that came late is
stamped late, never with the tick's time (a package stamped with its tick but carrying an older cycle made a joint
look as if it moved a late cycle's distance in one period: the gateway's ``q_jump``).

- ``target_speed_fraction``: the slider value in force at that cycle: a write is in the first package of the first
  cycle after it (``setSpeedSlider(x)`` → ``getTargetSpeedFraction()`` on the real controller), never in the data
  of a cycle before it;
- ``speed_scaling``: while the program plays, the controller's ramp toward a raised slider: ``applied δ / slider``
  while the applied override is still below the slider (accelerating), else 1.0; 0.0 while the watchdog holds it
  stopped. So ``speed_scaling × target_speed_fraction`` (what drivers, and ur-rtde's ``getSpeedScalingCombined``,
  take as the effective override) is the applied override while it rises and 0 whenever the robot is held (the
  slider still shows its last value then). After the slider drops, the applied override falls over the braking
  time while the combined value already shows the new slider (a scaling is at most 1): the bridge covers that
  with its braking envelope (``controller_bridge/bridge.py``);
- ``target_qd`` = applied δ × programmed velocity, and ``actual_qd`` the same (the emulated drive follows exactly);
- ``actual_q``/``target_q``: the program's q; ``timestamp``: the cycle's controller time [s] since the face was
  made (its monotonic clock; cycles 4 ms apart on time, more after a late one; at 125 Hz every other cycle);
- ``runtime_state`` 2 playing; in the watchdog's stop 3 pausing while δ still falls, then 4 paused;
  ``safety_mode`` 1 normal, 3 protective stop (the emulator's ``protective_stop``); ``robot_mode`` 7 running;
  ``robot_status_bits`` power on (+ program running); ``safety_status_bits`` normal or protective stopped;
- every other output as :data:`controller_emu.rtde_outputs.OUTPUTS` says (TCP, elbow, momentum and torques from the
  robot's model, constants where the emulator has no model). A cycle's values are computed once, in the serving
  thread (the model's only if a recipe asks for one), and each recipe's package is one struct pre-compiled at setup.

Hostile clients get a text message (``M``, level error) naming what was wrong and are disconnected: a size field
below 3 or above 4096 bytes, an unknown type, a payload that does not decode, a command before the protocol
version is agreed, a data package for a recipe they did not set up. A ``V`` asking for another version than 2 is
answered "refused" and the connection stays, as the protocol means. Every error is counted by reason
(:meth:`RtdeFace.stats`); the server keeps serving the other clients.

One thread serves every connection with a selector: before each output tick it reads every socket that has data,
so a slider write that has arrived is in the node before its next cycle.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import selectors
import socket
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import NamedTuple

from controller_emu.node import PENDING_KEPT, ControllerNode, ControllerOutput
from controller_emu.rtde_outputs import ArmModel, DataPacker, Flat, is_read_back, snapshot
from hrc_contract.config import ConfigError
from hrc_contract.messages import Override, to_payload
from hrc_devices.controllers.ur_rtde import codec as rtde
from hrc_devices.controllers.ur_rtde.codec import MessageType, Recipe, RtdeError
from hrc_devices.robots.model import RobotModel
from hrc_runtime.clocks import Clocks, read_clocks

log = logging.getLogger("hrc-controller-emu.rtde")

DEFAULT_PORT = 30004
CONTROL_PERIOD_S = 0.002
"""The real-time control period of an e-Series controller [s]: outputs are sent on its ticks."""
MAX_FREQUENCY_HZ = 500.0
CONTROLLER_VERSION = rtde.OUTPUT_TYPES_VERSION
"""What ``v`` answers: an e-Series controller (5.11), so ur-rtde's receive interface defaults to 500 Hz and asks
for the outputs that software has (ur-rtde picks its default recipe by version)."""
MAX_CLIENTS = 8
MAX_QUEUED_BYTES = 65536
"""A client whose unsent bytes exceed this is too slow to serve and is disconnected [bytes]."""
TEXT_SOURCE = "hrc-controller-emu"
N_JOINTS = 6


@dataclass(frozen=True)
class RtdeFaceStats:
    """The face's figures.

    Attributes:
        clients: connections open now.
        connections: connections accepted since the start.
        slider_writes: slider writes applied (each an override of the node).
        packages_sent: data packages sent, all clients.
        packages_skipped: packages not sent because the client had not taken the previous one yet.
        errors: refused inputs and protocol errors, by reason, sorted.
    """

    clients: int
    connections: int
    slider_writes: int
    packages_sent: int
    packages_skipped: int
    errors: Mapping[str, int]


class _ProtocolError(Exception):
    """Ends one connection: ``reason`` is counted, ``message`` is sent to the client."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason
        self.message = message


class _Cycle(NamedTuple):
    """One controller cycle as the outputs show it."""

    output: ControllerOutput
    previous: ControllerOutput | None  # the cycle before (target_qdd)
    slider_fraction: float  # in force at the cycle
    controller_time_s: float  # the cycle's time since the face was made


@dataclass
class _Client:
    sock: socket.socket
    peer: str
    inbuf: bytearray = field(default_factory=bytearray)
    outbuf: bytearray = field(default_factory=bytearray)
    negotiated: bool = False
    output: DataPacker | None = None
    output_ok: bool = False
    divisor: int = 1
    started: bool = False
    next_tick: int = 0
    wants_write: bool = False
    inputs: dict[int, Recipe] = field(default_factory=dict)
    next_input_id: int = 1
    owned: set[str] = field(default_factory=set)
    closing: bool = False
    last_cycle: _Cycle | None = None  # the cycle its last package carried


class RtdeFace:
    """The RTDE server of one emulated robot (see the module docstring).

    Args:
        node: the controller; slider writes go to its ``on_override``.
        host: the address to listen on (each emulated robot its own: 127.0.0.2, …).
        port: 30004 on a real controller.
        model: the robot's model (the TCP, elbow, momentum and torque outputs: :class:`ArmModel`).
        paced: send outputs on the 2 ms control ticks of the monotonic clock; False sends them only on
            :meth:`tick` (for tests that count packages without reading a clock).
        clock: the clocks a slider write is stamped and timed with.

    Raises:
        ConfigError: the robot has not 6 joints (RTDE's joint vectors are VECTOR6D), or its URDF lacks UR's frames.
    """

    def __init__(
        self,
        node: ControllerNode,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        model: RobotModel,
        paced: bool = True,
        clock: Callable[[], Clocks] = read_clocks,
    ) -> None:
        if node.trajectory.n_joints != N_JOINTS or model.n_joints != N_JOINTS:
            raise ConfigError(
                f"robot {node.robot!r} has {node.trajectory.n_joints} joints; the RTDE face serves {N_JOINTS}"
            )
        self._arm = ArmModel(model)
        self.node = node
        self.host = host
        self.port = port
        self._paced = paced
        self._clock = clock
        self._latest: _Cycle | None = None
        self._t0_mono_ns = clock().mono_ns  # controller time 0
        # accepted slider writes no cycle has taken yet: (mono ns, value), as many as the node keeps of its overrides
        self._writes: deque[tuple[int, float]] = deque(maxlen=PENDING_KEPT)
        self._slider_fraction = 0.0  # in force at the latest cycle
        self._override_seq = 0
        self._last_stamp_ns = -1
        self._inputs: dict[str, Flat] = {}  # registers written, read back in the outputs (the serving thread's)
        self._snapshot: tuple[_Cycle, bool, dict[str, Flat]] | None = None  # cycle, with the model's values, values
        self._owners: dict[str, _Client] = {}
        self._clients: dict[socket.socket, _Client] = {}
        self._errors: Counter[str] = Counter()
        self._connections = 0
        self._slider_writes = 0
        self._sent = 0
        self._skipped = 0
        self._tick = 0
        self._ticks_requested = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._selector = selectors.DefaultSelector()
        self._server: socket.socket | None = None
        self._wake_r, self._wake_w = socket.socketpair()
        self._thread: threading.Thread | None = None

    # -- the emulator's side --------------------------------------------------------------------------------------

    def start(self) -> None:
        """Listen on (host, port) and serve in a thread.

        Raises:
            ConfigError: the address cannot be listened on (in use, not local).
        """
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            server.bind((self.host, self.port))
        except OSError as exc:
            server.close()
            raise ConfigError(f"RTDE face cannot listen on {self.host}:{self.port}: {exc.strerror}") from None
        server.listen(MAX_CLIENTS)
        server.setblocking(False)
        self._server = server
        self._selector.register(server, selectors.EVENT_READ, "accept")
        self._wake_r.setblocking(False)
        self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._thread = threading.Thread(target=self._serve, name=f"rtde-{self.host}", daemon=True)
        self._thread.start()
        log.info("RTDE face of %s on %s:%d", self.node.robot, self.host, self.port)

    def on_cycle(self, output: ControllerOutput) -> None:
        """Store the latest controller cycle, with the slider in force at its time (the emulator's loop, every
        cycle; waits only for the face's short critical sections)."""
        with self._lock:
            while self._writes and self._writes[0][0] <= output.cycle_mono_ns:
                self._slider_fraction = self._writes.popleft()[1]
            previous = None if self._latest is None else self._latest.output
            controller_time_s = (output.cycle_mono_ns - self._t0_mono_ns) / 1e9
            self._latest = _Cycle(output, previous, self._slider_fraction, controller_time_s)

    def tick(self, count: int = 1) -> None:
        """Send ``count`` control ticks of outputs now (only for ``paced=False``)."""
        with self._lock:
            self._ticks_requested += count
        self._wake()

    def progress(self) -> str:
        """For the emulator's progress line: nothing (the closed controller's line says what its overrides did)."""
        return ""

    def stats(self) -> RtdeFaceStats:
        """The current figures (any thread)."""
        with self._lock:
            return RtdeFaceStats(
                clients=len(self._clients),
                connections=self._connections,
                slider_writes=self._slider_writes,
                packages_sent=self._sent,
                packages_skipped=self._skipped,
                errors=MappingProxyType(dict(sorted(self._errors.items()))),
            )

    def close(self) -> None:
        """Stop serving and close every connection."""
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for client in list(self._clients.values()):
            self._drop(client, None)
        if self._server is not None:
            self._server.close()
        self._selector.close()
        self._wake_r.close()
        self._wake_w.close()

    def __enter__(self) -> RtdeFace:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the loop ----------------------------------------------------------------------------------------------------

    def _wake(self) -> None:
        # Closed, or its buffer is full of earlier wake-ups: either way the loop will look.
        with contextlib.suppress(OSError):
            self._wake_w.send(b"\0")

    def _serve(self) -> None:
        t0_s = time.monotonic()
        while not self._stop.is_set():
            timeout = None
            if self._paced:
                timeout = max(0.0, t0_s + (self._tick + 1) * CONTROL_PERIOD_S - time.monotonic())
            try:
                events = self._selector.select(timeout)
            except OSError:
                if self._stop.is_set():
                    return
                raise
            for key, mask in events:
                self._on_event(key, mask)
            if self._paced:
                tick = math.floor((time.monotonic() - t0_s) / CONTROL_PERIOD_S)
                if tick > self._tick:
                    self._send_outputs(tick)
            else:
                with self._lock:
                    requested, self._ticks_requested = self._ticks_requested, 0
                for _ in range(requested):
                    self._send_outputs(self._tick + 1)

    def _on_event(self, key: selectors.SelectorKey, mask: int) -> None:
        if key.data == "accept":
            self._accept()
        elif key.data == "wake":
            with contextlib.suppress(OSError):
                self._wake_r.recv(4096)
        else:
            client = self._clients.get(key.fileobj)  # type: ignore[call-overload]
            if client is None:
                return
            if mask & selectors.EVENT_READ:
                self._read(client)
            if mask & selectors.EVENT_WRITE and not client.closing:
                self._flush(client)

    def _accept(self) -> None:
        if self._server is None:
            return
        try:
            sock, address = self._server.accept()
        except OSError:
            return
        if len(self._clients) >= MAX_CLIENTS:
            self._count("too_many_clients")
            sock.close()
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = _Client(sock=sock, peer=f"{address[0]}:{address[1]}")
        self._clients[sock] = client
        self._selector.register(sock, selectors.EVENT_READ, "client")
        with self._lock:
            self._connections += 1
        log.info("RTDE client %s connected", client.peer)

    def _read(self, client: _Client) -> None:
        try:
            data = client.sock.recv(65536)
        except BlockingIOError:
            return
        except OSError as exc:
            self._drop(client, f"connection error: {exc.strerror}")
            return
        if not data:
            self._drop(client, "closed by the client")
            return
        client.inbuf += data
        try:
            for message in rtde.take_messages(client.inbuf):
                self._handle(client, message)
                if client.closing:
                    return
        except (RtdeError, _ProtocolError) as exc:
            self._refuse(client, exc.reason, str(exc) if isinstance(exc, RtdeError) else exc.message)

    def _refuse(self, client: _Client, reason: str, message: str) -> None:
        """Count a protocol error, tell the client what was wrong and disconnect it."""
        self._count(reason)
        log.warning("RTDE client %s: %s; disconnecting", client.peer, message)
        text = rtde.encode_text(message, TEXT_SOURCE, rtde.TextLevel.ERROR)
        client.outbuf += rtde.pack_message(MessageType.TEXT_MESSAGE, text)  # after any whole message queued
        with contextlib.suppress(OSError):
            client.sock.send(client.outbuf)
        self._drop(client, None)

    def _drop(self, client: _Client, why: str | None) -> None:
        if client.closing:
            return
        client.closing = True
        for name in client.owned:
            if self._owners.get(name) is client:
                del self._owners[name]
        self._clients.pop(client.sock, None)
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(client.sock)
        client.sock.close()
        if why is not None:
            log.info("RTDE client %s: %s", client.peer, why)

    def _count(self, reason: str) -> None:
        with self._lock:
            self._errors[reason] += 1

    # -- the protocol ------------------------------------------------------------------------------------------------

    def _reply(self, client: _Client, message_type: MessageType, payload: bytes) -> None:
        self._queue(client, rtde.pack_message(message_type, payload))

    def _handle(self, client: _Client, message: rtde.Message) -> None:
        code = message.type_code
        if code not in MessageType._value2member_map_:
            raise _ProtocolError("unknown_type", f"unknown message type {code}; allowed: V v O I S P U M")
        kind = MessageType(code)
        if kind is MessageType.REQUEST_PROTOCOL_VERSION:
            version = rtde.decode_version_request(message.payload)
            client.negotiated = version == rtde.PROTOCOL_VERSION
            if not client.negotiated:
                self._count("bad_version")
            self._reply(client, kind, rtde.encode_accepted(client.negotiated))
            return
        if not client.negotiated:
            raise _ProtocolError("not_negotiated", f"message {kind.name} before protocol version 2 was agreed")
        if kind is MessageType.GET_URCONTROL_VERSION:
            self._reply(client, kind, rtde.encode_controller_version(*CONTROLLER_VERSION))
        elif kind is MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS:
            self._setup_outputs(client, message.payload)
        elif kind is MessageType.CONTROL_PACKAGE_SETUP_INPUTS:
            self._setup_inputs(client, message.payload)
        elif kind in (MessageType.CONTROL_PACKAGE_START, MessageType.CONTROL_PACKAGE_PAUSE):
            self._start_or_pause(client, kind)
        elif kind is MessageType.DATA_PACKAGE:
            self._on_data(client, message.payload)
        else:  # a client's text message: log it, nothing to answer
            text, source, _level = rtde.decode_text(message.payload)
            log.info("RTDE client %s says (%s): %s", client.peer, source, text)

    def _start_or_pause(self, client: _Client, kind: MessageType) -> None:
        if kind is MessageType.CONTROL_PACKAGE_PAUSE:
            client.started = False
            self._reply(client, kind, rtde.encode_accepted(True))
            return
        client.started = client.output_ok
        client.next_tick = self._tick + 1
        if not client.started:
            self._count("start_without_outputs")
        self._reply(client, kind, rtde.encode_accepted(client.started))

    def _setup_outputs(self, client: _Client, payload: bytes) -> None:
        frequency_hz, names = rtde.decode_output_setup(payload)
        types = tuple(rtde.output_type(name) or rtde.NOT_FOUND for name in names)
        valid = 0.0 < frequency_hz <= MAX_FREQUENCY_HZ and rtde.NOT_FOUND not in types and not client.started
        if not valid:
            self._count("output_setup_refused")
            log.warning(
                "RTDE client %s: output setup refused (%.1f Hz; allowed 0-%.0f Hz; not found: %s)",
                client.peer,
                frequency_hz,
                MAX_FREQUENCY_HZ,
                [n for n, t in zip(names, types, strict=True) if t == rtde.NOT_FOUND] or "none",
            )
            client.output, client.output_ok = None, False
            self._reply(client, MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS, rtde.encode_setup_reply(0, types))
            return
        client.output = DataPacker(Recipe(1, names, types))
        client.output_ok = True
        client.divisor = max(1, round(1.0 / (frequency_hz * CONTROL_PERIOD_S)))
        self._reply(client, MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS, rtde.encode_setup_reply(1, types))

    def _setup_inputs(self, client: _Client, payload: bytes) -> None:
        names = rtde.decode_input_setup(payload)
        types: list[str] = []
        for name in names:
            kind = rtde.input_type(name)
            owner = self._owners.get(name)
            if kind is None:
                types.append(rtde.NOT_FOUND)
            elif owner is not None and owner is not client:
                types.append(rtde.IN_USE)
            else:
                types.append(kind)
        recipe_id = client.next_input_id
        client.next_input_id += 1  # numbered in arrival order, failed setups included (ur-rtde counts them)
        if recipe_id > 255 or rtde.NOT_FOUND in types or rtde.IN_USE in types:
            self._count("input_setup_refused")
            self._reply(client, MessageType.CONTROL_PACKAGE_SETUP_INPUTS, rtde.encode_setup_reply(0, types))
            return
        for name in names:
            self._owners[name] = client
            client.owned.add(name)
        client.inputs[recipe_id] = Recipe(recipe_id, names, tuple(types))
        self._reply(client, MessageType.CONTROL_PACKAGE_SETUP_INPUTS, rtde.encode_setup_reply(recipe_id, types))

    def _on_data(self, client: _Client, payload: bytes) -> None:
        recipe_id = rtde.data_recipe_id(payload)
        recipe = client.inputs.get(recipe_id)
        if recipe is None:
            raise _ProtocolError(
                "unknown_recipe", f"data package for input recipe {recipe_id}; set up: {sorted(client.inputs)}"
            )
        values = dict(zip(recipe.names, rtde.decode_data(recipe, payload), strict=True))
        for name, value in values.items():
            if is_read_back(name):  # a register: the outputs show its last value, as the controller's do
                self._inputs[name] = (value,)  # type: ignore[assignment]
        if any(name.endswith("_mask") and name != "speed_slider_mask" and values[name] for name in values):
            self._count("io_ignored")
        mask = values.get("speed_slider_mask")
        fraction = values.get("speed_slider_fraction")
        if mask is None or fraction is None or mask == 0:
            return
        if mask != 1 or not isinstance(fraction, float) or not 0.0 <= fraction <= 1.0:
            self._count("slider_value")
            log.warning("RTDE client %s: slider mask %r fraction %r refused", client.peer, mask, fraction)
            return
        self._apply_slider(fraction)

    def _apply_slider(self, fraction: float) -> None:
        """The slider write as an override of the node (stamp strictly increasing, seq per face)."""
        now = self._clock()
        stamp_ns = max(now.wall_ns, self._last_stamp_ns + 1)
        message = Override(robot=self.node.robot, seq=self._override_seq, stamp_ns=stamp_ns, delta=fraction)
        reason = self.node.on_override(to_payload(message), now)
        if reason is not None:
            self._count(f"override_{reason}")
            return
        self._override_seq += 1
        self._last_stamp_ns = stamp_ns
        with self._lock:
            self._writes.append((now.mono_ns, fraction))  # the node applies it at its first cycle at or after now
            self._slider_writes += 1

    # -- outputs -------------------------------------------------------------------------------------------------------

    def _send_outputs(self, tick: int) -> None:
        self._tick = tick
        with self._lock:
            latest = self._latest
        if latest is None:
            return
        due: list[tuple[_Client, DataPacker]] = []
        skipped = 0
        for client in list(self._clients.values()):
            packer = client.output
            if not client.started or packer is None or tick < client.next_tick:
                continue
            if client.last_cycle is latest:
                continue  # no new cycle since its last package: the next tick sends it
            # The next package is due a whole number of periods later (ticks missed while late are skipped).
            client.next_tick += ((tick - client.next_tick) // client.divisor + 1) * client.divisor
            if client.outbuf:  # the last package is still queued: skip, as the real controller does
                skipped += 1
                continue
            due.append((client, packer))
        with self._lock:  # counted before they are sent, so a client that has its package sees it counted
            self._sent += len(due)
            self._skipped += skipped
        if due:
            values = self._values(latest, any(packer.needs_model for _, packer in due))
            for client, packer in due:
                self._queue(client, packer.pack(values))
                client.last_cycle = latest

    def _values(self, cycle: _Cycle, with_model: bool) -> dict[str, Flat]:
        """Every output's value in ``cycle``: computed once per cycle (with the model's if asked), then reused."""
        cached = self._snapshot
        if cached is not None and cached[0] is cycle and (cached[1] or not with_model):
            return cached[2]
        arm = self._arm if with_model else None
        values = snapshot(
            cycle.output, cycle.previous, cycle.slider_fraction, cycle.controller_time_s, self._inputs, arm
        )
        self._snapshot = (cycle, with_model, values)
        return values

    def _queue(self, client: _Client, data: bytes) -> None:
        if client.closing:
            return
        client.outbuf += data
        if len(client.outbuf) > MAX_QUEUED_BYTES:
            self._count("slow_client")
            self._drop(client, f"{len(client.outbuf)} bytes unsent: too slow, disconnected")
            return
        self._flush(client)

    def _flush(self, client: _Client) -> None:
        try:
            sent = client.sock.send(client.outbuf)
        except BlockingIOError:
            sent = 0
        except OSError as exc:
            if exc.errno not in (errno.EPIPE, errno.ECONNRESET):
                log.warning("RTDE client %s: send failed: %s", client.peer, exc)
            self._drop(client, "connection lost")
            return
        del client.outbuf[:sent]
        wants_write = bool(client.outbuf)
        if wants_write != client.wants_write:
            client.wants_write = wants_write
            events = selectors.EVENT_READ | (selectors.EVENT_WRITE if wants_write else 0)
            self._selector.modify(client.sock, events, "client")
