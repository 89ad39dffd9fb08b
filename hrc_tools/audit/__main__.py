"""``python -m hrc_tools.audit`` (``hrc-audit``): :func:`hrc_tools.audit.main.cli`."""

from hrc_tools.audit.main import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
