"""Communication fault injection on real Zenoh traffic between real processes."""

__all__ = [
    "delay_line",
    "relay",
    "rules",
]
