"""ABB Robot Web Services 1.0 (IRC5) as a :class:`~hrc_devices.controllers.vendor.VendorInterface`: the speed ratio.

    rws = AbbRwsInterface("192.168.125.1")          # port 80, "Default User" / "robotics" as shipped
    rws.connect()                                   # the Digest handshake (one 401, then authenticated)
    rws.write_speed_fraction(0.499)                 # POST speed-ratio=49 → returns 0.49
    reading = rws.read(timeout_s=0.05)              # GET speed ratio, execution state, joint target
    rws.close()

Standard library only: one keep-alive :class:`http.client.HTTPConnection` and
:mod:`hrc_devices.controllers.abb_rws.http_digest`. The first request is answered 401 with a challenge; every later one
carries an Authorization for that nonce with the next nonce count, so a steady write costs one round trip and a steady
read three (speed ratio, execution state, joint target: RWS 1.0 has no resource holding all three). A stale or refused
nonce costs one more round trip; a second 401 in a row is an authentication failure. A keep-alive connection the
controller closed is reopened once.

What RWS 1.0 does not offer, the reading says so: no joint velocities (``qd_radps`` None: the bridge differentiates
``q``), no target velocities, no further scaling. The speed ratio is an integer percent: a fraction is written
rounded **down** (:func:`speed_ratio_pct`), so below 1 % it writes 0, and 0 % is how this interface stops the robot:
RAPID keeps running at speed ratio 0 and resumes where it was, without the protective or program stop a stop
request would cause (which the gateway could not undo).
"""

from __future__ import annotations

import http.client
import json
import math
import secrets
import threading
import time
from collections.abc import Callable
from typing import Any

from hrc_devices.controllers.abb_rws.http_digest import (
    Credentials,
    DigestChallenge,
    DigestError,
    authorization_header,
    parse_challenge,
)
from hrc_devices.controllers.vendor import ControllerReading, VendorError
from hrc_runtime.clocks import Clocks, read_clocks

MAX_RESPONSE_BYTES = 65536
"""A response body longer than this is malformed [bytes]."""

MAX_JOINT_DEG = 10_000.0
"""A joint position beyond ±this is malformed (an unused axis reads 9E+09) [deg]."""

_SPEEDRATIO = "/rw/panel/speedratio"
_SET_SPEEDRATIO = "/rw/panel/speedratio?action=setspeedratio&json=1"
_EXECUTION = "/rw/rapid/execution?json=1"


def speed_ratio_pct(fraction: float) -> int:
    """The speed ratio to write for a speed fraction: the largest integer percent p with p/100 <= ``fraction``.

    Rounds down, so the controller never runs faster than asked; a fraction below 0.01 writes 0; NaN or a negative
    fraction writes 0 (fail closed); a fraction above 1 writes 100.
    """
    if not fraction >= 0.0:  # NaN included
        return 0
    if fraction >= 1.0:
        return 100
    pct = math.floor(fraction * 100.0)
    # floor(0.29 * 100) is 28 in binary floating point; step up while the next percent is still <= fraction.
    while pct < 100 and (pct + 1) / 100.0 <= fraction:
        pct += 1
    while pct > 0 and pct / 100.0 > fraction:
        pct -= 1
    return pct


def parse_state(body: bytes, expected_type: str) -> dict[str, Any]:
    """The first ``_embedded._state`` entry of an RWS 1.0 JSON answer, checked to be of ``expected_type``.

    Raises:
        VendorError: ``malformed`` (not JSON, another shape or another ``_type``).
    """
    try:
        document = json.loads(body)
        state = document["_embedded"]["_state"][0]
    except (ValueError, KeyError, IndexError, TypeError):
        raise VendorError("malformed", f"not an RWS 1.0 {expected_type} answer: {body[:80]!r}") from None
    if not isinstance(state, dict) or state.get("_type") != expected_type:
        raise VendorError("malformed", f"_type {str(state)[:60]!r}; expected {expected_type}")
    return state


def parse_speed_ratio(body: bytes) -> int:
    """The speed ratio of a ``GET /rw/panel/speedratio`` answer [%], an integer in [0, 100].

    Raises:
        VendorError: ``malformed``.
    """
    text = parse_state(body, "pnl-speedratio").get("speedratio")
    if not (isinstance(text, str) and text.isascii() and text.isdigit() and len(text) <= 3 and int(text) <= 100):
        raise VendorError("malformed", f"speedratio {str(text)[:20]!r}; allowed: an integer 0..100")
    return int(text)


