"""A planner that never answers (a library stuck in a loop), for the planner process's hang test: importable by the
spawned child, which unpickles it by its module name."""

from __future__ import annotations

import time
from typing import Any


class HangingPlanner:
    """Takes a request and sleeps for ever."""

    def solve(self, request: Any) -> Any:
        while True:
            time.sleep(3600.0)
