"""Fixtures of the booth tests: the emulator on a real pty, a manual clock, transcript replay."""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from msflash.led_controller import LedBooth, ManualClock, PtyBoothServer, serve_on_pty

TRANSCRIPTS = Path(__file__).resolve().parents[1] / "data" / "transcripts"


@pytest.fixture
def clock() -> ManualClock:
    """A clock that moves only when the test advances it."""
    return ManualClock()


@pytest.fixture
def booth_on_pty(clock: ManualClock) -> Iterator[PtyBoothServer]:
    """The default 7-channel emulator on a real pseudo-terminal, driven by ``clock``."""
    server = serve_on_pty(clock=clock)
    try:
        yield server
    finally:
        server.close()


@pytest.fixture
def booth(booth_on_pty: PtyBoothServer) -> Iterator[LedBooth]:
    """A driver connected to ``booth_on_pty`` (closed, not switched off, at teardown)."""
    driver = LedBooth.open(booth_on_pty.port, timeout_s=2.0)
    try:
        yield driver
    finally:
        driver.close()


@pytest.fixture
def wait_until() -> Callable[[Callable[[], bool]], None]:
    """Poll a condition that another thread makes true (tiny waits, generous bound)."""

    def _wait(condition: Callable[[], bool], bound_s: float = 5.0) -> None:
        deadline = time.monotonic() + bound_s
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f"condition {condition} not reached within {bound_s} s")
            time.sleep(0.001)

    return _wait


class ReplayPort:
    """A scripted serial port that plays the booth's side of a transcript.

    Each write must equal the next ``>`` line; the ``<`` and ``!`` lines that follow it are
    then served to the reader. Anything unexpected raises ``AssertionError`` at once, with
    the expected and the actual bytes; :meth:`assert_done` fails on anything left over.
    """

    name = "replay"

    def __init__(self, lines: list[tuple[str, bytes]]) -> None:
        self._script = collections.deque(lines)
        self._pending = bytearray()
        self._cv = threading.Condition()
        self.unexpected: list[str] = []
        with self._cv:
            self._release()

    @classmethod
    def from_file(cls, path: Path) -> ReplayPort:
        lines = []
        for number, text in enumerate(path.read_text(encoding="ascii").splitlines(), 1):
            if not text or text.startswith("#"):
                continue
            mark, _, frame = text.partition(" ")
            if mark not in (">", "<", "!"):
                raise ValueError(f"{path}:{number}: line starts with {mark!r}; expected '>', '<' or '!'")
            lines.append((mark, frame.encode("ascii") + b"\n"))
        return cls(lines)

    def _release(self) -> None:
        while self._script and self._script[0][0] in ("<", "!"):
            self._pending += self._script.popleft()[1]
        self._cv.notify_all()

    @property
    def in_waiting(self) -> int:
        with self._cv:
            return len(self._pending)

    def write(self, data: bytes) -> int:
        with self._cv:
            if not self._script:
                self.unexpected.append(f"unexpected write {data!r} after the end of the transcript")
                raise AssertionError(self.unexpected[-1])
            mark, expected = self._script[0]
            if mark != ">" or expected != data:
                self.unexpected.append(f"expected {mark} {expected!r}, got > {data!r}")
                raise AssertionError(self.unexpected[-1])
            self._script.popleft()
            self._release()
        return len(data)

    def read(self, size: int = 1) -> bytes:
        with self._cv:
            if not self._pending:
                self._cv.wait(0.02)
            out = bytes(self._pending[:size])
            del self._pending[:size]
            return out

    def flush(self) -> None:
        pass

    def cancel_read(self) -> None:
        with self._cv:
            self._cv.notify_all()

    def close(self) -> None:
        pass

    def assert_done(self) -> None:
        """Fail if any line of the transcript was not consumed or any write was unexpected."""
        with self._cv:
            left = list(self._script)
            unread = bytes(self._pending)
        assert not self.unexpected, self.unexpected
        assert not left, f"transcript lines not consumed: {left[:3]}"
        assert not unread, f"booth output not read by the driver: {unread!r}"


@pytest.fixture
def replay_port() -> type[ReplayPort]:
    """The :class:`ReplayPort` class (build one from a transcript file or a list of lines)."""
    return ReplayPort


@pytest.fixture
def transcripts_dir() -> Path:
    """Directory of the recorded transcripts."""
    return TRANSCRIPTS
