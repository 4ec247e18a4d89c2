"""Camera responsivities from a chart under LEDs + two broadband lights (reduced leave-one-out study)."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.calibration.camera_response import (
    estimate_responsivities,
    learn_prior,
    measurement_matrix,
    responsivity_rmse,
)
from msflash.calibration.errors import CalibrationError
from msflash.calibration.validation import calibration_lights
from msflash.lab.study.camera_calibration import leave_one_camera_out, summarise
from msflash.processing import datasets
from msflash.processing.image_formation import surface_responses
from msflash.processing.spectra import DEFAULT_GRID

FAST_CAMERAS = ("NikonD100", "Canon 40D", "Nikon D700", "Pentax K-5")


def test_measurement_matrix_is_the_image_formation_model():
    chart = datasets.macbeth().resample(DEFAULT_GRID)
    lights = calibration_lights()
    camera = datasets.paper_cameras()["NikonD100"].resample(DEFAULT_GRID, outside="zero")
    expected = np.stack([surface_responses(chart, lights.select([l]), camera) for l in range(lights.count)])
    np.testing.assert_allclose(measurement_matrix(chart, lights) @ camera.values, expected.reshape(-1, 3), rtol=1e-12)


def test_noise_free_recovery_is_exact():
    chart = datasets.macbeth().resample(DEFAULT_GRID)
    lights = calibration_lights()
    cameras = {k: v.resample(DEFAULT_GRID, outside="zero") for k, v in datasets.paper_cameras().items()}
    truth = cameras["Nikon D700"]
    responses = np.stack([surface_responses(chart, lights.select([l]), truth) for l in range(lights.count)])
    estimate = estimate_responsivities(
        responses,
        chart,
        lights,
        "pca_prior",
        learn_prior(cameras, ["Nikon D700"]),
        response_std=1e-6 * responses.max() + 0 * responses,
    )
    assert responsivity_rmse(estimate.responsivities, truth) < 2e-3


def test_reduced_leave_one_out_meets_bound():
    """A few cameras of the acceptance study (the full run is tests/lab/study/test_camera_calibration.py)."""
    summary = summarise(leave_one_camera_out(FAST_CAMERAS))
    assert summary["mean_rmse_prior"] <= 0.05
    assert summary["mean_rmse_prior"] < summary["mean_rmse_smoothness"]
    assert summary["flash_delta_e_max"] <= 1.0


def test_bad_inputs():
    chart = datasets.macbeth().resample(DEFAULT_GRID)
    lights = calibration_lights()
    good = np.ones((lights.count, chart.count, 3))
    with pytest.raises(CalibrationError, match=r"expected \(9, 24, 3\)"):
        estimate_responsivities(good[:, :3], chart, lights, "smoothness")
    with pytest.raises(CalibrationError, match="unknown; expected one of smoothness, pca_prior, pca_subspace"):
        estimate_responsivities(good, chart, lights, "magic")
    with pytest.raises(CalibrationError, match="needs a prior"):
        estimate_responsivities(good, chart, lights, "pca_prior")
    bad = good.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(CalibrationError, match="not finite"):
        estimate_responsivities(bad, chart, lights, "smoothness")
    with pytest.raises(CalibrationError, match="training cameras"):
        learn_prior({"a": datasets.paper_cameras()["NikonD100"]})


def test_prior_learns_curve_shapes_not_channel_gains():
    """A training camera's channel gains (white balance, peak normalisation) do not change the prior."""
    cameras = {k: v.resample(DEFAULT_GRID, outside="zero") for k, v in list(datasets.paper_cameras().items())[:5]}
    regained = dict(cameras)
    first = next(iter(cameras))
    regained[first] = cameras[first].replace(values=cameras[first].values * np.array([3.0, 0.5, 7.0]))
    a, b = learn_prior(cameras), learn_prior(regained)
    for channel in ("R", "G", "B"):
        np.testing.assert_allclose(a.moments[channel], b.moments[channel], rtol=1e-12)
        assert np.trace(a.moments[channel]) == pytest.approx(1.0)  # every shape has unit norm
    dead = dict(cameras)
    dead[first] = cameras[first].replace(values=cameras[first].values * np.array([1.0, 0.0, 1.0]))
    with pytest.raises(CalibrationError, match=f"camera '{first}' channel G is zero everywhere"):
        learn_prior(dead)


def test_subspace_prior_recovers_noise_free_camera():
    chart = datasets.macbeth().resample(DEFAULT_GRID)
    lights = calibration_lights()
    cameras = {k: v.resample(DEFAULT_GRID, outside="zero") for k, v in datasets.paper_cameras().items()}
    truth = cameras["Canon 40D"]
    responses = np.stack([surface_responses(chart, lights.select([l]), truth) for l in range(lights.count)])
    estimate = estimate_responsivities(
        responses,
        chart,
        lights,
        "pca_subspace",
        learn_prior(cameras, ["Canon 40D"]),
        response_std=1e-6 * responses.max() + 0 * responses,
    )
    assert responsivity_rmse(estimate.responsivities, truth) < 2e-3
