"""Noisy rendered captures for the failure and Pareto studies.

Unlike Table 1 (noise-free per-surface matrices), these studies render real raw frames with
:func:`processing.image_formation.render_frame` — photon and read noise, black level,
quantisation, saturation — and run the app's estimation path on them:
:func:`processing.accumulate.accumulate_statistics` then
:func:`processing.ambient.estimate_ambient`.

The world (:class:`World`)
--------------------------
- Scene: the 110-surface chart (:func:`processing.scenes.chart_scene`), square patches.
- Ambient: a spectrum in photons (any scale: only its shape matters, the exposure is metered).
- LEDs: a paper subset, scaled so that all LEDs at full drive give ``1 / ambient_to_flash`` times
  the ambient's mean camera signal (the sim rig's ``flash_to_ambient``, default 2 ⇒ ratio 0.5).
- Exposure: metered so the brightest expected pixel of the brightest frame (ambient + one LED)
  is at ``peak_fraction`` (0.8) of full scale, times ``exposure_factor`` (< 1 under-exposes,
  > 1 saturates). One exposure and gain 1 for every frame.
- Sensor: :class:`processing.sensor.SensorModel` defaults (16 bit, 0.5 e⁻/DN, 2 e⁻ read
  noise, full well 40 000 e⁻, RGB frames).

Frames: the ambient frame ``m_a`` and one frame per LED ``m_a + m_f,k`` — each independently
noisy. Perturbations: ``motion_px`` (the ambient frame's scene shifted sideways relative to the
LED frames), ``dead_led`` (that LED's frame is rendered without the LED, the estimator still
believes it was lit).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from msflash.lab.study.table1 import flash_norm, led_subset_indices
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.ambient import (
    CONDITION_WARNING,
    RESIDUAL_WARNING,
    SATURATION_WARNING,
    AmbientEstimate,
    estimate_ambient,
)
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.image_formation import expected_response, exposure_for_peak, render_frame, total_illumination
from msflash.processing.metrics import spectrum_rmse
from msflash.processing.model_error import EXPECTED_RATIO_WARNING, reference_for, with_model_error
from msflash.processing.scenes import Scene, chart_scene
from msflash.processing.sensor import SensorModel
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid
from msflash.processing.statistics import FrameStackSpec, SequenceStatistics

PEAK_FRACTION = 0.8
"""Metered peak of the brightest frame, as a fraction of full scale."""


@dataclass(frozen=True)
class World:
    """One simulated capture setup (picklable)."""

    scene: Scene
    ambient: Spectra
    """True ambient, photons, one spectrum."""
    leds: Spectra
    """LED spectra at full drive, photons, true relative powers."""
    camera: Spectra
    """Camera responsivities (n_wl, 3)."""
    sensor: SensorModel
    exposure_us: float


def make_world(
    camera: Spectra,
    ambient: Spectra,
    n_leds: int = 7,
    ambient_to_flash: float = 0.5,
    exposure_factor: float = 1.0,
    scene: Scene | None = None,
    patch_px: int = 8,
    border_px: int = 0,
    sensor: SensorModel | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> World:
    """A :class:`World`; see the module notes for the meaning of each knob."""
    if ambient_to_flash <= 0 or exposure_factor <= 0:
        raise SpectralDataError(
            f"noisy world: ambient_to_flash {ambient_to_flash}, exposure_factor {exposure_factor}; expected both > 0"
        )
    if scene is None:
        scene = chart_scene("chart110", patch_px=patch_px, border_px=border_px)
    scene = Scene(scene.reflectances.resample(grid), scene.labels, scene.shading, scene.specular, scene.specular_gain)
    ambient = ambient.resample(grid).to_unit("photons")
    camera = camera.resample(grid)
    all_leds = flash_norm(grid)
    leds = all_leds.select(led_subset_indices(n_leds))
    sensor = sensor or SensorModel()
    ambient_signal = float(np.mean(expected_response(scene, ambient, camera, 1.0)))
    dark = ambient.replace(values=np.zeros_like(ambient.values))
    flash_signal = float(
        np.mean(expected_response(scene, total_illumination(dark, leds, np.ones(leds.count)), camera, 1.0))
    )
    if ambient_signal <= 0 or flash_signal <= 0:
        raise SpectralDataError("noisy world: the ambient or the LEDs give no signal in this camera")
    leds = leds.replace(values=leds.values * (ambient_signal / (ambient_to_flash * flash_signal)))
    exposures = [exposure_for_peak(scene, ambient, camera, sensor, PEAK_FRACTION)]
    for k in range(leds.count):
        levels = np.eye(leds.count)[k]
        exposures.append(
            exposure_for_peak(scene, total_illumination(ambient, leds, levels), camera, sensor, PEAK_FRACTION)
        )
    return World(scene, ambient, leds, camera, sensor, min(exposures) * exposure_factor)


def shifted(scene: Scene, pixels: int) -> Scene:
    """The scene moved ``pixels`` to the right (wrapping around): motion between frames."""
    if pixels == 0:
        return scene
    return Scene(
        scene.reflectances,
        np.roll(scene.labels, pixels, axis=1),
        None if scene.shading is None else np.roll(scene.shading, pixels, axis=1),
        None if scene.specular is None else np.roll(scene.specular, pixels, axis=1),
        scene.specular_gain,
    )


def render_stack(
    world: World, rng: np.random.Generator, motion_px: int = 0, dead_led: int | None = None
) -> tuple[np.ndarray, list[np.ndarray], FrameStackSpec]:
    """Raw ambient frame, raw LED frames and their :class:`FrameStackSpec` (one LED per frame)."""
    k = world.leds.count
    ambient_frame = render_frame(
        shifted(world.scene, motion_px), world.ambient, world.camera, world.sensor, world.exposure_us, rng=rng
    )
    frames = []
    for index in range(k):
        levels = np.zeros(k) if index == dead_led else np.eye(k)[index]
        frames.append(
            render_frame(
                world.scene,
                total_illumination(world.ambient, world.leds, levels),
                world.camera,
                world.sensor,
                world.exposure_us,
                rng=rng,
            )
        )
    scale = 1.0 / world.exposure_us
    spec = FrameStackSpec(
        black_level=world.sensor.black_level,
        white_level=world.sensor.white_level,
        ambient_scale=scale,
        led_scales=(scale,) * k,
        led_levels=np.eye(k),
    )
    return ambient_frame, frames, spec


def patch_mean_frames(
    scene: Scene,
    ambient: np.ndarray,
    frames: list[np.ndarray],
    white_level: float,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Per-surface mean raw values as (n_surfaces, 1, C) float frames (a surface with any saturated pixel
    in any frame reads ``white_level``, so the statistics drop it)."""
    labels = scene.labels.ravel()
    n = scene.reflectances.count
    counts = np.bincount(labels, minlength=n).astype(float)
    present = counts > 0
    saturated = np.zeros(n, dtype=bool)
    means = []
    for frame in (ambient, *frames):
        samples = frame.reshape(labels.size, -1)
        saturated |= np.bincount(labels, weights=np.any(samples >= white_level, axis=1), minlength=n) > 0
        means.append(
            np.column_stack(
                [np.bincount(labels, weights=samples[:, c].astype(float), minlength=n) for c in range(samples.shape[1])]
            )
            / np.maximum(counts, 1)[:, None]
        )
    out = []
    for values in means:
        values = values[present]
        values[saturated[present]] = white_level
        out.append(values[:, None, :])
    return out[0], out[1:]


