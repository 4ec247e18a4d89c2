"""The spectral core: one grid type, one container, the only resamplers, the unit conversion."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import (
    DEFAULT_GRID,
    Spectra,
    WavelengthGrid,
    energy_to_photons,
    photons_to_energy,
    require_same_grid,
    require_unit,
)

EXACT = 1e-12


class TestWavelengthGrid:
    def test_size_and_wavelengths(self) -> None:
        assert DEFAULT_GRID.size == 31
        np.testing.assert_allclose(DEFAULT_GRID.wavelengths_nm[[0, -1]], [400, 700])

    @pytest.mark.parametrize(
        "start, stop, step, message",
        [
            (400, 700, 0, "step_nm"),
            (700, 400, 10, "below start"),
            (400, 705, 10, "does not divide"),
            (400, np.inf, 10, "finite"),
        ],
    )
    def test_bad_grids_are_refused(self, start, stop, step, message) -> None:
        with pytest.raises(SpectralDataError, match=message):
            WavelengthGrid(start, stop, step)

    def test_from_wavelengths_names_the_source(self) -> None:
        with pytest.raises(SpectralDataError, match=r"^seq.json: wavelengths_nm: .*not uniformly spaced"):
            WavelengthGrid.from_wavelengths([400, 410, 425], where="seq.json: wavelengths_nm")
        with pytest.raises(SpectralDataError, match="increase strictly"):
            WavelengthGrid.from_wavelengths([400, 400, 410])
        assert WavelengthGrid.from_wavelengths(np.arange(380, 781, 5)).same_as(WavelengthGrid(380, 780, 5))


class TestSpectra:
    def test_values_are_read_only_and_validated(self) -> None:
        s = Spectra(DEFAULT_GRID, np.ones(31), ("flat",))
        with pytest.raises(ValueError):
            s.values[0, 0] = 2.0
        with pytest.raises(SpectralDataError, match="30 samples per spectrum"):
            Spectra(DEFAULT_GRID, np.ones(30), ("short",))
        bad = np.ones(31)
        bad[5] = np.nan
        with pytest.raises(SpectralDataError, match="'led' has a non-finite value at 450 nm"):
            Spectra(DEFAULT_GRID, bad, ("led",), source="leds.csv")
        with pytest.raises(SpectralDataError, match="unit 'energy' for kind 'reflectance'"):
            Spectra(DEFAULT_GRID, np.ones(31), ("r",), kind="reflectance", unit="energy")

    def test_resample_interpolates_and_refuses_extrapolation(self) -> None:
        s = Spectra(WavelengthGrid(400, 700, 100), [0.0, 1.0, 2.0, 3.0], ("ramp",), source="ramp.csv")
        fine = s.resample(DEFAULT_GRID)
        np.testing.assert_allclose(fine.values[:, 0], (DEFAULT_GRID.wavelengths_nm - 400) / 100, atol=EXACT)
        wide = WavelengthGrid(380, 720, 10)
        with pytest.raises(SpectralDataError, match="ramp.csv: cannot resample"):
            s.resample(wide)
        zero = s.resample(wide, outside="zero").values[:, 0]
        assert zero[0] == 0 and zero[-1] == 0 and zero[2] == 0.0
        edge = s.resample(wide, outside="edge").values[:, 0]
        assert edge[0] == 0.0 and edge[-1] == 3.0

    def test_unit_conversion_round_trips_and_keeps_camera_responses(self) -> None:
        rng = np.random.default_rng(0)
        light = Spectra(DEFAULT_GRID, rng.random(31), ("light",), unit="energy")
        camera = Spectra(DEFAULT_GRID, rng.random((31, 3)), ("R", "G", "B"), kind="responsivity", unit="energy")
        response_energy = camera.values.T @ light.values[:, 0]
        response_photons = camera.to_unit("photons").values.T @ light.to_unit("photons").values[:, 0]
        np.testing.assert_allclose(response_photons, response_energy, rtol=EXACT)
        np.testing.assert_allclose(light.to_unit("photons").to_unit("energy").values, light.values, rtol=EXACT)
        wavelengths = DEFAULT_GRID.wavelengths_nm
        np.testing.assert_allclose(
            photons_to_energy(energy_to_photons(light.values, wavelengths), wavelengths), light.values, rtol=EXACT
        )
        with pytest.raises(SpectralDataError, match="expected 'photons'"):
            require_unit(light, "photons")

    def test_grid_mismatch_names_both_sources(self) -> None:
        a = Spectra(DEFAULT_GRID, np.ones(31), ("a",), source="leds.csv")
        b = Spectra(WavelengthGrid(400, 700, 5), np.ones(61), ("b",), source="camera.csv")
        with pytest.raises(SpectralDataError, match="leds.csv is sampled on .* but camera.csv on"):
            require_same_grid(a, b)

    def test_from_samples_bins_uneven_instrument_grids_preserving_area(self) -> None:
        rng = np.random.default_rng(1)
        wavelengths = np.sort(rng.uniform(399.0, 701.0, 700))
        values = np.exp(-0.5 * ((wavelengths - 550) / 15) ** 2)
        s = Spectra.from_samples(wavelengths, values, ("led",), source="spectro.txt")
        assert s.grid.step_nm == 1.0 and s.grid.start_nm >= wavelengths[0]
        area_samples = np.trapezoid(values, wavelengths)
        area_binned = s.values[:, 0].sum() * s.grid.step_nm
        assert area_binned == pytest.approx(area_samples, rel=1e-2)
        assert s.wavelengths_nm[np.argmax(s.values[:, 0])] == pytest.approx(550, abs=1.0)
        uniform = Spectra.from_samples(DEFAULT_GRID.wavelengths_nm, np.ones(31), ("flat",))
        assert uniform.grid.same_as(DEFAULT_GRID)
        with pytest.raises(SpectralDataError, match="increase strictly"):
            Spectra.from_samples([400.0, 399.0], [1.0, 1.0], ("x",))
