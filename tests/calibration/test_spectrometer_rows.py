"""Spectrometer exports whose rows are not one ascending row per wavelength, written as the instruments write them
(tests/calibration/spectrometer_writers.py: each program's layout, decimal commas, BOM, CRLF, a header block, the
dark's baseline in every reading): descending wavelengths, a repeated row, one wavelength read twice, one column.
They were refused ("expected strictly increasing wavelengths", "1 column"); the legitimate ones are read now
(calibration/spectrometer_rows.py, docs/calibration.md *Row order, repeats and one column*)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from msflash.calibration.errors import CalibrationError, CalibrationWarning
from msflash.calibration.files import load_calibration
from msflash.calibration.spectrometer import read_spectrometer_file
from tests.calibration.spectrometer_writers import FORMATS, Instrument, encoded, export_text
from tests.calibration.test_spectrometer_exports import _compare, _response_file, _truth, _write_booth, run


def _descending(instrument: Instrument) -> Instrument:
    """The same instrument scanning from long to short wavelengths (its exports list the samples in that order)."""
    return Instrument(
        instrument.wavelengths_nm[::-1].copy(),
        instrument.response[::-1].copy(),
        instrument.offset,
        instrument.dark_rate[::-1].copy(),
        instrument.read_noise,
    )


@pytest.mark.parametrize(
    ("form", "quirks"),
    [
        *((form, {}) for form in FORMATS),
        ("oceanview", {"text": {"decimal_comma": True}, "bytes": {"crlf": True, "bom": True}}),
        ("avasoft", {"text": {"decimal_comma": True}, "bytes": {"bom": True}}),
        ("thorlabs", {"text": {"decimal_comma": True}, "bytes": {"crlf": True}}),
    ],
    ids=[*FORMATS, "oceanview-comma-crlf-bom", "avasoft-comma-bom", "thorlabs-comma-crlf"],
)
def test_a_descending_export_calibrates_as_the_ascending_one(form: str, quirks: dict, tmp_path: Path) -> None:
    """LEDs, dark and the spectrometer's response all exported long to short: the stored LED spectra are those of
    the same readings exported short to long (each value kept with its wavelength)."""
    up, down = tmp_path / "up", tmp_path / "down"
    up.mkdir(), down.mkdir()
    instrument = Instrument.typical(4)
    stored = []
    for folder, used in ((up, instrument), (down, _descending(instrument))):
        files, dark, _ = _write_booth(folder, form, seed=4, instrument=used, **quirks)
        response = _response_file(folder, used)
        status, _, err = run(
            ["calibrate", "leds", *files, "--dark", str(dark), "--spectrometer-response", response]
            + ["--out", str(folder / "cal")]
        )
        assert status == 0, err
        stored.append(load_calibration(folder / "cal").led_spectra)
    # The noise was drawn in row order, so the readings differ by noise only; the shapes and ratios agree.
    _compare(stored[1], _truth(), energy_tol=0.01, shape_tol=0.02)
    _compare(stored[0], _truth(), energy_tol=0.01, shape_tol=0.02)


def _plain_export(tmp_path: Path, wavelengths: np.ndarray, counts: np.ndarray, **text: object) -> str:
    return export_text("plain", wavelengths, counts, 0.01, 4, name="led520", **text)  # type: ignore[arg-type]


def test_a_row_written_twice_is_read_once_without_a_warning(tmp_path: Path) -> None:
    instrument = Instrument.typical(5, pixels=400)
    counts = instrument.counts(None, 0.01, 4, np.random.default_rng(5)) + 500 * np.hanning(400)
    text = _plain_export(tmp_path, instrument.wavelengths_nm, counts)
    lines = text.splitlines()
    repeated = [*lines[:200], lines[199], *lines[200:]]  # a writer repeating a line at a segment boundary
    once, twice = tmp_path / "once.csv", tmp_path / "twice.csv"
    once.write_bytes(encoded(text, crlf=True))
    twice.write_bytes(encoded("\n".join(repeated) + "\n", crlf=True))
    read = read_spectrometer_file(twice)
    np.testing.assert_array_equal(read.wavelengths_nm, read_spectrometer_file(once).wavelengths_nm)
    np.testing.assert_array_equal(read.values, read_spectrometer_file(once).values)
    assert read.metadata["order"] == ("line 201 repeats line 200: read once",)


def test_wavelengths_rounded_in_the_export_are_averaged_with_a_warning(tmp_path: Path) -> None:
    """A 0.05-nm-pitch CCD exported with one decimal: adjacent pixels print one wavelength, each its own reading.
    Read as the mean of that wavelength's readings, every one of them kept in it; one warning names the lines."""
    instrument = Instrument.typical(6, start=500.0, stop=530.0, pixels=600)
    counts = instrument.counts(None, 0.01, 4, np.random.default_rng(6)) + 3000 * np.hanning(600)
    rounded = np.round(instrument.wavelengths_nm, 1)
    path = tmp_path / "rounded.txt"
    path.write_bytes(encoded(_plain_export(tmp_path, rounded, counts, decimal_comma=False), bom=True))
    with pytest.warns(
        CalibrationWarning,
        match=r"rounded\.txt: 2 readings at 500\.1 nm, [\d.]+ \(line 6\), [\d.]+ \(line 7\): averaged; \d+ more wavel",
    ):
        read = read_spectrometer_file(path)
    unique = np.unique(rounded)
    np.testing.assert_array_equal(read.wavelengths_nm, unique)
    written = np.round(counts, 3)  # the export writes 3 decimals
    np.testing.assert_allclose(read.values, [written[rounded == w].mean() for w in unique], rtol=1e-12)


