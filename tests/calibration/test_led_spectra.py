"""LED characterisation: peak, FWHM, Ohno model, warnings, relative power through the camera."""

from __future__ import annotations

import math

import numpy as np
import pytest

from msflash.calibration.errors import CalibrationError
from msflash.calibration.led_spectra import characterise_led, emission_model_Ohno2005, relative_power_through_camera
from msflash.calibration.spectrometer import SpectrometerMeasurement
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID

W = np.arange(380.0, 781.0, 1.0)


def measured(values, name="led"):
    return SpectrometerMeasurement(W, np.asarray(values, dtype=float), "energy", f"{name}.csv", name)


@pytest.mark.parametrize("peak,sigma", [(440.0, 8.0), (523.3, 12.0), (660.0, 9.5)])
def test_gaussian_peak_and_fwhm(peak, sigma):
    c = characterise_led(measured(np.exp(-0.5 * ((W - peak) / sigma) ** 2)))
    assert c.peak_nm == pytest.approx(peak, abs=0.05)
    assert c.fwhm_nm == pytest.approx(2 * math.sqrt(2 * math.log(2)) * sigma, rel=2e-3)
    assert c.centroid_nm == pytest.approx(peak, abs=0.05)
    assert not c.saturated and c.warnings == ()


def test_ohno_model_recovered_exactly():
    truth = emission_model_Ohno2005(W, 3.0, 597.0, 14.0, 22.0)
    c = characterise_led(measured(truth))
    assert c.model_residual < 1e-6
    assert c.model["peak_nm"] == pytest.approx(597.0, abs=1e-3)
    assert c.model["width_left_nm"] == pytest.approx(14.0, rel=1e-4)
    assert c.model["width_right_nm"] == pytest.approx(22.0, rel=1e-4)


def test_paper_leds_fit_and_broad_amber_flagged():
    leds = datasets.paper_leds()
    for index, name in enumerate(leds.names):
        m = SpectrometerMeasurement(leds.wavelengths_nm, leds.values[:, index], "energy", name, name)
        c = characterise_led(m)
        assert abs(c.peak_nm - int(name[3:])) < 15
        if name != "led596":
            assert c.model_residual < 0.05, (name, c.model_residual)


def test_saturation_warning():
    clipped = np.minimum(np.exp(-0.5 * ((W - 520) / 10) ** 2), 0.7)
    c = characterise_led(measured(clipped, "clipped"))
    assert c.saturated
    assert any("saturated" in w and "clipped.csv" in w for w in c.warnings)
    # The model is fitted on the unclipped flanks, so it still sees the true peak height.
    assert c.model["amplitude"] > 0.8


def test_noise_warning():
    rng = np.random.default_rng(0)
    noisy = np.exp(-0.5 * ((W - 520) / 10) ** 2) + rng.normal(0, 0.05, W.size)
    c = characterise_led(measured(noisy, "noisy"))
    assert c.snr < 100 and any("noisy" in w for w in c.warnings)


def test_no_peak_refused():
    with pytest.raises(CalibrationError, match=r"flat\.csv: no emission peak"):
        characterise_led(measured(np.ones_like(W), "flat"))


def test_relative_power_through_camera():
    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero").to_unit("photons")
    camera = datasets.isetcam_camera("NikonD100").resample(DEFAULT_GRID, outside="zero").to_unit("photons")
    true_power = np.array([1.0, 0.4, 0.7, 0.25, 0.9, 0.6, 0.5])
    responses = (camera.values.T @ (leds.values * true_power)).T * 123.0  # any exposure scale
    shapes = leds.normalised("each_max")  # the spectrometer lost the ratios
    powers = relative_power_through_camera(shapes, responses, camera)
    recovered = shapes.values * powers
    expected = leds.values * true_power
    np.testing.assert_allclose(recovered / recovered.max(), expected / expected.max(), rtol=1e-9, atol=1e-12)
    with pytest.raises(CalibrationError, match="expected \\(7, 3\\)"):
        relative_power_through_camera(shapes, responses[:3], camera)
