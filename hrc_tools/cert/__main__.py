"""``python -m hrc_tools.cert`` (``hrc-cert``): :func:`hrc_tools.cert.main.cli`."""

from hrc_tools.cert.main import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
