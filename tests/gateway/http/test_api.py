"""The REST API (contract, "REST") over fastapi's TestClient, fed through a StatusBoard.

Every body is parsed with the contract's models (``hrc_contract.status_models``), never by hand.
"""

from __future__ import annotations

import asyncio
import io
import json
import math
import re
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import support.status_examples as ex
from fastapi.testclient import TestClient
from jsonschema import Draft202012Validator
from openapi_spec_validator import OpenAPIV31SpecValidator
from pydantic import ValidationError

from gateway.core import ClosestPair, Fault, RobotDecision
from gateway.delay import DelayBudget
from gateway.http.api import STATUS_EVENT, StatusBoard, create_app, stream_status
from gateway.http.server import _feed
from gateway.status import effective_config, robot_status, status_document
from gateway.zones import ZoneThresholds
from hrc_contract.config import CellConfig
from hrc_contract.status_models import (
    EffectiveConfig,
    ErrorResponse,
    GatewayStatus,
    Health,
    NotReady,
    NotReadyResponse,
    Ready,
    RobotStatusResponse,
)
from hrc_contract.vocabulary import Zone


@pytest.fixture
def board(cell_config: CellConfig) -> StatusBoard:
    return StatusBoard(effective_config(cell_config))


@pytest.fixture
def client(board: StatusBoard) -> TestClient:
    return TestClient(create_app(board))


def decision(**fields: object) -> RobotDecision:
    """A UR5 decision slowed down by a person 1.23 m away; ``fields`` replace any field."""
    values: dict[str, object] = {
        "robot": "ur5",
        "zone": Zone.REDUCED_SPEED,
        "delta": 0.623456,
        "delta_bound": 0.623456,
        "min_distance_m": 1.234567,
        "closest": ClosestPair("front/h1", "hand_r", "tool"),
        "delay": DelayBudget(0.04, 0.03, 0.004, 0.012, 0.004, 0.004),
        "clearance_m": 1.0484,
        "thresholds": ZoneThresholds(1.0484, 1.0984, 1.9, 2.4),
        "faults": (),
        "data_age_s": {"joint_state": 0.004, "tracker/front": 0.03, "tracker/side": None},
        "controller_mode": "running",
    }
    values.update(fields)
    return RobotDecision(**values)  # type: ignore[arg-type]


# -- status -------------------------------------------------------------------------------------


def test_status_503_before_the_first_document(client: TestClient) -> None:
    for path in ("/api/v1/status", "/api/v1/robots/ur5", "/readyz"):
        response = client.get(path)
        assert response.status_code == 503, path
        assert "not published" in ErrorResponse.model_validate_json(response.content).detail


def test_status_200_with_the_document(board: StatusBoard, client: TestClient) -> None:
    doc = ex.gateway_status(ur5=ex.near_robot_status())
    board.publish(doc)
    response = client.get("/api/v1/status")
    assert response.status_code == 200
    assert response.headers["content-type"] == "application/json"
    assert GatewayStatus.model_validate_json(response.content) == doc


def test_status_is_served_as_the_gateway_serialised_it(board: StatusBoard, client: TestClient) -> None:
    """A line from the pipe is validated once and served byte for byte (no re-serialisation per GET)."""
    compact = ex.gateway_status(ur5=ex.near_robot_status()).model_dump_json()
    line = json.dumps(json.loads(compact), separators=(", ", ": ")).encode()  # not how pydantic would write it
    board.publish_json(line + b"\n")
    assert client.get("/api/v1/status").content == line


def test_a_line_that_is_not_a_status_is_refused_and_the_previous_kept(board: StatusBoard, client: TestClient) -> None:
    board.publish(ex.gateway_status(ur5=ex.robot_status(delta=0.5)))
    for line in (b"not json\n", b'{"cell": "demo"}\n', b"[]\n"):
        with pytest.raises(ValidationError):
            board.publish_json(line)
    assert GatewayStatus.model_validate_json(client.get("/api/v1/status").content).robots["ur5"].delta == 0.5


