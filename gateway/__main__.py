"""``python -m gateway`` (``hrc-gateway``): :func:`gateway.main.cli`."""

from gateway.main import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
