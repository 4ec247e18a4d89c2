"""Simulated chart responses: a chart rendered under each light through a noisy sensor.

:func:`simulate_chart_responses` is what ``msflash calibrate camera --simulate`` runs, and
:func:`calibration_lights` the lights it renders under (the LEDs plus broadband lights). The
leave-one-camera-out acceptance study built on them is :mod:`lab.study.camera_calibration`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from msflash.processing import datasets
from msflash.processing.colour_metrics import patch_pixels, usable_labels
from msflash.processing.image_formation import exposure_for_peak, render_frame
from msflash.processing.scenes import chart_scene
from msflash.processing.sensor import SensorModel
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid

BROADBAND_LIGHTS = ("A", "D65")
"""The two broadband lights of the study (known spectra, measured like the LEDs)."""


def calibration_lights(
    grid: WavelengthGrid = DEFAULT_GRID, broadband: Sequence[str] = BROADBAND_LIGHTS, leds: Spectra | None = None
) -> Spectra:
    """The LEDs (true ratios) plus broadband lights scaled to the strongest LED's peak, energy.

    ``leds`` are the booth's measured LEDs (a calibration's); by default the paper's 7.
    """
    leds = (datasets.paper_leds() if leds is None else leds.to_unit("energy")).resample(grid, outside="zero")
    peak = float(leds.values.max())
    columns = [leds.values] + [datasets.illuminant(name, grid).values * peak for name in broadband]
    return leds.replace(
        values=np.hstack(columns),
        names=leds.names + tuple(broadband),
        source=f"{leds.source} + " + " + ".join(broadband),
        unit="energy",
    )


def simulate_chart_responses(
    camera: Spectra,
    chart: Spectra,
    lights: Spectra,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Render the chart (12-pixel patches, the default :class:`SensorModel`) under each light alone and return
    linear patch means and standard errors.

    Each light gets its own exposure (brightest patch at 90 % of full scale); values are
    ``(mean − black) / exposure`` so all lights share one scale.

    Returns
    -------
    tuple
        ``(responses, std)``, each (n_lights, n_patches, 3).
    """
    sensor = SensorModel()
    rng = rng if rng is not None else np.random.default_rng(0)
    scene = chart_scene(chart, patch_px=12)
    labels = usable_labels(scene.labels, margin_px=1)
    responses = np.empty((lights.count, chart.count, 3))
    std = np.empty_like(responses)
    for l in range(lights.count):
        light = lights.select([l])
        exposure = exposure_for_peak(scene, light, camera, sensor, fraction=0.9)
        frame = render_frame(scene, light, camera, sensor, exposure, rng=rng).astype(float)
        for p in range(chart.count):
            samples = patch_pixels(frame, labels, p)
            responses[l, p] = [(s.mean() - sensor.black_level) / exposure for s in samples]
            std[l, p] = [max(s.std(ddof=1), 0.5) / np.sqrt(s.size) / exposure for s in samples]
    return responses, std
