"""What the gateway shows of the controller bridges: the newest statistics each bridge puts on
``hrc/<cell>/robot/<robot>/bridge_stats`` (interface, read-back value and latency), for the status only.

    view = BridgeView(config)                       # the robots whose interface is ur_rtde or abb_rws
    session.declare_subscriber(view.key, view.on_sample)
    view.snapshot(now_mono_ns)                      # → {robot: BridgeStatus}, for the status document

Nothing here feeds a decision: the gateway measures the override path itself from the echoed ``override_seq``.
A statistics document is checked like any input (size, JSON, fields, ranges); one that is not valid is counted and
dropped, the previous one is kept and ages.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import Counter
from collections.abc import Mapping
from typing import Any

from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.status_models import BridgeStatus

MAX_PAYLOAD_BYTES = 8192
"""A statistics document larger than this is refused [bytes]."""


def _number(doc: Mapping[str, Any], name: str, upper: float = math.inf) -> float | None:
    """``doc[name]`` if a finite number in [0, upper], None if absent or null.

    Raises:
        ValueError: any other value.
    """
    value = doc.get(name)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= upper:
        raise ValueError(f"{name} = {value!r}; allowed: a number in [0, {upper}] or null")
    return float(value)


def parse_bridge_stats(payload: bytes, robot: str, interface: str) -> dict[str, Any]:
    """The :class:`BridgeStatus` fields of one statistics document (without ``stats_age_s``).

    Raises:
        ValueError: too large, not a JSON object, another robot or interface, or a field out of range.
    """
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise ValueError(f"{len(payload)} bytes; allowed: at most {MAX_PAYLOAD_BYTES}")
    doc = json.loads(payload)
    if not isinstance(doc, dict):
        raise ValueError("not a JSON object")
    if doc.get("robot") != robot or doc.get("interface") != interface:
        raise ValueError(
            f"robot {doc.get('robot')!r}, interface {doc.get('interface')!r}; allowed: {robot!r}, {interface!r}"
        )
    mode = doc.get("mode")
    if mode is not None and not (isinstance(mode, str) and len(mode) <= 32):
        raise ValueError(f"mode {str(mode)[:40]!r}; allowed: a short string or null")
    rejected = doc.get("rejected", {})
    if not isinstance(rejected, dict) or not all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in rejected.values()
    ):
        raise ValueError("rejected: allowed: an object of counts")
    return {
        "interface": interface,
        "mode": mode,
        "readback": _number(doc, "readback", 1.0),
        "readback_latency_s": _number(doc, "readback_latency_s"),
        "readback_latency_max_s": _number(doc, "readback_latency_max_s"),
        "readings_per_s": _number(doc, "readings_per_s"),
        "rejected": sum(rejected.values()),
    }


class BridgeView:
    """The newest valid statistics of each bridged robot of the cell (any thread may call any method)."""

    def __init__(self, config: CellConfig) -> None:
        self.key = keys.robot_bridge_stats(config.cell, "*")
        self.interfaces = {
            name: robot.interface.kind for name, robot in config.robots.items() if robot.interface.kind != "zenoh"
        }
        self.rejected: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._newest: dict[str, tuple[dict[str, Any], int]] = {}

    def on_sample(self, sample: Any) -> None:
        """The subscriber's callback: check and store; never raises."""
        robot = keys.name_from_key(str(sample.key_expr), "robot")
        if robot not in self.interfaces:
            with self._lock:
                self.rejected["unknown_robot"] += 1
            return
        try:
            fields = parse_bridge_stats(sample.payload.to_bytes(), robot, self.interfaces[robot])
        except (ValueError, TypeError):
            with self._lock:
                self.rejected["invalid"] += 1
            return
        with self._lock:
            self._newest[robot] = (fields, time.monotonic_ns())

    def snapshot(self, now_mono_ns: int | None = None) -> dict[str, BridgeStatus]:
        """Every bridged robot's entry: its newest statistics and their age (nulls before any)."""
        now_ns = time.monotonic_ns() if now_mono_ns is None else now_mono_ns
        with self._lock:
            newest = dict(self._newest)
        out = {}
        for robot, interface in self.interfaces.items():
            if robot in newest:
                fields, received_ns = newest[robot]
                out[robot] = BridgeStatus(**fields, stats_age_s=round(max(0, now_ns - received_ns) / 1e9, 3))
            else:
                out[robot] = BridgeStatus.model_validate(
                    {"interface": interface, "stats_age_s": None, "mode": None, "readback": None}
                    | {"readback_latency_s": None, "readback_latency_max_s": None, "readings_per_s": None}
                    | {"rejected": 0}
                )
        return out
