"""``python -m controller_emu`` (``hrc-controller-emu``): :func:`controller_emu.main.cli`."""

from controller_emu.main import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
