"""The unkind link of a stock Arduino Mega, on both twins: reset on every open, the bootloader's window,
the boot banner, the USB latency timer, the serial kept in EEPROM, the ExposureActive wire left loose.

No timed assertions: what the window swallowed is counted by the twin, the order of lines is checked,
and the latency timer is tested on explicit times.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator

import pytest
import serial

from msflash.led_controller import BoothError, BoothTimeoutError, LedBooth, serve_on_pty
from msflash.led_controller.booth_probe import await_boot_banner
from msflash.led_controller.firmware_sim import SimulatedBooth
from msflash.led_controller.protocol import encode_request
from msflash.led_controller.usb_link import USB_PACKET_PAYLOAD, HeldReplies, PortOpenWatch
from tests.helpers import levels_close

from .conftest import SMALL_TOP, FarEnd


def test_the_watch_sees_pyserials_open_and_close_of_a_pty() -> None:
    """The mechanism behind reset-on-open: inotify IN_OPEN on /dev/pts/N is raised by pyserial's open."""
    master, slave = os.openpty()
    try:
        watch = PortOpenWatch(os.ttyname(slave))
        assert watch.changes() == []  # the pty's own slave fd was opened before the watch
        os.stat(os.ttyname(slave))  # looking is no open
        with serial.Serial(os.ttyname(slave), 115200, timeout=0.05, exclusive=True):
            assert watch.changes() == [+1]
        assert watch.changes() == [-1]
        watch.close()
    finally:
        os.close(master)
        os.close(slave)


def test_each_open_resets_the_emulator_and_its_bootloader_swallows_what_is_sent() -> None:
    with serve_on_pty(bootloader_s=0.4) as server:
        request = encode_request(1, "ID")
        with serial.Serial(server.port, 115200, timeout=0.05, exclusive=True) as link:
            link.write(request)  # at once: into the bootloader
            banner = await_boot_banner(link, 30.0)
            assert banner.startswith(b"\n!01:") and b"BOOT FW=msflash-emulator-0.1 PROTO=1" in banner
            assert server._bootloader.swallowed == len(request)
            link.timeout = 0.3
            assert link.read(200) == b""  # the ID sent into the bootloader is never answered
        with serial.Serial(server.port, 115200, timeout=0.05, exclusive=True) as link:
            await_boot_banner(link, 30.0)
        assert server.resets == 2 and server.emulator.boots == 3  # power-up, then one per open


def test_waiting_for_the_banner_leaves_the_links_timeout_as_it_was() -> None:
    """It polls with short reads; a caller's next read keeps its own timeout (the firmware fuzz test's
    10 s readline once got 0.1 s, and under load missed a reply the simulator gave a little later)."""
    with serve_on_pty(bootloader_s=0.2) as server:
        with serial.Serial(server.port, 115200, timeout=7.5, exclusive=True) as link:
            assert await_boot_banner(link, 30.0)
            assert link.timeout == 7.5
        with serial.Serial(server.port, 115200, timeout=None, exclusive=True) as link:
            assert await_boot_banner(link, 0.05) == b""  # ended by its deadline, within the bootloader
            assert link.timeout is None


def test_a_second_open_while_the_port_is_held_does_not_reset() -> None:
    """DTR is already up: a second open (another program, refused as busy by msflash) makes no edge."""
    with serve_on_pty(bootloader_s=0.2) as server, LedBooth.open(server.port) as booth:
        booth.set_levels([0.5] * 7)
        with pytest.raises(BoothError, match="port busy"):
            LedBooth.open(server.port)
        assert server.resets == 1 and levels_close(server.emulator.levels, [0.5] * 7)
        booth.ping()


def test_leds_left_on_survive_the_hosts_close_and_go_off_at_the_next_open() -> None:
    with serve_on_pty(bootloader_s=0.2) as server:
        booth = LedBooth.open(server.port)
        booth.set_levels([1.0] * 7)
        booth.close()  # no OFF, as a killed process
        assert server.emulator.levels == (1.0,) * 7
        with LedBooth.open(server.port) as again:
            assert server.emulator.levels == (0.0,) * 7  # the open reset the board
            assert again.boots_seen == 1


def test_a_board_with_auto_reset_disabled_answers_at_once_and_keeps_its_state() -> None:
    with serve_on_pty(auto_reset=False) as server:
        booth = LedBooth.open(server.port, boot_s=0)
        booth.set_levels([0.25] * 7)
        booth.close()
        with LedBooth.open(server.port, boot_s=0) as again:
            assert again.boots_seen == 0 and again.status().levels[0] == pytest.approx(0.25, abs=1e-4)
        assert server.resets == 0


def test_asking_too_early_keeps_the_bootloader_and_the_error_names_port_wait_and_cause() -> None:
    """The driver told not to wait (--booth-boot-s 0) sends ID into the bootloader: one line, no traceback."""
    with serve_on_pty(bootloader_s=0.3) as server:
        with pytest.raises(BoothTimeoutError) as caught:
            LedBooth.open(server.port, boot_s=0, timeout_s=0.3)
        message = str(caught.value)
        assert message.startswith(f"{server.port}: no reply to ID within ")
        assert "of opening the port" in message and "auto-reset" in message and "--booth-boot-s 2.5" in message
        assert server._bootloader.swallowed > 0


