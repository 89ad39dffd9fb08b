"""``python -m hrc_tools.sim`` (``hrc-sweep``): :func:`hrc_tools.sim.sweep.cli`."""

from hrc_tools.sim.sweep import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
