"""The spectral table reader follows the one set of row rules (processing/spectral_rows.py) that the spectrometer
reader follows: a table written descending (an instrument's scan order, an Excel sort "largest to smallest"), a row
written twice, one wavelength with two readings, wavelengths that turn back. Before, every one of them was refused
("wavelengths must increase strictly"), while ``calibrate leds`` read the same rows."""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError, SpectralDataWarning

FINGERPRINTS = Path(__file__).with_name("shipped_tables_4bed5cc.json")


def _fingerprint(path: Path) -> str:
    """sha256 of a table as read: its wavelengths, values (little-endian float64) and names."""
    spectra = datasets.load_spectra_csv(path, "spd", "energy", nan="zero")
    digest = hashlib.sha256()
    digest.update(spectra.wavelengths_nm.astype("<f8").tobytes())
    digest.update(spectra.values.astype("<f8").tobytes())
    digest.update("\x00".join(spectra.names).encode())
    return digest.hexdigest()


def test_every_shipped_table_reads_to_the_numbers_it_read_before_the_row_rules() -> None:
    """Fingerprints taken with main 4bed5cc's reader (strictly ascending tables only): bit for bit the same."""
    before = json.loads(FINGERPRINTS.read_text())
    now = {str(p.relative_to(datasets.DATA_DIR)): _fingerprint(p) for p in sorted(datasets.DATA_DIR.rglob("*.csv"))}
    assert now == before
    for path in datasets.DATA_DIR.rglob("*.csv"):  # and nothing was reordered or averaged in them
        assert "row_order" not in datasets.load_spectra_csv(path, "spd", "energy", nan="zero").metadata, path


def _table(wavelengths: np.ndarray, values: np.ndarray, names: tuple[str, ...]) -> str:
    """A table as a spreadsheet writes it: 6 significant digits, CRLF."""
    rows = [",".join(f"{v:.6g}" for v in (w, *row)) for w, row in zip(wavelengths, values, strict=True)]
    return "\r\n".join(["wavelength_nm," + ",".join(names), *rows]) + "\r\n"


@pytest.fixture
def ascending(tmp_path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    wavelengths = np.arange(380.0, 781.0, 5.0)
    values = np.abs(rng.normal(1.0, 0.3, (wavelengths.size, 3)))
    path = tmp_path / "up.csv"
    path.write_bytes(_table(wavelengths, values, ("a", "b", "c")).encode("utf-8-sig"))
    return path, wavelengths, values


def test_a_descending_table_reads_as_the_ascending_one(ascending: tuple[Path, np.ndarray, np.ndarray]) -> None:
    path, wavelengths, values = ascending
    down = path.with_name("down.csv")
    down.write_bytes(_table(wavelengths[::-1], values[::-1], ("a", "b", "c")).encode("utf-8-sig"))
    up_read, down_read = (datasets.load_spectra_csv(p, "spd", "energy") for p in (path, down))
    assert down_read.grid == up_read.grid and down_read.names == up_read.names
    np.testing.assert_array_equal(down_read.values, up_read.values)
    assert down_read.metadata["row_order"] == ("descending wavelengths: read in ascending order",)
    assert "row_order" not in up_read.metadata


def test_a_row_written_twice_is_read_once_without_a_warning(ascending: tuple[Path, np.ndarray, np.ndarray]) -> None:
    path, _, _ = ascending
    lines = path.read_bytes().decode("utf-8-sig").splitlines()
    twice = path.with_name("twice.csv")
    twice.write_text("\n".join([*lines[:11], lines[10], *lines[11:]]) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read = datasets.load_spectra_csv(twice, "spd", "energy")
    np.testing.assert_array_equal(read.values, datasets.load_spectra_csv(path, "spd", "energy").values)
    assert read.metadata["row_order"] == ("line 12 repeats line 11: read once",)


def test_two_readings_of_one_wavelength_are_averaged_with_a_warning_naming_the_file_and_lines(tmp_path: Path) -> None:
    path = tmp_path / "two.csv"
    path.write_text("wavelength_nm,lamp\n400,1\n405,2\n405,4\n410,3\n415,5\n")
    with pytest.warns(SpectralDataWarning) as said:
        read = datasets.load_spectra_csv(path, "spd", "energy")
    assert [str(w.message) for w in said] == [
        f"{path}: 2 readings at 405 nm, 2 (line 3), 4 (line 4): averaged (wavelengths rounded in the export, or a "
        "scan's change-over point)"
    ]
    assert read.values[:, 0].tolist() == [1, 3, 3, 5]


def test_wavelengths_that_turn_back_are_refused_naming_the_file_and_both_lines(tmp_path: Path) -> None:
    path = tmp_path / "two-scans.csv"
    path.write_text("# two scans\nwavelength_nm,lamp\n400,1\n410,2\n420,3\n410,2\n400,1\n")
    with pytest.raises(SpectralDataError) as refused:
        datasets.load_spectra_csv(path, "spd", "energy")
    assert str(refused.value) == (
        f"{path}:6: wavelength 410 nm after 420 nm (line 5); expected the wavelengths in one order, ascending or "
        "descending (two scans in one file?)"
    )


def test_a_table_saved_with_semicolons_and_decimal_commas_or_tabs_reads_as_the_comma_table(
    ascending: tuple[Path, np.ndarray, np.ndarray],
) -> None:
    """European Excel saves "CSV" with cells between semicolons and a decimal comma; "tab delimited" text separates
    cells by tabs. Both read to the comma table's numbers (refused before as no 'wavelength_nm,<name>,…' header)."""
    path, _, _ = ascending
    plain = datasets.load_spectra_csv(path, "spd", "energy")
    text = path.read_bytes().decode("utf-8-sig")
    for name, written in (
        ("semicolons.csv", text.replace(",", ";").replace(".", ",")),
        ("tabs.txt", text.replace(",", "\t")),
    ):
        other = path.with_name(name)
        other.write_text(written)
        read = datasets.load_spectra_csv(other, "spd", "energy")
        assert read.grid == plain.grid and read.names == plain.names
        np.testing.assert_array_equal(read.values, plain.values)


def test_a_cell_with_a_thousands_mark_in_a_semicolon_table_is_refused_naming_file_line_and_column(
    tmp_path: Path,
) -> None:
    path = tmp_path / "thousands.csv"
    path.write_text("wavelength_nm;lamp\n400;1,5\n410;1.234,5\n420;2\n")
    with pytest.raises(SpectralDataError) as refused:
        datasets.load_spectra_csv(path, "spd", "energy")
    assert str(refused.value).startswith(f"{path}:3: column 'lamp' holds '1.234,5'; expected a number")
