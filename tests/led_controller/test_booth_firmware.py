"""The firmware in simavr answers raw frames byte for byte as the emulator does.

The same script of requests (valid, refused and damaged) goes over a real pty to the emulator
and to the firmware image in simavr; every reply and event line must be identical. Skipped only
when the AVR toolchain is missing (``firmware_image`` fixture).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msflash.led_controller import ManualClock, serve_on_pty
from msflash.led_controller.booth_probe import await_boot_banner
from msflash.led_controller.emulator import BoothEmulator
from msflash.led_controller.emulator_wire import firmware_crc
from msflash.led_controller.firmware_sim import SimulatedBooth
from msflash.led_controller.protocol import MAX_LINE, encode_frame, encode_levels, encode_request
from tests.helpers import levels_close

from .conftest import SMALL_TOP

FIRMWARE = "msflash-avr-0.1"
L7 = ["1234"] * 7


def _framed(head: bytes) -> bytes:
    """``head`` with a correct CRC and terminator, whatever its layout."""
    return head + b"*%04X\n" % firmware_crc(head)


def _script() -> list[bytes]:
    requests: list[tuple[str, list[object]]] = [
        ("WDOG", ["600000"]),
        ("ID", []),
        ("SERIAL", []),  # never set: '-'
        ("SERIAL", ["bench-A_1.2"]),
        ("ID", []),  # SERIAL= last
        ("SERIAL", ["a", "b"]),
        ("SERIAL", ["-"]),
        ("SERIAL", ["x" * 33]),
        ("SERIAL", ["caf\u00e9".encode("ascii", "replace").decode()]),  # '?' is not allowed
        ("STAT", []),
        ("ID", ["x"]),
        ("SET", L7),
        ("SET", L7[:6]),
        ("SET", ["ffff"] * 7),
        ("SET", ["12345"] + L7[:6]),
        ("STAT", []),
        ("START", []),
        ("NEXT", []),
        ("ARM", ["CAMERA", "0", "0", "0"]),
        ("PADD", ["0100"] * 7),
        ("PADD", ["FFFF"] * 7),
        ("PADD", L7 + ["HOLD"]),
        ("PADD", L7 + ["HOLX"]),
        ("PSET", ["9"] + L7),
        ("PSET", ["x"] + L7),
        ("PSET", ["123456"] + L7),
        ("PSET", ["1"] + L7 + ["NOW"]),
        ("ARM", ["FOO", "0", "0", "0"]),
        ("ARM", ["BOOTH", "100", "100", "150"]),
        ("ARM", ["BOOTH", "0", "0", "0"]),
        ("ARM", ["CAMERA", "123456789", "0", "0"]),
        ("ARM", ["HOST", "0", "0"]),
        ("ARM", ["HOST", "0", "0", "0"]),
        ("SERIAL", ["while-armed"]),  # E_STATE: an EEPROM write stalls the MCU for ms
        ("PCLR", []),
        ("SET", L7),
        ("START", []),
        ("START", []),
        ("SET", ["0000"] * 7),
        ("NEXT", []),
        ("CNT", []),
        ("NEXT", []),
        ("NEXT", []),
        ("PSET", ["2"] + ["0800"] * 7),
        ("PSET", ["0"] + L7),
        ("NEXT", []),
        ("STAT", []),
        ("NEXT", []),
        ("NEXT", []),
        ("CNT", []),
        ("STAT", []),
        ("WDOG", ["49"]),
        ("WDOG", ["abc"]),
        ("WDOG", ["50"]),
        ("WDOG", ["600001"]),
        ("WDOG", ["0"]),
        ("PING", ["x"]),
        ("FOO", ["1"]),
        ("OFF", []),
        # pulse dimming: EXP= on PADD/PSET, the ON= on-times (exact, to the timer tick), ROLL
        ("PADD", ["8000"] * 7 + ["EXP=100"]),
        ("PADD", ["0148", "FFFF", "0000", "E666", "8000", "0001", "FFFE", "EXP=5000", "HOLD"]),
        ("PADD", ["0148", "1234", "0000", "E666", "8000", "0001", "FFFE", "EXP=123456"]),
        ("PADD", ["8000"] * 7 + ["EXP=4194304"]),
        ("PADD", ["8000"] * 7 + ["EXP=99999999"]),
        ("PADD", ["8000"] * 7 + ["EXP=15"]),
        ("PADD", ["8000"] * 7 + ["EXP=0"]),
        ("PADD", ["8000"] * 7 + ["EXP=12x"]),
        ("PADD", ["8000"] * 7 + ["EXP="]),
        ("PADD", ["8000"] * 7 + ["HOLD", "EXP=100"]),
        ("PADD", ["8000"] * 6 + ["EXP=100"]),
        ("PSET", ["0"] + ["4000"] * 7 + ["EXP=20000", "NOW"]),
        ("PSET", ["0"] + ["4000"] * 7 + ["NOW", "EXP=20000"]),
        ("PSET", ["1"] + ["FFFF"] * 7 + ["EXP=99"]),
        ("ROLL", ["300"]),
        ("PADD", ["0148", "FFFF", "0000", "E666", "8000", "0001", "FFFE", "EXP=1000"]),
        ("ROLL", ["x"]),
        ("ROLL", []),
        ("ROLL", ["000"]),
        ("PADD", ["0148", "FFFF", "0000", "E666", "8000", "0001", "FFFE", "EXP=1000"]),
        ("OFF", []),
        ("PCLR", []),
        ("STAT", []),
    ]
    lines = [encode_request(seq, name, *args) for seq, (name, args) in enumerate(requests, 1)]
    lines += [
        _framed(b"?41:000:"),  # empty body: unknown command ''
        _framed(b"?42:00C:SET  1234 12"),  # a double space is an empty word
        b"?43:002:ID*0000\n",  # checksum mismatch
        b"?44\n",  # too short
        b"?45:002:ID-1A4E\n",  # no checksum field
        b"?46:002:ID*1a4e\n",  # checksum not upper-case hex
        _framed(b"?47:003:ID"),  # length mismatch
        _framed(b"?00:002:ID"),  # sequence 00 is reserved
        _framed(b"=48:002:ID"),  # a reply mark from the host
        _framed(b"?4g:002:ID"),  # header not hex
        _framed(b"?49:002:I\x01"),  # body not printable
        encode_request(0x4A, "STAT"),  # BAD= counts them all
    ]
    return lines


def _exchange(port: str, lines: list[bytes]) -> list[bytes]:
    """Open the port (which resets the booth), take its boot banner, then send each line and collect
    everything the booth sends up to its reply. The banner is the first item."""
    received: list[bytes] = []
    pending = b""
    with serial.Serial(port, 115200, timeout=0.05, exclusive=True) as link:
        received.append(await_boot_banner(link, 30.0))  # a generous bound: it ends at the banner
        for line in lines:
            link.write(line)
            deadline = time.monotonic() + 10.0
            while True:
                pending += link.readline()  # may return part of a line when the timeout ends
                if pending.endswith(b"\n"):
                    received.append(pending)
                    pending = b""
                    if received[-1].startswith(b"="):
                        break
                if time.monotonic() > deadline:
                    raise AssertionError(f"{port}: no reply to {line!r} within 10 s; got {received[-3:]}")
    return received


@pytest.fixture
def simulated(firmware_image: Path) -> Iterator[SimulatedBooth]:
    with SimulatedBooth(firmware_image) as sim:
        yield sim


def test_firmware_answers_every_frame_as_the_emulator_does(simulated: SimulatedBooth) -> None:
    script = _script()
    with serve_on_pty(BoothEmulator(firmware=FIRMWARE, clock=ManualClock())) as server:
        expected = _exchange(server.port, script)
    got = _exchange(simulated.port, script)
    banner = b"BOOT FW=" + FIRMWARE.encode() + b" PROTO=1"
    assert expected[0] == got[0] == b"\n" + encode_frame("!", 1, banner.decode())  # the same boot banner
    assert len(expected) >= len(script)  # a reply to each line, and the DONE event
    for index, (want, have) in enumerate(zip(expected, got)):
        assert have == want, f"line {index}: firmware sent {have!r}, emulator {want!r}"
    assert len(got) == len(expected)


def test_an_overlong_line_is_refused_once_and_the_next_frame_is_read(simulated: SimulatedBooth) -> None:
    """The firmware refuses at the 1041st byte and drops the rest of the line (the emulator refuses
    per received chunk, so the two differ in how many refusals a long line earns)."""
    got = _exchange(simulated.port, [b"?" * (MAX_LINE + 200) + b"\n", encode_request(1, "STAT")])[1:]
    assert len(got) == 2 and b"ERR - E_LEN line too long" in got[0]
    assert b" BAD=1 " in got[1]  # on the same link: a re-open would reset the board (BAD=0)


def test_the_pattern_table_holds_its_capacity_and_refuses_one_more(small_image: Path) -> None:
    """On the 4-step build (the default's 256 steps would take 257 round trips on a slow simulator;
    that they fit the board's RAM is the Makefile's size check)."""
    with SimulatedBooth(small_image, top=SMALL_TOP) as sim:
        requests = [encode_request(1 + i, "PADD", *[f"{i:04X}"] * 2) for i in range(5)]
        replies = _exchange(sim.port, requests)[1:]
    assert [r.split(b"*")[0][8:] for r in replies] == [
        b"OK PADD 0",
        b"OK PADD 1",
        b"OK PADD 2",
        b"OK PADD 3",
        b"ERR PADD E_FULL pattern table full",
    ]


@pytest.fixture(scope="module")
def firmware_link(firmware_image: Path) -> Iterator[tuple[SimulatedBooth, serial.Serial]]:
    """One simulated booth for many examples, its watchdog off and its LEDs at 0.25."""
    with SimulatedBooth(firmware_image) as sim, serial.Serial(sim.port, 115200, timeout=10.0, exclusive=True) as link:
        assert await_boot_banner(link, 30.0), "no boot banner within 30 s"
        for frame in (encode_request(1, "WDOG", 0), encode_request(2, "SET", *["4000"] * 7)):
            link.write(frame)
            assert link.readline().startswith(b"=0")
        yield sim, link


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7), st.data())
def test_firmware_never_acts_on_a_damaged_set(
    firmware_link: tuple[SimulatedBooth, serial.Serial], levels: list[float], data: st.DataObject
) -> None:
    """The emulator's property (test_fuzz.py) on the firmware: one flipped bit or dropped byte
    anywhere in a SET frame is refused as a frame error and never changes the LEDs."""
    sim, link = firmware_link
    frame = encode_request(3, "SET", *encode_levels(levels, 7))[:-1]
    index = data.draw(st.integers(0, len(frame) - 1), label="index")
    if data.draw(st.booleans(), label="drop"):
        damaged = frame[:index] + frame[index + 1 :]
    else:
        damaged = (
            frame[:index]
            + bytes([frame[index] ^ (1 << data.draw(st.integers(0, 7), label="bit"))])
            + frame[index + 1 :]
        )
    link.write(damaged + b"\n")
    replies = [link.readline() for _ in range(damaged.count(b"\n") + 1)]
    assert all(r.startswith(b"=00:") and b":ERR - E_" in r for r in replies), replies
    assert levels_close(sim.levels, (0x4000 / 0xFFFF,) * 7)  # the pins' duty, 0x4000 of 0x10000 ticks
