"""The REST API of the gateway (contract, "REST"): status, one robot, effective config, health, the status stream
(server-sent events), the event log, Prometheus metrics, and the operator page at ``/``.

The app only reads a :class:`StatusBoard`, which the safety loop fills; the app cannot slow the loop
down (in the running gateway it lives in its own process, fed through a pipe).

Every route declares its response model (:mod:`hrc_contract.status_models`), so ``/openapi.json`` documents
the real shapes. The status is validated once, when it reaches the board; a GET then answers with the bytes
the gateway produced (``/api/v1/status``, ``/api/v1/config``) or serialises the parsed model
(``/api/v1/robots/{robot}``), without validating the response again.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import AsyncIterator, Callable
from importlib import resources
from typing import Annotated, Any, NamedTuple

from fastapi import APIRouter, Depends, FastAPI, HTTPException, Query, Request, Response
from fastapi.responses import HTMLResponse
from fastapi.sse import EventSourceResponse, ServerSentEvent
from prometheus_client import CONTENT_TYPE_LATEST

from gateway.events import EventRing
from gateway.http.metrics import GatewayMetrics
from hrc_contract.status_models import (
    EffectiveConfig,
    ErrorResponse,
    EventsResponse,
    GatewayStatus,
    Health,
    NotReady,
    NotReadyResponse,
    Ready,
    RobotStatusResponse,
)

STATUS_STALE_AFTER_S = 1.0
"""A status older than this means the safety loop is not running: the API says so with 503."""

JSON = "application/json"
STREAM_RECHECK_S = 0.25
"""A stream waits for a new document at most this long before it looks again (stale, or the gateway stopped) [s];
a new document or the stop wakes it at once."""
EVENTS_LIMIT = 1000
"""At most this many events in one ``GET /api/v1/events`` answer."""
STREAM_PATH = "/api/v1/stream"
STATUS_EVENT = "StatusEvent"
"""The OpenAPI component of one event of the status stream."""


class PublishedStatus(NamedTuple):
    """A status document as parsed (``status``) and as the gateway serialised it (``json``, UTF-8)."""

    status: GatewayStatus
    json: bytes


class StatusBoard:
    """The newest status document and the effective configuration, shared with the API (thread-safe)."""

    def __init__(
        self,
        effective_config: EffectiveConfig,
        stale_after_s: float = STATUS_STALE_AFTER_S,
        clock_s: Callable[[], float] = time.monotonic,
    ) -> None:
        self.effective_config = effective_config
        self.effective_config_json = effective_config.model_dump_json().encode()
        self.stale_after_s = stale_after_s
        self._clock_s = clock_s
        self._lock = threading.Lock()
        self._doc: PublishedStatus | None = None
        self._received_s = 0.0
        self.version = 0
        """Counts the documents published (a stream sends each version once)."""
        self.closed = False
        """Set by :meth:`close` when the gateway's input ended: open streams end, so shutdown never waits on them."""
        self._waiters: set[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = set()
        self.events = EventRing()
        self.metrics = GatewayMetrics(1.0 / effective_config.gateway.rate_hz)

    def publish(self, status: GatewayStatus, status_json: bytes | None = None) -> None:
        """Make ``status`` the newest document; ``status_json`` is its serialisation, if the caller has it."""
        published = PublishedStatus(status, status.model_dump_json().encode() if status_json is None else status_json)
        with self._lock:
            self._doc = published
            self._received_s = self._clock_s()
            self.version += 1
        self.metrics.observe(status)
        self._wake()

    def close(self) -> None:
        """The gateway's input ended: every open stream ends."""
        with self._lock:
            self.closed = True
        self._wake()

    def _wake(self) -> None:
        with self._lock:
            waiters = list(self._waiters)
        for loop, event in waiters:
            loop.call_soon_threadsafe(event.set)

    async def changed(self, version: int, timeout_s: float) -> None:
        """Wait (in the event loop) until a document newer than ``version`` is published or the board closes, at
        most ``timeout_s``."""
        waiter = (asyncio.get_running_loop(), asyncio.Event())
        with self._lock:
            self._waiters.add(waiter)
            if self.version != version or self.closed:  # checked after registering: no wake-up is lost
                waiter[1].set()
        try:
            await asyncio.wait_for(waiter[1].wait(), timeout_s)
        except TimeoutError:
            pass
        finally:
            with self._lock:
                self._waiters.discard(waiter)

    def publish_json(self, line: bytes | str) -> None:
        """Parse one status document (a JSON line from the gateway) and make it the newest.

        Raises:
            pydantic.ValidationError: the line is not a status document; the board keeps the previous one.
        """
        raw = line.encode() if isinstance(line, str) else line
        self.publish(GatewayStatus.model_validate_json(raw), raw.strip())

    def latest(self) -> tuple[PublishedStatus | None, float | None]:
        """The newest document and its age [s] (None, None before the first)."""
        with self._lock:
            if self._doc is None:
                return None, None
            return self._doc, self._clock_s() - self._received_s


def _board(request: Request) -> StatusBoard:
    board: StatusBoard = request.app.state.board
    return board


Board = Annotated[StatusBoard, Depends(_board)]


def _fresh_status(board: StatusBoard) -> PublishedStatus:
    doc, age = board.latest()
    if doc is None or age is None:
        raise HTTPException(503, "the gateway's safety loop has not published a status yet")
    if age > board.stale_after_s:
        raise HTTPException(503, f"the gateway's safety loop has published no status for {age:.1f} s")
    return doc


_NOT_RUNNING: dict[int | str, dict[str, Any]] = {
    503: {
        "model": ErrorResponse,
        "description": f"The safety loop has published no status (yet, or for {STATUS_STALE_AFTER_S:g} s).",
    }
}

status_router = APIRouter(prefix="/api/v1", tags=["status"])


@status_router.get(
    "/status", summary="Zones, δ and faults of every robot", response_model=GatewayStatus, responses=_NOT_RUNNING
)
def get_status(board: Board) -> Response:
    return Response(_fresh_status(board).json, media_type=JSON)


@status_router.get(
    "/robots/{robot}",
    summary="Zone, δ and faults of one robot",
    response_model=RobotStatusResponse,
    responses={
        404: {"model": ErrorResponse, "description": "Unknown robot; the message names the known robots."},
        **_NOT_RUNNING,
    },
)
def get_robot(robot: str, board: Board) -> Response:
    status = _fresh_status(board).status
    entry = status.robots.get(robot)
    if entry is None:
        raise HTTPException(404, f"unknown robot {robot!r}; known robots: {', '.join(sorted(status.robots))}")
    # Built from a validated entry: constructed without validating it again, serialised once.
    body = RobotStatusResponse.model_construct(cell=status.cell, stamp_ns=status.stamp_ns, robot=robot, **dict(entry))
    return Response(body.model_dump_json(), media_type=JSON)


@status_router.get(
    "/config", summary="The effective safety configuration, with its sha256", response_model=EffectiveConfig
)
def get_config(board: Board) -> Response:
    return Response(board.effective_config_json, media_type=JSON)


health_router = APIRouter(tags=["health"])


@health_router.get("/healthz", summary="The process is up", response_model=Health)
def healthz() -> Health:
    return Health(status="ok")


@health_router.get(
    "/readyz",
    summary="Inputs are fresh and overrides flow for every robot",
    response_model=Ready,
    responses={503: {"model": NotReadyResponse, "description": "No fresh status, or a robot has active faults."}},
)
def readyz(board: Board) -> Ready:
    status = _fresh_status(board).status
    not_ready = {name: [f.reason for f in robot.faults] for name, robot in status.robots.items() if robot.faults}
    if not_ready:
        raise HTTPException(503, NotReady(ready=False, faults=not_ready).model_dump())
    return Ready(ready=True)


def _fresh_version(board: StatusBoard) -> tuple[PublishedStatus | None, int]:
    """The newest document if fresh (else None), and the board's version."""
    version = board.version
    doc, age = board.latest()
    return (doc if age is not None and age <= board.stale_after_s else None), version


@status_router.get(
    "/stream",
    response_class=EventSourceResponse,
    summary="The status document at the status rate (server-sent events ``status``)",
    response_description="Server-sent events (``text/event-stream``), one per status document.",
)
async def stream_status(request: Request) -> AsyncIterator[ServerSentEvent]:
    """Each new status document once, as an event ``status`` whose data is the document; nothing while the
    safety loop publishes none (a client sees the silence and shows the data as stale). Ends when the gateway
    stops."""
    board: StatusBoard = request.app.state.board
    sent = -1
    while not board.closed:
        doc, version = _fresh_version(board)
        if doc is not None and version != sent:
            sent = version
            yield ServerSentEvent(raw_data=doc.json.decode(), event="status", id=str(version))
        await board.changed(sent, STREAM_RECHECK_S)


@status_router.get("/events", summary="The event log after a seq", response_model=EventsResponse)
def get_events(
    board: Board,
    since: Annotated[int, Query(ge=0, description="Only events with a larger seq (0: all that are held).")] = 0,
    limit: Annotated[int, Query(ge=1, le=EVENTS_LIMIT, description="At most this many events.")] = EVENTS_LIMIT,
) -> Response:
    events, last_seq = board.events.since(since, limit)
    body = EventsResponse.model_construct(events=events, last_seq=last_seq)
    return Response(body.model_dump_json(), media_type=JSON)


@health_router.get(
    "/metrics",
    summary="Prometheus metrics (text format)",
    response_class=Response,
    responses={200: {"content": {CONTENT_TYPE_LATEST: {}}, "description": "The Prometheus text format."}},
)
def metrics(board: Board) -> Response:
    return Response(board.metrics.exposition(), media_type=CONTENT_TYPE_LATEST)


page_router = APIRouter(tags=["operator page"])
OPERATOR_PAGE = resources.files("gateway.http").joinpath("static/operator.html")


@page_router.get("/", summary="The operator page (HTML; live from the stream)", response_class=HTMLResponse)
def operator_page() -> HTMLResponse:
    return HTMLResponse(OPERATOR_PAGE.read_bytes())


def _status_event_schema() -> dict[str, Any]:
    """One event of the status stream, as the HTML specification's fields (``event``, ``id``, ``data``); its
    ``data`` is the status document (JSON Schema's ``contentMediaType``/``contentSchema``)."""
    return {
        "title": STATUS_EVENT,
        "description": "One server-sent event of the status stream: a status document as the gateway published it.",
        "type": "object",
        "properties": {
            "event": {"const": "status"},
            "id": {
                "type": "string",
                "pattern": "^[0-9]+$",
                "description": "How many status documents the server had received when it sent this one: it "
                "increases, with gaps where a newer document replaced one before it was sent.",
            },
            "data": {
                "type": "string",
                "contentMediaType": "application/json",
                "contentSchema": {"$ref": "#/components/schemas/GatewayStatus"},
                "description": "The status document, JSON on one line.",
            },
        },
        "required": ["event", "id", "data"],
        "additionalProperties": False,
    }


def describe_status_stream(openapi: dict[str, Any]) -> dict[str, Any]:
    """The OpenAPI 3.1.0 document with the status stream described in 3.1's terms (edited in place, idempotent).

    FastAPI describes an event stream with ``itemSchema``, a field of OpenAPI 3.2 that makes a 3.1.0 document
    invalid, and its events' ``data`` as a bare string. Here the stream's ``schema`` is an array of
    :data:`STATUS_EVENT` (how the OpenAPI media type registry models ``text/event-stream`` without
    ``itemSchema``), whose ``data`` refers to ``GatewayStatus``.
    """
    content = openapi["paths"][STREAM_PATH]["get"]["responses"]["200"]["content"]["text/event-stream"]
    content.pop("itemSchema", None)
    content["schema"] = {
        "type": "array",
        "items": {"$ref": f"#/components/schemas/{STATUS_EVENT}"},
        "description": "The events of the stream, in the order sent; it ends when the gateway stops.",
    }
    openapi["components"]["schemas"][STATUS_EVENT] = _status_event_schema()
    return openapi


class GatewayApi(FastAPI):
    """The gateway's FastAPI app, whose ``/openapi.json`` is a valid OpenAPI 3.1.0 document."""

    def openapi(self) -> dict[str, Any]:
        return describe_status_stream(super().openapi())


def create_app(board: StatusBoard) -> FastAPI:
    app = GatewayApi(
        title="hrc-gateway",
        version="1",
        description="Status of the human-robot collaboration safety gateway (zones, speed override δ, faults). "
        "The contract: docs/contract.md.",
    )
    app.state.board = board
    app.include_router(status_router)
    app.include_router(health_router)
    app.include_router(page_router)
    return app
