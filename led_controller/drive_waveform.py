"""What the booth's LED pins do over time: the emulator's model of the firmware's drive.

The reference firmware (``firmware/board/board_mega2560.c``, ``docs/booth-firmware.md`` §2) drives
each LED one of two ways:

- **PWM** (``SET``, host paced, steps without an exposure): fast PWM at ``F_CPU / 2^BITS`` (244 Hz
  at 16 bits), high ``duty`` of every ``2^BITS`` ticks, the period restarting one clock after each
  level change. An exposure that is not a whole number of periods gets more or less than ``w·T``
  depending on where it cuts the period.
- **Pulses** (booth and camera master, steps given their exposure ``EXP=``): each LED on for
  ``round(w·T)`` timer ticks inside the exposure, both edges on the timer's compare hardware;
  :func:`pulse_plan` is the firmware's ``booth_pulse_plan`` to the tick.

:class:`DriveTrace` keeps, per channel, the drive from each change on and integrates it over any
window: the mean level of an LED over ``[t, t + T]`` is what a camera row exposed then collects,
as a fraction of the LED on throughout. Times are the emulator's clock, in seconds.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

CLOCK_HZ = 16_000_000
"""The reference board's CPU clock."""
PULSE_MARGIN_US = 10
"""``BOOTH_PULSE_MARGIN_US``: pulses end this long before the flash window does (camera master)."""
PRESCALERS = (1, 8, 64, 256, 1024)
"""The timer clock divisions the firmware picks from, shortest first."""
PULSE_FULL = 0xFFFF
"""Width meaning "on throughout the step" (w = 1)."""
EXPOSURE_MAX_US = 99_999_999
"""``EXP=`` takes 1..99999999 µs."""


def exposure_code(exposure_us: int) -> int:
    """``booth_exposure_code``: an exposure as 16 bits, exact below 4096 µs, else ``m << e`` (12-bit ``m``).

    >>> exposure_code(4095), exposure_code(5000), exposure_us_of(exposure_code(5000))
    (4095, 6596, 5000)
    """
    if exposure_us < 4096:
        return exposure_us
    e = 1
    while (exposure_us >> e) >= 4096:
        e += 1
    m = (exposure_us + (1 << (e - 1))) >> e
    if m >= 4096:
        e += 1
        m = (exposure_us + (1 << (e - 1))) >> e
    return e << 12 | m


def exposure_us_of(code: int) -> int:
    """``booth_exposure_us``: the exposure a code stands for, µs."""
    return (code & 0x0FFF) << (code >> 12)


@dataclass(frozen=True)
class PulsePlan:
    """A step's pulses (``booth_pulses_t``): timer division, window and each channel's width in ticks."""

    prescaler: int
    window: int
    """Ticks from the fire (trigger edge or ExposureActive edge) to the pulses' common end."""
    widths: tuple[int, ...]
    """Ticks on per channel; 0 off, :data:`PULSE_FULL` on throughout."""

    @property
    def tick_s(self) -> float:
        """One timer tick, seconds."""
        return self.prescaler / CLOCK_HZ

    def on_us(self, code: int) -> tuple[float, ...]:
        """Each channel's on-time per exposure, µs (the exposure itself for a channel on throughout)."""
        return tuple(
            exposure_us_of(code) if w == PULSE_FULL else w * self.prescaler / (CLOCK_HZ / 1e6) for w in self.widths
        )


