"""The sim rig's table options read by the one set of row rules (processing/spectral_rows.py): the ambient, the scene's
reflectances, the camera's responsivities and the LED spectra written descending (an Excel sort "largest to
smallest", saved as CSV UTF-8: BOM, CRLF) capture the same frames, bit for bit, as the ascending tables. On main
4bed5cc each was refused ("wavelengths must increase strictly"). So do the tables as a spreadsheet in a locale whose
decimal mark is a comma saves them (cells between semicolons, decimal commas) and as tab-delimited text; on 8f05306
each was refused ("header is 'wavelength_nm;…'; expected 'wavelength_nm,<name>,…'")."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.reader import read_sequence
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID, Spectra


def _write(path: Path, spectra: Spectra, style: str) -> str:
    """``spectra`` as a spreadsheet saves it: six significant digits, CRLF; ``descending``: sorted largest to smallest
    with a BOM; ``semicolons``: cells between semicolons, decimal commas; ``tabs``: tab-delimited."""
    order = slice(None, None, -1) if style == "descending" else slice(None)
    separator = {"semicolons": ";", "tabs": "\t"}.get(style, ",")
    mark = "," if style == "semicolons" else "."

    def cell(value: float) -> str:
        return f"{value:.6g}".replace(".", mark)

    rows = [
        separator.join([cell(w), *(cell(v) for v in row)])
        for w, row in zip(spectra.wavelengths_nm[order], spectra.values[order])
    ]
    text = "\r\n".join([separator.join(["wavelength_nm", *spectra.names]), *rows]) + "\r\n"
    path.write_bytes(text.encode("utf-8-sig" if style == "descending" else "utf-8"))
    return str(path)


def _capture(folder: Path, style: str) -> list[np.ndarray]:
    folder.mkdir()
    tables = {
        "--ambient": datasets.illuminant("A", DEFAULT_GRID),
        "--scene": datasets.macbeth().resample(DEFAULT_GRID),
        "--sim-camera": datasets.isetcam_camera("NikonD70").resample(DEFAULT_GRID).to_unit("energy"),
        "--led-spectra": datasets.paper_led_subset(5).resample(DEFAULT_GRID),
    }
    options = [w for o, s in tables.items() for w in (o, _write(folder / f"{o[2:]}.csv", s, style))]
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main(["capture", "--rig", "sim", "--seed", "3", *options, "--out", str(folder / "out")])
    assert status == 0, err.getvalue()
    sequence = read_sequence(folder / "out" / "sequence")
    return [sequence.load_frame(index) for index in range(len(sequence.frames))]


@pytest.mark.parametrize("style", ["descending", "semicolons", "tabs"])
def test_tables_as_spreadsheets_save_them_capture_the_frames_of_the_plain_ones(tmp_path: Path, style: str) -> None:
    plain, written = _capture(tmp_path / "plain", "plain"), _capture(tmp_path / style, style)
    assert len(plain) == len(written) == 6
    for expected, frame in zip(plain, written, strict=True):
        np.testing.assert_array_equal(frame, expected)
