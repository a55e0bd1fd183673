"""A scripted daemon on a real Unix socket, for tests of the operator's commands."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path


class ScriptedDaemon:
    """A Unix socket that answers each request line with the next scripted reply, and
    records the requests' commands: the daemon's side of the operator's commands."""

    def __init__(self, path: Path, replies: list[dict[str, object]]) -> None:
        self.requests: list[str] = []
        self._replies = iter(replies)
        self._server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._server.bind(str(path))
        self._server.listen(4)
        self._server.settimeout(0.05)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                connection, _ = self._server.accept()
            except TimeoutError:
                continue
            connection.settimeout(5.0)
            with connection, connection.makefile("rwb") as stream:
                for line in stream:
                    self.requests.append(json.loads(line)["cmd"])
                    stream.write(json.dumps({"ok": True, **next(self._replies)}).encode()
                                 + b"\n")
                    stream.flush()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self._server.close()
