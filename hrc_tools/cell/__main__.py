"""``python -m hrc_tools.cell`` (``hrc-cell``): :func:`hrc_tools.cell.launcher.cli`."""

from hrc_tools.cell.launcher import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
