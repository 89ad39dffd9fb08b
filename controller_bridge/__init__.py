"""The controller bridge: the cell's Zenoh contract on one side, a real controller's vendor interface on the other.

A closed controller offers an outside PC one speed input and a read-back; it reports no override echo and no
programmed velocity. The bridge writes the gateway's δ to the controller, confirms an override only when the
controller's read-back shows it, derives the programmed velocity honestly, and publishes the robot's joint state
on the cell's key (docs/contract.md). An open controller (ABB EGM) takes joint references instead: the bridge
answers its feedback with the gateway's joint commands and publishes the joint state it reads
(:mod:`.open_bridge`, :mod:`.open_shell`). Both shells open their resources through :mod:`.shell`.
"""

__all__ = ["bridge", "main", "open_bridge", "open_shell", "program_model", "shell"]
