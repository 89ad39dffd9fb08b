"""The open controller emulator's loop with its EGM face, in a thread of the test process (no Zenoh)."""

from __future__ import annotations

import threading

from controller_emu.egm_face import EgmFace
from controller_emu.open_node import OpenControllerNode
from hrc_runtime.clocks import read_clocks
from hrc_runtime.rate_loop import RateLoop


class EmulatorLoop:
    """The emulator's open loop in a thread: ``node.cycle`` then ``face.on_cycle`` every ``cycle_s`` (as
    ``controller_emu.main`` runs it, without Zenoh)."""

    def __init__(self, node: OpenControllerNode, face: EgmFace) -> None:
        self.node, self.face = node, face
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="emulator-loop", daemon=True)

    def _run(self) -> None:
        rate = RateLoop(self.node.config.cycle_s)
        while rate.sleep(self.stop):
            self.face.on_cycle(self.node.cycle(read_clocks()))

    def __enter__(self) -> EmulatorLoop:
        self.face.start()
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(timeout=5.0)
        self.face.close()
