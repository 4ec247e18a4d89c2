"""Property tests: the parsers of both sides only ever raise protocol errors, never crash or
act on a damaged frame."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msflash.led_controller import (
    BoothProtocolError,
    BoothTimeoutError,
    LedBooth,
    PtyBoothServer,
    protocol,
    serve_on_pty,
)
from msflash.led_controller.emulator import BoothEmulator
from tests.helpers import levels_close

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

level = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
levels7 = st.lists(level, min_size=7, max_size=7)


def _set_request(levels: list[float]) -> bytes:
    return protocol.encode_request(1, protocol.Command.SET, *protocol.encode_levels(levels, 7))


def _damaged(frame: bytes, data: st.DataObject) -> bytes:
    """``frame`` (without terminator) with one bit flipped or one byte dropped somewhere."""
    index = data.draw(st.integers(0, len(frame) - 1), label="index")
    if data.draw(st.booleans(), label="drop"):
        return frame[:index] + frame[index + 1 :]
    bit = data.draw(st.integers(0, 7), label="bit")
    return frame[:index] + bytes([frame[index] ^ (1 << bit)]) + frame[index + 1 :]


@FUZZ
@given(st.binary(max_size=200))
def test_driver_parser_on_arbitrary_bytes(line: bytes) -> None:
    try:
        frame = protocol.parse_frame(line)
    except BoothProtocolError as err:
        assert err.raw == line
    else:
        assert protocol.encode_frame(frame.mark, frame.seq, frame.body) == line + b"\n"


@FUZZ
@given(levels7, st.data())
def test_driver_parser_rejects_every_single_fault(levels: list[float], data: st.DataObject) -> None:
    frame = _set_request(levels)[:-1]
    with pytest.raises(BoothProtocolError):
        protocol.parse_frame(_damaged(frame, data))


class _Capture:
    def __init__(self) -> None:
        self.out = bytearray()

    def __call__(self, data: bytes) -> None:
        self.out += data

    def replies(self) -> list[protocol.Reply]:
        lines = bytes(self.out).split(b"\n")[:-1]
        frames = [protocol.parse_frame(line) for line in lines]  # the booth's output is always valid
        return [protocol.parse_reply(f, f.body.split(" ")[1]) for f in frames]


def _emulator() -> tuple[BoothEmulator, _Capture]:
    emulator = BoothEmulator(clock=lambda: 0.0)
    capture = _Capture()
    emulator.connect_output(capture)
    emulator.receive(_set_request([0.25] * 7))
    capture.out.clear()
    return emulator, capture


@FUZZ
@given(st.binary(max_size=200).filter(lambda b: b"\n" not in b))
def test_emulator_parser_on_arbitrary_bytes(line: bytes) -> None:
    emulator, capture = _emulator()
    emulator.receive(line + b"\n")
    assert levels_close(emulator.levels, [0.25] * 7)
    replies = capture.replies()
    assert len(replies) == 1 and not replies[0].ok


@FUZZ
@given(levels7, st.data())
def test_emulator_never_acts_on_a_damaged_set(levels: list[float], data: st.DataObject) -> None:
    emulator, capture = _emulator()
    damaged = _damaged(_set_request(levels)[:-1], data)
    emulator.receive(damaged + b"\n")
    assert levels_close(emulator.levels, [0.25] * 7)
    replies = capture.replies()
    # A flipped bit can make a newline (0x2A '*' → 0x0A): the link then carries two lines, each refused.
    assert len(replies) == damaged.count(b"\n") + 1
    assert all(not reply.ok and reply.code in protocol.FRAME_ERROR_CODES for reply in replies)


@pytest.fixture(scope="module")
def shared_booth() -> Iterator[tuple[PtyBoothServer, LedBooth]]:
    server = serve_on_pty(clock=lambda: 0.0)
    booth = LedBooth.open(server.port, timeout_s=2.0)
    try:
        yield server, booth
    finally:
        booth.close()
        server.close()


@settings(max_examples=60, deadline=None)
@given(levels7)
def test_levels_round_trip_over_the_pty(shared_booth: tuple[PtyBoothServer, LedBooth], levels: list[float]) -> None:
    server, booth = shared_booth
    booth.set_levels(levels)
    assert levels_close(server.emulator.levels, levels)


class _OneReplyPort:
    """Answers the first request with a given line, then nothing."""

    name = "fuzz"

    def __init__(self, reply: bytes) -> None:
        self._reply = reply
        self._pending = b""

    in_waiting = property(lambda self: len(self._pending))

    def write(self, data: bytes) -> int:
        self._pending, self._reply = self._reply, b""
        return len(data)

    def read(self, size: int = 1) -> bytes:
        if not self._pending:
            time.sleep(0.001)  # a real port blocks for its timeout; do not spin the reader
        out, self._pending = self._pending[:size], self._pending[size:]
        return out

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


@settings(max_examples=40, deadline=None)
@given(st.data())
def test_driver_never_returns_a_damaged_status(data: st.DataObject) -> None:
    good = protocol.encode_frame(
        "=", 1, "OK STAT STATE=IDLE MODE=- STEP=-1 STEPS=0 TRIG=0 WDOG=3000 ERR=- BAD=0 LEVELS=8000,4000"
    )
    # Damage the frame, not its terminator: a lost terminator only delays the error to the timeout.
    reply = _damaged(good[:-1], data) + b"\n"
    booth = LedBooth(_OneReplyPort(reply), timeout_s=0.05)
    try:
        with pytest.raises((BoothProtocolError, BoothTimeoutError)):
            booth.status()
    finally:
        booth.close()
