"""``python -m hrc_tools.record`` (``hrc-record``): :func:`hrc_tools.record.cell.cli`."""

from hrc_tools.record.cell import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
