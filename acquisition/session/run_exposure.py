"""Exposures of a run: planned for the rig, recorded (replay), the flash's, and the LED frames' SNR.

``--exposure`` is fixed, the replay's recording, or metered from previews (:func:`plan_exposure`,
through the capture engine's :func:`~acquisition.session.capture.preview_frames`); the flash
frame's exposure is fixed, recorded or predicted from the frames in memory
(:func:`flash_exposure_for`); the LED frames' SNR is measured as they were captured (:func:`led_capture`).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.devices.replay_camera import ReplayCamera
from msflash.acquisition.errors import UsageError
from msflash.acquisition.plan import CapturePlan, StepRole, TriggerSource
from msflash.acquisition.progress import progress
from msflash.acquisition.sequence.format import SequenceFrame
from msflash.acquisition.session.anti_flicker import FlashFlickerWarning, flash_whole_periods, with_anti_flicker
from msflash.acquisition.session.capture import preview_frames
from msflash.acquisition.session.engine import Cancellation
from msflash.acquisition.session.exposure import (
    ExposurePlan,
    ExposurePolicy,
    FlashEnergyWarning,
    camera_exposure_range,
    camera_noise_model,
    plan_exposures,
    whole_pwm_periods,
)
from msflash.acquisition.session.led_snr import format_led_snr, led_snr_warnings, measure_led_snr
from msflash.acquisition.session.metering import metering_view
from msflash.acquisition.session.rig import Rig

log = logging.getLogger(__name__)

SYNC_MODES: dict[str, TriggerSource] = {"host": "software", "booth": "booth", "camera": "camera"}
"""``--sync`` names and the plan trigger each stands for."""


@dataclass(frozen=True)
class Recorded:
    """A replay rig's recorded exposures and gains: replay must ask for exactly those."""

    ambient_us: float
    led_us: tuple[float, ...]
    flash_us: float | None
    """None when the recording has no flash frame (a sequence from ``msflash capture``)."""
    ambient_gain: float
    led_gains: tuple[float, ...]
    flash_gain: float
    flash_levels: tuple[float, ...] | None = None
    """The recorded flash frame's LED levels (None without one)."""


def recording_of(rig: Rig) -> Recorded | None:
    """What a replay rig's recording holds (None for other rigs)."""
    if not isinstance(rig.camera, ReplayCamera):
        return None
    sequence = rig.camera.sequence
    ambient = sequence.indices("ambient")
    leds = sequence.indices("led")
    flash = sequence.indices("flash")
    if not ambient:
        return None
    frames = sequence.frames
    return Recorded(
        frames[ambient[0]].exposure_us,
        tuple(frames[i].exposure_us for i in leds),
        frames[flash[0]].exposure_us if flash else None,
        frames[ambient[0]].gain,
        tuple(frames[i].gain for i in leds),
        frames[flash[0]].gain if flash else 1.0,
        tuple(frames[flash[0]].led_levels) if flash else None,
    )


def plan_exposure(
    rig: Rig, exposure_option: str | float, policy: ExposurePolicy, cancel: Cancellation | None = None
) -> ExposurePlan:
    """``--exposure``: fixed, the replay's recording, the fake's suggestion, or metered previews (auto).

    ``cancel`` stops the metering between preview frames (:class:`~acquisition.session.engine.Cancellation`).
    """
    n_leds = rig.led_spectra.count
    limits = camera_exposure_range(rig.camera)
    noise = camera_noise_model(rig.camera)
    method = "photon+read noise" if noise is not None else "difference image"
    nan = (float("nan"),) * n_leds
    if exposure_option != "auto":
        exposure = float(exposure_option)
        if not limits[0] <= exposure <= limits[1]:
            raise UsageError(f"--exposure {exposure:g}: outside the camera's range {limits[0]:g}–{limits[1]:g} µs")
        return with_anti_flicker(
            ExposurePlan(exposure, (exposure,) * n_leds, nan, method, limits, policy, mode="fixed"), policy.anti_flicker
        )
    recorded = recording_of(rig)
    if recorded is not None and len(recorded.led_us) == n_leds:
        return ExposurePlan(
            recorded.ambient_us,
            recorded.led_us,
            nan,
            method,
            limits,
            policy,
            mode="recorded",
            ambient_gain=recorded.ambient_gain,
            led_gains=recorded.led_gains,
        )
    suggested = float(getattr(rig.camera, "suggested_exposure_us", None) or 10_000.0)
    progress(
        f"auto exposure: metering ambient previews (≤ {policy.max_saturated_fraction:.2%} saturated, "
        f"bright end at {policy.target_fraction:.0%} of full scale)"
    )
    info = rig.camera.info

    def capture(levels, exposure_us: float):
        role: StepRole = "led" if any(level > 0 for level in levels) else "ambient"
        preview = CapturePlan.single(levels, exposure_us, role=role)
        frames = preview_frames(rig.camera, rig.booth, preview, cancel=cancel)
        return metering_view(frames[0].pixels, mosaic=info.cfa is not None)

    planned = plan_exposures(
        capture,
        n_leds,
        info.black_level,
        info.white_level,
        limits,
        noise,
        policy,
        start_us=suggested,
        cfa=info.cfa is not None,
        led_names=list(rig.led_spectra.names),
    )
    return with_anti_flicker(planned, policy.anti_flicker)


