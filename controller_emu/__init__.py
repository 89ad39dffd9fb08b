"""Emulator of a closed industrial controller: runs a pre-planned program and accepts only a speed override δ."""

__all__ = [
    "commissioning",
    "controller",
    "main",
    "node",
    "rtde_face",
    "rtde_outputs",
    "rws_face",
]
