"""The protocol's 1024-byte body limit (docs/booth-protocol.md §2), enforced by the driver and the emulator.

An over-long line is one framing error and the receiver picks up again at the next terminator: it is
never buffered whole, and its tail is not read as a second bad frame.
"""

from __future__ import annotations

import os
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from msflash.led_controller import BoothEmulator, BoothProtocolError, BoothTimeoutError, LedBooth
from msflash.led_controller.protocol import MAX_BODY, MAX_LINE, crc16, encode_frame, encode_request, frame_problem


def _frame_with_body(mark: bytes, body: bytes) -> bytes:
    head = mark + b"01:%03X:" % len(body) + body
    return head + b"*%04X" % crc16(head)


def test_a_body_past_1024_bytes_is_a_framing_error_even_with_its_length_and_checksum_right() -> None:
    assert frame_problem(_frame_with_body(b"=", b"A" * MAX_BODY)) is None
    line = _frame_with_body(b"=", b"A" * (MAX_BODY + 1))
    assert len(line) <= MAX_LINE  # the line fits; only the body limit refuses it
    assert frame_problem(line) == f"body of {MAX_BODY + 1} bytes is longer than {MAX_BODY}"


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


EVENT_WAIT_S = 60.0
"""Wait for an event the test already wrote: only a failure waits this long (the driver's 0.2 s
command timeout is too short for its reader thread to get 20 KB through a pty on a loaded host)."""


@pytest.fixture
def booth_and_wire(tmp_path: Path) -> Iterator[tuple[LedBooth, int]]:
    """A driver on one end of a raw pty, its transcript in ``tmp_path``; the test writes the booth's side."""
    master, slave = os.openpty()
    tty.setraw(slave)
    port = serial.Serial(os.ttyname(slave), timeout=0.02)
    booth = LedBooth(port, timeout_s=0.2, log_serial=tmp_path / "transcript.txt")
    try:
        yield booth, master
    finally:
        booth.close()
        os.close(master)
        os.close(slave)


def test_the_driver_reads_an_over_long_line_as_one_error_and_resynchronises(
    booth_and_wire: tuple[LedBooth, int], tmp_path: Path
) -> None:
    booth, wire = booth_and_wire
    _write_all(wire, b"!" + b"A" * 20_000 + b"\n")  # several reads' worth (4096 bytes each) before its end
    _write_all(wire, encode_frame("!", 1, "TRIG 1 0"))
    with pytest.raises(BoothProtocolError, match=f"longer than {MAX_LINE}"):
        booth.wait_event(timeout_s=EVENT_WAIT_S)
    event = booth.wait_event(timeout_s=EVENT_WAIT_S)
    assert (event.kind, event.args) == ("TRIG", ("1", "0"))
    with pytest.raises(BoothTimeoutError):
        booth.wait_event(timeout_s=0.1)
    # Two lines received: the over-long one, cut at MAX_LINE + 1 bytes, and the event. Its tail, read
    # after the cut, was dropped, not taken for more bad frames.
    received = [line for line in (tmp_path / "transcript.txt").read_text().splitlines() if line[0] in "<!"]
    assert [len(line) - 2 for line in received] == [MAX_LINE + 1, len(encode_frame("!", 1, "TRIG 1 0")) - 1]


def test_the_driver_refuses_an_event_whose_body_passes_the_limit(booth_and_wire: tuple[LedBooth, int]) -> None:
    booth, wire = booth_and_wire
    os.write(wire, _frame_with_body(b"!", b"TRIG 1 0" + b" " * MAX_BODY) + b"\n")
    with pytest.raises(BoothProtocolError, match=f"body of {MAX_BODY + 8} bytes is longer than {MAX_BODY}"):
        booth.wait_event(timeout_s=EVENT_WAIT_S)


def test_the_emulator_answers_an_over_long_line_once_and_reads_the_next_request() -> None:
    emulator = BoothEmulator()
    out: list[bytes] = []
    emulator.connect_output(out.append)
    data = b"?" + b"A" * (3 * MAX_LINE) + b"\n" + encode_request(2, "PING")
    for start in range(0, len(data), 100):  # as a serial link delivers it, in pieces
        emulator.receive(data[start : start + 100])
    assert [line.split(b"*")[0] for line in out] == [b"=00:019:ERR - E_LEN line too long", b"=02:007:OK PING"]


def test_the_emulator_refuses_channel_names_whose_identify_reply_would_not_fit() -> None:
    names = [f"led{i:02d}_{'x' * 20}" for i in range(40)]
    with pytest.raises(ValueError, match=f"ID reply would be .* bytes, over the protocol's {MAX_BODY}"):
        BoothEmulator(names=names, peaks_nm=[400.0 + i for i in range(40)])
