"""The driver against recorded transcripts: every line consumed, nothing unexpected or left over."""

from __future__ import annotations

from pathlib import Path

import pytest

from msflash.led_controller import BoothError, BoothProtocolError, BoothTimeoutError, LedBooth
from msflash.led_controller.protocol import encode_frame, encode_request
from tests.helpers import levels_close


@pytest.mark.parametrize("recording", ["emulator-camera-master.txt", "simavr-firmware-camera-master.txt"])
def test_camera_master_transcript(replay_port, transcripts_dir: Path, recording: str) -> None:
    """Replays a recording of the emulator and one of the reference firmware in simavr."""
    port = replay_port.from_file(transcripts_dir / recording)
    booth = LedBooth(port, timeout_s=2.0)
    with booth:
        info = booth.identify()
        assert info.channels == 7 and info.names[0] == "led440"
        booth.set_levels([0.25, 0.5, 0.75, 1.0, 0.0, 0.125, 1 / 65535])
        booth.load_pattern([[0.1] * 7, [0.2] * 7, [0.3] * 7])
        booth.arm("camera", settle_us=500)
        booth.start()
        triggers = [booth.wait_event("TRIG").args for _ in range(3)]
        assert triggers == [("1", "0"), ("2", "1"), ("3", "2")]
        assert booth.wait_event("DONE").args == ("3",)
        assert booth.trigger_count() == 3
        status = booth.status()
        assert status.state == "DONE" and status.trigger_count == 3
        assert levels_close(status.levels, [0.0] * 7)
        assert booth.pending_events() == []
    port.assert_done()


def test_error_transcript(replay_port, transcripts_dir: Path) -> None:
    port = replay_port.from_file(transcripts_dir / "emulator-errors.txt")
    with LedBooth(port, timeout_s=2.0) as booth:
        booth.identify()
        with pytest.raises(BoothError, match=r"refused START \(E_STATE"):
            booth.start()
        booth.set_levels([0.5] * 7)  # the booth could not read the first SET (E_CRC): sent once more
        booth.ping()  # the first reply arrived damaged: asked once more
    port.assert_done()


def _lines(*pairs: tuple[str, bytes]) -> list[tuple[str, bytes]]:
    return list(pairs)


def test_replay_fails_on_an_unexpected_request(replay_port) -> None:
    port = replay_port(_lines((">", encode_request(1, "PING")), ("<", encode_frame("=", 1, "OK PING"))))
    booth = LedBooth(port, timeout_s=0.5)
    try:
        with pytest.raises(AssertionError, match="expected > .*PING.* got > .*OFF"):
            booth.all_off()
    finally:
        booth.close()
    with pytest.raises(AssertionError, match="unexpected"):
        port.assert_done()


def test_replay_fails_on_left_over_lines(replay_port) -> None:
    port = replay_port(
        _lines(
            (">", encode_request(1, "PING")),
            ("<", encode_frame("=", 1, "OK PING")),
            (">", encode_request(2, "PING")),
            ("<", encode_frame("=", 2, "OK PING")),
        )
    )
    booth = LedBooth(port, timeout_s=0.5)
    booth.ping()
    booth.close()
    with pytest.raises(AssertionError, match="not consumed"):
        port.assert_done()


def test_stale_reply_is_dropped_and_the_command_times_out(replay_port) -> None:
    # The booth answers with a reply for another sequence number: never taken for ours.
    # CNT is a query: asked once more (sequence 2), again answered for another sequence number.
    port = replay_port(
        _lines(
            (">", encode_request(1, "CNT")),
            ("<", encode_frame("=", 9, "OK CNT 5")),
            (">", encode_request(2, "CNT")),
            ("<", encode_frame("=", 9, "OK CNT 5")),
        )
    )
    booth = LedBooth(port, timeout_s=0.05)
    try:
        with pytest.raises(BoothTimeoutError, match="no reply to CNT within 0.05 s") as info:
            booth.trigger_count()
        assert info.value.command == "CNT"
    finally:
        booth.close()
    port.assert_done()


def test_lost_event_is_reported(replay_port) -> None:
    port = replay_port(
        _lines(
            (">", encode_request(1, "START")),
            ("<", encode_frame("=", 1, "OK START")),
            ("!", encode_frame("!", 1, "TRIG 1 0")),
            ("!", encode_frame("!", 3, "DONE 2")),
        )
    )
    booth = LedBooth(port, timeout_s=0.5)
    try:
        booth.start()
        assert booth.wait_event("TRIG").seq == 1
        with pytest.raises(BoothProtocolError, match="event sequence jumped from 1 to 3"):
            booth.wait_event("DONE")
    finally:
        booth.close()
    port.assert_done()
