"""The REST API (contract, "REST") over fastapi's TestClient, fed through a StatusBoard."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from gateway.core import ClosestPair, RobotDecision
from gateway.delay import DelayBudget
from gateway.http_api import StatusBoard, create_app
from gateway.status import effective_config, robot_status, status_document
from gateway.zones import Zone, ZoneThresholds
from hrc_common.config import CellConfig


def robot_entry(faults: list[dict[str, str]] | None = None, delta: float = 1.0) -> dict[str, Any]:
    return {
        "zone": "autonomous" if not faults else "safety_exception",
        "delta": delta if not faults else 0.0,
        "min_distance_m": None,
        "closest": None,
        "t_delay_s": 0.094,
        "override_seq": 17,
        "data_age_s": {"joint_state": 0.004, "tracker/front": 0.03},
        "faults": faults or [],
    }


def status_doc(**robots: dict[str, Any]) -> dict[str, Any]:
    return {"cell": "demo", "stamp_ns": 1_790_000_000_000_000_000, "robots": robots, "humans": []}


@pytest.fixture
def board(cell_config: CellConfig) -> StatusBoard:
    return StatusBoard(effective_config(cell_config))


@pytest.fixture
def client(board: StatusBoard) -> TestClient:
    return TestClient(create_app(board))


# -- status -------------------------------------------------------------------------------------


def test_status_503_before_the_first_document(client: TestClient) -> None:
    for path in ("/api/v1/status", "/api/v1/robots/ur5", "/readyz"):
        response = client.get(path)
        assert response.status_code == 503, path
        assert "not published" in response.json()["detail"]


def test_status_200_with_the_document(board: StatusBoard, client: TestClient) -> None:
    doc = status_doc(ur5=robot_entry())
    board.publish(doc)
    response = client.get("/api/v1/status")
    assert response.status_code == 200
    assert response.json() == doc


def test_newest_document_wins(board: StatusBoard, client: TestClient) -> None:
    board.publish(status_doc(ur5=robot_entry(delta=1.0)))
    board.publish(status_doc(ur5=robot_entry(delta=0.25)))
    assert client.get("/api/v1/status").json()["robots"]["ur5"]["delta"] == 0.25


def test_status_503_when_stale(cell_config: CellConfig) -> None:
    now_s = [100.0]
    board = StatusBoard(effective_config(cell_config), stale_after_s=0.02, clock_s=lambda: now_s[0])
    client = TestClient(create_app(board))
    board.publish(status_doc(ur5=robot_entry()))
    assert client.get("/api/v1/status").status_code == 200
    now_s[0] += 0.05
    for path in ("/api/v1/status", "/api/v1/robots/ur5", "/readyz"):
        response = client.get(path)
        assert response.status_code == 503, path
        assert "no status for" in response.json()["detail"]
    board.publish(status_doc(ur5=robot_entry()))  # the loop comes back
    assert client.get("/api/v1/status").status_code == 200


def test_one_robot(board: StatusBoard, client: TestClient) -> None:
    board.publish(status_doc(ur5=robot_entry(), ur10=robot_entry(delta=0.5)))
    response = client.get("/api/v1/robots/ur10")
    assert response.status_code == 200
    body = response.json()
    assert body["robot"] == "ur10"
    assert body["cell"] == "demo"
    assert body["delta"] == 0.5
    assert body["override_seq"] == 17


def test_unknown_robot_404_names_the_known_ones(board: StatusBoard, client: TestClient) -> None:
    board.publish(status_doc(ur5=robot_entry(), ur10=robot_entry()))
    response = client.get("/api/v1/robots/kuka")
    assert response.status_code == 404
    detail = response.json()["detail"]
    assert "kuka" in detail
    assert "ur5" in detail
    assert "ur10" in detail


# -- config -------------------------------------------------------------------------------------


def test_config_is_the_effective_configuration(client: TestClient, cell_config: CellConfig) -> None:
    response = client.get("/api/v1/config")  # available before the first status
    assert response.status_code == 200
    body = response.json()
    assert re.fullmatch(r"[0-9a-f]{64}", body["config_sha256"])
    assert body["config_sha256"] == cell_config.sha256()
    assert body["cell"] == "demo"
    assert body["trackers"] == ["front", "side"]
    assert body["safety"]["method"] == "zanchettin2016"
    assert body["safety"]["human_speed_mps"] == 1.6
    assert body["safety"]["clearance_static_m"] == 0.05
    assert body["safety"]["t_reaction_s"] == 0.04
    assert body["safety"]["max_data_age_s"] == 0.2
    ur5 = body["robots"]["ur5"]
    assert Path(ur5["urdf"]).is_absolute()
    assert Path(ur5["urdf"]).is_file()
    assert ur5["base_pose_world"] == {"xyz": [0.0, 0.0, 0.8], "rpy": [0.0, 0.0, 0.0]}
    assert ur5["joints"][0] == "shoulder_pan_joint"
    assert len(ur5["braking_time_s"]) == len(ur5["joints"]) == 6
    assert ur5["links"][-1] == {"name": "tool", "frame_a": "wrist_3_link", "frame_b": "tool0", "radius_m": 0.07}


# -- health -------------------------------------------------------------------------------------


def test_healthz_always_200(client: TestClient) -> None:
    response = client.get("/healthz")
    assert response.status_code == 200
    assert response.json() == {"status": "ok"}


def test_readyz_503_with_faults_and_200_without(board: StatusBoard, client: TestClient) -> None:
    fault = {"code": "tracker_stale", "reason": "tracker 'front' data is 0.300 s old (limit 0.2 s)"}
    board.publish(status_doc(ur5=robot_entry(faults=[fault]), ur10=robot_entry()))
    response = client.get("/readyz")
    assert response.status_code == 503
    detail = response.json()["detail"]
    assert detail["ready"] is False
    assert detail["faults"] == {"ur5": [fault["reason"]]}
    board.publish(status_doc(ur5=robot_entry(), ur10=robot_entry()))
    response = client.get("/readyz")
    assert response.status_code == 200
    assert response.json() == {"ready": True}


def test_openapi_lists_the_paths(client: TestClient) -> None:
    response = client.get("/openapi.json")
    assert response.status_code == 200
    paths = response.json()["paths"]
    for path in ("/api/v1/status", "/api/v1/robots/{robot}", "/api/v1/config", "/healthz", "/readyz"):
        assert path in paths
        assert "get" in paths[path]


def test_status_document_of_a_decision_has_the_contract_fields(board: StatusBoard, client: TestClient) -> None:
    """robot_status / status_document (gateway/status.py) through the API: the contract's per-robot fields."""
    decision = RobotDecision(
        robot="ur5",
        zone=Zone.REDUCED_SPEED,
        delta=0.623456,
        delta_bound=0.623456,
        min_distance_m=1.234567,
        closest=ClosestPair("front/h1", "hand_r", "tool"),
        delay=DelayBudget(0.04, 0.03, 0.004, 0.012, 0.004, 0.004),
        clearance_m=1.0484,
        thresholds=ZoneThresholds(1.0484, 1.0984, 1.9, 2.4),
        faults=(),
        data_age_s={"joint_state": 0.004, "tracker/front": 0.03, "tracker/side": None},
        controller_mode="running",
    )
    doc = status_document(
        "demo", 1_790_000_000_000_000_000, {"ur5": robot_status(decision, 517)}, [], {}, {"robot/ur5": 3}, {}
    )
    board.publish(doc)
    body = client.get("/api/v1/robots/ur5").json()
    assert body["zone"] == "reduced_speed"
    assert body["delta"] == pytest.approx(0.6235)
    assert body["min_distance_m"] == pytest.approx(1.2346)
    assert body["closest"] == {"human": "front/h1", "capsule": "hand_r", "link": "tool"}
    assert body["t_delay_s"] == pytest.approx(0.094)
    assert body["override_seq"] == 517
    assert body["data_age_s"] == {"joint_state": 0.004, "tracker/front": 0.03, "tracker/side": None}
    assert body["faults"] == []
    assert client.get("/api/v1/status").json()["inputs"] == {"received": {"robot/ur5": 3}, "rejected": {}}
