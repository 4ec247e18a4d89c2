"""Acceptance study of camera calibration: leave-one-camera-out over the paper's 34 cameras.

For each camera: render a chart (Macbeth by default) under the paper's 7 LEDs and two broadband
lights (CIE A and D65) through a noisy sensor (photon + read noise, 16-bit), take linear patch
means and their standard errors (:func:`calibration.validation.simulate_chart_responses`), learn
the prior from the *other* 33 cameras, recover the responsivities with the learned prior and with
smoothness alone, and compare with the truth (:func:`~calibration.camera_response.responsivity_rmse`).
Then solve the complementary flash for a tungsten ambient with the recovered and with the true
responsivities and report the CIEDE2000 between the two resulting chart renderings (true camera,
D65-fitted camera → XYZ matrix).

:func:`leave_one_camera_out_seeds` repeats the study over several noise seeds: one seed is one
draw of the sensor noise, and the mean RMSE of a single draw moves between seeds as much as the
priors compared differ (``docs/calibration.md``, camera responsivities). :func:`regime_study`
measures the prior's gain per noise level and light set (``docs/calibration.md``, regimes).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import nnls

from msflash.calibration.camera_response import estimate_responsivities, learn_prior, responsivity_rmse
from msflash.calibration.validation import BROADBAND_LIGHTS, calibration_lights, simulate_chart_responses
from msflash.processing import datasets, lights
from msflash.processing.colour_metrics import chart_delta_e, delta_e_2000, reference_chart
from msflash.processing.errors import TargetUnreachableWarning
from msflash.processing.flash import solve_complementary
from msflash.processing.image_formation import surface_responses
from msflash.processing.render import camera_to_xyz_matrix
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid

STUDY_SEEDS = (0, 1, 2, 3, 4)
"""Noise seeds of :func:`leave_one_camera_out_seeds` (seed 0 is the single-seed study)."""


@dataclass(frozen=True)
class CameraCalibrationResult:
    """One camera of the leave-one-out study."""

    camera: str
    family: str
    """``Jiang`` (the 28 cameras of Jiang et al. 2013) or ``ISETCam`` (the 6 others)."""
    seed: int
    """The noise seed of the run."""
    rmse_prior: float
    """RMSE of the learned-prior estimate (max-normalised, per channel then averaged)."""
    rmse_smoothness: float
    """RMSE of the smoothness-only estimate."""
    flash_delta_e_mean: float
    """Mean over patches of ΔE00 between charts lit by the flash solved with recovered vs true responsivities."""
    flash_delta_e_max: float
    """Largest such ΔE00."""


def flash_delta_e(
    true_camera: Spectra, recovered: Spectra, chart: Spectra, ambient: str = "tungsten"
) -> tuple[float, float]:
    """ΔE00 (mean, max over patches) between the complementary-flash charts of two responsivity sets."""
    grid = true_camera.grid
    leds = datasets.paper_leds().resample(grid, outside="zero").to_unit("photons")
    ambient_spd = lights.ambient_spectrum(ambient, grid).to_unit("photons")
    ambient_weights = nnls(leds.values, ambient_spd.values[:, 0])[0]
    target = datasets.illuminant("D65", grid).to_unit("photons")
    d65 = datasets.illuminant("D65", grid)
    matrix = camera_to_xyz_matrix(true_camera, chart, d65.to_unit("photons"))
    reference = reference_chart(chart, d65)
    labs = []
    for camera in (true_camera, recovered):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TargetUnreachableWarning)  # reported in the solution; same for both
            solution = solve_complementary(ambient_weights, leds, camera, target)
        light = ambient_spd.replace(values=ambient_spd.values + leds.values @ solution.flash_weights[:, None])
        rgb = surface_responses(chart, light, true_camera)
        labs.append(chart_delta_e(rgb, matrix, reference).lab)
    delta = delta_e_2000(labs[0], labs[1])
    return float(delta.mean()), float(delta.max())


def _study_world(
    camera_names: Sequence[str] | None, chart: str, seed: int, grid: WavelengthGrid
) -> tuple[dict[str, Spectra], list[str], Spectra, Any, np.random.Generator]:
    """The 34 cameras on ``grid``, the cameras to study, the chart, the lights and the noise generator."""
    cameras = {name: spectra.resample(grid, outside="zero") for name, spectra in datasets.paper_cameras().items()}
    names = list(cameras) if camera_names is None else list(camera_names)
    reflectances = datasets.macbeth().resample(grid) if chart == "macbeth" else datasets.chart110()
    return cameras, names, reflectances, calibration_lights(grid), np.random.default_rng(seed)


def leave_one_camera_out(
    camera_names: Sequence[str] | None = None,
    chart: str = "macbeth",
    seed: int = 0,
) -> list[CameraCalibrationResult]:
    """Run the study over ``camera_names`` (default: all 34), each against a prior learned without it."""
    grid = DEFAULT_GRID
    cameras, names, reflectances, lights, rng = _study_world(camera_names, chart, seed, grid)
    results = []
    for name in names:
        truth = cameras[name]
        responses, std = simulate_chart_responses(truth, reflectances, lights, rng=rng)
        prior = learn_prior(cameras, exclude=[name])
        with_prior = estimate_responsivities(responses, reflectances, lights, "pca_prior", prior, std)
        smooth_only = estimate_responsivities(responses, reflectances, lights, "smoothness", None, std)
        mean_de, max_de = flash_delta_e(truth, with_prior.responsivities, datasets.macbeth().resample(grid))
        results.append(
            CameraCalibrationResult(
                name,
                camera_family(name),
                seed,
                responsivity_rmse(with_prior.responsivities, truth),
                responsivity_rmse(smooth_only.responsivities, truth),
                mean_de,
                max_de,
            )
        )
    return results


def leave_one_camera_out_seeds(
    seeds: Sequence[int] = STUDY_SEEDS,
    camera_names: Sequence[str] | None = None,
    chart: str = "macbeth",
) -> list[CameraCalibrationResult]:
    """:func:`leave_one_camera_out` once per noise seed, all results in one list (seed by seed)."""
    return [result for seed in seeds for result in leave_one_camera_out(camera_names, chart, seed)]


def camera_family(name: str) -> str:
    """``ISETCam`` for the 6 MIT-licensed cameras of the paper, ``Jiang`` for the 28 others."""
    return "ISETCam" if name in datasets.paper_cameras(include_noncommercial=False) else "Jiang"


def summarise(results: Sequence[CameraCalibrationResult]) -> dict:
    """Means and ratios of a study (pooled over its seeds), overall and per camera family.

    ``improvement`` is ``1 − mean RMSE(prior) / mean RMSE(smoothness)``, the figure issue 7 asks
    to be ≥ 0.30; ``per_seed`` and ``families`` hold the same means per seed and per family.
    """
    prior = float(np.mean([r.rmse_prior for r in results]))
    smooth = float(np.mean([r.rmse_smoothness for r in results]))

    def means(subset: list[CameraCalibrationResult]) -> dict:
        a, b = float(np.mean([r.rmse_prior for r in subset])), float(np.mean([r.rmse_smoothness for r in subset]))
        return {
            "cameras": len({r.camera for r in subset}),
            "mean_rmse_prior": a,
            "mean_rmse_smoothness": b,
            "improvement": 1 - a / b,
        }

    return {
        "cameras": len({r.camera for r in results}),
        "seeds": sorted({r.seed for r in results}),
        "per_seed": {seed: means([r for r in results if r.seed == seed]) for seed in sorted({r.seed for r in results})},
        "families": {
            family: means([r for r in results if r.family == family]) for family in sorted({r.family for r in results})
        },
        "mean_rmse_prior": prior,
        "mean_rmse_smoothness": smooth,
        "improvement": 1 - prior / smooth,
        "max_rmse_prior": float(max(r.rmse_prior for r in results)),
        "flash_delta_e_mean": float(np.mean([r.flash_delta_e_mean for r in results])),
        "flash_delta_e_max": float(max(r.flash_delta_e_max for r in results)),
    }


LIGHT_SETS = {"LEDs": (), "LEDs+A": ("A",), "LEDs+A+D65": ("A", "D65")}
"""Light sets of :func:`regime_study`: the LEDs alone, plus one, plus two broadband lights."""


def regime_study(
    noise_factors: Sequence[float] = (1.0, 4.0, 16.0),
    methods: Sequence[str] = ("smoothness", "pca_prior", "pca_subspace"),
    camera_names: Sequence[str] | None = None,
    chart: str = "macbeth",
    seed: int = 0,
) -> dict[tuple[float, str, str], list[float]]:
    """Leave-one-camera-out RMSE per (noise factor, light set, method), one value per camera.

    The chart is rendered once per camera under all lights (as :func:`leave_one_camera_out`);
    a noise factor ``k > 1`` adds Gaussian noise of ``sqrt(k² − 1)`` × the standard error to every
    patch mean (and multiplies the standard error by ``k``), i.e. ``k`` times the noise of the
    study's sensor. Light subsets drop rows; nothing is tuned on the camera under test.
    """
    from msflash.calibration.camera_response import fit_channels, measurement_matrix

    grid = DEFAULT_GRID
    cameras, names, reflectances, lights, rng = _study_world(camera_names, chart, seed, grid)
    results: dict[tuple[float, str, str], list[float]] = {}
    for name in names:
        truth = cameras[name]
        responses, std = simulate_chart_responses(truth, reflectances, lights, rng=rng)
        prior = learn_prior(cameras, exclude=[name])
        for factor in noise_factors:
            noisy = responses + rng.normal(size=responses.shape) * std * np.sqrt(max(factor**2 - 1, 0.0))
            for set_name, broadband in LIGHT_SETS.items():
                index = list(range(lights.count - len(BROADBAND_LIGHTS))) + [lights.names.index(b) for b in broadband]
                design = measurement_matrix(reflectances, lights.select(index))
                data, errors = noisy[index].reshape(-1, 3), (std[index] * factor).reshape(-1, 3)
                for method in methods:
                    fit = fit_channels(design, data, errors, method, None if method == "smoothness" else prior)
                    estimate = fit.normalised(grid, "regime study").responsivities
                    results.setdefault((float(factor), set_name, method), []).append(responsivity_rmse(estimate, truth))
    return results
