"""Held pattern steps and PSET: a computed flash step is never exposed with stale levels.

Tests taking ``far_end``/``far_booth`` run against the emulator and the firmware in simavr. The
firmware runs on simulated time paced to the wall clock, so where the host must act inside a
step's slot the period is long (1 s) rather than the emulator's manual 10 ms.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest

from msflash.led_controller.booth import LedBooth
from msflash.led_controller.emulator import BoothEmulator, ManualClock
from msflash.led_controller.emulator_pty import PtyBoothServer
from msflash.led_controller.errors import BoothError
from msflash.led_controller.protocol import Command, encode_request
from tests.helpers import levels_close

from .conftest import FarEnd

Wait = Callable[[Callable[[], bool]], None]
STALE = [0.9] * 7
FLASH = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]


def test_pset_round_trip_is_framed_like_any_request() -> None:
    frame = encode_request(5, Command.PATTERN_SET, 2, *(["FFFF"] * 7))
    assert frame.startswith(b"?05:") and b":PSET 2 FFFF" in frame


def test_booth_master_holds_then_exposes_the_pset_levels(
    far_booth: LedBooth, far_end: FarEnd, wait_until: Wait
) -> None:
    booth = far_booth
    # The host reads the levels inside the released step's slot: on the firmware (simulated time
    # paced to the wall clock, replies held up to 16 ms by the USB latency timer) a 10 ms slot had
    # often ended, the LEDs off after the last step, before the read; 0.5 s slots there.
    period_s = 0.010 if far_end.kind == "emulator" else 0.5
    booth.load_pattern([[0.2] * 7, STALE], held=(1,))
    booth.arm("booth", settle_us=1000, pulse_us=100, period_us=round(period_s * 1e6))
    booth.start()
    far_end.advance(0.001)
    wait_until(lambda: len(far_end.pulses) == 1)
    far_end.advance(2.5 * period_s)  # long past the held step's time: it waits, LEDs off, no pulse
    wait_until(lambda: far_end.levels == (0.0,) * 7)
    status = booth.status()
    assert (status.state, status.step) == ("RUNNING", 1)
    assert len(far_end.pulses) == 1 and far_end.levels == (0.0,) * 7
    booth.set_step(1, FLASH)
    assert levels_close(far_end.levels, FLASH)
    far_end.advance(0.001)
    wait_until(lambda: len(far_end.pulses) == 2)
    flash = far_end.pulses[1]
    assert levels_close(flash.levels, FLASH)
    assert flash.settled_us is None or flash.settled_us >= 1000  # settled from the PSET (firmware: exact)
    assert [booth.wait_event("TRIG").args for _ in range(2)] == [("1", "0"), ("2", "1")]
    far_end.advance(period_s)
    assert booth.wait_event("DONE", timeout_s=5.0).args == ("2",)


def test_pset_before_the_step_fills_it_without_waiting(far_booth: LedBooth, far_end: FarEnd, wait_until: Wait) -> None:
    booth = far_booth
    booth.load_pattern([[0.2] * 7, STALE], held=(1,))
    booth.arm("booth", settle_us=1000, pulse_us=100, period_us=1_000_000)
    booth.start()
    booth.set_step(1, FLASH)  # well inside step 0's 1 s slot
    far_end.advance(0.001)
    wait_until(lambda: len(far_end.pulses) >= 1)
    far_end.advance(1.0)
    wait_until(lambda: len(far_end.pulses) == 2)
    first, second = far_end.pulses
    assert levels_close(second.levels, FLASH)
    assert second.time_us - first.time_us == pytest.approx(1_000_000, abs=1000)  # on its schedule, no wait
    with pytest.raises(BoothError, match="E_STATE"):
        booth.set_step(0, FLASH)  # already exposed
    with pytest.raises(BoothError, match="E_RANGE"):
        booth.set_step(5, FLASH)


def test_camera_master_exposure_during_a_held_step_is_reported_as_hold(far_booth: LedBooth, far_end: FarEnd) -> None:
    booth, emulator = far_booth, far_end
    booth.load_pattern([[0.2] * 7, STALE], held=(1,))
    booth.arm("camera", settle_us=0, pulse_us=0, period_us=0)
    booth.start()
    emulator.camera_strobe()  # step 0 exposed; its end reaches the held step
    assert emulator.levels == (0.0,) * 7
    emulator.exposure_active(True)  # an exposure nobody should have started
    assert [booth.wait_event("TRIG").args for _ in range(2)] == [("1", "0"), ("2", "HOLD")]
    emulator.exposure_active(False)


def test_host_mode_refuses_next_onto_a_held_step(far_booth: LedBooth, far_end: FarEnd) -> None:
    booth = far_booth
    booth.load_pattern([STALE], held=(0,))
    booth.arm("host", settle_us=0, pulse_us=0, period_us=0)
    booth.start()
    with pytest.raises(BoothError, match="E_STATE"):
        booth.next_step()
    assert far_end.levels == (0.0,) * 7
    booth.set_step(0, FLASH)
    assert booth.next_step() == 0
    assert levels_close(far_end.levels, FLASH)


def test_emulator_parses_pset_itself() -> None:
    emulator = BoothEmulator(clock=ManualClock())
    out: list[bytes] = []
    emulator.connect_output(out.append)
    emulator.receive(encode_request(1, Command.PATTERN_SET, 0, *(["0000"] * 7)))
    assert b"ERR PSET E_RANGE" in out[-1]
    emulator.receive(encode_request(2, Command.PATTERN_SET, "x", *(["0000"] * 7)))
    assert b"ERR PSET E_ARG" in out[-1]


def test_pset_now_starts_the_next_step_at_once_after_the_previous_trigger(
    booth: LedBooth, booth_on_pty: PtyBoothServer, clock: ManualClock, wait_until: Wait
) -> None:
    emulator = booth_on_pty.emulator
    exposed: list[tuple[float, ...]] = []
    emulator.on_trigger_out = lambda count: exposed.append(emulator.levels)
    booth.load_pattern([[0.2] * 7, STALE, [0.3] * 7], held=(1,))
    booth.arm("booth", settle_us=1000, pulse_us=100, period_us=10_000)
    booth.start()
    clock.advance(0.001)
    wait_until(lambda: len(exposed) == 1)  # step 0 triggered; step 1 due at 10 ms
    booth.set_step(1, FLASH, now=True)  # the host has step 0's frame: start step 1 now
    assert levels_close(emulator.levels, FLASH) and len(exposed) == 1  # settling, no pulse yet
    clock.advance(0.001)  # 2 ms: one settle later, long before its scheduled 11 ms
    wait_until(lambda: len(exposed) == 2)
    assert levels_close(exposed[1], FLASH)
    clock.advance(0.009)  # later steps keep the period from the new slot: step 2 at 1 + 10 + 1 ms
    assert len(exposed) == 2
    clock.advance(0.001)
    wait_until(lambda: len(exposed) == 3)
    assert levels_close(exposed[2], [0.3] * 7)
    assert [booth.wait_event("TRIG").args for _ in range(3)] == [("1", "0"), ("2", "1"), ("3", "2")]


def test_pset_now_starts_the_held_step_early_on_both_far_ends(
    far_booth: LedBooth, far_end: FarEnd, wait_until: Wait
) -> None:
    """PSET … NOW after step 0's pulse starts step 1 at once: its pulse comes one settle after the
    PSET, long before its 1 s slot (simulated time on the firmware)."""
    booth = far_booth
    booth.load_pattern([[0.2] * 7, STALE], held=(1,))
    booth.arm("booth", settle_us=1000, pulse_us=100, period_us=1_000_000)
    booth.start()
    far_end.advance(0.001)
    wait_until(lambda: len(far_end.pulses) == 1)
    assert booth.wait_event("TRIG").args == ("1", "0")  # the host holds step 0's frame
    booth.set_step(1, FLASH, now=True)
    far_end.advance(0.001)
    wait_until(lambda: len(far_end.pulses) == 2)
    first, second = far_end.pulses
    assert levels_close(second.levels, FLASH)
    assert second.time_us - first.time_us < 500_000  # not at its scheduled 1 s
    assert second.settled_us is None or second.settled_us >= 1000
    assert booth.wait_event("TRIG").args == ("2", "1")


def test_pset_now_before_the_previous_trigger_only_fills_the_step(
    booth: LedBooth, booth_on_pty: PtyBoothServer, clock: ManualClock, wait_until: Wait
) -> None:
    emulator = booth_on_pty.emulator
    exposed: list[tuple[float, ...]] = []
    emulator.on_trigger_out = lambda count: exposed.append(emulator.levels)
    booth.load_pattern([[0.2] * 7, STALE], held=(1,))
    booth.arm("booth", settle_us=1000, pulse_us=100, period_us=10_000)
    booth.start()
    booth.set_step(1, FLASH, now=True)  # step 0 not triggered yet: its exposure must not see FLASH
    clock.advance(0.001)
    wait_until(lambda: len(exposed) == 1)
    assert levels_close(exposed[0], [0.2] * 7)
    clock.advance(0.005)
    assert len(exposed) == 1 and levels_close(emulator.levels, [0.2] * 7)  # step 1 keeps its slot
    clock.advance(0.005)
    wait_until(lambda: len(exposed) == 2)
    assert levels_close(exposed[1], FLASH)


def test_pset_now_on_a_booth_without_it_falls_back_to_plain_pset(booth: LedBooth, booth_on_pty: PtyBoothServer) -> None:
    emulator = booth_on_pty.emulator
    real = emulator._cmd_pattern_set

    def old_firmware(args: list[str]) -> str:
        if args and args[-1] == "NOW":
            return real(["x"])  # E_ARG, as firmware without NOW answers
        return real(args)

    emulator._handlers = lambda real_handlers=emulator._handlers: {  # type: ignore[method-assign]
        **real_handlers(),
        Command.PATTERN_SET: old_firmware,
    }
    booth.load_pattern([[0.2] * 7, STALE], held=(1,))
    booth.set_step(1, FLASH, now=True)
    assert emulator.held_steps == ()
    booth.set_step(0, FLASH, now=True)  # remembered: plain PSET at once
    assert emulator.held_steps == ()
