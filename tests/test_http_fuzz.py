"""The REST API fuzzed from its own OpenAPI document (schemathesis): no server error, responses match the schema."""

from __future__ import annotations

import schemathesis
from hypothesis import HealthCheck, settings

from gateway.http_api import StatusBoard, create_app

STATUS = {
    "cell": "demo",
    "stamp_ns": 1,
    "robots": {"ur5": {"zone": "autonomous", "delta": 1.0, "faults": []}},
    "humans": [],
}

board = StatusBoard({"cell": "demo", "config_sha256": "0" * 64}, stale_after_s=1e9)
board.publish(STATUS)
schema = schemathesis.openapi.from_asgi("/openapi.json", create_app(board))


@schema.parametrize()
@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
def test_api_never_fails_with_a_server_error(case: schemathesis.Case) -> None:
    response = case.call()
    assert response.status_code < 500, (case.path, response.text)
    case.validate_response(response, checks=(schemathesis.checks.not_a_server_error,))
