"""Zenoh key expressions of the contract (`docs/contract.md`, "Zenoh key expressions")."""

from __future__ import annotations


def robot_state(cell: str, robot: str) -> str:
    return f"hrc/{cell}/robot/{robot}/state"


def robot_override(cell: str, robot: str) -> str:
    return f"hrc/{cell}/robot/{robot}/override"


def robot_joint_command(cell: str, robot: str) -> str:
    """Joint references for an open controller (``control = "open"``), ``hrc.joint_command/1``."""
    return f"hrc/{cell}/robot/{robot}/joint_command"


def robot_emu_stats(cell: str, robot: str) -> str:
    """Controller emulator statistics (program cycles completed, rejections); not part of a real controller."""
    return f"hrc/{cell}/robot/{robot}/emu_stats"


def robot_bridge_stats(cell: str, robot: str) -> str:
    """Controller bridge statistics (interface, read-back value and latency); for display, never for decisions."""
    return f"hrc/{cell}/robot/{robot}/bridge_stats"


def tracker_humans(cell: str, tracker: str) -> str:
    return f"hrc/{cell}/tracker/{tracker}/humans"


def gateway_subscriptions(cell: str) -> tuple[str, str]:
    """What the gateway reads: every robot's joint state and every tracker's humans (never the truth keys)."""
    return f"hrc/{cell}/robot/*/state", f"hrc/{cell}/tracker/*/humans"


def gateway_status(cell: str) -> str:
    return f"hrc/{cell}/gateway/status"


def operator_track_reset(cell: str) -> str:
    """Where the operator station puts ``hrc.track_reset/1`` (read by the gateway)."""
    return f"hrc/{cell}/operator/track_reset"


def truth_robot_state(cell: str, robot: str) -> str:
    """Ground truth of the controller emulator (true joint state each cycle); never read by the gateway."""
    return f"hrc/{cell}/truth/robot/{robot}/state"


def truth_humans(cell: str) -> str:
    """Ground truth of the tracker emulator (true capsules, before noise, drops and latency)."""
    return f"hrc/{cell}/truth/humans"


def alive(cell: str, component: str) -> str:
    return f"hrc/{cell}/alive/{component}"


def name_from_key(key: str, kind: str) -> str | None:
    """The robot or tracker name in ``hrc/<cell>/<kind>/<name>/...``, or None if the key is not of that kind."""
    parts = key.split("/")
    if len(parts) >= 5 and parts[0] == "hrc" and parts[2] == kind:
        return parts[3]
    return None
