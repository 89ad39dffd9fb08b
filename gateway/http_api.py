"""The REST API of the gateway (contract, "REST"): status, one robot, effective config, health.

The app only reads a :class:`StatusBoard`, which the safety loop fills; the app cannot slow the loop
down (in the running gateway it lives in its own process, fed through a pipe).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Depends, FastAPI, HTTPException, Request

STATUS_STALE_AFTER_S = 1.0
"""A status older than this means the safety loop is not running: the API says so with 503."""


class StatusBoard:
    """The newest status document and the effective configuration, shared with the API (thread-safe)."""

    def __init__(
        self,
        effective_config: dict[str, Any],
        stale_after_s: float = STATUS_STALE_AFTER_S,
        clock_s: Callable[[], float] = time.monotonic,
    ) -> None:
        self.effective_config = effective_config
        self.stale_after_s = stale_after_s
        self._clock_s = clock_s
        self._lock = threading.Lock()
        self._doc: dict[str, Any] | None = None
        self._received_s = 0.0

    def publish(self, doc: dict[str, Any]) -> None:
        with self._lock:
            self._doc = doc
            self._received_s = self._clock_s()

    def latest(self) -> tuple[dict[str, Any] | None, float | None]:
        """The newest document and its age [s] (None, None before the first)."""
        with self._lock:
            if self._doc is None:
                return None, None
            return self._doc, self._clock_s() - self._received_s


def _board(request: Request) -> StatusBoard:
    board: StatusBoard = request.app.state.board
    return board


Board = Annotated[StatusBoard, Depends(_board)]


def _fresh_status(board: StatusBoard) -> dict[str, Any]:
    doc, age = board.latest()
    if doc is None or age is None:
        raise HTTPException(503, "the gateway's safety loop has not published a status yet")
    if age > board.stale_after_s:
        raise HTTPException(503, f"the gateway's safety loop has published no status for {age:.1f} s")
    return doc


status_router = APIRouter(prefix="/api/v1", tags=["status"])


@status_router.get("/status", summary="Zones, δ and faults of every robot")
def get_status(board: Board) -> dict[str, Any]:
    return _fresh_status(board)


@status_router.get("/robots/{robot}", summary="Zone, δ and faults of one robot")
def get_robot(robot: str, board: Board) -> dict[str, Any]:
    doc = _fresh_status(board)
    robots: dict[str, Any] = doc["robots"]
    if robot not in robots:
        raise HTTPException(404, f"unknown robot {robot!r}; known robots: {', '.join(sorted(robots))}")
    entry: dict[str, Any] = robots[robot]
    return {"cell": doc["cell"], "stamp_ns": doc["stamp_ns"], "robot": robot, **entry}


@status_router.get("/config", summary="The effective safety configuration, with its sha256")
def get_config(board: Board) -> dict[str, Any]:
    return board.effective_config


health_router = APIRouter(tags=["health"])


@health_router.get("/healthz", summary="The process is up")
def healthz() -> dict[str, str]:
    return {"status": "ok"}


@health_router.get("/readyz", summary="Inputs are fresh and overrides flow for every robot")
def readyz(board: Board) -> dict[str, Any]:
    doc = _fresh_status(board)
    not_ready = {
        name: [f["reason"] for f in robot["faults"]] for name, robot in doc["robots"].items() if robot["faults"]
    }
    if not_ready:
        raise HTTPException(503, {"ready": False, "faults": not_ready})
    return {"ready": True}


def create_app(board: StatusBoard) -> FastAPI:
    app = FastAPI(
        title="hrc-gateway",
        version="1",
        description="Status of the human-robot collaboration safety gateway (zones, speed override δ, faults).",
    )
    app.state.board = board
    app.include_router(status_router)
    app.include_router(health_router)
    return app
