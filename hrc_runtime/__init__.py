"""How any program runs, and nothing else: configuration finding and loading, clocks, the rate loop, the newest-wins
ring, command-line helpers, logging, signals, real-time scheduling, memory, sd_notify, the Zenoh session, access
control, PKI, MCAP writing. What programs know of the devices (robots, controllers, trackers, ROS 2) is
``hrc_devices``.

Imports only hrc_contract of the project.
"""

__all__ = [
    "access_control",
    "cli",
    "clocks",
    "config",
    "locate",
    "logs",
    "mcap_sink",
    "memory",
    "newest_wins",
    "pki",
    "rate_loop",
    "realtime",
    "sd_notify",
    "signals",
    "zenoh_session",
]
