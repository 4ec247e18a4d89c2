"""Exposure planning: meter the ambient, then expose each LED frame for SNR below saturation.

Two steps, both on short host-paced previews that are never written to the sequence:

1. **Ambient auto-exposure.** Ambient previews (LEDs off) are taken until the *bright end* — the
   pixel value that only ``max_saturated_fraction`` of the pixels exceed (a pixel's value is its
   brightest channel) — sits at ``target_fraction`` of full scale (white − black) within
   ``tolerance``. Too bright (more than ``max_saturated_fraction`` saturated) divides the exposure
   by 4; otherwise the exposure is scaled by target ÷ bright end (at most ×16 per preview; the
   sensor is linear, so one unsaturated preview usually suffices). Clamped to the camera's range.
2. **LED exposures.** One preview of ambient + each LED, at ``led_preview_fraction`` of the
   ambient exposure (shorter, so that even a strong LED rarely saturates; a saturated preview is
   retaken 4× shorter), gives each pixel's rate with the LED on (DN/µs). Each LED frame then gets
   the longest exposure whose bright end of ambient + LED stays at ``headroom_fraction`` of full
   scale — the LED-only difference's SNR only grows with exposure — clamped to the camera's range.

Each LED frame's SNR is predicted from the previews (:mod:`acquisition.session.led_snr`); frames
are read through :mod:`acquisition.session.metering`; the flash frame's exposure is
:mod:`acquisition.session.flash_exposure`'s, made whole PWM periods here (:func:`whole_pwm_periods`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from msflash.acquisition.session import exposure_information as info
from msflash.acquisition.session.led_snr import (
    NoiseModel,
    led_snr_problem,
    led_snr_warnings,
    snr_from_difference,
    snr_or_none,
    snr_with_model,
)
from msflash.acquisition.session.metering import (
    Levels,
    brightest_channel,
    clamp,
    linear_quantile,
    meter,
    rates,
    unsaturated,
)

DEFAULT_EXPOSURE_RANGE_US = (1.0, 10_000_000.0)
"""Exposure limits assumed for a camera that does not report its own."""

MAX_INFORMATION_BLOCKS = 4096
"""The information criterion looks at most at this many blocks (evenly spaced) of a large frame."""

CRITERIA = ("bright_end", "information")
"""The exposure criteria :class:`ExposurePolicy` offers."""


@dataclass(frozen=True)
class ExposurePolicy:
    """What auto-exposure aims for."""

    max_saturated_fraction: float = 0.001
    """At most this fraction of pixels may saturate in any planned frame (0.1 %)."""
    target_fraction: float = 0.7
    """Ambient frame: the bright end sits at this fraction of full scale."""
    headroom_fraction: float = 0.9
    """LED and flash frames: the bright end of ambient + LEDs stays at or below this fraction."""
    tolerance: float = 0.1
    """Ambient metering stops when the bright end is within this relative distance of the target."""
    max_previews: int = 8
    """Ambient previews at most."""
    led_preview_fraction: float = 0.25
    """LED previews are taken at this fraction of the ambient exposure."""
    min_snr: float = 1.0
    """Planned LED SNR (median pixel) below this is reported as a warning. Per pixel, so modest: the
    estimate pools every pixel and bins 4×4 blocks (×4 SNR) first."""
    stride: int = 2
    """Metering looks at every ``stride``-th row and column (4× fewer pixels by default)."""
    criterion: str = "bright_end"
    """How exposures are chosen: ``"bright_end"`` (the ambient's bright end at ``target_fraction``, each
    LED frame's at ``headroom_fraction``; at most ``max_saturated_fraction`` saturated per frame) or
    ``"information"`` (starting from the bright-end plan, the ambient and LED exposures that maximise the
    information the unsaturated blocks carry about the LED-only signals; see
    :mod:`acquisition.session.exposure_information`). Not the default: the blocks it gives up (up to
    ``max_lost_fraction``) are missing from the synthesised images too (docs/measurements-acquisition.md)."""
    max_lost_fraction: float = 0.25
    """Information criterion: at most this fraction of the estimator's blocks may be lost to saturation
    in the union of the frames (a guard; the criterion itself weighs what a lost block costs)."""
    block_size: int = 4
    """The estimator's block (pixels per side, per CFA plane for a mosaic): a block saturated in any frame
    is dropped from every frame (``processing/statistics.py``)."""
    anti_flicker: str = "off"
    """``--anti-flicker``: ``50`` or ``60`` (the mains in Hz), ``auto`` or ``off``: exposures rounded to whole
    flicker periods where they allow (:mod:`acquisition.session.anti_flicker`)."""

    def __post_init__(self) -> None:
        if self.anti_flicker not in ("off", "50", "60", "auto"):
            raise ValueError(f"anti_flicker {self.anti_flicker!r}; expected off, 50, 60 or auto")
        if self.criterion not in CRITERIA:
            raise ValueError(f"criterion {self.criterion!r}; expected one of {', '.join(CRITERIA)}")
        if not 0 <= self.max_lost_fraction < 1:
            raise ValueError(f"max_lost_fraction {self.max_lost_fraction}; expected 0 ≤ f < 1")
        if self.block_size < 1:
            raise ValueError(f"block_size {self.block_size}; expected ≥ 1")
        if not 0 <= self.max_saturated_fraction < 0.5:
            raise ValueError(f"max_saturated_fraction {self.max_saturated_fraction}; expected 0 ≤ f < 0.5")
        if not 0 < self.target_fraction <= self.headroom_fraction <= 1:
            raise ValueError(
                f"target {self.target_fraction}, headroom {self.headroom_fraction}; expected 0 < target ≤ headroom ≤ 1"
            )


@dataclass
class ExposurePlan:
    """Chosen exposures and what they are expected to give."""

    ambient_exposure_us: float
    led_exposures_us: tuple[float, ...]
    predicted_snr: tuple[float, ...]
    snr_method: str
    exposure_range_us: tuple[float, float]
    policy: ExposurePolicy
    previews: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    mode: str = "auto"
    lost_block_fraction: float | None = None
    """Information criterion: the predicted fraction of the estimator's blocks saturated in some frame."""
    ambient_gain: float = 1.0
    """Analogue gain of the ambient frame (a replay's recorded gain; 1 otherwise)."""
    led_gains: tuple[float, ...] | None = None
    """Analogue gain of each LED frame (a replay's recorded gains), or None for ``ambient_gain``."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (for the sequence's ``extra`` and run.json)."""
        return {
            "mode": self.mode,
            "ambient_exposure_us": self.ambient_exposure_us,
            "led_exposures_us": list(self.led_exposures_us),
            "predicted_led_snr": [snr_or_none(v) for v in self.predicted_snr],
            "snr_method": self.snr_method,
            "exposure_range_us": list(self.exposure_range_us),
            "policy": asdict(self.policy),
            "previews": self.previews,
            "warnings": list(self.warnings),
            "lost_block_fraction": self.lost_block_fraction,
        }


def camera_exposure_range(camera: Any) -> tuple[float, float]:
    """The camera's exposure range (µs), or :data:`DEFAULT_EXPOSURE_RANGE_US`."""
    found = getattr(camera, "exposure_range_us", None)
    if found:
        low, high = float(found[0]), float(found[1])
        if 0 <= low < high:
            return max(low, DEFAULT_EXPOSURE_RANGE_US[0]), high
    return DEFAULT_EXPOSURE_RANGE_US


def camera_noise_model(camera: Any) -> NoiseModel | None:
    """The sensor's noise model: a simulated sensor's, or the camera's ``noise_model`` (profile), or None."""
    sensor = getattr(camera, "sensor", None)
    if sensor is not None and hasattr(sensor, "electrons_per_dn"):
        return NoiseModel(float(sensor.electrons_per_dn), float(sensor.read_noise_e))
    model = getattr(camera, "noise_model", None)
    if isinstance(model, NoiseModel):
        return model
    if model is not None:
        return NoiseModel(float(model[0]), float(model[1]))
    return None


def auto_ambient_exposure(
    capture: Callable[[float], np.ndarray],
    start_us: float,
    black: float,
    white: float,
    limits: tuple[float, float],
    policy: ExposurePolicy,
) -> tuple[float, np.ndarray, float, list[Levels], list[str]]:
    """Meter ambient previews until the bright end sits at the target.

    ``capture(exposure_us)`` returns an ambient frame. Returns the chosen exposure, the last
    unsaturated preview and its exposure (for the LED rates), every preview metered, and warnings.
    """
    exposure = clamp(start_us, limits)
    metered: list[Levels] = []
    notes: list[str] = []
    good: tuple[np.ndarray, float] | None = None
    for _ in range(policy.max_previews):
        pixels = capture(exposure)
        levels = meter(pixels, black, white, policy, exposure)
        metered.append(levels)
        if levels.saturated_fraction > policy.max_saturated_fraction:
            if exposure <= limits[0]:
                notes.append(
                    f"ambient too bright: {levels.saturated_fraction:.2%} of pixels saturate at the "
                    f"camera's shortest exposure {limits[0]:g} µs; reduce the light or the aperture"
                )
                good = (pixels, exposure)
                break
            exposure = clamp(exposure / 4.0, limits)
            continue
        good = (pixels, exposure)
        factor = policy.target_fraction / levels.bright_end if levels.bright_end > 0 else 16.0
        if abs(factor - 1.0) <= policy.tolerance:
            break
        proposed = clamp(exposure * min(max(factor, 1 / 16), 16.0), limits)
        if proposed == exposure:
            if factor > 1:
                notes.append(
                    f"ambient too dark: at the camera's longest exposure {limits[1]:g} µs the bright end "
                    f"is {levels.bright_end:.1%} of full scale (target {policy.target_fraction:.0%}); "
                    "add light, open the aperture or raise the gain"
                )
            break
        exposure = proposed
        if 1 / 16 < factor < 16.0 and levels.bright_end >= 0.02:
            break  # a well-measured unsaturated preview: the sensor is linear, the prediction lands on target
    else:
        notes.append(f"ambient metering did not settle in {policy.max_previews} previews")
    if good is None:
        good = (pixels, metered[-1].exposure_us)
    return exposure, good[0], good[1], metered, notes


def plan_exposures(
    capture: Callable[[Sequence[float], float], np.ndarray],
    n_leds: int,
    black: float,
    white: float,
    limits: tuple[float, float],
    noise: NoiseModel | None,
    policy: ExposurePolicy = ExposurePolicy(),
    start_us: float = 10_000.0,
    cfa: bool = False,
    led_names: Sequence[str] | None = None,
) -> ExposurePlan:
    """Auto-exposure for an ambient + each-LED sequence.

    ``capture(levels, exposure_us)`` returns one preview frame with the LEDs at ``levels``;
    ``led_names`` name the LEDs in warnings (``1`` … ``n`` when None).
    """
    names = list(led_names) if led_names is not None else [str(i + 1) for i in range(n_leds)]
    dark = (0.0,) * n_leds
    ambient_us, ambient_px, ambient_px_us, metered, notes = auto_ambient_exposure(
        lambda e: capture(dark, e), start_us, black, white, limits, policy
    )
    previews = [{"leds": "off", **asdict(m)} for m in metered]
    led_us: list[float] = []
    led_previews: list[tuple[np.ndarray, float]] = []
    for led in range(n_leds):
        levels = tuple(1.0 if i == led else 0.0 for i in range(n_leds))
        exposure, preview, metered_led = _led_exposure(
            capture, levels, names[led], ambient_us, black, white, limits, policy, notes
        )
        previews.extend({"leds": f"led {led + 1}", **asdict(m)} for m in metered_led)
        led_us.append(exposure)
        led_previews.append(preview)
    lost: float | None = None
    if policy.criterion == "information" and n_leds:
        ambient_us, chosen, lost = _most_informative(
            ambient_px, ambient_px_us, led_previews, ambient_us, led_us, black, white, limits, noise, policy, cfa
        )
        led_us = list(chosen)
    ambient = (ambient_px, ambient_px_us, ambient_us)
    snrs = _predicted_snrs(ambient, led_previews, led_us, black, white, noise, policy.stride, cfa)
    notes.extend(_snr_notes(names, snrs, policy))
    method = "photon+read noise" if noise is not None else "difference image"
    return ExposurePlan(
        ambient_us, tuple(led_us), tuple(snrs), method, limits, policy, previews, notes, lost_block_fraction=lost
    )


def _led_exposure(
    capture: Callable[[Sequence[float], float], np.ndarray],
    levels: Sequence[float],
    name: str,
    ambient_us: float,
    black: float,
    white: float,
    limits: tuple[float, float],
    policy: ExposurePolicy,
    notes: list[str],
) -> tuple[float, tuple[np.ndarray, float], list[Levels]]:
    """One LED frame's exposure from its previews, the last preview with its exposure, and each preview metered.

    The preview is taken at ``led_preview_fraction`` of the ambient exposure, 4× shorter while it
    saturates; the frame then gets the longest exposure whose bright end stays at ``headroom_fraction``.
    A preview without signal, or saturated at the shortest exposure, adds a warning to ``notes``.
    """
    preview_us = clamp(ambient_us * policy.led_preview_fraction, limits)
    metered: list[Levels] = []
    for _ in range(4):
        pixels = capture(levels, preview_us)
        metered.append(meter(pixels, black, white, policy, preview_us))
        if metered[-1].saturated_fraction <= policy.max_saturated_fraction or preview_us <= limits[0]:
            break
        preview_us = clamp(preview_us / 4.0, limits)
    combined = brightest_channel(rates(pixels, preview_us, black, policy.stride))
    bright_rate = linear_quantile(combined, 1.0 - policy.max_saturated_fraction)
    if bright_rate > 0:
        exposure = clamp(policy.headroom_fraction * (white - black) / bright_rate, limits)
    else:
        exposure = limits[1]
        notes.append(f"LED {name}: no signal in its preview")
    saturated = metered[-1].saturated_fraction
    if saturated > policy.max_saturated_fraction:
        exposure = limits[0]
        notes.append(
            f"LED {name}: saturates {saturated:.2%} of pixels at the shortest exposure {limits[0]:g} µs; dim the LED"
        )
    return exposure, (pixels, preview_us), metered


def _predicted_snrs(
    ambient: tuple[np.ndarray, float, float],
    led_previews: Sequence[tuple[np.ndarray, float]],
    led_us: Sequence[float],
    black: float,
    white: float,
    noise: NoiseModel | None,
    stride: int,
    cfa: bool,
) -> list[float]:
    """Each LED frame's SNR at its planned exposure, predicted from the previews.

    ``ambient`` is the ambient preview, its exposure and the planned ambient exposure. With a noise
    model, from the expected values; otherwise the previews' difference-image SNR scaled by √(exposure ratio).
    """
    ambient_px, ambient_px_us, ambient_us = ambient
    ambient_rate = rates(ambient_px, ambient_px_us, black, stride)
    ambient_ok = unsaturated(ambient_px, white, stride)
    snrs: list[float] = []
    for (pixels, preview_us), exposure in zip(led_previews, led_us, strict=True):
        if noise is not None:
            led_rate = rates(pixels, preview_us, black, stride)
            valid = ambient_ok & unsaturated(pixels, white, stride)
            snrs.append(snr_with_model(ambient_rate, led_rate, ambient_us, exposure, noise, valid))
            continue
        measured = snr_from_difference(ambient_px, pixels, ambient_px_us, preview_us, black, white, cfa)
        snrs.append(measured * math.sqrt(exposure / preview_us) if math.isfinite(measured) else measured)
    return snrs


def _snr_notes(names: Sequence[str], snrs: Sequence[float], policy: ExposurePolicy) -> list[str]:
    """A warning for each LED whose planned SNR is no measurement or below ``min_snr``."""
    notes: list[str] = []
    for name, snr in zip(names, snrs, strict=True):
        if led_snr_problem(snr) is not None:
            notes.extend(led_snr_warnings([name], [snr], "planned SNR"))
        elif not snr >= policy.min_snr:
            notes.append(
                f"LED {name}: planned SNR {snr:.3g} below {policy.min_snr:g} — the LED is weak against "
                "the ambient; dim the ambient or move the booth closer"
            )
    return notes


def _most_informative(
    ambient_px: np.ndarray,
    ambient_px_us: float,
    led_previews: Sequence[tuple[np.ndarray, float]],
    ambient_us: float,
    led_us: Sequence[float],
    black: float,
    white: float,
    limits: tuple[float, float],
    noise: NoiseModel | None,
    policy: ExposurePolicy,
    cfa: bool,
) -> tuple[float, tuple[float, ...], float]:
    """The information criterion on the previews, from the bright-end plan: ambient and LED exposures, lost fraction.

    Every pixel of the previews (a mosaic's too: each pixel's own channel), grouped by the
    estimator's blocks (``block_size`` per side, per CFA plane: 2·``block_size`` raw pixels).
    """
    block = policy.block_size * (2 if cfa else 1)
    limit_dn = policy.headroom_fraction * (white - black)

    def grouped(pixels: np.ndarray, exposure_us: float) -> tuple[np.ndarray, np.ndarray]:
        rate = info.group_blocks(rates(pixels, exposure_us, black, 1), block)
        clipped = np.any(info.group_blocks(np.asarray(pixels) >= white, block), axis=1)
        if rate.shape[0] > MAX_INFORMATION_BLOCKS:  # an even sample of the blocks estimates the sums and fractions
            keep = np.linspace(0, rate.shape[0] - 1, MAX_INFORMATION_BLOCKS).astype(int)
            rate, clipped = rate[keep], clipped[keep]
        crossing = info.crossings(rate, clipped, exposure_us, limit_dn)
        return info.thin_members(rate, block, 2 if cfa else 1), crossing

    ambient, ambient_crossing = grouped(ambient_px, ambient_px_us)
    leds = [grouped(pixels, preview_us) for pixels, preview_us in led_previews]
    blocks = info.Blocks(ambient, tuple(r for r, _ in leds), ambient_crossing, tuple(c for _, c in leds))
    dn_per_e = 1.0 / noise.electrons_per_dn if noise is not None else 1.0
    read_dn = noise.read_noise_e * dn_per_e if noise is not None else 0.0
    return info.most_informative(blocks, ambient_us, led_us, limits, dn_per_e, read_dn, policy.max_lost_fraction)


# -- flash energy under PWM dimming (host paced) ------------------------------------------------


class FlashEnergyWarning(UserWarning):
    """A frame's LED energy may differ from level × full: a PWM-dimmed booth and an exposure that is
    not a whole number of PWM periods (docs/flash-energy.md)."""


def pwm_energy_error(level: float, exposure_us: float, period_us: float) -> float:
    """The worst relative energy error of an LED PWM-dimmed at ``level`` over an exposure, over all phases.

    ``exposure = n·P + r``: the n whole periods give exactly ``level·n·P``; the remainder ``r``
    collects between ``max(0, r − (1 − level)·P)`` and ``min(r, level·P)`` depending on where it
    cuts the period. 0 for levels 0 and 1 and for whole periods.

    >>> round(pwm_energy_error(0.5, 1000.0, 4096.0), 3), pwm_energy_error(0.5, 8192.0, 4096.0)
    (1.0, 0.0)
    """
    if not 0.0 < level < 1.0 or not exposure_us > 0 or not period_us > 0:
        return 0.0
    remainder = math.fmod(exposure_us, period_us)
    high = level * period_us
    least, most = max(0.0, remainder - (period_us - high)), min(remainder, high)
    wanted = level * remainder
    return max(abs(least - wanted), abs(most - wanted)) / (level * exposure_us)


def whole_pwm_periods(
    exposure_us: float,
    levels: Sequence[float],
    pwm_hz: float,
    limits: tuple[float, float],
    policy: ExposurePolicy = ExposurePolicy(),
) -> tuple[float, str | None]:
    """A frame's exposure for a PWM-dimmed booth (host paced): whole PWM periods, or a warning.

    With every level 0 or 1 nothing changes. Otherwise the exposure becomes the nearest whole
    number of periods, never more than ``headroom_fraction / target_fraction`` of it (the flash
    exposure aims its bright end at the target: longer would saturate) and within the camera's
    ``limits``; when no whole number fits (an exposure shorter than a period), the exposure is kept
    and the warning gives the worst energy error over the fractional levels (:func:`pwm_energy_error`).

    Returns
    -------
    (exposure_us, warning or None)
    """
    fractional = [float(w) for w in levels if 0.0 < float(w) < 1.0]
    if not fractional or not pwm_hz > 0:
        return exposure_us, None
    period = 1e6 / pwm_hz
    longest = exposure_us * policy.headroom_fraction / policy.target_fraction
    candidates = [n * period for n in (math.floor(exposure_us / period), math.ceil(exposure_us / period)) if n >= 1]
    fitting = [c for c in candidates if c <= longest and limits[0] <= c <= limits[1]]
    if fitting:
        return min(fitting, key=lambda c: abs(c - exposure_us)), None
    error = max(pwm_energy_error(w, exposure_us, period) for w in fractional)
    return exposure_us, (
        f"flash exposure {exposure_us:.0f} µs: the booth dims by PWM at {pwm_hz:g} Hz (a {period:.0f} µs period) "
        f"when the host paces it, and no whole number of periods fits this exposure, so a frame's LED "
        f"energy may be off by up to {error:.0%} of its level; expected --sync booth or camera (the booth "
        "then pulses each LED for level × exposure) or a longer exposure"
    )