def test_the_http_child_feeds_valid_lines_skips_others_and_stops_at_the_end(board: StatusBoard) -> None:
    lines = [
        ex.gateway_status(ur5=ex.robot_status(delta=0.25)).model_dump_json().encode() + b"\n",
        b"garbage\n",
        ex.gateway_status(ur5=ex.robot_status(delta=0.75)).model_dump_json().encode() + b"\n",
        b'{"cell": "demo", "robots": {}}\n',
    ]
    server = SimpleNamespace(should_exit=False)
    _feed(board, io.BytesIO(b"".join(lines)), server)  # type: ignore[arg-type]
    published, _ = board.latest()
    assert published is not None
    assert published.status.robots["ur5"].delta == 0.75
    assert server.should_exit


def test_newest_document_wins(board: StatusBoard, client: TestClient) -> None:
    board.publish(ex.gateway_status(ur5=ex.robot_status(delta=1.0)))
    board.publish(ex.gateway_status(ur5=ex.robot_status(delta=0.25)))
    assert GatewayStatus.model_validate_json(client.get("/api/v1/status").content).robots["ur5"].delta == 0.25


def test_status_503_when_stale(cell_config: CellConfig) -> None:
    now_s = [100.0]
    board = StatusBoard(effective_config(cell_config), stale_after_s=0.02, clock_s=lambda: now_s[0])
    client = TestClient(create_app(board))
    board.publish(ex.gateway_status())
    assert client.get("/api/v1/status").status_code == 200
    now_s[0] += 0.05
    for path in ("/api/v1/status", "/api/v1/robots/ur5", "/readyz"):
        response = client.get(path)
        assert response.status_code == 503, path
        assert "no status for" in ErrorResponse.model_validate_json(response.content).detail
    board.publish(ex.gateway_status())  # the loop comes back
    assert client.get("/api/v1/status").status_code == 200


def test_one_robot(board: StatusBoard, client: TestClient) -> None:
    ur10 = ex.near_robot_status(delta=0.5)
    board.publish(ex.gateway_status(ur5=ex.robot_status(), ur10=ur10))
    response = client.get("/api/v1/robots/ur10")
    assert response.status_code == 200
    body = RobotStatusResponse.model_validate_json(response.content)
    assert (body.robot, body.cell, body.stamp_ns) == ("ur10", "demo", ex.STAMP_NS)
    assert body.model_dump(exclude={"robot", "cell", "stamp_ns"}) == ur10.model_dump()


def test_unknown_robot_404_names_the_known_ones(board: StatusBoard, client: TestClient) -> None:
    board.publish(ex.gateway_status(ur5=ex.robot_status(), ur10=ex.robot_status()))
    response = client.get("/api/v1/robots/kuka")
    assert response.status_code == 404
    detail = ErrorResponse.model_validate_json(response.content).detail
    assert "kuka" in detail
    assert "ur5" in detail
    assert "ur10" in detail


# -- config -------------------------------------------------------------------------------------


def test_config_is_the_effective_configuration(client: TestClient, cell_config: CellConfig) -> None:
    response = client.get("/api/v1/config")  # available before the first status
    assert response.status_code == 200
    body = EffectiveConfig.model_validate_json(response.content)
    assert re.fullmatch(r"[0-9a-f]{64}", body.config_sha256)
    assert body.config_sha256 == cell_config.sha256()
    assert body.cell == "demo"
    assert body.trackers == ["front", "side"]
    assert body.safety == cell_config.safety
    assert body.safety.method == "zanchettin2016"
    assert body.safety.human_speed_mps == 1.6
    assert body.safety.clearance_static_m == 0.05
    assert body.safety.t_reaction_s == 0.04
    assert body.safety.max_data_age_s == 0.2
    assert body.zones == cell_config.zones
    assert body.gateway == cell_config.gateway
    ur5 = body.robots["ur5"]
    assert Path(ur5.urdf).is_absolute()
    assert Path(ur5.urdf).is_file()
    assert ur5.base_pose_world.model_dump() == {"xyz": (0.0, 0.0, 0.8), "rpy": (0.0, 0.0, 0.0)}
    assert ur5.joints[0] == "shoulder_pan_joint"
    assert len(ur5.braking_time_s) == len(ur5.joints) == 6
    assert ur5.links[-1].model_dump() == {
        "name": "tool",
        "frame_a": "wrist_3_link",
        "frame_b": "tool0",
        "radius_m": 0.07,
    }


