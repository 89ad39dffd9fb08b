"""``python -m tracker_emu`` (``hrc-tracker-emu``): :func:`tracker_emu.main.cli`."""

from tracker_emu.main import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
