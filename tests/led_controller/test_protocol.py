"""Pure encode/parse of the booth wire format, including malformed frames."""

from __future__ import annotations

import math

import pytest

from msflash.led_controller import protocol
from msflash.led_controller.emulator_wire import firmware_crc
from msflash.led_controller.errors import BoothProtocolError
from msflash.led_controller.protocol import Command


def test_crc_matches_the_standard_check_value_and_the_firmware_table() -> None:
    assert protocol.crc16(b"123456789") == 0x29B1
    assert firmware_crc(b"123456789") == 0x29B1
    assert protocol.crc16(b"?01:002:ID") == firmware_crc(b"?01:002:ID")


def test_request_round_trip() -> None:
    data = protocol.encode_request(0x2A, Command.SET, "0000", "FFFF")
    assert data == b"?2A:00D:SET 0000 FFFF*%04X\n" % protocol.crc16(b"?2A:00D:SET 0000 FFFF")
    frame = protocol.parse_frame(data[:-1])
    assert (frame.mark, frame.seq, frame.body) == ("?", 0x2A, "SET 0000 FFFF")


@pytest.mark.parametrize("body", ["OK PING", "", "ERR SET E_ARG needs 7 levels", "x" * protocol.MAX_BODY])
def test_reply_round_trip(body: str) -> None:
    data = protocol.encode_frame("=", 255, body)
    frame = protocol.parse_frame(data.rstrip(b"\n"))
    assert frame.body == body and frame.seq == 255 and frame.mark == "="


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        (b"=01:007:OK PING*0000", "checksum"),
        (b"=01:008:OK PING*F93D", "length field"),
        (b"=01:007:OK PING", "not in frame form"),
        (b"=01:007:ok ping*f93d", "not in frame form"),
        (b"#01:007:OK PING*F93D", "not in frame form"),
        (b"=01:007:OK\tPING*F93D", "not in frame form"),
        (b"", "not in frame form"),
    ],
)
def test_malformed_frames_are_protocol_errors(line: bytes, problem: str) -> None:
    with pytest.raises(BoothProtocolError, match=problem) as info:
        protocol.parse_frame(line, command="PING")
    assert info.value.raw == line
    assert info.value.command == "PING"
    assert "expected" in str(info.value)


def test_encode_frame_refuses_what_cannot_be_framed() -> None:
    with pytest.raises(ValueError, match="printable"):
        protocol.encode_frame("=", 1, "a*b")
    with pytest.raises(ValueError, match="printable"):
        protocol.encode_frame("=", 1, "x" * (protocol.MAX_BODY + 1))
    with pytest.raises(ValueError, match="seq"):
        protocol.encode_request(0, Command.PING)


@pytest.mark.parametrize(("level", "code"), [(0.0, 0), (1.0, 0xFFFF), (0.5, 0x8000), (1 / 65535, 1)])
def test_levels_quantise_to_16_bits(level: float, code: int) -> None:
    assert protocol.level_to_code(level) == code
    assert abs(protocol.code_to_level(code) - level) <= 0.5 / protocol.LEVEL_MAX


@pytest.mark.parametrize("bad", [-1e-9, 1.0000001, math.nan, math.inf, -math.inf])
def test_levels_outside_the_unit_interval_are_refused_not_clipped(bad: float) -> None:
    with pytest.raises(ValueError, match=r"LED level 3: .* expected a number in \[0, 1\]"):
        protocol.encode_levels([0, 0, 0, bad], 4)


def test_level_count_must_match_the_channels() -> None:
    with pytest.raises(ValueError, match="got 2 values; expected one per channel .7."):
        protocol.encode_levels([0.1, 0.2], 7)


def _reply(body: str) -> tuple[protocol.Reply, bytes]:
    raw = protocol.encode_frame("=", 1, body).rstrip(b"\n")
    frame = protocol.parse_frame(raw)
    return protocol.parse_reply(frame, body.split(" ")[1]), raw


def test_parse_identify() -> None:
    reply, raw = _reply("OK ID FW=fw-1.2 PROTO=1 CH=2 NAMES=a,b PEAKS=440,480.5 BITS=12 STEPS=64")
    info = protocol.parse_identify(reply, raw)
    assert info == protocol.BoothInfo("fw-1.2", 1, 2, ("a", "b"), (440.0, 480.5), 12, 64)


@pytest.mark.parametrize(
    ("body", "match"),
    [
        ("OK ID FW=x PROTO=1 CH=3 NAMES=a,b PEAKS=1,2 BITS=16 STEPS=4", "inconsistent"),
        ("OK ID FW=x PROTO=1 CH=2 NAMES=a,b PEAKS=1,2 BITS=16", "lacks STEPS"),
        ("OK ID FW=x PROTO=1 CH=two NAMES=a,b PEAKS=1,2 BITS=16 STEPS=4", "bad number"),
        ("OK ID FW=x PROTO=1 CH=2 NAMES=a,b PEAKS=1,2 BITS=8 STEPS=4", "out-of-range"),
        ("OK ID garbage", "without '='"),
    ],
)
def test_parse_identify_rejects_inconsistent_replies(body: str, match: str) -> None:
    reply, raw = _reply(body)
    with pytest.raises(BoothProtocolError, match=match) as info:
        protocol.parse_identify(reply, raw)
    assert info.value.command == "ID" and info.value.raw == raw


def test_parse_status() -> None:
    reply, raw = _reply(
        "OK STAT STATE=RUNNING MODE=BOOTH STEP=2 STEPS=16 TRIG=3 WDOG=3000 ERR=E_CRC BAD=1 LEVELS=0000,FFFF"
    )
    status = protocol.parse_status(reply, raw)
    assert status == protocol.BoothStatus("RUNNING", "BOOTH", 2, 16, 3, 3.0, (0.0, 1.0), "E_CRC", 1)


def test_parse_status_rejects_bad_levels() -> None:
    reply, raw = _reply("OK STAT STATE=IDLE MODE=- STEP=-1 STEPS=0 TRIG=0 WDOG=0 ERR=- BAD=0 LEVELS=FFFFF")
    with pytest.raises(BoothProtocolError, match="4-hex-digit LEVELS"):
        protocol.parse_status(reply, raw)


def test_parse_reply_checks_the_echoed_command() -> None:
    frame = protocol.parse_frame(protocol.encode_frame("=", 1, "OK OFF").rstrip(b"\n"))
    with pytest.raises(BoothProtocolError, match="reply to SET has the wrong form") as info:
        protocol.parse_reply(frame, "SET")
    assert info.value.expected.startswith("'OK SET")
    err = protocol.parse_reply(
        protocol.parse_frame(protocol.encode_frame("=", 0, "ERR - E_CRC bad").rstrip(b"\n")), "SET"
    )
    assert (err.ok, err.code, err.text) == (False, "E_CRC", "bad")


def test_parse_event() -> None:
    frame = protocol.parse_frame(protocol.encode_frame("!", 7, "TRIG 3 2").rstrip(b"\n"))
    event = protocol.parse_event(frame)
    assert (event.kind, event.seq, event.args) == ("TRIG", 7, ("3", "2"))
    with pytest.raises(BoothProtocolError, match="bad event"):
        protocol.parse_event(protocol.parse_frame(protocol.encode_frame("!", 0, "TRIG").rstrip(b"\n")))
