"""The sim rig's table options read by the one set of row rules (processing/spectral_rows.py): the ambient, the scene's
reflectances, the camera's responsivities and the LED spectra written descending (an Excel sort "largest to
smallest", saved as CSV UTF-8: BOM, CRLF) capture the same frames, bit for bit, as the ascending tables. On main
4bed5cc each was refused ("wavelengths must increase strictly")."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.reader import read_sequence
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID, Spectra


def _write(path: Path, spectra: Spectra, descending: bool) -> str:
    """``spectra`` as a spreadsheet saves it: six significant digits, CRLF, and a BOM when sorted descending."""
    order = slice(None, None, -1) if descending else slice(None)
    rows = [
        f"{w:g}," + ",".join(f"{v:.6g}" for v in row)
        for w, row in zip(spectra.wavelengths_nm[order], spectra.values[order])
    ]
    text = "\r\n".join(["wavelength_nm," + ",".join(spectra.names), *rows]) + "\r\n"
    path.write_bytes(text.encode("utf-8-sig" if descending else "utf-8"))
    return str(path)


def _capture(folder: Path, descending: bool) -> list[np.ndarray]:
    folder.mkdir()
    tables = {
        "--ambient": datasets.illuminant("A", DEFAULT_GRID),
        "--scene": datasets.macbeth().resample(DEFAULT_GRID),
        "--sim-camera": datasets.isetcam_camera("NikonD70").resample(DEFAULT_GRID).to_unit("energy"),
        "--led-spectra": datasets.paper_led_subset(5).resample(DEFAULT_GRID),
    }
    options = [w for o, s in tables.items() for w in (o, _write(folder / f"{o[2:]}.csv", s, descending))]
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main(["capture", "--rig", "sim", "--seed", "3", *options, "--out", str(folder / "out")])
    assert status == 0, err.getvalue()
    sequence = read_sequence(folder / "out" / "sequence")
    return [sequence.load_frame(index) for index in range(len(sequence.frames))]


def test_descending_tables_capture_the_frames_of_the_ascending_ones(tmp_path: Path) -> None:
    ascending, descending = _capture(tmp_path / "up", False), _capture(tmp_path / "down", True)
    assert len(ascending) == len(descending) == 6
    for up, down in zip(ascending, descending, strict=True):
        np.testing.assert_array_equal(down, up)
