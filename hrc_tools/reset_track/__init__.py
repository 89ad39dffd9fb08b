"""``hrc-reset-track``: an operator releases a lost track (authenticated, over Zenoh)."""

__all__ = [
    "main",
]
