"""Shipped spectral data, the CSV reader and the illuminants."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import DEFAULT_GRID, WavelengthGrid


class TestShippedFiles:
    def test_provenance_and_licences_are_beside_the_data(self) -> None:
        sources = (datasets.DATA_DIR / "SOURCES.md").read_text(encoding="utf-8")
        assert (datasets.DATA_DIR / "LICENSE-ISETCam-MIT.txt").read_text(encoding="utf-8").startswith("The files")
        assert "CC BY-NC-SA" in (datasets.DATA_DIR / "noncommercial" / "LICENSE.md").read_text(encoding="utf-8")
        for path in datasets.DATA_DIR.rglob("*.csv"):
            assert path.name in sources, f"{path.name} is shipped but not described in SOURCES.md"

    def test_total_size_stays_small(self) -> None:
        total = sum(p.stat().st_size for p in datasets.DATA_DIR.rglob("*") if p.is_file())
        assert total < 1_000_000

    def test_noncommercial_data_only_in_its_folder(self) -> None:
        for path in datasets.DATA_DIR.rglob("*.csv"):
            if "noncommercial" not in path.parts:
                assert "Jiang" not in path.read_text(encoding="utf-8").splitlines()[0], path


class TestPaperData:
    def test_leds(self) -> None:
        leds = datasets.paper_leds()
        # Named after their measured peaks (processing/led_wavelength.py), the paper's nominal ones beside them.
        assert leds.names == ("led440", "led478", "led500", "led522", "led597", "led636", "led661")
        assert (leds.kind, leds.unit, leds.count) == ("spd", "energy", 7)
        assert leds.grid == WavelengthGrid(380, 1068, 4)
        peaks = leds.wavelengths_nm[np.argmax(leds.values, axis=0)]
        np.testing.assert_allclose(peaks, datasets.PAPER_LED_PEAKS_NM, atol=8)
        assert [round(p) for p in leds.metadata["peak_nm"].values()] == [int(n[3:]) for n in leds.names]
        assert list(leds.metadata["nominal_peak_nm"].values()) == list(datasets.PAPER_LED_PEAKS_NM)

    @pytest.mark.parametrize(
        ("count", "expected"),
        [
            (3, ("led440", "led522", "led661")),
            (4, ("led440", "led500", "led522", "led661")),
            (5, ("led440", "led500", "led522", "led597", "led661")),
            (6, ("led440", "led478", "led500", "led522", "led597", "led661")),
            (7, None),
        ],
    )
    def test_led_subsets_follow_the_paper(self, count: int, expected: tuple[str, ...] | None) -> None:
        subset = datasets.paper_led_subset(count)
        assert subset.names == (expected or datasets.paper_leds().names)

    def test_led_subset_rejects_unknown_count(self) -> None:
        with pytest.raises(SpectralDataError, match="expected one of 3, 4, 5, 6, 7"):
            datasets.paper_led_subset(2)

    def test_charts(self) -> None:
        assert datasets.natural100().count == 100
        chart = datasets.chart110()
        assert (chart.count, chart.kind, chart.unit, chart.grid) == (110, "reflectance", "none", DEFAULT_GRID)
        np.testing.assert_allclose(chart.values[:, :100], datasets.natural100().values)
        gray = chart.values[:, 100:]
        np.testing.assert_allclose(gray, np.broadcast_to(np.logspace(0, np.log10(0.05), 10), gray.shape), rtol=1e-5)
        for source in ("isetcam", "paper"):
            assert datasets.macbeth(source).count == 24  # type: ignore[arg-type]

    def test_paper_cameras(self) -> None:
        cameras = datasets.paper_cameras()
        assert len(cameras) == 34
        for name, camera in cameras.items():
            assert camera.names == ("R", "G", "B"), name
            assert (camera.kind, camera.unit, camera.grid) == ("responsivity", "photons", DEFAULT_GRID)
            assert camera.values.max() == pytest.approx(1.0)
        assert "CC BY-NC-SA" in cameras["Canon 20D"].metadata["licence"]
        permissive = datasets.paper_cameras(include_noncommercial=False)
        assert sorted(permissive) == sorted(
            ["AptinaMT9M031", "AptinaMT9M131", "NikonD1", "NikonD70", "NikonD100", "NikonD200IR"]
        )
        assert all("MIT" in c.metadata["licence"] for c in permissive.values())


class TestOtherSets:
    @pytest.mark.parametrize("name", datasets.ISETCAM_CAMERAS)
    def test_isetcam_cameras(self, name: str) -> None:
        camera = datasets.isetcam_camera(name)
        assert (camera.names, camera.kind, camera.unit) == (("R", "G", "B"), "responsivity", "photons")
        assert np.all(np.isfinite(camera.values))
        camera.resample(DEFAULT_GRID)  # every shipped camera covers the processing grid

    def test_aptina_nan_set_to_zero_as_the_paper_does(self) -> None:
        camera = datasets.isetcam_camera("aptinamt9m031")
        assert len(camera.metadata["nan_set_to_zero"]) == 3
        assert camera.values[0, 0] == 0.0 and camera.values[0, 2] == 0.0

    def test_isetcam_leds_and_vrhel(self) -> None:
        assert datasets.isetcam_leds("luxeon8").count == 8
        assert datasets.isetcam_leds("luxeon4").unit == "energy"
        assert datasets.vrhel("munsell").count == 64
        assert datasets.vrhel("skin").count == 26
        with pytest.raises(SpectralDataError, match="expected one of objects"):
            datasets.vrhel("plastic")

    def test_water(self) -> None:
        absorption = datasets.water_absorption().resample(DEFAULT_GRID)
        assert absorption.metadata["unit"] == "1/m"
        # pure water absorbs red far more than blue (Pope & Fry 1997)
        assert absorption.column("a_w")[-1] > 10 * absorption.column("a_w")[5]


class TestCsvReader:
    def write(self, tmp_path: Path, text: str) -> Path:
        path = tmp_path / "table.csv"
        path.write_text(text, encoding="utf-8")
        return path

    def test_reads_comments_header_and_values(self, tmp_path: Path) -> None:
        path = self.write(tmp_path, "# a comment\nwavelength_nm,a,b\n400,1,2\n\n410,3,4\n")
        spectra = datasets.load_spectra_csv(path, "spd", "energy")
        assert spectra.names == ("a", "b") and spectra.grid == WavelengthGrid(400, 410, 10)
        assert spectra.values.tolist() == [[1, 2], [3, 4]]
        assert spectra.metadata["comments"] == ["a comment"] and spectra.source == str(path)

    def test_nan_is_an_error_naming_file_line_and_column(self, tmp_path: Path) -> None:
        path = self.write(tmp_path, "# c\nwavelength_nm,a,b\n400,1,nan\n410,3,4\n")
        with pytest.raises(SpectralDataError, match=r"table\.csv:3: column 'b' is missing"):
            datasets.load_spectra_csv(path, "spd", "energy")
        spectra = datasets.load_spectra_csv(path, "spd", "energy", nan="zero")
        assert spectra.values[0, 1] == 0.0 and spectra.metadata["nan_set_to_zero"] == [(3, "b")]

    @pytest.mark.parametrize(
        ("text", "match"),
        [
            ("wavelength_nm,a\n400,1\n410,x\n", r"table\.csv:3: column 'a' holds 'x'; expected a number"),
            ("wavelength_nm,a\n400,1\n410,1,2\n", r"table\.csv:3: 3 cells; expected 2"),
            ("lambda,a\n400,1\n", r"table\.csv:1: header"),
            ("wavelength_nm,a\n400,1\n410,2\n430,3\n", r"table\.csv.*not uniformly spaced"),
            ("# only comments\n", r"table\.csv: no data rows"),
        ],
    )
    def test_bad_tables_are_named(self, tmp_path: Path, text: str, match: str) -> None:
        with pytest.raises(SpectralDataError, match=match):
            datasets.load_spectra_csv(self.write(tmp_path, text), "spd", "energy")

    def test_byte_order_mark_and_windows_line_ends(self, tmp_path: Path) -> None:
        """Excel's 'CSV UTF-8' starts with a BOM: the header read '\\ufeffwavelength…' and was refused
        (msflash flash --target table.csv: "header is 'wavelength,value'" with the BOM invisible)."""
        path = tmp_path / "table.csv"
        path.write_bytes("\ufeffwavelength_nm,a\r\n400,1\r\n410,3\r\n".encode())
        spectra = datasets.load_spectra_csv(path, "spd", "energy")
        assert spectra.names == ("a",) and spectra.values[:, 0].tolist() == [1, 3]

    def test_missing_file(self, tmp_path: Path) -> None:
        with pytest.raises(SpectralDataError, match="missing.csv: cannot be read"):
            datasets.load_spectra_csv(tmp_path / "missing.csv", "spd", "energy")

    def test_names_must_match_columns(self, tmp_path: Path) -> None:
        path = self.write(tmp_path, "wavelength_nm,a,b\n400,1,2\n410,3,4\n")
        with pytest.raises(SpectralDataError, match="1 names given for 2 spectra"):
            datasets.load_spectra_csv(path, "spd", "energy", names=["x"])


class TestIlluminants:
    @pytest.mark.parametrize("name", ["A", "D50", "D65", "FL2", "fl11", "blackbody:3200"])
    def test_standard_illuminants(self, name: str) -> None:
        spectrum = datasets.illuminant(name)
        assert (spectrum.grid, spectrum.kind, spectrum.unit) == (DEFAULT_GRID, "spd", "energy")
        assert spectrum.values.max() == pytest.approx(1.0)

    def test_blackbody_follows_planck(self) -> None:
        grid = WavelengthGrid(400, 700, 50)
        wavelengths_m = grid.wavelengths_nm * 1e-9
        # colour uses the ITS-90 second radiation constant, hence the loose tolerance
        planck = 1.0 / (
            wavelengths_m**5 * (np.exp(6.62607015e-34 * 299792458.0 / (wavelengths_m * 1.380649e-23 * 3200)) - 1)
        )
        np.testing.assert_allclose(
            datasets.illuminant("blackbody:3200", grid).values[:, 0], planck / planck.max(), rtol=2e-4
        )

    def test_unknown_illuminant(self) -> None:
        with pytest.raises(SpectralDataError, match="illuminant 'D99': unknown; expected one of A, B, C, D50"):
            datasets.illuminant("D99")
        with pytest.raises(SpectralDataError, match="bad temperature"):
            datasets.illuminant("blackbody:hot")


def test_a_and_the_d_series_extend_beyond_the_780_nm_tables() -> None:
    """CIE A (Planck) and D65 (the D-series basis, 300–830 nm) on the CIE's own 360–830 nm grid; D65 computed
    agrees with its table where both exist; FL2 (a table only) is refused, or zero beyond it on request."""
    wide = WavelengthGrid(360.0, 830.0, 5.0)
    d65_wide, d65 = datasets.illuminant("D65", wide), datasets.illuminant("D65", WavelengthGrid(380.0, 780.0, 5.0))
    overlap = d65_wide.values[4:85, 0]
    np.testing.assert_allclose(overlap / overlap.max(), d65.values[:, 0] / d65.values[:, 0].max(), atol=0.01)
    assert np.all(d65_wide.values > 0)
    a = datasets.illuminant("A", WavelengthGrid(360.0, 1000.0, 5.0))
    assert np.all(np.diff(a.values[:, 0]) > 0)  # 2856 K: rising through the near infrared
    with pytest.raises(SpectralDataError):
        datasets.illuminant("FL2", wide)
    fl2 = datasets.illuminant("FL2", wide, outside="zero").values[:, 0]
    inside = (wide.wavelengths_nm >= 380) & (wide.wavelengths_nm <= 780)  # FL2's table
    assert fl2[~inside].max() == 0 and fl2[inside].min() > 0
