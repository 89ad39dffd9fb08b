"""``hrc-cert``: the cell's certificate authority and the programs' certificates."""

__all__ = [
    "main",
]
