"""``python -m hrc_tools.faultinject`` (``hrc-fault-relay``): :func:`hrc_tools.faultinject.relay.cli`."""

from hrc_tools.faultinject.relay import cli

__all__ = ["cli"]

if __name__ == "__main__":
    cli()
