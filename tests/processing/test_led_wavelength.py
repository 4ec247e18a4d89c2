"""One number for each LED's wavelength (processing/led_wavelength.py, docs/decisions/led-wavelength.md)."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.calibration.led_spectra import characterise_led
from msflash.calibration.spectrometer import SpectrometerMeasurement
from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.led_wavelength import led_name, led_peaks_nm, peak_nm, with_peaks
from msflash.processing.spectra import Spectra, WavelengthGrid


@pytest.mark.parametrize("true_peak", [440.0, 478.3, 521.75, 597.2, 660.6])
@pytest.mark.parametrize("step", [1.0, 4.0, 5.0, 10.0])
def test_the_peak_of_a_narrow_led_does_not_depend_on_the_sampling(true_peak: float, step: float) -> None:
    wavelengths = np.arange(380.0, 781.0, step)
    spectrum = np.exp(-0.5 * ((wavelengths - true_peak) / 11.0) ** 2)
    assert peak_nm(wavelengths, spectrum) == pytest.approx(true_peak, abs=0.5 if step > 5 else 0.1)


def test_the_papers_leds_keep_their_number_on_every_grid_within_half_a_nanometre() -> None:
    leds = datasets.paper_leds()
    measured = led_peaks_nm(leds)
    for step in (4, 5, 10):
        bare = leds.resample(WavelengthGrid(400, 700, step)).replace(metadata={})
        np.testing.assert_allclose(led_peaks_nm(bare), measured, atol=0.5)
    # Recorded where measured, the number travels with the spectra: resampled, in photons, a subset.
    moved = leds.resample(WavelengthGrid(400, 700, 10)).to_unit("photons").select([4, 1])
    assert led_peaks_nm(moved) == (measured[4], measured[1])


def test_the_peak_is_of_the_energy_spectrum() -> None:
    wavelengths = np.arange(400.0, 701.0, 1.0)
    broad = Spectra(WavelengthGrid(400, 700, 1), np.exp(-0.5 * ((wavelengths - 600.0) / 30.0) ** 2), ("amber",))
    photons = broad.to_unit("photons")
    assert peak_nm(wavelengths, photons.values[:, 0]) > 600.5  # ×λ moves a broad peak redder
    assert led_peaks_nm(photons) == led_peaks_nm(broad) == (600.0,)


def test_names_derive_from_the_peak_and_the_paper_keeps_its_nominal_figures() -> None:
    leds = datasets.paper_leds()
    assert leds.names == tuple(led_name(p) for p in led_peaks_nm(leds))
    assert tuple(leds.metadata["nominal_peak_nm"].values()) == datasets.PAPER_LED_PEAKS_NM


def test_calibration_reports_the_same_number() -> None:
    leds = datasets.paper_leds()
    for index, name in enumerate(leds.names):
        measurement = SpectrometerMeasurement(leds.wavelengths_nm, leds.values[:, index], "energy", name, name)
        assert characterise_led(measurement).peak_nm == led_peaks_nm(leds)[index]


def test_edges_flat_tops_and_nothing() -> None:
    wavelengths = np.arange(400.0, 451.0, 10.0)
    assert peak_nm(wavelengths, np.array([5.0, 4, 3, 2, 1, 0])) == 400.0  # at the edge: the sample
    assert peak_nm(wavelengths, np.array([0.0, 1, 1, 1, 0, 0])) == 420.0  # a flat top (saturated): its middle
    with pytest.raises(SpectralDataError, match="no positive value"):
        peak_nm(wavelengths, np.zeros(6))
    with pytest.raises(SpectralDataError, match="one per wavelength"):
        peak_nm(wavelengths, np.ones(5))
    spectra = Spectra(WavelengthGrid(400, 450, 10), np.array([0.0, 1, 3, 1, 0, 0]), ("x",))
    assert with_peaks(spectra).metadata["peak_nm"] == {"x": 420.0}
