"""What the live view's tests share: a sim rig served by a :class:`LiveServer` in a background thread
(:func:`serve_in_thread`; ``msflash live`` serves on the main thread)."""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from msflash.acquisition.app.live.requests import bind
from msflash.acquisition.app.live.server import LiveServer
from msflash.acquisition.session.rig import open_rig


async def _let_closed_connections_finish() -> None:
    """A few turns of the loop: connections the runner closed at shutdown finish closing in callbacks it has queued
    (a transport's ``connection_lost``); a loop closed before them leaves their sockets open, each a
    ``ResourceWarning`` when collected (seen under load, with a page's keep-alive connections)."""
    for _ in range(3):
        await asyncio.sleep(0.01)


@contextlib.contextmanager
def serve_in_thread(server: LiveServer) -> Iterator[LiveServer]:
    """Serve ``server`` on its own event loop in a background thread while the block runs ."""
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


def start_live_process(tmp_path: Path) -> tuple[subprocess.Popen, str, Path]:
    """``msflash live --port 0`` in a subprocess (sim rig, the booth transcript logged): the process,
    the page's URL (printed once the rig is open and the socket listens) and the transcript's path."""
    transcript = tmp_path / "serial.log"
    command = [sys.executable, "-m", "msflash.acquisition.app.cli", "live", "--port", "0"]
    command += ["--runs", str(tmp_path / "runs"), "--log-serial", str(transcript)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert process.stdout is not None
    return process, process.stdout.readline().strip(), transcript


def page_token(page: str) -> str:
    """The session token the live page carries."""
    return page.split('name="msflash-token" content="')[1].split('"')[0]


def stopped_with_the_leds_off(transcript: Path) -> bool:
    """Whether the booth transcript sends OFF after the last SET (what a stopping live view must do)."""
    sent = [line for line in transcript.read_text().splitlines() if line.startswith(">")]
    last_set = max(i for i, line in enumerate(sent) if ":SET " in line)
    return any(":OFF*" in line for line in sent[last_set + 1 :])
