"""How any program runs: configuration finding and loading, robot model, clocks, the rate loop, command-line helpers,
logging, signals, real-time scheduling, sd_notify, the Zenoh session, access control, PKI, MCAP writing, and the
geometry every side shares (the robot's link capsules from its URDF: :mod:`link_motion`; segment distances in
numpy: :mod:`segments`).

Imports only hrc_contract of the project.
"""

__all__ = [
    "access_control",
    "cli",
    "clocks",
    "config",
    "link_motion",
    "locate",
    "logs",
    "mcap_sink",
    "pki",
    "rate_loop",
    "realtime",
    "robot_model",
    "sd_notify",
    "segments",
    "signals",
    "zenoh_session",
]
