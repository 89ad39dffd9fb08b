"""``python -m hrc_tools.router`` (``hrc-router``): :func:`hrc_tools.router.main.cli`."""

from hrc_tools.router.main import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