def test_a_banner_later_than_the_wait_gets_id_again() -> None:
    """A slow bootloader (longer than --booth-boot-s): ID sent into it is lost, the late banner brings a new ID."""
    with serve_on_pty(bootloader_s=0.6) as server, LedBooth.open(server.port, boot_s=0.2, timeout_s=3.0) as booth:
        assert booth.info.channels == 7 and booth.boots_seen == 1
        assert server._bootloader.swallowed > 0


def test_a_restart_during_a_sequence_is_an_error_not_a_hang() -> None:
    with serve_on_pty(bootloader_s=0.2) as server, LedBooth.open(server.port) as booth:
        booth.load_pattern([[0.1] * 7, [0.2] * 7])
        booth.arm("camera", settle_us=100)
        booth.start()
        server.emulator.boot()  # a brown-out: the firmware starts again
        with pytest.raises(BoothError, match="restarted"):
            booth.wait_event("TRIG", timeout_s=5.0)


def test_the_latency_timer_holds_short_replies_to_its_tick_and_sends_full_packets_at_once() -> None:
    held = HeldReplies(0.016, start=100.0)
    held.hold(b"=01:002:OK*ABCD\n", 100.003)
    assert held.next_due() == pytest.approx(100.016)
    assert held.take(100.010) == b""
    assert held.take(100.016) == b"=01:002:OK*ABCD\n"
    held.hold(b"x" * (USB_PACKET_PAYLOAD + 5), 100.020)
    assert held.take(100.021) == b"x" * USB_PACKET_PAYLOAD  # a full packet goes at once, the rest waits
    assert held.take(100.032) == b"x" * 5
    with pytest.raises(ValueError, match="latency"):
        HeldReplies(-1, start=0)


def test_the_serial_is_kept_across_resets(far_end: FarEnd) -> None:
    """Set from the host, kept in EEPROM (firmware) or the board's memory (emulator) when the next open resets it."""
    booth = LedBooth.open(far_end.port)
    assert booth.info.serial is None
    booth.set_serial("bench-B2")
    booth.set_levels([0.5] * 7)
    booth.close()  # no OFF
    assert levels_close(far_end.levels, [0.5] * 7)
    with LedBooth.open(far_end.port) as again:
        assert again.info.serial == "bench-B2" and again.boots_seen == 1
        assert far_end.levels == (0.0,) * 7
        with pytest.raises(ValueError, match="serial 'a b'"):
            again.set_serial("a b")


@pytest.fixture
def firmware_sim(firmware_image: object) -> Iterator[SimulatedBooth]:
    with SimulatedBooth(bootloader_s=0.5) as sim:
        yield sim


def test_the_firmware_resets_on_each_open_in_simavr(firmware_sim: SimulatedBooth, wait_until) -> None:
    for _ in range(2):
        with LedBooth.open(firmware_sim.port) as booth:
            assert booth.boots_seen == 1 and booth.info.firmware == "msflash-avr-0.1"
    wait_until(lambda: firmware_sim.link()["opens"] == 0, 20.0)  # the bridge sees the close on its next poll
    assert firmware_sim.link()["resets"] == 2


def test_the_eeprom_file_keeps_the_serial_between_simulator_runs(firmware_image: object, tmp_path) -> None:
    eeprom = tmp_path / "eeprom.bin"
    with SimulatedBooth(bootloader_s=0.3, eeprom=eeprom) as sim, LedBooth.open(sim.port) as booth:
        booth.set_serial("bench-C3")
    with SimulatedBooth(bootloader_s=0.3, eeprom=eeprom) as sim, LedBooth.open(sim.port) as booth:
        assert booth.info.serial == "bench-C3"


def _loose_wire_triggers(sim: SimulatedBooth, channels: int) -> int:
    """Arm camera master, disconnect the ExposureActive wire, count the TRIG events in 0.3 s of simulated time."""
    with LedBooth.open(sim.port) as booth:
        booth.set_watchdog(0)
        booth.load_pattern([[0.5] * channels] * 4)
        booth.arm("camera", settle_us=100)
        booth.start()
        sim.exposure_wire_loose()
        sim.advance(0.3)
        time.sleep(0.2)
        return sum(1 for event in booth.pending_events() if event.kind == "TRIG")


def test_a_loose_exposure_wire_is_held_by_the_pull_up(firmware_sim: SimulatedBooth) -> None:
    """With the pull-up the input goes high once (one exposure start, never its end) and stays there."""
    assert _loose_wire_triggers(firmware_sim, 7) <= 1


def test_without_the_pull_up_a_loose_wire_floats_and_triggers(small_image: object) -> None:
    """The small test image has no pull-up: what the firmware did before — noise on a floating input."""
    with SimulatedBooth(small_image, channels=2, top=SMALL_TOP, bootloader_s=0.3) as sim:  # type: ignore[arg-type]
        assert _loose_wire_triggers(sim, 2) > 1
