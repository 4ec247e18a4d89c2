"""The driver against the booth over a real pseudo-terminal.

Tests taking ``far_end``/``far_booth`` run twice: against the Python emulator and against the
firmware image in simavr (conftest.py); the others use emulator-only features (manual clock,
fault injection, other channel counts).
"""

from __future__ import annotations

import os
from collections.abc import Callable

import pytest

from msflash.led_controller import (
    BoothEmulator,
    BoothError,
    BoothNotFoundError,
    BoothTimeoutError,
    LedBooth,
    ManualClock,
    PtyBoothServer,
    serve_on_pty,
)
from msflash.led_controller.firmware_sim import SimulatedBooth
from tests.helpers import levels_close

from .conftest import SMALL_TOP, FarEnd

Wait = Callable[..., None]


def test_identify_reports_the_default_channels(far_booth: LedBooth) -> None:
    info = far_booth.info
    assert info.channels == 7
    assert info.names == ("led440", "led480", "led500", "led520", "led596", "led636", "led660")
    assert info.peaks_nm == (440.0, 480.0, 500.0, 520.0, 596.0, 636.0, 660.0)
    assert info.protocol == 1 and info.level_bits == 16


@pytest.mark.parametrize("far", ["emulator", "firmware"])
def test_configurable_channels(far: str, request: pytest.FixtureRequest) -> None:
    """The firmware's channels, resolution and table size are build settings (its small test image)."""
    if far == "emulator":
        emulator = BoothEmulator(names=("uv", "ir"), peaks_nm=(365, 850), level_bits=12, max_steps=4)
        far_end: PtyBoothServer | SimulatedBooth = serve_on_pty(emulator)

        def levels():
            return emulator.levels
    else:
        sim = SimulatedBooth(request.getfixturevalue("small_image"), channels=2, top=SMALL_TOP)
        far_end, levels = sim, lambda: sim.levels
    with far_end, LedBooth.open(far_end.port) as booth:
        assert booth.info.names == ("uv", "ir") and booth.info.peaks_nm == (365.0, 850.0)
        assert booth.info.level_bits == 12 and booth.info.max_steps == 4
        booth.set_levels([1.0, 0.5])
        # 12-bit drive: 0.5 lands on the nearest lower 12-bit step.
        assert levels()[0] == 1.0 and abs(levels()[1] - 0.5) < 1 / 4095
        with pytest.raises(ValueError, match="expected 1..4"):
            booth.load_pattern([[0, 0]] * 5)


@pytest.mark.parametrize(("version", "remedy"), [(2, "update msflash"), (0, "update the booth's firmware")])
def test_a_booth_of_another_protocol_version_is_refused(version: int, remedy: str) -> None:
    """PROTO= is raised by every change that is not additive (docs/booth-protocol.md §9): a driver
    that took such a booth for its own would send it commands it reads differently."""
    emulator = BoothEmulator(firmware="booth-9.0", protocol=version)
    with serve_on_pty(emulator) as server:
        with pytest.raises(BoothError) as caught:
            LedBooth.open(server.port)
        message = str(caught.value)
        assert message.startswith(
            f"{server.port}: booth firmware booth-9.0 speaks booth protocol {version}; expected protocol 1"
        )
        assert remedy in message


def test_set_levels_reach_the_booth_with_16_bit_precision(far_booth: LedBooth, far_end: FarEnd) -> None:
    """On the firmware the levels are read back from the PWM compare registers."""
    booth = far_booth
    levels = [0.0, 1.0, 0.5, 1 / 65535, 0.123456, 0.999, 0.25]
    booth.set_levels(levels)
    assert levels_close(far_end.levels, levels)
    assert levels_close(booth.status().levels, levels)
    booth.all_off()
    assert far_end.levels == (0.0,) * 7


