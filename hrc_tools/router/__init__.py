"""``hrc-router``: a Zenoh router for a cell spread over several machines."""

__all__ = [
    "main",
]