# -- health -------------------------------------------------------------------------------------


def test_healthz_always_200(client: TestClient) -> None:
    response = client.get("/healthz")
    assert response.status_code == 200
    assert Health.model_validate_json(response.content) == Health(status="ok")


def test_readyz_503_with_faults_and_200_without(board: StatusBoard, client: TestClient) -> None:
    board.publish(ex.gateway_status(ur5=ex.robot_status(faults=[ex.STALE_TRACKER]), ur10=ex.robot_status()))
    response = client.get("/readyz")
    assert response.status_code == 503
    detail = NotReadyResponse.model_validate_json(response.content).detail
    assert detail == NotReady(ready=False, faults={"ur5": [ex.STALE_TRACKER.reason]})
    board.publish(ex.gateway_status(ur5=ex.robot_status(), ur10=ex.robot_status()))
    response = client.get("/readyz")
    assert response.status_code == 200
    assert Ready.model_validate_json(response.content) == Ready(ready=True)


# -- OpenAPI ------------------------------------------------------------------------------------


def _ref(openapi: dict[str, object], path: str, code: str) -> str:
    responses = openapi["paths"][path]["get"]["responses"]  # type: ignore[index]
    return str(responses[code]["content"]["application/json"]["schema"]["$ref"])


def test_openapi_documents_every_response_with_its_model(client: TestClient) -> None:
    response = client.get("/openapi.json")
    assert response.status_code == 200
    openapi = response.json()
    expected = {
        ("/api/v1/status", "200"): "GatewayStatus",
        ("/api/v1/status", "503"): "ErrorResponse",
        ("/api/v1/robots/{robot}", "200"): "RobotStatusResponse",
        ("/api/v1/robots/{robot}", "404"): "ErrorResponse",
        ("/api/v1/robots/{robot}", "503"): "ErrorResponse",
        ("/api/v1/config", "200"): "EffectiveConfig",
        ("/healthz", "200"): "Health",
        ("/readyz", "200"): "Ready",
        ("/readyz", "503"): "NotReadyResponse",
    }
    for (path, code), model in expected.items():
        assert _ref(openapi, path, code) == f"#/components/schemas/{model}", (path, code)
    robot = openapi["components"]["schemas"]["RobotStatus"]
    assert robot["additionalProperties"] is False
    assert {"zone", "delta", "faults", "override_seq", "delay_budget_s"} <= set(robot["required"])


def test_openapi_is_a_valid_openapi_3_1_document(client: TestClient) -> None:
    """Judged by openapi-spec-validator (FastAPI describes an event stream with 3.2's ``itemSchema``)."""
    openapi = client.get("/openapi.json").json()
    assert openapi["openapi"] == "3.1.0"
    errors = [
        f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in OpenAPIV31SpecValidator(openapi).iter_errors()
    ]
    assert errors == []


def _validator(openapi: dict[str, Any], component: str) -> Draft202012Validator:
    """A JSON Schema validator of one component, its ``#/components/...`` references resolved in the document."""
    return Draft202012Validator({"$ref": f"#/components/schemas/{component}", "components": openapi["components"]})


def _first_stream_event(board: StatusBoard) -> dict[str, str]:
    """The first server-sent event of ``GET /api/v1/stream`` as its fields (the route's generator, driven here)."""
    request = SimpleNamespace(app=SimpleNamespace(state=SimpleNamespace(board=board)))

    async def first() -> dict[str, str]:
        events = stream_status(request)  # type: ignore[arg-type]
        event = await anext(events)  # the rest of the generator is closed by asyncio.run
        return {"event": str(event.event), "id": str(event.id), "data": str(event.raw_data)}

    return asyncio.run(first())


