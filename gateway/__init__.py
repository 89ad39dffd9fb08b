"""The safety gateway: delay-aware speed override for a closed robot controller."""

__all__ = [
    "core",
    "delay",
    "events",
    "http",
    "inputs",
    "iso15066",
    "kernels",
    "kinematics",
    "link_ends",
    "main",
    "methods",
    "node",
    "recording",
    "reference",
    "separation",
    "status",
    "tracks",
    "zones",
]
