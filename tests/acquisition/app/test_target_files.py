"""``--target FILE`` read by the one set of row rules and as a spectrometer export, through the command line.

Before (main 4bed5cc), ``--target`` took only a strictly ascending ``wavelength_nm,value`` table: the same light
written descending (an instrument's scan order, an Excel sort), or the spectrometer export ``calibrate leds`` reads,
was refused. Here each is written by independent means — tables as a spreadsheet writes them, exports by the
instrument writers of tests/calibration/spectrometer_writers.py (OceanView, SpectraSuite, AvaSoft, SpectraWiz,
Thorlabs; decimal commas, BOM, CRLF, a stored dark) — and ``msflash flash --target FILE`` must solve the flash of
the ascending table, to the bit. Hostile files are refused in one line naming the file and line (exit 2).
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.session.sequence_spectra import target_file_spectrum
from msflash.processing.spectra import Spectra
from msflash.processing.user_files import shown_path
from tests.calibration.spectrometer_writers import FORMATS, encoded, export_text

# The warnings a user is meant to read are shown as the interpreter's default filters show them, not raised as the
# suite's "error" filter would: the command line prints them as "msflash: warning: …" lines (acquisition/app/cli.py).
pytestmark = pytest.mark.filterwarnings(
    "default::msflash.processing.errors.SpectralDataWarning", "default::msflash.calibration.errors.CalibrationWarning"
)


def _run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(argv)
    return status, out.getvalue(), err.getvalue()


def _flash(sequence: Path, target: Path) -> tuple[int, dict | None, str]:
    """Exit status, the flash's JSON (without the target's name) and stderr of ``flash --target``."""
    status, out, err = _run(["flash", str(sequence), "--mode", "complementary", "--target", str(target), "--json"])
    if status != 0:
        return status, None, err
    payload = json.loads(out)
    payload.pop("target")
    return status, payload, err


def _light() -> tuple[np.ndarray, np.ndarray]:
    """A warm lamp seen by a CCD at a 0.5 nm pitch, in whole counts (every writer prints them exactly)."""
    wavelengths = np.arange(340.0, 800.5, 0.5)
    metres = wavelengths * 1e-9
    planck = 1 / (metres**5 * (np.exp(1.4388e-2 / (metres * 3200.0)) - 1))
    shape = planck / planck.max() + 0.3 * np.exp(-0.5 * ((wavelengths - 545.0) / 12.0) ** 2)
    return wavelengths, np.round(300.0 + 50000.0 * shape / shape.max())


def _table(wavelengths: np.ndarray, values: np.ndarray) -> str:
    """``wavelength_nm,lamp`` as a spreadsheet saves it (CRLF)."""
    return "\r\n".join(["wavelength_nm,lamp", *(f"{w:g},{v:g}" for w, v in zip(wavelengths, values))]) + "\r\n"


def _assert_read_as_the_table(sequence: Path, written: Path, table: Path, flash: dict) -> tuple[Spectra, str]:
    """``written`` gives ``flash --target``'s flash of the ascending ``table`` (``flash``) and its spectrum, to the bit;
    returns the spectrum read and the command's stderr."""
    status, payload, err = _flash(sequence, written)
    assert status == 0, err
    assert payload == flash
    read, expected = target_file_spectrum(str(written)), target_file_spectrum(str(table))
    assert read.grid == expected.grid
    np.testing.assert_array_equal(read.values, expected.values)
    return read, err