def parse_joint_target(body: bytes, n_joints: int) -> tuple[float, ...]:
    """The joint positions of a ``GET .../jointtarget`` answer [rad]: ``rax_1..rax_6`` then ``eax_a..`` [deg].

    Raises:
        VendorError: ``malformed`` (a field missing, not a number, not finite or beyond :data:`MAX_JOINT_DEG`).
    """
    state = parse_state(body, "ms-jointtarget")
    names = ([f"rax_{i}" for i in range(1, 7)] + [f"eax_{c}" for c in "abcdef"])[:n_joints]
    q_rad = []
    for name in names:
        text = state.get(name)
        try:
            q_deg = float(text)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise VendorError("malformed", f"{name} {str(text)[:20]!r} is not a number") from None
        if not abs(q_deg) <= MAX_JOINT_DEG:
            raise VendorError("malformed", f"{name} = {q_deg} deg; allowed: finite, within ±{MAX_JOINT_DEG} deg")
        q_rad.append(math.radians(q_deg))
    return tuple(q_rad)


def parse_execution_state(body: bytes) -> str:
    """``ctrlexecstate`` of a ``GET /rw/rapid/execution`` answer (``running`` or ``stopped``).

    Raises:
        VendorError: ``malformed``.
    """
    text = parse_state(body, "rap-execution").get("ctrlexecstate")
    if text not in ("running", "stopped"):
        raise VendorError("malformed", f"ctrlexecstate {str(text)[:20]!r}; allowed: running, stopped")
    return str(text)


def reading_of(ratio_pct: int, execution: str, q_rad: tuple[float, ...], now: Clocks) -> ControllerReading:
    """The bridge's reading of one poll: the speed ratio [%], the execution state and the joint target [rad], as
    parsed by :func:`parse_speed_ratio`, :func:`parse_execution_state` and :func:`parse_joint_target`, received at
    ``now``. RWS 1.0 offers no joint velocities, no target velocities and no further scaling: those are None."""
    return ControllerReading(
        received_wall_ns=now.wall_ns,
        received_mono_ns=now.mono_ns,
        q_rad=q_rad,
        qd_radps=None,
        target_qd_radps=None,
        speed_fraction=ratio_pct / 100.0,
        speed_scaling=None,
        running=execution == "running",
        state_text=f"ctrlexecstate={execution} speedratio={ratio_pct}",
    )


def _error_message(body: bytes) -> str:
    """The ``msg`` of an RWS error body, or the start of the body."""
    try:
        return str(json.loads(body)["_embedded"]["status"]["msg"])[:200]
    except (ValueError, KeyError, TypeError):
        return repr(body[:80])


