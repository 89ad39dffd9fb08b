"""``python -m hrc_tools.reset_track`` (``hrc-reset-track``): :func:`hrc_tools.reset_track.main.cli`."""

from hrc_tools.reset_track.main import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