def report_exposure(plan: ExposurePlan, names: list[str]) -> None:
    progress(
        f"exposure ({plan.mode}): ambient {plan.ambient_exposure_us:.0f} µs; LEDs "
        + ", ".join(f"{n} {e:.0f}" for n, e in zip(names, plan.led_exposures_us))
        + " µs"
    )
    if plan.mode == "auto":
        progress(f"planned LED SNR ({plan.snr_method}, median pixel): " + format_led_snr(names, plan.predicted_snr))
    for note in plan.warnings:
        progress(f"warning: {note}")


@dataclass
class LedCapture:
    """The ambient + LED frames as captured, kept in memory for estimation (no re-read from disk)."""

    plan: ExposurePlan
    frames: list[RawFrame]
    entries: list[SequenceFrame]
    last_frame_at: float
    """``time.perf_counter()`` when the last LED frame was handed over (written)."""
    snr: list[float]
    snr_method: str
    snr_warnings: tuple[str, ...] = ()
    """One per LED whose measured SNR is no measurement (no LED signal; :func:`led_snr_warnings`)."""


def led_capture(
    rig: Rig,
    led_names: list[str],
    plan: ExposurePlan,
    frames: list[RawFrame],
    entries: list[SequenceFrame],
    last_frame_at: float,
) -> LedCapture:
    """The LED frames with their measured SNR (reported)."""
    info = rig.camera.info
    pixels = [metering_view(f.pixels, mosaic=info.cfa is not None) for f in frames]
    snr, method = measure_led_snr(
        pixels[0],
        frames[0].exposure_us,
        pixels[1:],
        [f.exposure_us for f in frames[1:]],
        info.black_level,
        info.white_level,
        camera_noise_model(rig.camera),
        cfa=info.cfa is not None,
        gain=frames[0].gain,
        led_gains=[f.gain for f in frames[1:]],
    )
    names = led_names
    progress(f"LED SNR ({method}, median pixel): " + format_led_snr(names, snr))
    warned = tuple(led_snr_warnings(names, snr, "measured SNR"))
    for note in warned:
        progress(f"warning: {note}")
    return LedCapture(plan, frames, entries, last_frame_at, snr, method, warned)


def flash_exposure_for(
    rig: Rig, plan: ExposurePlan, levels: np.ndarray, predict: Callable[[np.ndarray], float], sync: str = "host"
) -> float:
    """The flash frame's exposure: fixed, recorded (replay), or ``predict(levels)`` from the frames in memory.

    A predicted exposure is made whole flicker periods when ``--anti-flicker`` is on and the exposure allows, else a
    :class:`~acquisition.session.anti_flicker.FlashFlickerWarning` names it
    (:func:`~acquisition.session.anti_flicker.flash_whole_periods`). A predicted exposure for a booth that dims by
    PWM here (host paced, or a booth without pulse dimming) is made whole PWM periods, or a
    :class:`FlashEnergyWarning` gives the energy error (:func:`~acquisition.session.exposure.whole_pwm_periods`);
    whole flicker periods, once reached, are kept (the PWM's energy error is then what is warned about).
    """
    if plan.mode != "auto":
        recorded = recording_of(rig)
        if plan.mode == "recorded" and recorded is not None and recorded.flash_us is not None:
            return recorded.flash_us
        return plan.ambient_exposure_us
    predicted = predict(levels)
    exposure_us, flicker_note = flash_whole_periods(predicted, plan)
    if flicker_note is not None:
        warnings.warn(flicker_note, FlashFlickerWarning, stacklevel=2)
    elif exposure_us != predicted:
        log.info("flash exposure %.0f µs → %.0f µs: whole flicker periods (--anti-flicker)", predicted, exposure_us)
    info = getattr(rig.booth, "info", None)
    pwm_hz = getattr(info, "pwm_hz", None)
    if pwm_hz is None or (sync in ("booth", "camera") and getattr(info, "pulse_dimming", False)):
        return exposure_us
    whole_flicker = plan.policy.anti_flicker != "off" and flicker_note is None
    chosen, note = whole_pwm_periods(
        exposure_us,
        [float(v) for v in levels],
        pwm_hz,
        (exposure_us, exposure_us) if whole_flicker else plan.exposure_range_us,
        plan.policy,
    )
    if note is not None:
        warnings.warn(note, FlashEnergyWarning, stacklevel=2)
    elif chosen != exposure_us:
        log.info(
            "flash exposure %.0f µs → %.0f µs: whole periods of the booth's %g Hz PWM", exposure_us, chosen, pwm_hz
        )
    return chosen