def reliability(estimate: AmbientEstimate, truth: np.ndarray) -> dict[str, Any]:
    """Error and reliability signals of one estimate against the true spectrum."""
    centre = estimate.spectrum.values[:, 0]
    peak = float(np.max(np.abs(centre)))
    error = spectrum_rmse(centre, truth) if peak > 0 else float("nan")
    band_ratio = float(np.max(estimate.spectrum_std) / peak) if peak > 0 else float("inf")
    if peak > 0:
        normalised = centre / peak
        gain = float(normalised @ truth) / float(truth @ truth)
        coverage = float(np.mean(np.abs(normalised - gain * truth) <= 2 * estimate.spectrum_std / peak))
    else:
        coverage = float("nan")
    return {
        "error": error,
        "refused": False,
        "warned": bool(estimate.warnings),
        "n_warnings": len(estimate.warnings),
        "relative_residual": estimate.relative_residual,
        "condition_number": estimate.condition_number,
        "band_ratio": band_ratio,
        "band_coverage_2sigma": coverage,
        "expected_ratio": estimate.expected_ratio,
        "saturated_fraction": estimate.saturated_fraction,
        "flags": {
            "condition": bool(estimate.condition_number > CONDITION_WARNING),
            "residual": bool(estimate.model_misfit > RESIDUAL_WARNING),
            "saturation": bool(estimate.saturated_fraction > SATURATION_WARNING),
            "risk": bool(estimate.expected_ratio is not None and estimate.expected_ratio >= EXPECTED_RATIO_WARNING),
        },
    }


def refused_record(reason: str, saturated_fraction: float = float("nan")) -> dict[str, Any]:
    """The record of an estimate :func:`estimate_ambient` refused (counts as a warning)."""
    return {
        "error": float("nan"),
        "refused": True,
        "warned": True,
        "n_warnings": 1,
        "reason": reason,
        "relative_residual": float("nan"),
        "condition_number": float("nan"),
        "band_ratio": float("nan"),
        "band_coverage_2sigma": float("nan"),
        "saturated_fraction": saturated_fraction,
        "flags": {"condition": False, "residual": False, "saturation": False, "risk": False},
    }


def estimate(
    statistics: SequenceStatistics, leds: Spectra, method: str = "tikhonov", alpha: float | str = "auto"
) -> AmbientEstimate:
    """:func:`estimate_ambient` (re-exported so studies time exactly one call)."""
    return estimate_ambient(statistics, leds, method, alpha)


def app_estimate(
    statistics: SequenceStatistics, world: World, method: str = "tikhonov", alpha: float | str = "auto"
) -> AmbientEstimate:
    """The estimate as the app makes it (acquisition.session.analysis.estimate_sequence): eq. 4–6 on the
    (inverse-variance weighted) statistics, with the LED model's error in the band and the miss risk in
    the warnings (:mod:`processing.model_error`)."""
    return with_model_error(
        estimate_ambient(statistics, world.leds, method, alpha), reference_for(world.leds, world.camera)
    )


def estimate_record(
    world: World,
    ambient: np.ndarray,
    frames: list[np.ndarray],
    spec: FrameStackSpec,
    method: str = "tikhonov",
    alpha: float | str = "auto",
    bin_factor: int = 4,
) -> dict[str, Any]:
    """Statistics (binned as the app does), estimate, and :func:`reliability`; refusals recorded, not raised."""
    started = time.perf_counter()
    statistics = accumulate_statistics(ambient, frames, spec, bin_factor=bin_factor, weighting=True)
    try:
        result = app_estimate(statistics, world, method, alpha)
    except (SolverError, SpectralDataError) as err:
        return refused_record(str(err), statistics.saturated_fraction)
    record = reliability(result, world.ambient.values[:, 0])
    record["elapsed_s"] = time.perf_counter() - started
    return record


def with_exposure(world: World, factor: float) -> World:
    """The same world with the exposure multiplied by ``factor``."""
    return replace(world, exposure_us=world.exposure_us * factor)
