"""The REST API fuzzed from its own OpenAPI document (schemathesis): no server error, and every response has a
documented status code and content type and conforms to its documented schema (the contract's models).

Three boards: a fresh status of a healthy cell (200s, and 404 for unknown robots), a faulted robot (readyz 503
with the faults), and a loop that never published (503 everywhere but config and healthz).
"""

from __future__ import annotations

import schemathesis
import support.status_examples as ex
from hypothesis import HealthCheck, settings

from gateway.http.api import StatusBoard, create_app
from gateway.status import effective_config
from hrc_runtime.config import load_cell_config

CONFORMANCE = (
    schemathesis.checks.status_code_conformance,
    schemathesis.checks.content_type_conformance,
    schemathesis.checks.response_schema_conformance,
)
"""Documented status code and content type, body valid against the documented schema (a documented 503 is fine:
``not_a_server_error`` is only checked where the loop runs and no robot is faulted)."""
CONFIG = effective_config(load_cell_config(None))


def _schema(board: StatusBoard) -> schemathesis.schemas.BaseSchema:
    """The API's schema, less the status stream (it never ends while the loop runs; tests/test_http_operator.py
    reads it)."""
    return schemathesis.openapi.from_asgi("/openapi.json", create_app(board)).exclude(path="/api/v1/stream")


healthy = StatusBoard(CONFIG, stale_after_s=1e9)
healthy.publish(ex.gateway_status(ur5=ex.near_robot_status(), ur10=ex.robot_status()))
faulted = StatusBoard(CONFIG, stale_after_s=1e9)
faulted.publish(ex.gateway_status(ur5=ex.robot_status(faults=[ex.STALE_TRACKER])))
never_published = StatusBoard(CONFIG)

healthy_schema = _schema(healthy)
faulted_schema = _schema(faulted)
never_published_schema = _schema(never_published)


def _check(case: schemathesis.Case, no_server_error: bool = False) -> None:
    response = case.call()
    assert response.status_code != 500, (case.path, response.text)
    checks = (schemathesis.checks.not_a_server_error, *CONFORMANCE) if no_server_error else CONFORMANCE
    case.validate_response(response, checks=checks)


@healthy_schema.parametrize()
@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
def test_healthy_cell(case: schemathesis.Case) -> None:
    _check(case, no_server_error=True)


@faulted_schema.parametrize()
@settings(max_examples=10, deadline=None, suppress_health_check=list(HealthCheck))
def test_faulted_cell(case: schemathesis.Case) -> None:
    _check(case)


@never_published_schema.parametrize()
@settings(max_examples=10, deadline=None, suppress_health_check=list(HealthCheck))
def test_loop_never_published(case: schemathesis.Case) -> None:
    _check(case)
