"""Emulator of an industrial controller: closed (runs a pre-planned program and accepts only a speed override δ) or
open (follows the joint references the gateway streams, or an ABB EGM face's: `egm_face`)."""

__all__ = [
    "commissioning",
    "egm_face",
    "faces",
    "main",
    "node",
    "open_follower",
    "open_node",
    "rtde_face",
    "rtde_outputs",
    "rws_face",
]
