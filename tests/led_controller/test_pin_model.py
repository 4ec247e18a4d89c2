"""The simavr harness's LED pins (sim/pin_model.c) against the datasheet's arithmetic, on a probe image.

``build/timer_probe.elf`` (sim/timer_probe.c) sets up PWM duties and one-shot pulses whose pin
waveforms the ATmega2560 datasheet fixes; the harness must integrate exactly those on-times. This
is what lets the flash-energy figures of the booth firmware be measured from its own pins.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from msflash.led_controller.firmware_sim import BUILD_DIR, SimulatedBooth


@pytest.fixture(scope="module")
def probe(firmware_image: Path) -> Iterator[SimulatedBooth]:
    with SimulatedBooth(BUILD_DIR / "timer_probe.elf") as sim:
        deadline = time.monotonic() + 30.0
        while len(sim.pulses) < 3:  # markers every 5 ms of simulated time
            assert time.monotonic() < deadline, "timer_probe: no markers within 30 s"
            time.sleep(0.01)
        yield sim


def test_fast_pwm_duties_are_ocr_plus_one_of_top_plus_one(probe: SimulatedBooth) -> None:
    """Mode 14, TOP 0xFFFF: non-inverting high OCR + 1 ticks, OCR = TOP constantly high, inverting
    high TOP − OCR ticks; integrated over whole periods (4096 µs)."""
    start = probe.pulses[0].time_us
    on = probe.integrate(start, 4 * 4096.0).fractions()[0]
    assert on[0] == pytest.approx(0.25, abs=1e-9)
    assert on[1] == 1.0  # simavr 1.6's own pin: constantly low
    assert on[2] == pytest.approx(0.25, abs=1e-9)


def test_an_ocr_write_with_the_same_low_byte_takes_effect(probe: SimulatedBooth) -> None:
    """OCR5A 0x0400 → 0x0800 (low byte unchanged, which simavr 1.6 ignores) at marker 3."""
    before = probe.integrate(2000.0, 8 * 256.0).fractions()[0][6]
    after = probe.integrate(probe.pulses[1].time_us, 8 * 256.0).fractions()[0][6]
    assert before == pytest.approx(0x401 / 0x1000, abs=1e-9)
    assert after == pytest.approx(0x801 / 0x1000, abs=1e-9)


def test_a_one_shot_is_exactly_its_width_and_a_blocked_compare_never_sets(probe: SimulatedBooth) -> None:
    """TOP 0, TCNT written 0x10000 − 1500 at clk/8: OCR 65535 − w is high w ticks (0.5 µs each),
    ending 1500 ticks after the write; a compare equal to the value written is blocked."""
    for pulse in probe.pulses[:3]:
        assert probe.integrate(pulse.time_us, 800.0).on_us[0][3:6] == (500.0, 0.5, 0.0)
        # the pulses end 750 µs (+ up to a tick of prescaler phase) after the write: nothing before 249 µs
        assert probe.integrate(pulse.time_us, 249.0).on_us[0][3:6] == (0.0, 0.0, 0.0)
