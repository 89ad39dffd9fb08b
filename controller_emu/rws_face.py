"""The emulated controller's ABB Robot Web Services face (RWS 1.0, as an IRC5 serves it), for the ABB bridge.

    face = RwsFace(node, "127.0.0.3", 8080)   # user "Default User", password "robotics", as shipped
    face.start()                             # a threaded HTTP server; face.port is the bound port
    face.on_cycle(output)                    # every emulator cycle: stores the newest state (non-blocking)
    face.close()

Resources (JSON only: ``json=1`` is required on GETs; the XML a real controller serves by default is not):

    POST /rw/panel/speedratio?action=setspeedratio   form ``speed-ratio=<0..100 integer>``  → 204
    GET  /rw/panel/speedratio?json=1                 ``pnl-speedratio``: the ratio last written [%]
    GET  /rw/motionsystem/mechunits/ROB_1/jointtarget?json=1   ``ms-jointtarget``: rax_1..rax_6 [deg]
    GET  /rw/rapid/execution?json=1                  ``rap-execution``: ctrlexecstate running / stopped
    GET  /rw/panel/ctrlstate?json=1                  ``pnl-ctrlstate``: motoron / guardstop
    GET  /logout                                     204 (abb-robot-client's ``close``)

Anything else is 404, a bad form 400, both with the RWS 1.0 error body ``{"_embedded": {"status": {"code", "msg"}}}``
(the codes are this emulator's own, not ABB's). Every request needs HTTP Digest (MD5, ``qop=auth``,
:mod:`hrc_devices.controllers.abb_rws.http_digest`), else 401 with a challenge; after a success the ``-http-session-``
and ``ABBCX`` cookies are issued as a real controller does, but they are not accepted instead of Digest.

A speed-ratio write becomes an override of the node, ``delta = ratio / 100``, stamped with the emulator's wall
clock and numbered by this face. The node's watchdog then stops the robot when writes stop arriving. **A real IRC5
has no such watchdog on the speed ratio**: the ratio last written stays in force if the bridge dies. The README
tells integrators to add one in RAPID, a semi-static background task that checks a heartbeat::

    ! a persistent counter the bridge increments with every write (POST .../RAPID/T_HB/HB/hb_count?action=set),
    ! or a virtual input it toggles; the task stops the motion task when it has not changed for 0.2 s
    WHILE TRUE DO
        IF hb_count = hb_last THEN
            hb_silent := hb_silent + 1;
            IF hb_silent >= 4 SetDO doHeartbeatLost, 1;   ! wired to a general stop / SafeMove input
        ELSE
            hb_silent := 0; hb_last := hb_count;
        ENDIF
        WaitTime 0.05;
    ENDWHILE

(a signal to a stop input, not ``StopMove`` from a background task, so that the stop is the controller's own.)

Hostile requests are answered and counted, never crash the server: bodies over :data:`MAX_BODY_BYTES` (413),
chunked bodies (411), malformed or wrong Digest headers (401), a replayed nonce count (401), a request not
complete within ``request_timeout_s`` (408, connection closed: slowloris), more than :data:`MAX_CONNECTIONS`
connections at once (503, as a real controller refuses too many sessions).
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import math
import secrets
import socket
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from types import MappingProxyType
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from controller_emu.node import ControllerNode, ControllerOutput
from hrc_contract.messages import Override, to_payload
from hrc_devices.controllers.abb_rws.http_digest import (
    NONCE_LIFETIME_S,
    Credentials,
    DigestChallenge,
    DigestError,
    check_authorization,
    make_nonce,
    nonce_issued_ns,
    parse_authorization,
)
from hrc_devices.robots.time_scaling import Mode
from hrc_runtime.clocks import Clocks, read_clocks

log = logging.getLogger("hrc-controller-emu.rws")

REALM = "validusers@robapi.abb"
"""The Digest realm of RWS 1.0."""

MECHUNIT = "ROB_1"
"""The one mechanical unit served."""

MAX_BODY_BYTES = 1024
"""A request body larger than this is refused with 413 [bytes]."""

MAX_CONNECTIONS = 16
"""Connections served at once; one more is answered 503 and closed."""

MAX_NONCES = 1024
"""Nonce counts remembered (only nonces that authenticated a request; the oldest is forgotten first)."""

REQUEST_TIMEOUT_S = 10.0
"""A request (from the first byte awaited to the end of its body) must arrive within this [s]."""

_GET_PATHS = {
    "/rw/panel/speedratio",
    f"/rw/motionsystem/mechunits/{MECHUNIT}/jointtarget",
    "/rw/rapid/execution",
    "/rw/panel/ctrlstate",
}
_SPEEDRATIO_PATH = "/rw/panel/speedratio"


class FormError(ValueError):
    """A speed-ratio form that cannot be applied (the message says what was given and what is allowed)."""


@dataclass(frozen=True)
class RwsFaceStats:
    """What the face served and refused.

    Attributes:
        writes: speed-ratio writes applied.
        reads: GETs answered 200.
        speed_ratio_pct: the ratio last written [%] (100 before any, as a controller starts).
        connections: connections open now.
        refused: refused requests by reason (``challenged`` is a client's normal first 401), sorted by reason.
    """

    writes: int
    reads: int
    speed_ratio_pct: int
    connections: int
    refused: Mapping[str, int]


def parse_speed_ratio_form(body: bytes) -> int:
    """The ``speed-ratio`` of a ``setspeedratio`` form body [%].

    Raises:
        FormError: not ASCII form data, a field other than ``speed-ratio``, the field missing or repeated, or a value
            that is not an integer in [0, 100].
    """
    try:
        fields = parse_qsl(body.decode("ascii"), keep_blank_values=True, strict_parsing=True, max_num_fields=4)
    except (UnicodeDecodeError, ValueError):
        raise FormError("the body is not form data; allowed: speed-ratio=<integer 0..100>") from None
    names = sorted({name for name, _ in fields})
    values = [value for name, value in fields if name == "speed-ratio"]
    if names != ["speed-ratio"] or len(values) != 1:
        raise FormError(f"fields {names} ({len(fields)} given); allowed: speed-ratio exactly once")
    text = values[0]
    if not (text.isascii() and text.isdigit() and len(text) <= 3) or int(text) > 100:
        raise FormError(f"speed-ratio {text[:16]!r}; allowed: an integer 0..100")
    return int(text)


def format_rapid_num(value: float) -> str:
    """A number as the controller prints a RAPID ``num`` (single precision: 7 significant digits)."""
    return format(value, ".7g")


def _document(base: str, self_href: str, state: dict[str, str]) -> dict[str, Any]:
    return {
        "_links": {"base": {"href": base}},
        "_embedded": {"_links": {"self": {"href": self_href}}, "_state": [state]},
    }


def speedratio_document(base: str, ratio_pct: int) -> dict[str, Any]:
    """``GET /rw/panel/speedratio`` (``ratio_pct`` in [0, 100] [%])."""
    state = {"_type": "pnl-speedratio", "_title": "speedratio", "speedratio": str(ratio_pct)}
    return _document(f"{base}/rw/panel/", "speedratio", state)


def jointtarget_document(base: str, q_rad: tuple[float, ...]) -> dict[str, Any]:
    """``GET /rw/motionsystem/mechunits/ROB_1/jointtarget``: the first six joints [deg] as ``rax_1..rax_6``, any
    further ones as ``eax_a..eax_f``, the rest 0."""
    q_deg = [math.degrees(q) for q in q_rad]
    state = {"_type": "ms-jointtarget", "_title": MECHUNIT}
    for index, name in enumerate([f"rax_{i}" for i in range(1, 7)] + [f"eax_{c}" for c in "abcdef"]):
        state[name] = format_rapid_num(q_deg[index]) if index < len(q_deg) else "0"
    return _document(f"{base}/rw/motionsystem/mechunits/{MECHUNIT}/", "jointtarget", state)


def execution_state(mode: Mode) -> str:
    """The RAPID execution state a mode shows: the program runs at any speed ratio, 0 % included; a protective
    stop stops it."""
    return "stopped" if mode == "protective_stop" else "running"


def controller_state(mode: Mode) -> str:
    """The controller state a mode shows (``guardstop`` in a protective stop, else ``motoron``)."""
    return "guardstop" if mode == "protective_stop" else "motoron"


def execution_document(base: str, mode: Mode) -> dict[str, Any]:
    """``GET /rw/rapid/execution``."""
    state = {
        "_type": "rap-execution",
        "_title": "execution",
        "ctrlexecstate": execution_state(mode),
        "cycle": "forever",
    }
    return _document(f"{base}/rw/rapid/", "execution", state)


def ctrlstate_document(base: str, mode: Mode) -> dict[str, Any]:
    """``GET /rw/panel/ctrlstate``."""
    state = {"_type": "pnl-ctrlstate", "_title": "ctrlstate", "ctrlstate": controller_state(mode)}
    return _document(f"{base}/rw/panel/", "ctrlstate", state)


def error_document(base: str, status: int, message: str) -> dict[str, Any]:
    """An RWS 1.0 error body; ``code`` is this emulator's (``-status``), not one of ABB's return codes."""
    return {
        "_links": {"base": {"href": f"{base}/"}},
        "_embedded": {"_state": [], "status": {"code": -status, "msg": message}},
    }


@dataclass(frozen=True)
class _Snapshot:
    q_rad: tuple[float, ...]
    mode: Mode


class _DeadlineReader(io.RawIOBase):
    """A socket reader that refuses to wait past the handler's deadline (a trickling client cannot hold it)."""

    def __init__(self, sock: socket.socket, handler: _Handler) -> None:
        self._sock = sock
        self._handler = handler

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        remaining_s = self._handler.deadline_mono_s - time.monotonic()
        if remaining_s <= 0.0:
            raise TimeoutError("request deadline passed")
        self._sock.settimeout(remaining_s)
        count = self._sock.recv_into(buffer)
        self._handler.bytes_read += count
        return count


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False
    request_queue_size = 64  # socketserver's 5 drops the SYNs of a burst of connections: each then waits 1 s

    def __init__(self, address: tuple[str, int], face: RwsFace) -> None:
        self.face = face
        self._slots = threading.BoundedSemaphore(MAX_CONNECTIONS)
        self._open: set[socket.socket] = set()
        self._open_lock = threading.Lock()
        super().__init__(address, _Handler)

    def process_request(self, request: Any, client_address: Any) -> None:
        if not self._slots.acquire(blocking=False):
            self.face.count("too_many_connections")
            _refuse_busy(request)
            self.shutdown_request(request)
            return
        with self._open_lock:
            self._open.add(request)
        super().process_request(request, client_address)

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._open_lock:
                self._open.discard(request)
            self._slots.release()

    def open_connections(self) -> int:
        """Connections being served now."""
        with self._open_lock:
            return len(self._open)

    def drop_connections(self) -> None:
        """Shut every open connection down, so that their threads end now."""
        with self._open_lock:
            for request in self._open:
                with contextlib.suppress(OSError):
                    request.shutdown(socket.SHUT_RDWR)


def _session_cookies() -> list[tuple[str, str]]:
    """The session cookies a real controller sets after a successful login (issued, not accepted as credentials)."""
    return [
        ("Set-Cookie", f"-http-session-={secrets.token_hex(16)}; path=/; httponly"),
        ("Set-Cookie", f"ABBCX={secrets.randbelow(10**9)}; path=/; httponly"),
    ]


def _refuse_busy(request: socket.socket) -> None:
    body = json.dumps(error_document("", 503, "too many active connections")).encode()
    head = f"HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\nContent-Length: {len(body)}\r\n"
    try:
        request.settimeout(0.1)
        request.sendall(head.encode() + b"Connection: close\r\n\r\n" + body)
    except OSError:
        pass


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True  # headers and body are two writes: Nagle + delayed ACK would add 40 ms
    server_version = "RWS-emulator"
    sys_version = ""
    server: _Server
    deadline_mono_s: float = 0.0
    bytes_read: int = 0

    def setup(self) -> None:
        super().setup()
        self.rfile = io.BufferedReader(_DeadlineReader(self.connection, self))

    def handle_one_request(self) -> None:
        self.deadline_mono_s = time.monotonic() + self.server.face.request_timeout_s
        self.bytes_read = 0
        self.timed_out = False
        super().handle_one_request()
        if self.timed_out and self.bytes_read > 0:
            # Part of a request arrived and the rest did not: say so (an idle keep-alive connection is just closed).
            self.server.face.count("timeout")
            self._try_reply_timeout()

    def _try_reply_timeout(self) -> None:
        body = json.dumps(error_document(self.server.face.base_url, 408, "request not complete in time")).encode()
        try:
            self.connection.settimeout(0.1)
            self.wfile.write(
                b"HTTP/1.1 408 Request Timeout\r\nContent-Type: application/json\r\nConnection: close\r\n"
                + f"Content-Length: {len(body)}\r\n\r\n".encode()
                + body
            )
        except OSError:
            pass

    def log_error(self, format: str, *args: Any) -> None:
        if format.startswith("Request timed out"):
            self.timed_out = True
        log.debug("%s: " + format, self.client_address[0], *args)

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("%s: " + format, self.client_address[0], *args)

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """The stdlib's own refusals (bad request line, headers too long or too many, unknown method) as RWS errors."""
        self.server.face.count(f"http_{code}")
        self.close_connection = True
        self.request_version = "HTTP/1.1"  # an unparsable request line would else get an HTTP/0.9 answer: no status
        self._reply_error(code, (message or HTTPStatus(code).phrase)[:200])

    def do_GET(self) -> None:
        self.server.face.handle(self, "GET")

    def do_POST(self) -> None:
        self.server.face.handle(self, "POST")

    # Reply helpers, used by RwsFace.handle.
    def _reply(self, status: int, body: bytes | None, headers: Sequence[tuple[str, str]] = ()) -> None:
        self.connection.settimeout(self.server.face.request_timeout_s)
        self.send_response(status)
        for name, value in headers:
            self.send_header(name, value)
        if body is None:
            self.send_header("Content-Length", "0")
        else:
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
        if self.close_connection:
            self.send_header("Connection", "close")
        self.end_headers()
        if body is not None:
            self.wfile.write(body)

    def _reply_error(self, status: int, message: str, headers: Sequence[tuple[str, str]] = ()) -> None:
        document = error_document(self.server.face.base_url, status, message)
        self._reply(status, json.dumps(document).encode(), headers)


class RwsFace:
    """The RWS 1.0 face of one emulated controller (see the module docstring).

    Args:
        node: the emulated controller (speed-ratio writes go to its ``on_override``).
        host: the address to serve on (give each emulated robot its own loopback address).
        port: the TCP port; 0 picks a free one (read :attr:`port` after :meth:`start`).
        user: the Digest user name.
        password: the Digest password.
        request_timeout_s: a request must arrive within this, else 408 and the connection is closed [s].
        clock: the clocks read at each write (the override's stamp is its wall clock).
    """

    def __init__(
        self,
        node: ControllerNode,
        host: str,
        port: int,
        user: str = "Default User",
        password: str = "robotics",
        *,
        request_timeout_s: float = REQUEST_TIMEOUT_S,
        clock: Callable[[], Clocks] = read_clocks,
    ) -> None:
        if not request_timeout_s > 0.0:
            raise ValueError(f"request_timeout_s = {request_timeout_s}; allowed: > 0 s")
        self.node = node
        self.host = host
        self.port = port
        self.request_timeout_s = request_timeout_s
        self._credentials = Credentials(user, password)
        self._clock = clock
        self._secret = secrets.token_bytes(32)
        self._opaque = secrets.token_hex(8)
        q_rad, _ = node.trajectory.sample(node.state.tau_s)
        self._snapshot = _Snapshot(tuple(float(q) for q in q_rad), node.state.mode)
        self._lock = threading.Lock()
        self._ratio_pct = 100
        self._seq = 0
        self._last_stamp_ns = -1
        self._writes = 0
        self._reads = 0
        self._refused: Counter[str] = Counter()
        self._nonce_counts: OrderedDict[str, int] = OrderedDict()
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None

    @property
    def base_url(self) -> str:
        """``http://host:port`` as served."""
        return f"http://{self.host}:{self.port}"

    def start(self) -> None:
        """Bind and serve on a thread of its own.

        Raises:
            OSError: the address cannot be bound.
        """
        server = _Server((self.host, self.port), self)
        self.port = server.server_address[1]
        self._server = server
        self._thread = threading.Thread(
            target=server.serve_forever, args=(0.05,), name=f"rws-{self.host}:{self.port}", daemon=True
        )
        self._thread.start()
        log.info("RWS 1.0 face of %s on %s", self.node.robot, self.base_url)

    def on_cycle(self, output: ControllerOutput) -> None:
        """Keep the newest state for the GETs (called by the emulator loop every cycle; no lock, no I/O)."""
        self._snapshot = _Snapshot(tuple(output.joint_state.q), output.state.mode)

    def close(self) -> None:
        """Stop serving and drop open connections."""
        server, self._server = self._server, None
        if server is None:
            return
        server.shutdown()
        server.drop_connections()
        server.server_close()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def __enter__(self) -> RwsFace:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def count(self, reason: str) -> None:
        """Count a refused request."""
        with self._lock:
            self._refused[reason] += 1

    def progress(self) -> str:
        """For the emulator's progress line: nothing (the closed controller's line says what its overrides did)."""
        return ""

    def stats(self) -> RwsFaceStats:
        """The current figures (safe from any thread)."""
        server = self._server
        connections = 0 if server is None else server.open_connections()
        with self._lock:
            return RwsFaceStats(
                writes=self._writes,
                reads=self._reads,
                speed_ratio_pct=self._ratio_pct,
                connections=connections,
                refused=MappingProxyType(dict(sorted(self._refused.items()))),
            )

    def handle(self, request: _Handler, method: str) -> None:
        """Answer one request (on the connection's thread)."""
        body = self._read_body(request, method)
        if body is None:
            return
        if not self._authenticated(request, method):
            return
        target = urlsplit(request.path)
        try:
            query = dict(parse_qsl(target.query, keep_blank_values=True, strict_parsing=False, max_num_fields=8))
        except ValueError:
            query = {}
        cookies = () if "ABBCX=" in (request.headers.get("Cookie") or "") else _session_cookies()
        if method == "POST":
            self._post(request, target.path, query, body, cookies)
        else:
            self._get(request, target.path, query, cookies)

    def _read_body(self, request: _Handler, method: str) -> bytes | None:
        """The body (b"" for a GET without one), or None after refusing the request."""
        if request.headers.get("Transfer-Encoding") is not None:
            self.count("chunked")
            request.close_connection = True
            request._reply_error(411, "chunked bodies are not accepted; send Content-Length")
            return None
        lengths = request.headers.get_all("Content-Length") or []
        if not lengths:
            if method == "POST":
                self.count("no_length")
                request.close_connection = True
                request._reply_error(411, "POST needs a Content-Length")
                return None
            return b""
        text = lengths[0].strip()
        if len(lengths) > 1 or not (text.isascii() and text.isdigit()):
            self.count("bad_length")
            request.close_connection = True
            request._reply_error(400, f"Content-Length {lengths[0][:20]!r}; allowed: one decimal integer")
            return None
        length = int(text)
        if length > MAX_BODY_BYTES:
            self.count("too_large")
            request.close_connection = True
            request._reply_error(413, f"body of {length} bytes; at most {MAX_BODY_BYTES} allowed")
            return None
        body = request.rfile.read(length)
        if len(body) < length:
            request.close_connection = True
            return None
        return body

    def _authenticated(self, request: _Handler, method: str) -> bool:
        """True if the request's Digest authorization is valid; else a 401 with a challenge was sent."""
        now_mono_ns = self._clock().mono_ns
        header = request.headers.get("Authorization")
        stale = False
        if header is None:
            self.count("challenged")
            message = "authentication required (HTTP Digest)"
        else:
            try:
                auth = parse_authorization(header)
            except DigestError as exc:
                self.count("auth_malformed")
                message = f"malformed Authorization: {exc}"
            else:
                with self._lock:
                    verdict = check_authorization(
                        auth,
                        method,
                        request.path,
                        self._credentials,
                        REALM,
                        self._secret,
                        self._opaque,
                        now_mono_ns,
                        self._nonce_counts.get(auth.nonce),
                    )
                    if verdict.reason is None:
                        self._remember_nonce(verdict.nonce, verdict.nc, now_mono_ns)
                        return True
                    self._refused[f"auth_{verdict.reason}"] += 1
                stale = verdict.stale
                message = f"authentication refused: {verdict.reason}"
        challenge = DigestChallenge(REALM, make_nonce(self._secret, now_mono_ns), self._opaque, stale=stale)
        request._reply_error(401, message, [("WWW-Authenticate", challenge.header_value())])
        return False

    def _remember_nonce(self, nonce: str, nc: int, now_mono_ns: int) -> None:
        """Store a nonce's last count (caller holds the lock); forget an expired one, and the oldest past MAX_NONCES."""
        self._nonce_counts[nonce] = nc
        self._nonce_counts.move_to_end(nonce)
        while len(self._nonce_counts) > MAX_NONCES:
            self._nonce_counts.popitem(last=False)
        oldest = next(iter(self._nonce_counts))
        issued_ns = nonce_issued_ns(self._secret, oldest)
        if issued_ns is not None and (now_mono_ns - issued_ns) / 1e9 > NONCE_LIFETIME_S:
            del self._nonce_counts[oldest]

    def _post(
        self, request: _Handler, path: str, query: Mapping[str, str], body: bytes, cookies: Sequence[tuple[str, str]]
    ) -> None:
        if path != _SPEEDRATIO_PATH:
            self.count("not_found")
            request._reply_error(404, f"no resource {path[:80]!r} to POST; allowed: {_SPEEDRATIO_PATH}", cookies)
            return
        if query.get("action") != "setspeedratio":
            self.count("bad_action")
            request._reply_error(400, f"action {query.get('action', '')[:40]!r}; allowed: setspeedratio", cookies)
            return
        try:
            ratio_pct = parse_speed_ratio_form(body)
        except FormError as exc:
            self.count("bad_form")
            request._reply_error(400, str(exc), cookies)
            return
        reason = self._write(ratio_pct)
        if reason is not None:
            self.count(f"override_{reason}")
            request._reply_error(500, f"the controller refused the override: {reason}", cookies)
            return
        request._reply(204, None, cookies)

    def _write(self, ratio_pct: int) -> str | None:
        """Apply a speed ratio as the node's override; None if accepted, else the node's reason."""
        with self._lock:
            now = self._clock()
            # Stamps must grow for the node to accept them; two writes in one clock tick get consecutive stamps.
            stamp_ns = max(now.wall_ns, self._last_stamp_ns + 1)
            message = Override(robot=self.node.robot, seq=self._seq, stamp_ns=stamp_ns, delta=ratio_pct / 100.0)
            reason = self.node.on_override(to_payload(message), now)
            self._seq += 1
            if reason is None:
                self._last_stamp_ns = stamp_ns
                self._ratio_pct = ratio_pct
                self._writes += 1
            return reason

    def _get(self, request: _Handler, path: str, query: Mapping[str, str], cookies: Sequence[tuple[str, str]]) -> None:
        if path == "/logout":
            request._reply(204, None, cookies)
            return
        if path not in _GET_PATHS:
            self.count("not_found")
            request._reply_error(404, f"no resource {path[:80]!r}; served: {', '.join(sorted(_GET_PATHS))}", cookies)
            return
        if query.get("json") != "1":
            self.count("not_json")
            request._reply_error(406, "this emulator serves JSON only: add json=1", cookies)
            return
        base = self.base_url
        snapshot = self._snapshot
        if path == _SPEEDRATIO_PATH:
            with self._lock:
                document = speedratio_document(base, self._ratio_pct)
        elif path.endswith("/jointtarget"):
            document = jointtarget_document(base, snapshot.q_rad)
        elif path == "/rw/rapid/execution":
            document = execution_document(base, snapshot.mode)
        else:
            document = ctrlstate_document(base, snapshot.mode)
        with self._lock:
            self._reads += 1
        request._reply(200, json.dumps(document).encode(), cookies)