def test_bad_levels_are_refused_before_anything_is_sent(far_booth: LedBooth, far_end: FarEnd) -> None:
    booth = far_booth
    booth.set_levels([0.5] * 7)
    with pytest.raises(ValueError, match="LED level 2"):
        booth.set_levels([0.1, 0.1, 1.5, 0.1, 0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match="step 1: LED levels: got 6 values"):
        booth.load_pattern([[0] * 7, [0] * 6])
    assert levels_close(far_end.levels, [0.5] * 7)
    assert booth.status().steps == 0


def test_context_manager_switches_off_on_exception(far_end: FarEnd) -> None:
    with pytest.raises(RuntimeError, match="boom"), LedBooth.open(far_end.port) as booth:
        booth.set_levels([1.0] * 7)
        assert far_end.levels == (1.0,) * 7
        raise RuntimeError("boom")
    assert far_end.levels == (0.0,) * 7


def test_context_manager_switches_off_on_keyboard_interrupt(booth_on_pty: PtyBoothServer) -> None:
    with pytest.raises(KeyboardInterrupt), LedBooth.open(booth_on_pty.port) as booth:
        booth.set_levels([0.3] * 7)
        raise KeyboardInterrupt
    assert booth_on_pty.emulator.levels == (0.0,) * 7


def test_booth_refusal_names_command_and_code(far_booth: LedBooth) -> None:
    booth = far_booth
    with pytest.raises(BoothError, match=r"booth refused START \(E_STATE: not armed\)"):
        booth.start()
    with pytest.raises(BoothError, match="pattern table empty"):
        booth.arm("camera")
    assert booth.status().last_error == "E_STATE"


def test_camera_master_advances_on_exposure_active(far_booth: LedBooth, far_end: FarEnd) -> None:
    booth, emulator = far_booth, far_end
    steps = [[i / 10] * 7 for i in range(1, 4)]
    booth.load_pattern(steps)
    booth.arm("camera", settle_us=200)
    booth.start()
    seen = []
    for i in range(3):
        seen.append(emulator.levels)  # what the simulated camera would render for frame i
        emulator.camera_strobe()
        event = booth.wait_event("TRIG")
        assert event.args == (str(i + 1), str(i))
    done = booth.wait_event("DONE")
    assert done.args == ("3",)
    assert all(levels_close(s, e) for s, e in zip(seen, steps))
    assert emulator.levels == (0.0,) * 7
    assert booth.trigger_count() == 3
    assert booth.status().state == "DONE"


def test_booth_master_sequence_over_the_trigger_output(far_booth: LedBooth, far_end: FarEnd, wait_until: Wait) -> None:
    """Each pulse exposes its step's levels, at least settle_us after they were set (the firmware's
    pulses are timed in simavr's simulated time, so the check is exact and not a wall-clock one)."""
    booth = far_booth
    steps = [[0.2] * 7, [0.4] * 7]
    booth.load_pattern(steps)
    booth.arm("booth", settle_us=1000, pulse_us=100, period_us=10_000)
    booth.start()
    far_end.advance(0.001)
    wait_until(lambda: len(far_end.pulses) >= 1)
    far_end.advance(0.010)
    wait_until(lambda: len(far_end.pulses) == 2)
    assert [booth.wait_event("TRIG").args for _ in range(2)] == [("1", "0"), ("2", "1")]
    pulses = far_end.pulses
    assert all(levels_close(p.levels, s) for p, s in zip(pulses, steps))
    assert all(p.settled_us is None or p.settled_us >= 1000 for p in pulses)
    far_end.advance(0.010)
    assert booth.wait_event("DONE").args == ("2",)
    assert far_end.levels == (0.0,) * 7


def test_booth_master_pulses_the_trigger_after_settling(
    booth: LedBooth, booth_on_pty: PtyBoothServer, clock: ManualClock, wait_until: Wait
) -> None:
    emulator = booth_on_pty.emulator
    exposed: list[tuple[int, tuple[float, ...]]] = []
    emulator.on_trigger_out = lambda count: exposed.append((count, emulator.levels))
    steps = [[0.2] * 7, [0.4] * 7]
    booth.load_pattern(steps)
    booth.arm("booth", settle_us=1000, pulse_us=100, period_us=10_000)
    booth.start()
    wait_until(lambda: emulator.state == "RUNNING" and levels_close(emulator.levels, steps[0]))
    assert exposed == []  # the LEDs are still settling
    clock.advance(0.001)
    wait_until(lambda: len(exposed) == 1)
    assert exposed[0][0] == 1 and levels_close(exposed[0][1], steps[0])
    assert booth.wait_event("TRIG").args == ("1", "0")
    clock.advance(0.010)
    wait_until(lambda: len(exposed) == 2)
    assert levels_close(exposed[1][1], steps[1])
    clock.advance(0.010)
    assert booth.wait_event("DONE").args == ("2",)
    assert emulator.levels == (0.0,) * 7


def test_host_paced_steps_reply_after_settling(far_booth: LedBooth, far_end: FarEnd) -> None:
    booth = far_booth
    steps = [[0.1] * 7, [0.9] * 7]
    booth.load_pattern(steps)
    booth.arm("host", settle_us=0)
    booth.start()
    assert booth.next_step() == 0
    assert levels_close(far_end.levels, steps[0])
    assert booth.next_step() == 1
    assert levels_close(far_end.levels, steps[1])
    assert booth.next_step() is None
    assert booth.wait_event("DONE").args == ("2",)
    assert far_end.levels == (0.0,) * 7


def test_watchdog_switches_off_when_the_host_falls_silent(
    booth: LedBooth, booth_on_pty: PtyBoothServer, clock: ManualClock, wait_until: Wait
) -> None:
    booth.set_watchdog(0.5)
    booth.set_levels([1.0] * 7)
    clock.advance(0.4)
    booth.ping()  # feeds the watchdog
    clock.advance(0.4)
    booth_on_pty.emulator.tick()
    assert booth_on_pty.emulator.levels == (1.0,) * 7
    clock.advance(0.2)
    wait_until(lambda: booth_on_pty.emulator.levels == (0.0,) * 7)
    assert booth.wait_event("WDOG").kind == "WDOG"


def test_watchdog_event_interrupts_a_wait_for_another_event(far_booth: LedBooth, far_end: FarEnd) -> None:
    booth = far_booth
    booth.load_pattern([[0.5] * 7])
    booth.arm("camera")
    booth.start()
    # The short watchdog is the last request before the silence, sent while the sequence runs: set
    # before START, a host slower than 0.3 s between them had the table aborted before it started
    # (docs/decisions/firmware-tests-under-load.md).
    booth.set_watchdog(0.3)
    far_end.advance(0.5)
    with pytest.raises(BoothError, match="watchdog switched the LEDs off while waiting for DONE"):
        booth.wait_event("DONE")
    assert far_end.levels == (0.0,) * 7
    assert booth.status().state == "IDLE"


def test_wait_event_times_out_naming_the_event(far_booth: LedBooth) -> None:
    booth = far_booth
    with pytest.raises(BoothTimeoutError, match="no TRIG event within 0.01 s") as info:
        booth.wait_event("TRIG", timeout_s=0.01)
    assert info.value.timeout_s == 0.01


def test_missing_port_is_not_found(tmp_path) -> None:
    with pytest.raises(BoothNotFoundError, match="no such port"):
        LedBooth.open(str(tmp_path / "ttyNOPE"))


def test_transcript_is_recorded(booth_on_pty: PtyBoothServer, tmp_path) -> None:
    path = tmp_path / "t.txt"
    booth_on_pty.emulator.exposure_active(True)  # one exposure, ignored: nothing armed
    booth_on_pty.emulator.exposure_active(False)
    with LedBooth.open(booth_on_pty.port, log_serial=path) as booth:
        booth.set_levels([0.0] * 7)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("# msflash booth transcript")
    # The port's open reset the booth: its boot banner comes first, then the exchange.
    assert [line[:5] for line in lines[1:]] == ["! !01", "> ?01", "< =01", "> ?02", "< =02", "> ?03", "< =03"]
    assert "BOOT FW=" in lines[1] and "SET 0000" in lines[4] and "OFF" in lines[6]


def test_an_unwritable_transcript_is_a_booth_error_and_the_port_is_released(
    booth_on_pty: PtyBoothServer, tmp_path
) -> None:
    fds = len(os.listdir("/proc/self/fd"))
    missing = tmp_path / "no-such-dir" / "booth.txt"
    with pytest.raises(BoothError) as caught:
        LedBooth.open(booth_on_pty.port, log_serial=missing)
    assert str(caught.value) == (
        f"{booth_on_pty.port}: cannot record the serial transcript in {missing} "
        "(No such file or directory); expected a writable file path"
    )
    assert len(os.listdir("/proc/self/fd")) == fds  # the serial port opened for it is closed again
    with LedBooth.open(booth_on_pty.port) as booth:  # and the booth is still usable
        booth.ping()


def test_a_second_host_on_the_same_booth_is_refused_as_busy(booth: LedBooth, booth_on_pty: PtyBoothServer) -> None:
    """Two programs on one booth took each other's replies (both failed with 'no reply') and could drive
    the LEDs under each other's frames; the port is opened exclusively, so the second is told it is busy."""
    with pytest.raises(BoothError, match=rf"booth {booth_on_pty.port}: port busy; expected it free"):
        LedBooth.open(booth_on_pty.port)
    booth.set_levels([0.5] * 7)  # the first host is undisturbed
    assert levels_close(booth_on_pty.emulator.levels, [0.5] * 7)
