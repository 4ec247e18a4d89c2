"""The export writers on their own: every CFA through LibRaw, and the refusals of each writer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rawpy
import tifffile

from msflash.acquisition.errors import UsageError
from msflash.acquisition.export.dng import CFA_COLOURS, write_dng
from msflash.acquisition.export.formats import parse_formats
from msflash.acquisition.export.ome_tiff import OmePlane, write_ome_tiff
from msflash.acquisition.export.spectra_csv import SpectrumColumn, write_spectra_csv

MOSAIC = (np.arange(24 * 36).reshape(24, 36) % 1000 + 64).astype(np.uint16)
NEUTRAL = (0.5, 1.0, 0.25)


def dng(path: Path, **changes) -> Path:
    arguments = {
        "mosaic": MOSAIC,
        "cfa": "RGGB",
        "black_level": 64,
        "white_level": 1023,
        "neutral": NEUTRAL,
        "xyz_to_camera": np.eye(3),
        "camera_model": "unit",
    }
    arguments.update(changes)
    return write_dng(path, **arguments)


@pytest.mark.parametrize("cfa", list(CFA_COLOURS))
def test_every_cfa_reads_back_in_libraw(tmp_path: Path, cfa: str) -> None:
    path = dng(tmp_path / "f.dng", cfa=cfa)
    with rawpy.imread(str(path)) as raw:
        colours = raw.color_desc.decode()
        assert "".join(colours[c] for c in raw.raw_pattern.ravel()) == cfa
        np.testing.assert_array_equal(raw.raw_image, MOSAIC)
        assert raw.black_level_per_channel == [64] * 4 and raw.white_level == 1023
        multipliers = np.asarray(raw.camera_whitebalance[:3])
    np.testing.assert_allclose(multipliers[1] / multipliers, NEUTRAL, rtol=1e-6)


def test_eight_bit_counts_are_written_as_sixteen(tmp_path: Path) -> None:
    path = dng(tmp_path / "f.dng", mosaic=(MOSAIC % 256).astype(np.uint8), white_level=255, black_level=0)
    with tifffile.TiffFile(path) as tiff:
        assert tiff.pages[0].dtype == np.uint16
        np.testing.assert_array_equal(tiff.pages[0].asarray(), MOSAIC % 256)


@pytest.mark.parametrize(
    ("changes", "what"),
    [
        ({"mosaic": MOSAIC.astype(np.float32)}, r"expected \(H, W\) counts"),
        ({"mosaic": np.stack([MOSAIC] * 3, axis=2)}, r"expected \(H, W\) counts"),
        ({"cfa": "RGBW"}, "CFA 'RGBW'"),
        ({"neutral": (1.0, 0.0, 0.5)}, "neutral"),
        ({"xyz_to_camera": np.eye(2)}, "colour matrix"),
    ],
)
def test_dng_refuses_what_it_cannot_describe(tmp_path: Path, changes: dict, what: str) -> None:
    with pytest.raises(ValueError, match=what):
        dng(tmp_path / "f.dng", **changes)


def test_ome_tiff_refuses_frames_that_do_not_fit_the_planes(tmp_path: Path) -> None:
    planes = [OmePlane("a", 1.0, 1.0), OmePlane("b", 1.0, 1.0)]
    frames = [np.zeros((4, 5), np.uint16), np.zeros((4, 6), np.uint16)]
    with pytest.raises(ValueError, match="frame 1"):
        write_ome_tiff(tmp_path / "a.ome.tif", frames, planes, [], "cam", "seq")
    with pytest.raises(ValueError, match="1 frames for 2 planes"):
        write_ome_tiff(tmp_path / "b.ome.tif", frames[:1], planes, [], "cam", "seq")


def test_spectra_csv_refuses_a_short_column_and_repeated_headers(tmp_path: Path) -> None:
    wavelengths = np.array([400.0, 410.0, 420.0])
    with pytest.raises(ValueError, match="has 2 values; expected 3"):
        write_spectra_csv(tmp_path / "a.csv", wavelengths, [SpectrumColumn("x", "u", np.ones(2))])
    twice = [SpectrumColumn("x", "u", np.ones(3))] * 2
    with pytest.raises(ValueError, match="repeat"):
        write_spectra_csv(tmp_path / "b.csv", wavelengths, twice)


def test_format_names() -> None:
    assert parse_formats("DNG,ome-tiff, csv") == ("dng", "ome-tiff", "csv")
    with pytest.raises(UsageError, match="--export dng,,csv: format '': unknown"):
        parse_formats("dng,,csv", "--export")