def test_the_stream_is_documented_as_events_carrying_the_status_document(
    board: StatusBoard, client: TestClient
) -> None:
    openapi = client.get("/openapi.json").json()
    content = openapi["paths"]["/api/v1/stream"]["get"]["responses"]["200"]["content"]["text/event-stream"]
    assert content["schema"]["items"] == {"$ref": f"#/components/schemas/{STATUS_EVENT}"}
    data = openapi["components"]["schemas"][STATUS_EVENT]["properties"]["data"]
    assert data["contentMediaType"] == "application/json"
    assert data["contentSchema"] == {"$ref": "#/components/schemas/GatewayStatus"}
    # an event the route really sends is valid against what the document says, and so is the status it carries
    board.publish(ex.gateway_status(ur5=ex.near_robot_status()))
    event = _first_stream_event(board)
    _validator(openapi, STATUS_EVENT).validate(event)
    _validator(openapi, "GatewayStatus").validate(json.loads(event["data"]))
    assert not _validator(openapi, STATUS_EVENT).is_valid({**event, "event": "other"})


# -- the document the gateway builds (gateway/status.py) ------------------------------------------


def test_status_document_of_a_decision_has_the_contract_fields(board: StatusBoard, client: TestClient) -> None:
    """robot_status / status_document through the API: the contract's per-robot fields, rounded."""
    doc = status_document(
        "demo",
        ex.STAMP_NS,
        {"ur5": robot_status(decision(delta_applied=0.61), 517)},
        [{"id": "front/h1", "tracker": "front", "capsules": 13}],
        {"tracker/front": {"not_json": 2}},
        {"robot/ur5": 3},
        ex.loop_status(),
    )
    board.publish_json(doc.model_dump_json())
    body = RobotStatusResponse.model_validate_json(client.get("/api/v1/robots/ur5").content)
    assert body.zone == "reduced_speed"
    assert body.delta == pytest.approx(0.6235)
    assert body.min_distance_m == pytest.approx(1.2346)
    assert body.closest is not None
    assert body.closest.model_dump() == {"human": "front/h1", "capsule": "hand_r", "link": "tool"}
    assert body.t_delay_s == pytest.approx(0.094)
    assert body.delay_budget_s.override_path_s == pytest.approx(0.012)
    assert body.thresholds_m.monitored_m == pytest.approx(2.4)
    assert body.override_seq == 517
    assert body.data_age_s == {"joint_state": 0.004, "tracker/front": 0.03, "tracker/side": None}
    assert body.faults == []
    assert body.delta_applied == pytest.approx(0.61)
    status = GatewayStatus.model_validate_json(client.get("/api/v1/status").content)
    assert status.inputs.model_dump() == {"received": {"robot/ur5": 3}, "rejected": {"tracker/front": {"not_json": 2}}}
    assert [h.id for h in status.humans] == ["front/h1"]


def test_faults_are_code_and_reason(board: StatusBoard, client: TestClient) -> None:
    faults = (Fault("tracker_stale", "tracker 'front' data is 0.300 s old (limit 0.2 s)"),)
    entry = robot_status(decision(zone=Zone.SAFETY_EXCEPTION, delta=0.0, faults=faults), 9)
    assert [f.model_dump() for f in entry.faults] == [{"code": "tracker_stale", "reason": faults[0].reason}]


def test_a_decision_with_numbers_that_are_not_finite_still_gives_a_valid_status() -> None:
    """Absurd input must not stop the loop's status: a non-finite number becomes null (or 0 for a bound)."""
    entry = robot_status(
        decision(
            delta_bound=math.nan,
            min_distance_m=math.inf,
            thresholds=ZoneThresholds(1.0484, 1.0984, math.inf, math.nan),
            data_age_s={"joint_state": math.inf},
        ),
        1,
    )
    assert entry.delta_bound == 0.0
    assert entry.min_distance_m is None
    assert (entry.thresholds_m.reduce_m, entry.thresholds_m.monitored_m) == (None, None)
    assert entry.data_age_s == {"joint_state": None}
    doc = ex.gateway_status(ur5=entry)
    assert GatewayStatus.model_validate_json(doc.model_dump_json()) == doc