def test_a_second_scan_appended_is_refused_naming_both_lines(tmp_path: Path) -> None:
    instrument = Instrument.typical(7, pixels=200)
    counts = instrument.counts(None, 0.01, 4, np.random.default_rng(7)) + 1000 * np.hanning(200)
    text = _plain_export(tmp_path, instrument.wavelengths_nm, counts)
    rows = [line for line in text.splitlines() if line[:1].isdigit()]
    path = tmp_path / "two-scans.csv"
    path.write_text(text + "\n".join(rows[:50]) + "\n")
    with pytest.raises(CalibrationError) as refused:
        read_spectrometer_file(path)
    message = str(refused.value)
    assert message.startswith(f"{path}:205: wavelength 340 nm after 800 nm (line 204); expected the wavelengths in one")


@pytest.mark.parametrize(
    ("header", "step"),
    [
        (["Start wavelength (nm): 380", "Step (nm): 2,5"], 2.5),
        (["# start_wavelength;380", "# end_wavelength;877,5"], 2.5),
        (["First wavelength = 380 nm", "Interval = 5"], 5.0),
    ],
)
def test_one_column_under_a_header_giving_the_grid_is_read(header: list[str], step: float, tmp_path: Path) -> None:
    values = 100 + 1000 * np.hanning(200)
    path = tmp_path / "one.txt"
    text = "\n".join(["Spectral data, one value a line", *header, "Irradiance", *(f"{v:.3f}" for v in values)])
    path.write_bytes(encoded(text + "\n", bom=True, crlf=True))
    read = read_spectrometer_file(path)
    np.testing.assert_allclose(read.wavelengths_nm, 380 + step * np.arange(200))
    np.testing.assert_allclose(read.values, np.round(values, 3))


def test_one_column_without_a_grid_is_refused_saying_what_is_expected(tmp_path: Path) -> None:
    path = tmp_path / "values.csv"
    path.write_text("Irradiance\n1\n2\n3\n")
    with pytest.raises(CalibrationError) as refused:
        read_spectrometer_file(path)
    assert str(refused.value) == (
        f"{path}:2: 1 column; expected at least 2 (wavelength_nm, value), or one value a line under a header giving "
        "the first wavelength and the step ('Start wavelength: 380' and 'Step: 1', or 'End: 780')"
    )
