"""The gateway's view of the controller bridges' statistics: checked like any input, shown, never decisive."""

from __future__ import annotations

import json
from typing import Any

import pytest

from gateway.bridge_view import MAX_PAYLOAD_BYTES, BridgeView, parse_bridge_stats
from hrc_contract.config import CellConfig

GOOD = {
    "robot": "ur5",
    "interface": "abb_rws",
    "mode": "running",
    "readback": 0.42,
    "readback_latency_s": 0.012,
    "readback_latency_max_s": None,
    "readings_per_s": 50.0,
    "rejected": {"timeout": 2, "malformed": 1},
}


def test_a_valid_document_gives_its_fields() -> None:
    fields = parse_bridge_stats(json.dumps(GOOD).encode(), "ur5", "abb_rws")
    assert fields["readback"] == 0.42
    assert fields["readback_latency_s"] == 0.012
    assert fields["rejected"] == 3


@pytest.mark.parametrize(
    "change",
    [
        {"robot": "ur10"},
        {"interface": "ur_rtde"},
        {"readback": 1.5},
        {"readback": float("nan")},
        {"readback_latency_s": -0.1},
        {"readings_per_s": "many"},
        {"mode": "x" * 100},
        {"rejected": {"timeout": -1}},
        {"rejected": [1]},
    ],
)
def test_an_invalid_document_is_refused(change: dict[str, Any]) -> None:
    with pytest.raises(ValueError):  # noqa: PT011 (the message names the field; checked in the next test)
        parse_bridge_stats(json.dumps(GOOD | change).encode(), "ur5", "abb_rws")


def test_a_huge_or_non_object_document_is_refused() -> None:
    with pytest.raises(ValueError, match="bytes"):
        parse_bridge_stats(b" " * (MAX_PAYLOAD_BYTES + 1), "ur5", "abb_rws")
    with pytest.raises(ValueError, match="object"):
        parse_bridge_stats(b"[1, 2]", "ur5", "abb_rws")


class _Sample:
    def __init__(self, key: str, payload: bytes) -> None:
        self.key_expr = key
        self.payload = self

        self._bytes = payload

    def to_bytes(self) -> bytes:
        return self._bytes


def _bridged(cell_config: CellConfig) -> CellConfig:
    robot = cell_config.robots["ur5"]
    interface = {"kind": "abb_rws", "url": "http://127.0.0.3:8081", "password_env": "HRC_RWS_PASSWORD"}
    bridged = robot.model_validate(robot.model_dump() | {"interface": interface})
    return cell_config.model_copy(update={"robots": {"ur5": bridged}})


def test_the_view_shows_each_bridged_robot_and_counts_what_it_refuses(cell_config: CellConfig) -> None:
    view = BridgeView(_bridged(cell_config))
    before = view.snapshot()["ur5"]
    assert before.interface == "abb_rws"
    assert before.stats_age_s is None
    view.on_sample(_Sample("hrc/demo/robot/ur5/bridge_stats", json.dumps(GOOD).encode()))
    view.on_sample(_Sample("hrc/demo/robot/ur5/bridge_stats", b"{not json"))
    view.on_sample(_Sample("hrc/demo/robot/ur10/bridge_stats", json.dumps(GOOD).encode()))
    shown = view.snapshot()["ur5"]
    assert shown.readback == 0.42  # the invalid document after it kept the valid one
    assert shown.stats_age_s is not None
    assert dict(view.rejected) == {"invalid": 1, "unknown_robot": 1}


def test_a_cell_without_bridges_shows_none(cell_config: CellConfig) -> None:
    assert BridgeView(cell_config).snapshot() == {}
