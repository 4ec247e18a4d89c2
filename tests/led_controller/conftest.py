"""Fixtures of the booth tests: the emulator on a real pty, a manual clock, transcript replay."""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from msflash.led_controller import BoothEmulator, LedBooth, ManualClock, PtyBoothServer, serve_on_pty
from msflash.led_controller.firmware_sim import (
    BUILD_DIR,
    ELF,
    SimulatedBooth,
    TriggerPulse,
    build,
    toolchain_missing,
)

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


# -- one protocol suite, two far ends: the Python emulator and the firmware in simavr --------


@dataclass
class FarEnd:
    """What a protocol test needs of the booth at the far end of the pty, whichever it is.

    ``kind`` is ``"emulator"`` (BoothEmulator on a manual clock) or ``"firmware"`` (the AVR
    image in simavr, on simulated time paced to the wall clock). ``pulses`` lists trigger-output
    pulses as :class:`~led_controller.firmware_sim.TriggerPulse`; the emulator has no notion of
    when its levels changed, so its ``settled_us`` is None (its settle is tested on the manual
    clock in test_booth_emulator.py).
    """

    kind: str
    port: str
    levels_now: Callable[[], tuple[float, ...]]
    exposure_active: Callable[[bool], None]
    advance: Callable[[float], None]
    pulses_now: Callable[[], list[TriggerPulse]]
    emulator: BoothEmulator | None = None
    """The emulator (``kind`` emulator), for its drive model."""
    sim: SimulatedBooth | None = None
    """The harness (``kind`` firmware), for exposure windows over the LED pins."""

    @property
    def levels(self) -> tuple[float, ...]:
        return self.levels_now()

    @property
    def pulses(self) -> list[TriggerPulse]:
        return self.pulses_now()

    def camera_strobe(self) -> None:
        self.exposure_active(True)
        self.exposure_active(False)


@pytest.fixture(scope="session")
def firmware_image() -> Path:
    """The firmware built with make (skips when the AVR toolchain is not installed)."""
    reason = toolchain_missing()
    if reason:
        pytest.skip(reason)
    build()
    return ELF


SMALL_TOP = (1 << 12) - 1
"""PWM TOP of the small test image (12-bit drive)."""


@pytest.fixture(scope="session")
def small_image(firmware_image: Path) -> Path:
    """The 2-channel, 12-bit, 4-step test image, channels uv and ir (``make sim`` builds it with ``firmware_image``)."""
    return BUILD_DIR / "booth_small.elf"


@pytest.fixture(params=["emulator", "firmware"])
def far_end(request: pytest.FixtureRequest, clock: ManualClock) -> Iterator[FarEnd]:
    """The booth at the far end of a real pty: the emulator, then the firmware in simavr."""
    if request.param == "emulator":
        server = serve_on_pty(clock=clock)
        pulses: list[TriggerPulse] = []
        emulator = server.emulator
        emulator.on_trigger_out = lambda count: pulses.append(TriggerPulse(int(clock() * 1e6), None, emulator.levels))
        try:
            yield FarEnd(
                "emulator",
                server.port,
                lambda: emulator.levels,
                emulator.exposure_active,
                clock.advance,
                lambda: list(pulses),
                emulator=emulator,
            )
        finally:
            server.close()
    else:
        request.getfixturevalue("firmware_image")
        with SimulatedBooth() as sim:
            yield FarEnd(
                "firmware", sim.port, lambda: sim.levels, sim.exposure_active, sim.advance, lambda: sim.pulses, sim=sim
            )


@pytest.fixture
def far_booth(far_end: FarEnd) -> Iterator[LedBooth]:
    """A driver connected to ``far_end`` (closed, not switched off, at teardown)."""
    driver = LedBooth.open(far_end.port, timeout_s=2.0)
    try:
        yield driver
    finally:
        driver.close()
