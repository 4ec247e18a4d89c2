"""The sim rig's ``--ambient FILE`` read as ``--target`` reads a measured light: a spectral table, or the spectrometer
export of the lamp as the instrument's program writes it (tests/calibration/spectrometer_writers.py). The export and the
table of the same numbers capture the same frames, bit for bit; a raw-counts export says so in one warning line. On
8f05306 ``--ambient`` of an export was refused ("header is 'Data from …'; expected 'wavelength_nm,<name>,…'")."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.reader import read_sequence
from tests.acquisition.app.test_target_files import _light, _table
from tests.calibration.spectrometer_writers import encoded, export_text

pytestmark = pytest.mark.filterwarnings(
    "default::msflash.processing.errors.SpectralDataWarning", "default::msflash.calibration.errors.CalibrationWarning"
)


def _capture(ambient: Path, out: Path) -> tuple[list[np.ndarray], str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main(["capture", "--rig", "sim", "--seed", "5", "--ambient", str(ambient), "--out", str(out)])
    assert status == 0, err.getvalue()
    sequence = read_sequence(out / "sequence")
    return [sequence.load_frame(index) for index in range(len(sequence.frames))], err.getvalue()


@pytest.mark.parametrize(("form", "decimal_comma"), [("oceanview", False), ("avasoft", True), ("thorlabs", False)])
def test_an_ambient_exported_by_a_spectrometer_captures_the_frames_of_its_table(
    tmp_path: Path, form: str, decimal_comma: bool
) -> None:
    wavelengths, counts = _light()
    table = tmp_path / "lamp.csv"
    table.write_text(_table(wavelengths, counts), newline="")
    export = tmp_path / "lamp.txt"
    export.write_bytes(
        encoded(export_text(form, wavelengths, counts, 0.01, 4, name="lamp", decimal_comma=decimal_comma), crlf=True)
    )
    expected, _ = _capture(table, tmp_path / "from-table")
    frames, err = _capture(export, tmp_path / "from-export")
    assert len(frames) == len(expected) == 8
    for frame, wanted in zip(frames, expected, strict=True):
        np.testing.assert_array_equal(frame, wanted)
    warned = [line for line in err.splitlines() if line.startswith("msflash: warning:") and "raw spectrometer" in line]
    assert len(warned) == 1 and str(export) in warned[0], err


def test_an_ambient_file_that_is_neither_table_nor_export_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    notes = tmp_path / "lamp.txt"
    notes.write_text("measured the lamp on Tuesday\nit was warm\n")
    status = main(["capture", "--rig", "sim", "--ambient", str(notes), "--out", str(tmp_path / "c")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    assert err[0].startswith(f"msflash: error: {notes}") and "as an export" in err[0], err


def test_an_ambient_value_beyond_noise_is_refused_naming_its_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wavelengths, counts = _light()
    rows = ["wavelength_nm,lamp"] + [f"{w:g},{c:g}" for w, c in zip(wavelengths, counts, strict=True)]
    bad = len(rows) // 2
    rows[bad] = f"{wavelengths[bad - 1]:g},{-counts.max():g}"  # a whole peak below zero: no noise
    lamp = tmp_path / "lamp.csv"
    lamp.write_text("# lamp, measured\n" + "\n".join(rows) + "\n")
    status = main(["capture", "--rig", "sim", "--ambient", str(lamp), "--out", str(tmp_path / "c")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    assert err[0].startswith(f"msflash: error: {lamp}:{bad + 2}: column 'lamp' at {wavelengths[bad - 1]:g} nm"), err
    assert not (tmp_path / "c").exists()


def test_a_file_named_like_a_light_leaves_the_name_a_light(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A file ``tungsten`` beside the command does not replace the light ``--ambient tungsten`` names;
    ``./tungsten`` reads it (as ``--target`` treats a file named like an illuminant)."""
    monkeypatch.chdir(tmp_path)
    named, _ = _capture(Path("tungsten"), tmp_path / "named")
    wavelengths, counts = _light()
    (tmp_path / "tungsten").write_text(_table(wavelengths, counts), newline="")
    beside, _ = _capture(Path("tungsten"), tmp_path / "beside")
    for frame, wanted in zip(beside, named, strict=True):
        np.testing.assert_array_equal(frame, wanted)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main(["capture", "--rig", "sim", "--seed", "5", "--ambient", "./tungsten", "--out", "file"])
    assert status == 0, err.getvalue()
    sequence = read_sequence(tmp_path / "file" / "sequence")
    assert not np.array_equal(sequence.load_frame(0), named[0])
