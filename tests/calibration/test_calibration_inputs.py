"""The calibration steps as a notebook calls them (``session.calibration_inputs``), without the CLI."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.acquisition.errors import UsageError
from msflash.acquisition.session.calibration_inputs import (
    camera_from_chart_sequences,
    measured_leds,
    simulated_camera_calibration,
)


def test_a_simulated_camera_is_recovered_and_its_section_names_how() -> None:
    lines: list[str] = []
    result = simulated_camera_calibration("NikonD100", report=lines.append)
    assert result.rmse_vs_truth < 0.1  # the prior from the other 33 cameras; docs/calibration.md has the table
    section = result.section()
    assert section["simulated_camera"] == "NikonD100" and section["method"] == "pca_prior"
    assert section["lights"] == list(result.lights.names) and len(section["relative_residual"]) == 3
    assert lines and "NikonD100" in lines[0]  # progress goes where the caller says


def test_an_unknown_camera_or_a_mismatched_light_list_is_refused_by_name() -> None:
    with pytest.raises(UsageError, match="--camera 'NoSuchCam'"):
        simulated_camera_calibration("NoSuchCam")
    with pytest.raises(UsageError, match="expected at least one chart sequence"):
        camera_from_chart_sequences([], [])
    with pytest.raises(UsageError, match="--chart chart110"):
        camera_from_chart_sequences([], [], chart="chart110")


def test_spectrometer_exports_become_spectra_with_their_characterisation(tmp_path) -> None:
    wavelengths = np.arange(380, 781, 1.0)
    files = []
    for peak in (450.0, 530.0, 630.0):
        path = tmp_path / f"led{peak:.0f}.csv"
        values = np.exp(-0.5 * ((wavelengths - peak) / 10.0) ** 2) * 1000 + 5
        path.write_text("wavelength_nm,counts\n" + "".join(f"{w:g},{v:.4f}\n" for w, v in zip(wavelengths, values)))
        files.append(path)
    dark = tmp_path / "dark.csv"
    dark.write_text("wavelength_nm,counts\n" + "".join(f"{w:g},5\n" for w in wavelengths))
    result = measured_leds(files, dark=dark, report=lambda line: None)
    assert result.spectra.count == 3
    assert [round(c.peak_nm) for c in result.characterisations] == [450, 530, 630]
    assert result.section["sources"] == [str(f) for f in files] and result.section["dark"] == str(dark)
    assert np.allclose(result.section["fwhm_nm"], 2 * np.sqrt(2 * np.log(2)) * 10, atol=1.5)
