"""A TCP relay that delays every byte by a settable time, both ways: a slow link to a controller's vendor face.

with TcpDelay(("127.0.0.1", 0), ("127.0.0.1", 8081)) as relay:   # relay.address: where clients connect
    relay.delay_s = 0.3                                          # from now on, each chunk waits 0.3 s
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections import deque
from types import TracebackType


class TcpDelay:
    """Accepts on ``listen`` and relays each connection to ``upstream``; every chunk read is sent ``delay_s`` after
    it arrived (the delay in force when it arrived), in order."""

    def __init__(self, listen: tuple[str, int], upstream: tuple[str, int]) -> None:
        self.upstream = upstream
        self.delay_s = 0.0
        self._server = socket.create_server(listen, reuse_port=False)
        self._server.settimeout(0.2)
        self.address: tuple[str, int] = self._server.getsockname()[:2]
        self._stop = threading.Event()
        self._sockets: list[socket.socket] = []
        self._threads = [threading.Thread(target=self._accept, daemon=True)]
        self._threads[0].start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._server.accept()
            except OSError:
                continue
            try:
                server = socket.create_connection(self.upstream, timeout=2.0)
            except OSError:
                client.close()
                continue
            for sock in (client, server):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.settimeout(0.2)
                self._sockets.append(sock)
            for a, b in ((client, server), (server, client)):
                queue: deque[tuple[float, bytes]] = deque()
                ready = threading.Condition()
                for target in (self._read, self._write):
                    thread = threading.Thread(target=target, args=(a, b, queue, ready), daemon=True)
                    thread.start()
                    self._threads.append(thread)

    def _read(
        self, src: socket.socket, dst: socket.socket, queue: deque[tuple[float, bytes]], ready: threading.Condition
    ) -> None:
        while not self._stop.is_set():
            try:
                chunk = src.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                chunk = b""
            with ready:
                queue.append((time.monotonic() + self.delay_s, chunk))
                ready.notify()
            if not chunk:
                return

    def _write(
        self, src: socket.socket, dst: socket.socket, queue: deque[tuple[float, bytes]], ready: threading.Condition
    ) -> None:
        while not self._stop.is_set():
            with ready:
                while not queue and not self._stop.is_set():
                    ready.wait(0.2)
                if not queue:
                    continue
                due_s, chunk = queue.popleft()
            time.sleep(max(0.0, due_s - time.monotonic()))
            if not chunk:
                with contextlib.suppress(OSError):
                    dst.shutdown(socket.SHUT_WR)
                return
            try:
                dst.sendall(chunk)
            except OSError:
                return

    def close(self) -> None:
        self._stop.set()
        self._server.close()
        for sock in self._sockets:
            with contextlib.suppress(OSError):
                sock.close()

    def __enter__(self) -> TcpDelay:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
