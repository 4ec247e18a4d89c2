"""Fault injection on the pty: every fault gives a clear error and the booth's LEDs end up off."""

from __future__ import annotations

import os
import tty
from collections.abc import Callable

import pytest
import serial

from msflash.led_controller import (
    BoothError,
    BoothProtocolError,
    BoothTimeoutError,
    LedBooth,
    ManualClock,
    PtyBoothServer,
)
from tests.helpers import levels_close

OFF = (0.0,) * 7


@pytest.mark.parametrize("kind", ["drop", "flip"])
def test_damaged_reply_to_a_command_that_acts_is_a_protocol_error_and_exit_switches_off(
    booth_on_pty: PtyBoothServer, kind: str
) -> None:
    """START acts (a second START is refused: not armed): it is never sent again, the damaged reply is the error."""
    emulator = booth_on_pty.emulator
    with (
        pytest.raises(BoothProtocolError, match="bad reply to START") as info,
        LedBooth.open(booth_on_pty.port) as booth,
    ):
        booth.load_pattern([[0.5] * 7])
        booth.arm("camera")
        emulator.inject_fault(kind)
        booth.start()
    assert info.value.command == "START"
    assert info.value.raw.startswith(b"=0")
    assert emulator.levels == OFF


def test_damaged_request_that_acts_never_sets_a_wrong_step(booth: LedBooth, booth_on_pty: PtyBoothServer) -> None:
    emulator = booth_on_pty.emulator
    booth.load_pattern([[0.2] * 7])
    booth.arm("camera")
    emulator.inject_fault("garble_input")
    with pytest.raises(BoothProtocolError, match=r"could not read the START request \(E_CRC"):
        booth.start()
    assert emulator.state == "ARMED" and emulator.levels == OFF
    status = booth.status()
    assert status.bad_frames == 1 and status.last_error == "E_CRC"


@pytest.mark.parametrize("kind", ["drop", "flip", "drop_end", "garble_input"])
def test_an_idempotent_command_is_sent_once_more_after_one_damaged_exchange(
    booth: LedBooth, booth_on_pty: PtyBoothServer, kind: str, caplog: pytest.LogCaptureFixture
) -> None:
    """A flipped bit, a lost byte or line end in the reply, or a request the booth could not read:
    STAT, CNT, ID, PING, SET, OFF and WDOG leave the booth as once would, so they are sent again once
    (logged) before anything fails. A lost line end costs the reply's timeout first."""
    emulator = booth_on_pty.emulator
    booth.timeout_s = 0.5
    booth.set_levels([0.2] * 7)
    for call in (booth.status, booth.trigger_count, booth.identify, booth.ping, lambda: booth.set_levels([0.6] * 7)):
        emulator.inject_fault(kind)
        caplog.clear()
        with caplog.at_level("WARNING", logger="msflash.led_controller.booth_link"):
            call()
        assert any(" once more after " in record.getMessage() for record in caplog.records), caplog.text
    assert levels_close(emulator.levels, [0.6] * 7)


def test_two_damaged_exchanges_in_a_row_fail_in_one_line(booth: LedBooth, booth_on_pty: PtyBoothServer) -> None:
    emulator = booth_on_pty.emulator
    emulator.inject_fault("flip", count=2)
    with pytest.raises(BoothProtocolError, match="bad reply to STAT"):
        booth.status()
    assert booth.status().state == "IDLE"  # the link itself is fine


def test_damaged_event_is_reported(booth: LedBooth, booth_on_pty: PtyBoothServer) -> None:
    emulator = booth_on_pty.emulator
    booth.load_pattern([[0.5] * 7])
    booth.arm("camera")
    booth.start()
    emulator.inject_fault("flip")
    emulator.exposure_active(True)
    with pytest.raises(BoothProtocolError, match="bad line"):
        booth.wait_event("TRIG")


def test_stall_times_out_and_the_watchdog_switches_off(
    booth_on_pty: PtyBoothServer, clock: ManualClock, wait_until: Callable[..., None]
) -> None:
    emulator = booth_on_pty.emulator
    with (
        pytest.raises(BoothTimeoutError, match=r"no reply to STAT within 0.05 s") as info,
        LedBooth.open(booth_on_pty.port, timeout_s=30.0) as booth,
    ):
        booth.set_levels([1.0] * 7)  # answered: a loaded host may take longer than the stall's timeout
        booth.timeout_s = 0.05
        emulator.inject_fault("stall")
        booth.status()
    assert info.value.command == "STAT" and info.value.timeout_s == 0.05
    # all_off in __exit__ also timed out: attached to the original error, not replacing it.
    assert any("all_off" in note and "OFF" in note for note in info.value.__notes__)
    assert emulator.levels == (1.0,) * 7
    clock.advance(3.0)  # the default watchdog period
    wait_until(lambda: emulator.levels == OFF)
    assert emulator.state == "IDLE"


def test_unplug_is_a_clear_error_and_the_booth_is_off(booth_on_pty: PtyBoothServer) -> None:
    emulator = booth_on_pty.emulator
    with (
        pytest.raises(BoothError, match="serial link lost during PING") as info,
        LedBooth.open(booth_on_pty.port, timeout_s=30.0) as booth,  # only a failure waits
    ):
        booth.set_levels([1.0] * 7)
        booth_on_pty.close()  # the booth unplugged
        booth.ping()
    assert "check the USB cable" in str(info.value)
    assert any("all_off" in note for note in info.value.__notes__)
    assert emulator.levels == OFF


def test_close_fault_while_waiting_for_an_event(booth: LedBooth, booth_on_pty: PtyBoothServer) -> None:
    emulator = booth_on_pty.emulator
    booth.load_pattern([[0.5] * 7])
    booth.arm("camera")
    booth.start()
    assert levels_close(emulator.levels, [0.5] * 7)
    emulator.inject_fault("close")
    with pytest.raises(BoothError, match="serial link lost during waiting for an event"):
        booth.wait_event("DONE", timeout_s=5.0)
    assert emulator.levels == OFF
    with pytest.raises(BoothError, match="serial link lost during OFF"):
        booth.all_off()


def test_commands_after_close_are_refused(booth: LedBooth) -> None:
    booth.close()
    with pytest.raises(BoothError, match="PING on a closed booth"):
        booth.ping()


def test_a_hang_up_between_write_and_flush_is_a_lost_link() -> None:
    """pyserial's flush (``tcdrain``) on a pty hung up right after the write raises ``termios.error``,
    neither an ``OSError`` nor a ``SerialException``: it is the lost link, not a crash."""
    master, slave = os.openpty()
    tty.setraw(slave)

    class HungUpAfterWrite(serial.Serial):
        def write(self, data: bytes) -> int | None:
            written = super().write(data)
            os.close(master)  # the far end goes away between the write and its drain
            return written

    booth = LedBooth(HungUpAfterWrite(os.ttyname(slave), timeout=0.02), timeout_s=0.2)
    try:
        with pytest.raises(BoothError, match="serial link lost during PING"):
            booth.ping()
    finally:
        booth.close()
        os.close(slave)
