"""``python -m controller_bridge``: the same as ``hrc-controller-bridge``."""

from controller_bridge.main import cli

cli()
