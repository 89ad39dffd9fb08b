"""A Zenoh subscriber's messages kept for a test to inspect."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import zenoh


class Recorder:
    """Messages received by a subscriber callback, parsed by ``parse``, kept under a lock."""

    def __init__(self, parse: Callable[[bytes], Any]) -> None:
        self._parse = parse
        self._lock = threading.Lock()
        self._items: list[Any] = []

    def on_sample(self, sample: zenoh.Sample) -> None:
        item = self._parse(sample.payload.to_bytes())
        with self._lock:
            self._items.append(item)

    def items(self) -> list[Any]:
        with self._lock:
            return list(self._items)

    def latest(self) -> Any:
        with self._lock:
            return self._items[-1] if self._items else None
