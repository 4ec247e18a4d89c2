"""A :class:`~acquisition.app.live.server.LiveServer` served on its own event loop in a background thread
(tests and ``msflash bench --part live``; ``msflash live`` serves on the main thread)."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Iterator

from msflash.acquisition.app.live.server import LiveServer


async def _let_closed_connections_finish() -> None:
    """A few turns of the loop: connections the runner closed at shutdown finish closing in callbacks it has queued
    (a transport's ``connection_lost``); a loop closed before them leaves their sockets open, each a
    ``ResourceWarning`` when collected (seen under load, with a page's keep-alive connections)."""
    for _ in range(3):
        await asyncio.sleep(0.01)


@contextlib.contextmanager
def serve_in_thread(server: LiveServer) -> Iterator[LiveServer]:
    """Serve ``server`` on its own event loop in a background thread while the block runs (tests, bench)."""
    loop = asyncio.new_event_loop()
    stop = asyncio.Event()
    started = threading.Event()
    failure: list[BaseException] = []

    def main() -> None:
        asyncio.set_event_loop(loop)

        async def run() -> None:
            started.set()
            await server.serve(stop)

        try:
            loop.run_until_complete(run())
        except BaseException as err:  # noqa: BLE001 - raised again in the caller's thread
            failure.append(err)
            started.set()
        finally:
            try:
                loop.run_until_complete(_let_closed_connections_finish())
            finally:
                loop.close()

    thread = threading.Thread(target=main, name="msflash-live", daemon=True)
    thread.start()
    started.wait()
    try:
        yield server
    finally:
        if not loop.is_closed():
            loop.call_soon_threadsafe(stop.set)
        thread.join(timeout=60)
        if failure:
            raise failure[0]
