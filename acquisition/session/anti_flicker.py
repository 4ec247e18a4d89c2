"""Anti-flicker exposures: each frame's exposure a whole number of the mains lamps' flicker periods (issue 30, item 5).

A lamp on 50 Hz mains flickers at 100 Hz, on 60 Hz at 120 Hz (docs/flicker.md). A frame exposed for a whole number of
flicker periods collects the lamp's mean whatever its phase, so every frame of the sequence sees the same ambient;
a shorter one sees the lamp's mean over its own window, which differs from frame to frame.
:func:`with_anti_flicker` turns an exposure plan into one of whole periods where the exposure allows: each exposure
becomes the longest whole number of periods not above it by more than :data:`ROUND_UP_TOLERANCE` (the plan chose it
against saturation, so it is not lengthened beyond that), never shorter than one period; an exposure shorter than one
period stays as planned and is named in a warning (the estimate then reads each frame's ambient gain,
:mod:`processing.flicker`).

The flash re-capture's exposure, predicted from the frames once the LED frames are in, is rounded the same way
(:func:`flash_whole_periods`, from :func:`acquisition.session.run_exposure.flash_exposure_for`), or named in a
:class:`FlashFlickerWarning` where no whole number of periods fits.

``--anti-flicker auto`` does not know the supply: it takes whole periods of both (multiples of 50 ms, five 100 Hz
periods and six 120 Hz ones), so it helps only exposures of 50 ms and more.
"""

from __future__ import annotations

import math
from dataclasses import replace

from msflash.acquisition.session.exposure import ExposurePlan, FlashEnergyWarning

ANTI_FLICKER_CHOICES = ("off", "50", "60", "auto")
"""``--anti-flicker``: the mains frequency in Hz, ``auto`` (whole periods of both), or ``off`` (the default)."""

ROUND_UP_TOLERANCE = 0.05
"""An exposure may grow by at most this fraction to reach a whole period (the plan's headroom covers it)."""


def flicker_period_us(choice: str) -> float | None:
    """The period every anti-flicker exposure is a multiple of, µs (None for ``off``).

    >>> flicker_period_us("50"), round(flicker_period_us("60"), 1), flicker_period_us("auto")
    (10000.0, 8333.3, 50000.0)
    """
    if choice == "off":
        return None
    if choice == "50":
        return 1e6 / 100.0
    if choice == "60":
        return 1e6 / 120.0
    if choice == "auto":
        return 5e6 / 100.0  # 5 × 10 ms = 6 × 8.33 ms
    raise ValueError(f"anti-flicker {choice!r}; expected one of {', '.join(ANTI_FLICKER_CHOICES)}")


def whole_periods(exposure_us: float, period_us: float) -> float | None:
    """``exposure_us`` as a whole number of ``period_us`` (module notes), or None when it is shorter than one.

    >>> whole_periods(25_000, 10_000), whole_periods(9_600, 10_000), whole_periods(3_000, 10_000)
    (20000.0, 10000.0, None)
    """
    periods = math.floor(exposure_us * (1.0 + ROUND_UP_TOLERANCE) / period_us + 1e-9)
    return None if periods < 1 else float(periods * period_us)


def with_anti_flicker(plan: ExposurePlan, choice: str) -> ExposurePlan:
    """``plan`` with each exposure a whole number of flicker periods where it allows (module notes), and a warning
    naming the frames it does not (``off``: ``plan`` as it is)."""
    period = flicker_period_us(choice)
    if period is None:
        return plan
    low, high = plan.exposure_range_us
    short: list[str] = []

    def rounded(label: str, exposure_us: float) -> float:
        whole = whole_periods(exposure_us, period)
        if whole is None or not low <= whole <= high:
            short.append(f"{label} {exposure_us:.0f} µs")
            return exposure_us
        return whole

    ambient = rounded("ambient", plan.ambient_exposure_us)
    leds = tuple(rounded(f"LED {i + 1}", e) for i, e in enumerate(plan.led_exposures_us))
    warnings = list(plan.warnings)
    if short:
        warnings.append(
            f"--anti-flicker {choice}: {', '.join(short)} shorter than one flicker period ({period / 1000:.2f} ms): "
            "those frames may see a flickering lamp at different strengths (the estimate reads each frame's "
            "ambient gain; docs/flicker.md)"
        )
    return replace(plan, ambient_exposure_us=ambient, led_exposures_us=leds, warnings=warnings)


class FlashFlickerWarning(FlashEnergyWarning):
    """The flash frame's exposure is not a whole number of flicker periods (``--anti-flicker`` on): its ambient share
    may differ from the frames' the flash was computed from."""


def flash_whole_periods(exposure_us: float, plan: ExposurePlan) -> tuple[float, str | None]:
    """The flash frame's predicted exposure as a whole number of flicker periods (:func:`whole_periods`, within the
    camera's range), or as it is with a warning naming it when no whole number fits; as it is, silently, when
    ``--anti-flicker`` is off.

    >>> from msflash.acquisition.session.exposure import ExposurePolicy
    >>> policy = ExposurePolicy(anti_flicker="50")
    >>> plan = ExposurePlan(20_000.0, (20_000.0,), (float("nan"),), "fixed", (10.0, 1e6), policy)
    >>> flash_whole_periods(31_000.0, plan)
    (30000.0, None)
    >>> flash_whole_periods(4_000.0, plan)[1][:56]
    'flash exposure 4000 µs: shorter than one flicker period '
    """
    choice = plan.policy.anti_flicker
    period = flicker_period_us(choice)
    if period is None:
        return exposure_us, None
    whole = whole_periods(exposure_us, period)
    low, high = plan.exposure_range_us
    if whole is not None and low <= whole <= high:
        return whole, None
    why = (
        "shorter than one flicker period"
        if whole is None
        else "no whole number of flicker periods in the camera's range"
    )
    return exposure_us, (
        f"flash exposure {exposure_us:.0f} µs: {why} ({period / 1000:.2f} ms, --anti-flicker {choice}), so the flash "
        "frame may see a flickering lamp at another strength than the frames its mix was computed from "
        "(docs/flicker.md); a longer exposure (less flash power) would allow whole periods"
    )
