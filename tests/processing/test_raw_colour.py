"""The neutral and colour matrix DNG and EXR exports carry (processing.raw_colour)."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.raw_colour import camera_matrix, camera_neutral, rgb_chromaticities
from msflash.processing.render import reflectances_to_xyz
from msflash.processing.spectra import Spectra
from tests.helpers import GRID, camera


def test_the_neutral_is_the_cameras_response_to_white_under_the_light() -> None:
    light = datasets.illuminant("A", GRID)
    cam = camera()
    response = cam.to_unit("photons").values.T @ light.to_unit("photons").values[:, 0]
    np.testing.assert_allclose(camera_neutral(light, cam), response / response.max(), rtol=1e-12)
    # The unit the spectra come in does not matter.
    np.testing.assert_allclose(
        camera_neutral(light.to_unit("photons"), cam.to_unit("energy")), camera_neutral(light, cam), rtol=1e-12
    )


def test_a_light_the_camera_misses_in_a_channel_is_refused() -> None:
    values = np.zeros(GRID.size)
    values[-3:] = 1.0  # deep red only: the blue channel of a real camera sees almost nothing, but not zero
    cam = camera()
    curves = cam.values.copy()
    curves[-3:, 2] = 0.0
    blind = cam.replace(values=curves)
    red = Spectra(GRID, values[:, None], ("red",), kind="spd", unit="energy")
    with pytest.raises(SpectralDataError, match="expected three values > 0"):
        camera_neutral(red, blind)


def test_the_colour_matrix_maps_d65_white_to_a_largest_channel_of_one_and_inverts_the_fit() -> None:
    matrix = camera_matrix(camera())
    white = Spectra(GRID, np.ones((GRID.size, 1)), ("white",), kind="reflectance", unit="none")
    d65_white = reflectances_to_xyz(white, datasets.illuminant("D65", GRID))[0]
    assert (matrix.xyz_to_camera @ d65_white).max() == pytest.approx(1.0)
    product = matrix.xyz_to_camera @ matrix.camera_to_xyz
    np.testing.assert_allclose(product / product[0, 0], np.eye(3), atol=1e-12)
    # The camera's neutral under D65 is what the matrix gives for D65's white, as DNG readers assume.
    neutral = camera_neutral(datasets.illuminant("D65", GRID), camera())
    np.testing.assert_allclose(matrix.xyz_to_camera @ d65_white, neutral, atol=0.05)


def test_chromaticities_refuse_a_primary_outside_the_visible() -> None:
    with pytest.raises(SpectralDataError, match="blue primary"):
        rgb_chromaticities(np.array([[1.0, 0.0, -1.0], [0.0, 1.0, 0.0], [0.0, 0.0, -0.5]]))
