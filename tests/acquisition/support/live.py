"""What the live view's tests share: a sim rig served by a :class:`LiveServer` in a background thread."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from msflash.acquisition.app.live.in_thread import serve_in_thread
from msflash.acquisition.app.live.requests import bind
from msflash.acquisition.app.live.server import LiveServer
from msflash.acquisition.session.rig import open_rig


@contextlib.contextmanager
def live_server(runs: Path, **options: Any) -> Iterator[LiveServer]:
    """A sim rig (booth emulator on a pty) and its live server on 127.0.0.1 at a free port."""
    sock = bind("127.0.0.1", 0)
    try:
        with open_rig("sim") as rig:
            server = LiveServer(rig, runs, sock, **options)
            with serve_in_thread(server):
                yield server
    finally:
        sock.close()


def wait_until(condition: Callable[[], Any], what: str, timeout_s: float = 30.0) -> Any:
    """Poll ``condition`` until it is truthy; fail naming ``what`` after ``timeout_s`` (a hang guard, not a timing)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def emulator_levels(server: LiveServer) -> tuple[float, ...]:
    """The levels the booth emulator at the far end of the pty holds (not what the server believes)."""
    emulator = server.rig.emulator
    assert emulator is not None
    return tuple(emulator.levels)
