"""Emulator of an industrial controller: closed (runs a pre-planned program and accepts only a speed override δ) or
open (follows the joint references the gateway streams, as ABB's EGM)."""

__all__ = [
    "commissioning",
    "main",
    "node",
    "open_follower",
    "open_node",
    "rtde_face",
    "rtde_outputs",
    "rws_face",
]