@pytest.fixture(scope="module")
def ascending(base_sequence: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The ascending table of the light, and the flash ``flash --target`` solves with it."""
    path = tmp_path_factory.mktemp("target") / "lamp.csv"
    path.write_text(_table(*_light()), newline="")
    status, payload, err = _flash(base_sequence, path)
    assert status == 0 and payload is not None, err
    assert "warning" not in err.replace("msflash: warning: complementary flash", ""), err
    return path, payload


def test_a_descending_table_gives_the_flash_of_the_ascending_one(
    base_sequence: Path, ascending: tuple[Path, dict], tmp_path: Path
) -> None:
    """Sorted "largest to smallest" and saved as Excel's CSV UTF-8 (BOM, CRLF)."""
    table, flash = ascending
    wavelengths, values = _light()
    down = tmp_path / "lamp-descending.csv"
    down.write_bytes(encoded(_table(wavelengths[::-1], values[::-1]), bom=True))
    _assert_read_as_the_table(base_sequence, down, table, flash)


EXPORTS = [
    *((form, {}, {}) for form in FORMATS),
    ("oceanview", {"decimal_comma": True}, {"crlf": True, "bom": True}),
    ("avasoft", {"decimal_comma": True}, {"bom": True}),
    ("avasoft", {"stored_dark": True}, {"crlf": True}),
    ("thorlabs", {"decimal_comma": True}, {"crlf": True}),
    ("oceanview", {"descending": True}, {}),
    ("spectrawiz", {"descending": True}, {"crlf": True}),
]


@pytest.mark.parametrize(
    ("form", "text", "file"),
    EXPORTS,
    ids=[*FORMATS, "oceanview-comma-crlf-bom", "avasoft-comma-bom", "avasoft-stored-dark", "thorlabs-comma-crlf"]
    + ["oceanview-descending", "spectrawiz-descending-crlf"],
)
def test_a_spectrometer_export_gives_the_flash_of_the_table_of_its_numbers(
    form: str, text: dict, file: dict, base_sequence: Path, ascending: tuple[Path, dict], tmp_path: Path
) -> None:
    """The light's export, as the instrument's program writes it: the flash of the table holding the same numbers
    (the dark an AvaSoft export stores beside its sample taken off), and a warning that raw counts still hold the
    spectrometer's response."""
    table, flash = ascending
    wavelengths, values = _light()
    options = dict(text)
    dark = np.round(80.0 + 20.0 * np.cos(wavelengths / 40.0)) if options.pop("stored_dark", False) else None
    sample = values if dark is None else values + dark
    if options.pop("descending", False):
        wavelengths, sample = wavelengths[::-1], sample[::-1]
        dark = None if dark is None else dark[::-1]
    export = tmp_path / f"lamp-{form}.txt"
    export.write_bytes(
        encoded(export_text(form, wavelengths, sample, 0.01, 4, stored_dark=dark, name="lamp", **options), **file)
    )
    read, err = _assert_read_as_the_table(base_sequence, export, table, flash)
    if form == "plain":  # "wavelength_nm,counts" under '#' comments: a table
        assert read.metadata["read_as"] == "table"
    else:
        assert read.metadata["read_as"].startswith("spectrometer export")
        warned = [line for line in err.splitlines() if "raw spectrometer counts" in line]
        assert len(warned) == 1 and warned[0].startswith(f"msflash: warning: {shown_path(export)}: "), err


def test_two_readings_of_one_wavelength_are_averaged_and_said_once(base_sequence: Path, tmp_path: Path) -> None:
    """Read when the command line is parsed and again when the flash is solved: one warning line, naming the lines."""
    wavelengths, values = _light()
    text = _table(wavelengths, values).splitlines()
    text.insert(101, f"{wavelengths[99]:g},{values[99] + 40:g}")  # line 102 reads the wavelength of line 101 again
    path = tmp_path / "rounded.csv"
    path.write_text("\n".join(text) + "\n")
    status, _, err = _flash(base_sequence, path)
    assert status == 0, err
    warned = [line for line in err.splitlines() if "averaged" in line]
    assert warned == [
        f"msflash: warning: {path}: 2 readings at {wavelengths[99]:g} nm, {values[99]:g} (line 101), "
        f"{values[99] + 40:g} (line 102): averaged (wavelengths rounded in the export, or a scan's change-over point) "
        "(SpectralDataWarning)"
    ]


def test_a_target_file_is_read_once_per_command(
    base_sequence: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Read when the command line is parsed (its warnings said) and wanted again when the flash is solved (quiet):
    one reading of the file serves both, where the quiet one read it a second time."""
    from msflash.calibration import light_files

    wavelengths, values = _light()
    path = tmp_path / "lamp.csv"
    path.write_text(_table(wavelengths, values))
    reads: list[Path] = []
    real = light_files.read_measured_light

    def counted(file: Path, **options: object) -> object:
        reads.append(Path(file))
        return real(file, **options)  # type: ignore[arg-type]

    monkeypatch.setattr(light_files, "read_measured_light", counted)
    status, _, err = _flash(base_sequence, path)
    assert status == 0, err
    assert reads == [path]


def _oceanview(wavelengths: np.ndarray, values: np.ndarray) -> list[str]:
    return export_text("oceanview", wavelengths, values, 0.01, 4, name="lamp").splitlines()


def _hostile_table(case: str) -> tuple[list[str], int]:
    """A table with one hostile thing in it, and the line an error must name."""
    wavelengths, values = _light()
    lines = _table(wavelengths, values).splitlines()
    if case == "nan":
        lines[40] = f"{wavelengths[39]:g},NaN"
    elif case == "text":
        lines[40] = f"{wavelengths[39]:g},n/a"
    elif case == "one row":
        lines = lines[:2]
        return lines, 2
    elif case == "micrometres":
        lines = ["wavelength_nm,lamp", *(f"{w / 1000:g},{v:g}" for w, v in zip(wavelengths, values))]
        return lines, 2
    elif case == "angstrom":
        lines = ["wavelength_nm,lamp", *(f"{w * 10:g},{v:g}" for w, v in zip(wavelengths, values))]
        return lines, 2
    elif case == "infrared only":
        lines = ["wavelength_nm,lamp", *(f"{w + 900:g},{v:g}" for w, v in zip(wavelengths, values))]
        return lines, 2
    elif case == "negative":
        lines[40] = f"{wavelengths[39]:g},{-0.2 * values.max():g}"
    elif case == "two scans":
        lines += lines[1:20]
        return lines, len(wavelengths) + 2
    return lines, 41


def _hostile_export(case: str) -> tuple[list[str], int]:
    """An OceanView export with one hostile thing in it, and the line an error must name."""
    wavelengths, values = _light()
    lines = _oceanview(wavelengths, values)
    first = lines.index(">>>>>Begin Spectral Data<<<<<") + 1  # index of the first data line
    row = first + 39
    if case == "nan":
        lines[row] = f"{wavelengths[39]:.2f}\tNaN"
    elif case == "text":
        lines[row] = f"{wavelengths[39]:.2f}\tn/a"
    elif case == "one row":
        lines = [*lines[:first], lines[first], lines[-1]]
        return lines, first + 1
    elif case == "micrometres":
        lines = _oceanview(wavelengths / 1000, values)
        return lines, first + 1
    elif case == "angstrom":
        lines = _oceanview(wavelengths * 10, values)
        return lines, first + 1
    elif case == "infrared only":
        lines = _oceanview(wavelengths + 900, values)
        return lines, first + 1
    elif case == "negative":
        lines[row] = f"{wavelengths[39]:.2f}\t{-0.2 * values.max():.2f}"
    elif case == "two scans":
        lines = [*lines[:-1], *lines[first : first + 20], lines[-1]]
        return lines, len(lines) - 20
    return lines, row + 1


HOSTILE = ("nan", "text", "one row", "micrometres", "angstrom", "infrared only", "negative", "two scans")


@pytest.mark.parametrize("kind", ["table", "export"])
@pytest.mark.parametrize("case", HOSTILE)
def test_a_hostile_target_is_refused_in_one_line_naming_file_and_line(
    case: str, kind: str, base_sequence: Path, tmp_path: Path
) -> None:
    lines, line = (_hostile_table if kind == "table" else _hostile_export)(case)
    path = tmp_path / ("target.csv" if kind == "table" else "target.txt")
    path.write_text("\n".join(lines) + "\n")
    status, _, err = _flash(base_sequence, path)
    assert status == 2, err
    assert "Traceback" not in err
    errors = err.splitlines()
    assert len(errors) == 1 and errors[0].startswith("msflash: error: argument --target: "), err
    assert f"{path}:{line}: " in errors[0] and "expected" in errors[0], errors[0]
    if case == "negative":  # OceanView's ">>>>>Begin Spectral Data<<<<<" names no column (it read as 'Spectral')
        assert f"column '{'lamp' if kind == 'table' else 'value'}' at 359.5 nm is -10060; " in errors[0], errors[0]


def test_a_file_neither_table_nor_export_is_refused_saying_what_was_expected(
    base_sequence: Path, tmp_path: Path
) -> None:
    path = tmp_path / "notes.txt"
    path.write_text("measured the lamp on Tuesday\nsee the lab book\n")
    status, _, err = _flash(base_sequence, path)
    assert status == 2
    assert err.splitlines() == [
        f"msflash: error: argument --target: {path}: neither a spectral table nor a spectrometer export: as a table, "
        "line 1: header is 'measured the lamp on Tuesday'; expected 'wavelength_nm,<name>,…'; as an export, 0 data "
        "lines; expected at least 3 lines of 'wavelength_nm, value'"
    ]


def test_run_on_the_sim_rig_solves_the_tables_flash_from_an_export_and_says_its_warning_once(
    ascending: tuple[Path, dict], tmp_path: Path
) -> None:
    """``msflash run --target``: the target is read when the line is parsed, then solved with twice (the decision
    before the flash frame, both flashes after it), quietly."""
    table, _ = ascending
    wavelengths, values = _light()
    export = tmp_path / "lamp.txt"
    export.write_bytes(encoded(export_text("avasoft", wavelengths[::-1], values[::-1], 0.01, 4, name="lamp")))
    solved = []
    for target, out in ((table, tmp_path / "table"), (export, tmp_path / "export")):
        status, _, err = _run(
            ["run", "--rig", "sim", "--seed", "0", "--mode", "complementary"]
            + ["--target", str(target), "--out", str(out)]
        )
        assert status == 0, err
        solved.append(json.loads((out / "flash-complementary.json").read_text()))
        said = [line for line in err.splitlines() if "raw spectrometer counts" in line]
        assert len(said) == (target == export), err
    for payload in solved:
        for key in ("target", "sequence"):
            payload.pop(key)
    assert solved[1] == solved[0]


def test_the_python_api_says_a_target_files_warning_once(base_sequence: Path, tmp_path: Path) -> None:
    """``msflash.solve_flash(…, target=FILE)`` reads the file as ``--target`` does: its warning said, once per
    version of the file (the solver's own reading is quiet)."""
    import warnings

    import msflash
    from msflash.processing.errors import SpectralDataWarning

    wavelengths, values = _light()
    text = _table(wavelengths, values).splitlines()
    text.insert(51, f"{wavelengths[49]:g},{values[49] + 40:g}")
    path = tmp_path / "api-rounded.csv"
    path.write_text("\n".join(text) + "\n")
    sequence = msflash.read_sequence(base_sequence)
    estimate = msflash.estimate_ambient(sequence)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        first = msflash.solve_flash(sequence, estimate, "complementary", str(path))
        again = msflash.solve_flash(sequence, estimate, "complementary", path)
    averaged = [w for w in said if issubclass(w.category, SpectralDataWarning)]
    assert len(averaged) == 1 and f"{path}: 2 readings at {wavelengths[49]:g} nm" in str(averaged[0].message)
    np.testing.assert_array_equal(first.flash_weights, again.flash_weights)


def test_a_folder_named_like_an_illuminant_leaves_the_name_an_illuminant(
    base_sequence: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A folder ``D65`` in the working directory (a lab's runs sorted by light) is no target file: the default
    ``--target D65`` and a typed ``--target A`` stay illuminants. On 9d2686d the default was read as the folder and
    every ``flash`` and ``run`` there was refused ("D65: is a directory")."""
    monkeypatch.chdir(tmp_path)
    expected = {}
    for name in ("D65", "A"):
        status, out, err = _run(["flash", str(base_sequence), "--mode", "complementary", "--target", name, "--json"])
        assert status == 0, err
        expected[name] = json.loads(out)["flash_weights"]
        (tmp_path / name).mkdir()
    status, out, err = _run(["flash", str(base_sequence), "--mode", "complementary", "--json"])
    assert status == 0 and json.loads(out)["flash_weights"] == expected["D65"], err
    status, out, err = _run(["flash", str(base_sequence), "--mode", "complementary", "--target", "A", "--json"])
    assert status == 0 and json.loads(out)["flash_weights"] == expected["A"], err
    # A path is still a file, and a folder is refused as one, in one line naming it.
    status, _, err = _run(["flash", str(base_sequence), "--mode", "complementary", "--target", "A/"])
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and "--target: A: is a directory" in lines[0], err


def test_a_file_named_like_an_illuminant_is_read_only_as_a_path(
    base_sequence: Path, ascending: tuple[Path, dict], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file ``D65`` beside the command (a lamp's table saved without a suffix) does not silently replace the
    illuminant the default ``--target D65`` names: the name wins, and ``./D65`` reads the file."""
    monkeypatch.chdir(tmp_path)
    status, out, err = _run(["flash", str(base_sequence), "--mode", "complementary", "--json"])
    assert status == 0, err
    d65 = json.loads(out)["flash_weights"]
    (tmp_path / "D65").write_text(ascending[0].read_text(), newline="")
    status, out, err = _run(["flash", str(base_sequence), "--mode", "complementary", "--json"])
    assert status == 0 and json.loads(out)["flash_weights"] == d65, err
    status, out, err = _run(["flash", str(base_sequence), "--mode", "complementary", "--target", "./D65", "--json"])
    assert status == 0, err
    assert json.loads(out)["flash_weights"] == ascending[1]["flash_weights"] != d65


@pytest.mark.filterwarnings("ignore::msflash.processing.errors.TargetUnreachableWarning")
def test_the_python_api_reads_a_path_as_a_file_and_a_string_as_the_command_line_does(
    base_sequence: Path, ascending: tuple[Path, dict], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``msflash.solve_flash(…, target=Path("D65"))`` reads the file even where its name is an illuminant's, and a
    ``Path`` without a suffix is read, not refused; the string ``"D65"`` stays the illuminant, as ``--target D65``.
    On c35c0d4 a suffixless ``Path`` raised a TypeError."""
    import msflash

    monkeypatch.chdir(tmp_path)
    for name in ("D65", "lamp"):
        (tmp_path / name).write_text(ascending[0].read_text(), newline="")
    sequence = msflash.read_sequence(base_sequence)
    estimate = msflash.estimate_ambient(sequence)
    lamp = ascending[1]["flash_weights"]
    for target in (Path("D65"), Path("lamp"), "lamp", "./D65"):
        weights = msflash.solve_flash(sequence, estimate, "complementary", target).flash_weights
        assert weights.tolist() == lamp, target
    d65 = msflash.solve_flash(sequence, estimate, "complementary", "D65").flash_weights
    assert d65.tolist() != lamp
