"""The simulated rig's ambients and lights by name (processing.lights)."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing import lights
from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import DEFAULT_GRID


class TestAmbients:
    @pytest.mark.parametrize("name", lights.AMBIENTS)
    def test_ambients(self, name: str) -> None:
        spectrum = lights.ambient_spectrum(name)
        assert (spectrum.names, spectrum.unit, spectrum.grid) == ((name,), "energy", DEFAULT_GRID)
        assert np.all(spectrum.values >= 0) and spectrum.values.max() == pytest.approx(1.0)

    def test_ambient_shapes_are_plausible(self) -> None:
        wavelengths = DEFAULT_GRID.wavelengths_nm
        assert 500 <= wavelengths[np.argmax(lights.ambient_spectrum("green").values)] <= 560
        orange = lights.ambient_spectrum("orange").values[:, 0]
        assert orange[wavelengths >= 620].min() > 10 * orange[wavelengths <= 520].max()
        daylight = lights.ambient_spectrum("daylight").values[:, 0]
        underwater = lights.ambient_spectrum("underwater", water_path_m=5.0).values[:, 0]
        ratio = underwater / daylight
        assert ratio[-1] < 0.1 * ratio[4]  # red is absorbed first
        with pytest.raises(SpectralDataError, match="expected one of tungsten"):
            lights.ambient_spectrum("moonlight")
