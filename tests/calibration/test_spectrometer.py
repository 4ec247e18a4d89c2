"""Spectrometer exports: formats, units, grids, dark subtraction and bad files."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.calibration.errors import CalibrationError
from msflash.calibration.spectrometer import (
    measurement_to_spectra,
    parse_spectrometer_text,
    read_spectrometer_file,
)
from msflash.calibration.spectrometer_dark import remove_baseline
from msflash.processing.spectra import DEFAULT_GRID, PHOTON_REFERENCE_NM


def gaussian(w, peak=520.0, sigma=10.0):
    return np.exp(-0.5 * ((w - peak) / sigma) ** 2)


def export(w, v, separator=",", header="wavelength_nm,value", comments=("# PR-715 export",)):
    lines = list(comments) + ([header] if header else [])
    lines += [f"{a:.6f}{separator}{b:.9g}" for a, b in zip(w, v)]
    return "\n".join(lines) + "\n"


class TestParse:
    def test_csv_with_comments_and_header(self, tmp_path):
        w = np.arange(380.0, 781.0, 4.0)
        path = tmp_path / "led520.csv"
        path.write_text(export(w, gaussian(w)))
        m = read_spectrometer_file(path)
        assert m.name == "led520" and m.unit == "energy"
        np.testing.assert_allclose(m.wavelengths_nm, w)
        np.testing.assert_allclose(m.values, gaussian(w), rtol=1e-8)

    @pytest.mark.parametrize("separator", ["\t", " ", "   ", ";"])
    def test_text_separators(self, separator):
        w = np.arange(400.0, 701.0, 1.0)
        m = parse_spectrometer_text(export(w, gaussian(w), separator, header="Wavelength (nm)\tIrradiance"), "x.txt")
        np.testing.assert_allclose(m.values, gaussian(w), rtol=1e-8)

    @pytest.mark.parametrize("separator", [";", "\t"])
    def test_decimal_commas_with_semicolon_or_tab_separators(self, separator):
        """'380,0;2,1699' (a spectrometer program in a decimal-comma locale) was split at every comma:
        '4 columns', and --column 2 then read the integer parts (2.0, 5.0, 45.0…) without a word."""
        w = np.arange(400.0, 701.0, 1.0)
        v = 1000 * gaussian(w) + 2.1699
        text = "Wellenlänge;Wert\n".replace(";", separator) + "".join(
            f"{a:.1f}{separator}{b:.4f}\n".replace(".", ",") for a, b in zip(w, v)
        )
        m = parse_spectrometer_text(text, "de.csv")
        np.testing.assert_allclose(m.wavelengths_nm, w)
        np.testing.assert_allclose(m.values, np.round(v, 4), rtol=1e-12)

    def test_decimal_commas_between_comma_separators_are_refused_with_a_hint(self):
        text = "nm,W\n400,0,2,5\n410,0,3,5\n420,0,2,5\n"
        with pytest.raises(CalibrationError, match=r"ambig\.csv:2: 4 columns; .*export with ';' or tab separators"):
            parse_spectrometer_text(text, "ambig.csv")

    @pytest.mark.parametrize("encoding", ["utf-16", "utf-16-be", "utf-8-sig"])
    def test_utf16_and_bom_files_with_windows_line_endings(self, tmp_path, encoding):
        """A UTF-16 export (Windows 'Unicode') was refused as 'binary data'."""
        w = np.arange(380.0, 781.0, 4.0)
        text = export(w, gaussian(w), header="Wavelength (nm),µW/cm²/nm").replace("\n", "\r\n")
        data = text.encode(encoding)
        if encoding == "utf-16-be":
            data = b"\xfe\xff" + data
        path = tmp_path / "win.csv"
        path.write_bytes(data)
        m = read_spectrometer_file(path)
        np.testing.assert_allclose(m.values, gaussian(w), rtol=1e-8)

    def test_ocean_optics_block(self):
        w = np.arange(400.0, 500.0, 0.5)
        text = (
            "Data from x.txt Node\nIntegration Time (sec): 0.1\n>>>>>Begin Spectral Data<<<<<\n"
            + "\n".join(f"{a:.2f}\t{b:.6f}" for a, b in zip(w, gaussian(w, 450)))
            + "\n>>>>>End Spectral Data<<<<<\n"
        )
        m = parse_spectrometer_text(text, "oo.txt")
        assert m.values.size == w.size and len(m.header) == 3

    def test_value_column_chosen(self):
        text = "nm,dark,raw,counts\n400,1,2,3\n410,1,5,6\n420,1,2,3\n"
        assert parse_spectrometer_text(text, "three.csv", column=2).values.tolist() == [2, 5, 2]
        with pytest.raises(CalibrationError, match=r"three\.csv:2: 4 columns; expected 2"):
            parse_spectrometer_text(text, "three.csv")

    def test_photon_units_convert(self):
        w = np.arange(400.0, 701.0, 10.0)
        photons = parse_spectrometer_text(export(w, np.ones_like(w)), "p.csv", unit="photons")
        energy = measurement_to_spectra(photons, DEFAULT_GRID, unit="energy")
        np.testing.assert_allclose(energy.values[:, 0], PHOTON_REFERENCE_NM / w)

    def test_arbitrary_nonuniform_grid(self):
        rng = np.random.default_rng(1)
        w = np.sort(rng.uniform(350, 800, 2500))  # a CCD spectrometer: ~0.18 nm, uneven
        m = parse_spectrometer_text(export(w, gaussian(w, 530, 12)), "ccd.txt")
        assert not m.uniform
        spectra = measurement_to_spectra(m, DEFAULT_GRID)
        np.testing.assert_allclose(spectra.values[:, 0], gaussian(DEFAULT_GRID.wavelengths_nm, 530, 12), atol=5e-3)

    def test_dark_subtraction(self):
        w = np.arange(400.0, 701.0, 2.0)
        light = parse_spectrometer_text(export(w, gaussian(w) + 0.1), "l.csv")
        dark = parse_spectrometer_text(export(w, np.full_like(w, 0.1)), "d.csv")
        np.testing.assert_allclose(remove_baseline(light, dark).values, gaussian(w), atol=1e-8)
        other = parse_spectrometer_text(export(w[:-1], np.full(w.size - 1, 0.1)), "d2.csv")
        with pytest.raises(CalibrationError, match=r"d2\.csv: dark export .*expected the same instrument grid"):
            remove_baseline(light, other)


class TestBadFiles:
    def test_empty(self, tmp_path):
        path = tmp_path / "empty.csv"
        path.write_text("# nothing\n")
        with pytest.raises(CalibrationError, match=r"empty\.csv: 0 data lines"):
            read_spectrometer_file(path)

    def test_missing_file(self, tmp_path):
        with pytest.raises(CalibrationError, match=r"nope\.csv: cannot be read"):
            read_spectrometer_file(tmp_path / "nope.csv")

    def test_binary(self, tmp_path):
        path = tmp_path / "spec.spc"
        path.write_bytes(b"\x00\x01\x02" * 10)
        with pytest.raises(CalibrationError, match="binary data"):
            read_spectrometer_file(path)

    def test_non_monotonic(self):
        with pytest.raises(CalibrationError, match=r"bad\.csv:4: wavelength 405 nm after 410 nm"):
            parse_spectrometer_text("nm,v\n400,1\n410,2\n405,1\n420,0\n", "bad.csv")

    def test_nan(self):
        with pytest.raises(CalibrationError, match=r"nan\.csv:3: column 2 is 'nan'; expected a finite number"):
            parse_spectrometer_text("nm,v\n400,1\n410,nan\n420,0\n", "nan.csv")

    def test_negative(self):
        with pytest.raises(
            CalibrationError,
            match=r"neg\.csv:4: column 'v' at 420 nm is -0\.5; expected a non-negative value, "
            r"or measurement noise down to −0\.1 .*dark subtracted twice",
        ):
            parse_spectrometer_text("nm,v\n400,1\n410,2\n420,-0.5\n", "neg.csv")

    def test_small_negative_noise_kept(self):
        assert parse_spectrometer_text("nm,v\n400,-0.01\n410,2\n420,0\n", "ok.csv").values[0] == -0.01

    def test_wrong_columns(self):
        with pytest.raises(CalibrationError, match=r"one\.csv:2: 1 column; expected at least 2"):
            parse_spectrometer_text("value\n1\n2\n3\n", "one.csv")
        with pytest.raises(CalibrationError, match=r"ragged\.csv:3: 3 columns; expected 2"):
            parse_spectrometer_text("400,1\n410,2\n420,3,4\n", "ragged.csv")

    def test_text_inside_data(self):
        with pytest.raises(CalibrationError, match=r"mid\.csv:3: 'oops' is not numeric"):
            parse_spectrometer_text("400,1\n410,2\noops\n420,3\n", "mid.csv")

    def test_not_nanometres(self):
        with pytest.raises(CalibrationError, match="expected nanometres"):
            parse_spectrometer_text("0.4,1\n0.41,2\n0.42,1\n", "um.csv")

    def test_emission_outside_the_grid_is_refused(self):
        """An export that misses the grid (an IR LED at 2450 nm) became an all-zero LED column."""
        w = np.arange(2380.0, 2781.0, 1.0)
        m = parse_spectrometer_text(export(w, gaussian(w, 2450, 12)), "ir.csv")
        with pytest.raises(CalibrationError, match=r"ir\.csv: no emission on 400–700 nm .*peak at 2450 nm"):
            measurement_to_spectra(m, DEFAULT_GRID)

    def test_no_signal(self):
        with pytest.raises(CalibrationError, match="no positive value"):
            parse_spectrometer_text("400,0\n410,0\n420,0\n", "zero.csv")