class AbbRwsInterface:
    """The speed ratio and read-back of an IRC5 over RWS 1.0 (see the module docstring).

    Args:
        host: the controller's address (its WAN port, or the emulator's ``--rws`` address).
        port: the HTTP port.
        user: the Digest user name.
        password: the Digest password.
        mechunit: the mechanical unit to read.
        n_joints: the robot's joint count (``rax_1..`` then ``eax_a..``; at most 12).
        timeout_s: the connection, write and handshake timeout [s].
        clock: the bridge's clocks (the reading's stamps).
    """

    kind = "abb_rws"

    def __init__(
        self,
        host: str,
        port: int = 80,
        user: str = "Default User",
        password: str = "robotics",
        *,
        mechunit: str = "ROB_1",
        n_joints: int = 6,
        timeout_s: float = 1.0,
        clock: Callable[[], Clocks] = read_clocks,
    ) -> None:
        if not 1 <= n_joints <= 12:
            raise ValueError(f"n_joints = {n_joints}; allowed: 1..12 (rax_1..rax_6, eax_a..eax_f)")
        if not timeout_s > 0.0:
            raise ValueError(f"timeout_s = {timeout_s}; allowed: > 0 s")
        self.host = host
        self.port = port
        self.n_joints = n_joints
        self.timeout_s = timeout_s
        self._credentials = Credentials(user, password)
        self._jointtarget = f"/rw/motionsystem/mechunits/{mechunit}/jointtarget?json=1"
        self._clock = clock
        self._lock = threading.Lock()
        self._conn: http.client.HTTPConnection | None = None
        self._challenge: DigestChallenge | None = None
        self._nc = 0
        self.round_trips = 0
        """HTTP requests sent (each one round trip), 401s and retries included."""

    def connect(self) -> None:
        """Open the connection and authenticate (reads the speed ratio).

        Raises:
            VendorError: ``connect`` (unreachable), ``auth`` (credentials refused), ``timeout``, ``malformed``.
        """
        deadline_s = time.monotonic() + self.timeout_s
        status, body = self._request("GET", f"{_SPEEDRATIO}?json=1", None, deadline_s)
        self._expect(status, 200, body, "GET speedratio")
        parse_speed_ratio(body)

    def write_speed_fraction(self, fraction: float) -> float:
        """Write the speed ratio, rounded down to an integer percent; returns the fraction written (p / 100).

        Raises:
            VendorError: the write failed or was refused.
        """
        pct = speed_ratio_pct(fraction)
        deadline_s = time.monotonic() + self.timeout_s
        status, body = self._request("POST", _SET_SPEEDRATIO, f"speed-ratio={pct}".encode(), deadline_s)
        self._expect(status, 204, body, "POST setspeedratio")
        return pct / 100.0

    def read(self, timeout_s: float) -> ControllerReading:
        """Poll the speed ratio, the execution state and the joint target (three round trips).

        Raises:
            VendorError: timeout, a closed connection, a refusal or an invalid answer.
        """
        deadline_s = time.monotonic() + timeout_s
        status, body = self._request("GET", f"{_SPEEDRATIO}?json=1", None, deadline_s)
        self._expect(status, 200, body, "GET speedratio")
        ratio_pct = parse_speed_ratio(body)
        status, body = self._request("GET", _EXECUTION, None, deadline_s)
        self._expect(status, 200, body, "GET execution")
        execution = parse_execution_state(body)
        status, body = self._request("GET", self._jointtarget, None, deadline_s)
        now = self._clock()
        self._expect(status, 200, body, "GET jointtarget")
        return reading_of(ratio_pct, execution, parse_joint_target(body, self.n_joints), now)

    def close(self) -> None:
        """Close the connection (a later call reconnects)."""
        with self._lock:
            self._drop()

    def __enter__(self) -> AbbRwsInterface:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @staticmethod
    def _expect(status: int, expected: int, body: bytes, what: str) -> None:
        if status != expected:
            raise VendorError("refused", f"{what}: HTTP {status} (expected {expected}): {_error_message(body)}")

    def _drop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def _authorization(self, method: str, target: str) -> dict[str, str]:
        if self._challenge is None:
            return {}
        self._nc += 1
        header = authorization_header(
            self._challenge, self._credentials, method, target, self._nc, secrets.token_hex(8)
        )
        return {"Authorization": header}

    def _request(self, method: str, target: str, body: bytes | None, deadline_s: float) -> tuple[int, bytes]:
        """One request, authenticated; answers a 401 once with the new challenge and reopens a closed keep-alive
        connection once. Returns the status and the body."""
        with self._lock:
            retried_auth = retried_closed = False
            while True:
                status, headers, data = self._exchange(method, target, body, deadline_s, may_retry=not retried_closed)
                if status is None:  # the kept-alive connection had been closed by the controller
                    retried_closed = True
                    continue
                if status != 401:
                    return status, data
                if retried_auth:
                    raise VendorError("auth", f"{method} {target}: credentials refused: {_error_message(data)}")
                try:
                    self._challenge = parse_challenge(headers.get("WWW-Authenticate", ""))
                except DigestError as exc:
                    raise VendorError("auth", f"{method} {target}: unusable challenge: {exc}") from None
                self._nc = 0
                retried_auth = True

    def _exchange(
        self, method: str, target: str, body: bytes | None, deadline_s: float, *, may_retry: bool
    ) -> tuple[int | None, http.client.HTTPMessage, bytes]:
        """Send one request and read its answer; status None if a reused connection turned out closed."""
        remaining_s = deadline_s - time.monotonic()
        if remaining_s <= 0.0:
            raise VendorError("timeout", f"{method} {target}: no time left")
        reused = self._conn is not None
        if self._conn is None:
            self._conn = http.client.HTTPConnection(self.host, self.port, timeout=remaining_s)
        headers = {"Accept": "application/json", **self._authorization(method, target)}
        if body is not None:
            headers["Content-Type"] = "application/x-www-form-urlencoded"
        self.round_trips += 1
        try:
            response, data = _send(self._conn, method, target, body, headers, remaining_s)
        except (OSError, http.client.HTTPException) as exc:
            self._drop()
            if reused and may_retry and isinstance(exc, _CLOSED):
                return None, http.client.HTTPMessage(), b""
            raise _transport_error(exc, f"{method} {self.host}:{self.port}{target}", remaining_s) from None
        if len(data) > MAX_RESPONSE_BYTES:
            self._drop()
            raise VendorError("malformed", f"{method} {target}: answer over {MAX_RESPONSE_BYTES} bytes")
        if response.will_close:
            self._drop()
        return response.status, response.headers, data


_CLOSED = (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError)
"""What a kept-alive connection the controller has closed raises (the request is sent again, once)."""


def _send(
    conn: http.client.HTTPConnection,
    method: str,
    target: str,
    body: bytes | None,
    headers: dict[str, str],
    timeout_s: float,
) -> tuple[http.client.HTTPResponse, bytes]:
    """One request and its answer on ``conn``, waiting at most ``timeout_s`` for each socket operation [s]."""
    if conn.sock is not None:
        conn.sock.settimeout(timeout_s)
    else:
        conn.timeout = timeout_s
    conn.request(method, target, body=body, headers=headers)
    response = conn.getresponse()
    return response, response.read(MAX_RESPONSE_BYTES + 1)


def _transport_error(exc: BaseException, what: str, timeout_s: float) -> VendorError:
    """The :class:`VendorError` for a failed exchange."""
    if isinstance(exc, TimeoutError):
        return VendorError("timeout", f"{what}: no answer within {timeout_s:.3f} s")
    if isinstance(exc, ConnectionRefusedError):
        return VendorError("connect", f"{what}: {exc!r}")
    return VendorError("closed", f"{what}: {exc!r}")
