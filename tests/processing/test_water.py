"""The underwater light model: absorption components, attenuation with depth and distance."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from msflash.processing import datasets, lights, water
from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import DEFAULT_GRID, WavelengthGrid

WAVELENGTHS = DEFAULT_GRID.wavelengths_nm


def at(values: np.ndarray, nm: float) -> float:
    return float(values[WAVELENGTHS == nm][0])


class TestAbsorption:
    def test_pure_water_is_pope_and_fry(self) -> None:
        a = water.WATER_TYPES["pure"].absorption(DEFAULT_GRID)
        assert a.names == water.ABSORPTION_COMPONENTS
        assert at(a.column("water"), 700) == pytest.approx(0.624)  # Pope & Fry 1997, 700 nm
        assert at(a.column("water"), 440) == pytest.approx(0.00635, rel=0.02)
        assert np.all(a.values[:, 1:] == 0)  # nothing else in a pool

    def test_pure_water_transmittance_is_beer_lambert(self) -> None:
        absorption = datasets.water_absorption().resample(DEFAULT_GRID)
        transmittance = water.water_transmittance(2.0).values[:, 0]
        np.testing.assert_allclose(transmittance, np.exp(-2.0 * absorption.values[:, 0]))

    def test_phytoplankton_is_bricaud_1998(self) -> None:
        body = water.WaterBody(chlorophyll_mg_m3=2.0, cdom_440_per_m=0.0, nap_440_per_m=0.0)
        phytoplankton = body.absorption(DEFAULT_GRID).column("phytoplankton")
        assert at(phytoplankton, 440) == pytest.approx(0.037824 * 2.0**0.626633)  # Aphi, Ephi at 440 nm
        assert WAVELENGTHS[np.argmax(phytoplankton)] in (430, 440)  # the blue chlorophyll peak
        assert at(phytoplankton, 670) > at(phytoplankton, 600)  # and the red one

    def test_cdom_and_particles_decay_exponentially_from_440(self) -> None:
        body = water.WaterBody(chlorophyll_mg_m3=1.0, cdom_440_per_m=0.3, nap_440_per_m=0.05)
        a = body.absorption(DEFAULT_GRID)
        assert at(a.column("cdom"), 440) == pytest.approx(0.3)
        assert at(a.column("cdom"), 540) == pytest.approx(0.3 * np.exp(-1.4))
        assert at(a.column("nap"), 640) == pytest.approx(0.05 * np.exp(-2.2))
        assert body.total_absorption(DEFAULT_GRID) == pytest.approx(a.values.sum(axis=1))

    def test_default_particles_follow_chlorophyll(self) -> None:
        assert water.WaterBody(chlorophyll_mg_m3=4.0).nap_440 == pytest.approx(0.0124 * 4.0**0.724)

    def test_attenuation_includes_backscatter_and_mean_cosine(self) -> None:
        body = water.WATER_TYPES["coastal"]
        a, bb = body.total_absorption(), body.backscattering()
        assert np.all(bb > 0) and np.all(bb < 0.1 * a.max())
        assert body.diffuse_attenuation() == pytest.approx((a + bb) / 0.85)

    @pytest.mark.parametrize("field", ["chlorophyll_mg_m3", "cdom_440_per_m", "nap_440_per_m", "mean_cosine"])
    def test_rejects_bad_constituents(self, field: str) -> None:
        with pytest.raises(SpectralDataError, match=field):
            water.WaterBody(**{field: -1.0})


class TestUnderwaterAmbient:
    def test_no_water_is_the_surface_light(self) -> None:
        d65 = datasets.illuminant("D65")
        ambient = water.underwater_ambient(0.0, 0.0)
        assert ambient.unit == "energy" and ambient.values.max() == pytest.approx(1.0)
        assert ambient.values == pytest.approx(d65.values)

    def test_red_goes_first_and_more_with_depth(self) -> None:
        d65 = datasets.illuminant("D65").values[:, 0]
        shallow = water.underwater_ambient(2.0, 1.0).values[:, 0] / d65
        deep = water.underwater_ambient(10.0, 1.0).values[:, 0] / d65
        for ratio in (shallow, deep):
            assert at(ratio, 650) < 0.5 * at(ratio, 500)
        assert at(deep, 650) / at(deep, 500) < at(shallow, 650) / at(shallow, 500)

    def test_exact_beer_lambert_factor(self) -> None:
        body = water.WATER_TYPES["ocean"]
        d65 = datasets.illuminant("D65").values[:, 0]
        expected = d65 * np.exp(-body.diffuse_attenuation() * 5.0 - body.path_attenuation() * 1.5)
        ambient = water.underwater_ambient(5.0, 1.5, water="ocean").values[:, 0]
        assert ambient == pytest.approx(expected / expected.max())

    def test_green_coastal_water_shifts_the_peak_to_green(self) -> None:
        ocean = water.underwater_ambient(5.0, 1.0, water="clear_ocean")
        coastal = water.underwater_ambient(5.0, 1.0, water="coastal")
        assert WAVELENGTHS[np.argmax(ocean.values)] < 500 < WAVELENGTHS[np.argmax(coastal.values)]

    def test_overrides_and_presets(self) -> None:
        body = replace(water.WATER_TYPES["ocean"], chlorophyll_mg_m3=3.0, cdom_440_per_m=0.2)
        explicit = water.underwater_ambient(5.0, 1.0, water=body)
        assert explicit.values == pytest.approx(water.underwater_ambient(5.0, 1.0, water="coastal").values)
        with pytest.raises(SpectralDataError, match="expected one of pure"):
            water.underwater_ambient(water="bathtub")
        with pytest.raises(SpectralDataError, match="depth_m"):
            water.underwater_ambient(-1.0)

    def test_flash_path_is_there_and_back(self) -> None:
        assert water.flash_path_transmittance(0.75, "ocean").values == pytest.approx(
            water.WATER_TYPES["ocean"].transmittance(1.5).values
        )

    def test_the_sim_rig_ambient(self) -> None:
        rig = lights.ambient_spectrum("underwater_ocean")
        assert rig.names == ("underwater_ocean",)
        assert rig.values == pytest.approx(water.underwater_ambient(5.0, 1.0, water="ocean").values)

    def test_other_grids(self) -> None:
        grid = WavelengthGrid(400, 700, 5)
        assert water.underwater_ambient(5.0, 1.0, grid=grid).grid == grid