def pulse_plan(duty: Sequence[int], top: int, code: int, roll_us: int, camera: bool) -> PulsePlan | None:
    """``booth_pulse_plan``: the pulses of a step (duties 0..``top``) for exposure ``code``; None: PWM."""
    if not code:
        return None
    exposure_us = exposure_us_of(code)
    per_us = CLOCK_HZ // 1_000_000
    k = 0
    while k < len(PRESCALERS) and exposure_us * per_us > 65535 * PRESCALERS[k]:
        k += 1
    if k == len(PRESCALERS):
        return None
    p = PRESCALERS[k]
    ticks = exposure_us * per_us // p
    margin = (PULSE_MARGIN_US * per_us + p - 1) // p + 1
    roll = (roll_us * per_us + p - 1) // p
    if ticks < roll + margin + 3:
        return None
    cap = ticks - roll - margin - 2
    window = ticks - roll - margin if camera else ticks - (per_us + p - 1) // p - 1
    widths = []
    for d in duty:
        if d == 0:
            widths.append(0)
        elif d >= top:
            widths.append(PULSE_FULL)
        else:
            widths.append(min((d * ticks + top // 2) // top, cap))
    return PulsePlan(p, window, tuple(widths))


def on_time_text(on_us: float) -> str:
    """An on-time as the firmware writes it in ``ON=``: µs, up to 4 decimals, no trailing zeros.

    >>> on_time_text(89.8125), on_time_text(100.0), on_time_text(0.0625)
    ('89.8125', '100', '0.0625')
    """
    cycles = round(on_us * (CLOCK_HZ / 1e6))
    whole, part = divmod(cycles, CLOCK_HZ // 1_000_000)
    if not part:
        return str(whole)
    return f"{whole}." + f"{part * (10_000 // (CLOCK_HZ // 1_000_000)):04d}".rstrip("0")


def pwm_hz_text(level_bits: int) -> str:
    """``PWMHZ=`` of a ``level_bits`` drive at clk/1, exact (``"244.140625"`` at 16 bits)."""
    return f"{CLOCK_HZ / (1 << level_bits):.10f}".rstrip("0").rstrip(".")


# -- one channel's drive over time ----------------------------------------------------------


@dataclass(frozen=True)
class Drive:
    """One channel's drive from ``start_s`` until the next change.

    ``kind``: ``"level"`` (constantly ``high`` 0 or 1), ``"pwm"`` (high for ``duty`` of every
    ``period_s``, periods from ``origin_s``) or ``"pulse"`` (high within ``[on_s, off_s)``, low
    elsewhere).
    """

    start_s: float
    kind: str
    high: float = 0.0
    duty: float = 0.0
    period_s: float = 0.0
    origin_s: float = 0.0
    on_s: float = 0.0
    off_s: float = 0.0

    def high_time(self, a: float, b: float) -> float:
        """Seconds high within ``[a, b]`` (the caller clips to this drive's span)."""
        if b <= a:
            return 0.0
        if self.kind == "level":
            return self.high * (b - a)
        if self.kind == "pulse":
            return max(0.0, min(b, self.off_s) - max(a, self.on_s))
        return self._pwm_cumulative(b) - self._pwm_cumulative(a)

    def _pwm_cumulative(self, t: float) -> float:
        x = t - self.origin_s
        if x <= 0:
            return 0.0
        periods = math.floor(x / self.period_s)
        return periods * self.duty * self.period_s + min(x - periods * self.period_s, self.duty * self.period_s)


class DriveTrace:
    """Each channel's drive over time; :meth:`mean_levels` integrates it over exposure windows.

    Changes must come in time order per channel (the emulator stamps them so); a change dated
    before the last one replaces the later ones (a command that overtook a scheduled change).
    """

    def __init__(self, channels: int, keep_s: float = 600.0) -> None:
        self._drives: list[list[Drive]] = [[Drive(-math.inf, "level")] for _ in range(channels)]
        self._keep_s = keep_s

    def set(self, channel: int, drive: Drive) -> None:
        """From ``drive.start_s`` on, ``channel`` is driven so."""
        drives = self._drives[channel]
        while len(drives) > 1 and drives[-1].start_s > drive.start_s:
            drives.pop()
        drives.append(drive)
        oldest = drive.start_s - self._keep_s
        while len(drives) > 2 and drives[1].start_s < oldest:
            drives.pop(0)

    def high_time(self, channel: int, a: float, b: float) -> float:
        """Seconds ``channel`` was high within ``[a, b]``."""
        drives = self._drives[channel]
        starts = [d.start_s for d in drives]
        i = max(0, bisect.bisect_right(starts, a) - 1)
        if drives[i].kind == "level" and (i + 1 == len(drives) or drives[i + 1].start_s >= b):
            return drives[i].high * (b - a)  # one steady level: exact (mean_levels divides it back)
        total = 0.0
        while i < len(drives) and drives[i].start_s < b:
            end = drives[i + 1].start_s if i + 1 < len(drives) else math.inf
            total += drives[i].high_time(max(a, drives[i].start_s), min(b, end))
            i += 1
        return total

    def mean_levels(self, starts_s: Sequence[float], duration_s: float) -> list[list[float]]:
        """``[row][channel]``: each channel's mean level over ``[start, start + duration_s]`` per row."""
        return [[self._mean(c, s, duration_s) for c in range(len(self._drives))] for s in starts_s]

    def _mean(self, channel: int, start: float, duration: float) -> float:
        drives = self._drives[channel]
        i = max(0, bisect.bisect_right([d.start_s for d in drives], start) - 1)
        if drives[i].kind == "level" and (i + 1 == len(drives) or drives[i + 1].start_s >= start + duration):
            return drives[i].high  # steady over the window: exactly its level, no rounding of (a + T) − a
        return self.high_time(channel, start, start + duration) / duration
