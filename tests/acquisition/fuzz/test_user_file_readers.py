"""What the user-file fuzzer found (issue 32 item 5; tests/acquisition/fuzz/user_file_fuzz_worker.py), one test per
class of bug, each failing before its fix: ``--reference-chart`` read outside the one reader of a user's
file, values so large that the fits overflow, and ``--target`` silently taking the first of several spectra."""

from __future__ import annotations

import contextlib
import io
import json
import os
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.processing import datasets
from tests.calibration.spectrometer_writers import Instrument, export_text
from tests.helpers import write_test_sequence

CHART = {
    "patches": [
        {"rect": [4, 4, 16, 16], "wavelengths_nm": [400, 550, 700], "reflectance": [0.2, 0.5, 0.4]},
        {"rect": [30, 20, 16, 16], "wavelengths_nm": [400, 700], "reflectance": [0.8, 0.8]},
    ]
}


def run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(argv)
    return status, out.getvalue(), err.getvalue()


def refused(argv: list[str], *named: str) -> str:
    """The one error line of ``argv`` (exit 2), which must name each of ``named``."""
    status, _, err = run(argv)
    errors = [line for line in err.splitlines() if line.startswith("msflash: error: ")]
    assert status == 2 and len(errors) == 1 and "Traceback" not in err, err
    assert all(name in errors[0] for name in named), errors[0]
    return errors[0]


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_test_sequence(tmp_path_factory.mktemp("seq") / "tungsten")


def _chart_text(kind: str) -> str:
    chart = json.loads(json.dumps(CHART))
    patch = chart["patches"][0]
    if kind == "descending":  # np.interp on descending wavelengths: another reflectance, silently
        patch["wavelengths_nm"] = [700, 550, 400]
    elif kind == "percent":
        patch["reflectance"] = [20, 50, 40]
    elif kind == "fractional rect":
        patch["rect"] = [4.5, 4, 16, 16]
    elif kind == "boolean rect":
        patch["rect"] = [True, 4, 16, 16]
    text = json.dumps(chart)
    if kind == "deep":
        text = text.replace('"patches"', '"x": ' + "[" * 100_000 + "]" * 100_000 + ', "patches"')
    elif kind == "twice":
        text = text.replace('{"patches"', '{"patches": [], "patches"')
    elif kind == "NaN":
        text = text.replace("0.5", "NaN")
    return text


@pytest.mark.timeout(120)  # a FIFO blocked the read for ever
@pytest.mark.parametrize(
    "kind", ["fifo", "dev_zero", "deep", "twice", "NaN", "descending", "percent", "fractional rect", "boolean rect"]
)
def test_a_wrong_reference_chart_is_refused_in_one_line(sequence: Path, tmp_path: Path, kind: str) -> None:
    """Before: a FIFO hung ``estimate``, ``/dev/zero`` ended in MemoryError (exit 1), nesting 100 000 deep in
    RecursionError (exit 1); a key twice, NaN (read as a number), descending wavelengths and a percentage
    were taken (exit 0, other numbers)."""
    chart = tmp_path / "chart.json"
    if kind == "fifo":
        os.mkfifo(chart)
    elif kind == "dev_zero":
        chart.symlink_to("/dev/zero")
    else:
        chart.write_text(_chart_text(kind))
    refused(["estimate", str(sequence), "--model", "prior", "--reference-chart", str(chart)], str(chart))


def test_a_valid_reference_chart_still_joins_the_estimate(sequence: Path, tmp_path: Path) -> None:
    chart = tmp_path / "chart.json"
    chart.write_text(json.dumps(CHART))
    status, out, err = run(["estimate", str(sequence), "--model", "prior", "--reference-chart", str(chart), "--json"])
    assert status == 0, err
    assert json.loads(out)["spectrum"]


def test_an_export_with_values_past_1e100_is_refused_naming_its_line(tmp_path: Path) -> None:
    """Before: values ×1e300 were read, the fits' sums overflowed, and ``calibrate leds`` exited 0 having written
    ``centroids_nm: [null, …]``, a calibration every later command refused."""
    instrument = Instrument.typical(3)
    truth = datasets.paper_leds().select([0, 3, 6])
    rng = np.random.default_rng(1)
    files = []
    for index, scale in enumerate((1.0, 1e300, 1.0)):
        column = truth.values[:, index] / truth.values[:, index].max()
        irradiance = np.interp(instrument.wavelengths_nm, truth.wavelengths_nm, column, left=0, right=0) * 250
        counts = instrument.counts(irradiance, 0.01, 4, rng) * scale
        path = tmp_path / f"led{index}.txt"
        path.write_text(export_text("plain", instrument.wavelengths_nm, counts, 0.01, 4))
        files.append(str(path))
    error = refused(["calibrate", "leds", *files, "--no-dark", "--out", str(tmp_path / "cal")], "led1.txt")
    assert "magnitude at most 1e+100" in error
    assert not (tmp_path / "cal").exists()


def test_a_spectral_table_with_values_past_1e100_is_refused(tmp_path: Path) -> None:
    table = tmp_path / "ambient.csv"
    table.write_text("wavelength_nm,a\n" + "".join(f"{w},{1e300}\n" for w in range(400, 701, 10)))
    with pytest.raises(Exception, match=r"ambient.csv:2: column 'a' holds '1e\+300'; expected a finite number"):
        datasets.load_spectra_csv(table, kind="spd", unit="energy")


def test_a_target_of_several_spectra_is_refused_not_its_first_column_taken(sequence: Path, tmp_path: Path) -> None:
    """Before: ``--target`` took the first spectrum of a file of several (msflash's own exported spectra.csv
    among them: its first column is the ambient estimate), silently; ``--ambient`` refused the same file."""
    status, _, err = run(["export", str(sequence), "--to", "csv", "--out", str(tmp_path / "exported")])
    assert status == 0, err
    exported = tmp_path / "exported" / "spectra.csv"
    error = refused(["flash", str(sequence), "--mode", "complementary", "--target", str(exported)], str(exported))
    assert "expected one target illuminant" in error
    two = tmp_path / "two.csv"
    two.write_text("wavelength_nm,flat,D65\n" + "".join(f"{w},0.25,{1 + w / 1000}\n" for w in range(400, 701, 10)))
    refused(["flash", str(sequence), "--mode", "complementary", "--target", str(two)], "2 spectra (flat, D65)")
    negative = tmp_path / "negative.csv"
    negative.write_text("wavelength_nm,x\n" + "".join(f"{w},{-1 if w == 550 else 1}\n" for w in range(400, 701, 10)))
    refused(["flash", str(sequence), "--mode", "complementary", "--target", str(negative)], "negative.csv", "550")


def test_a_light_or_white_reflectance_of_several_columns_is_refused(tmp_path: Path) -> None:
    """The same class as ``--target``: ``calibrate camera --light FILE.csv`` and ``calibrate leds
    --white-reflectance FILE.csv`` took the first column of a file of several; the white reference's table in
    percent was taken as factors 0–100."""
    from msflash.acquisition.errors import UsageError
    from msflash.acquisition.session.calibration_inputs import read_white_reflectance
    from msflash.calibration.chart_sequence import resolve_light
    from msflash.calibration.errors import CalibrationError
    from msflash.processing.spectra import DEFAULT_GRID

    two = tmp_path / "two.csv"
    two.write_text("wavelength_nm,a,b\n" + "".join(f"{w},0.5,0.9\n" for w in range(380, 781, 10)))
    with pytest.raises(CalibrationError, match="two.csv: 2 spectra; expected one light"):
        resolve_light(str(two), DEFAULT_GRID)
    with pytest.raises(UsageError, match="two.csv: 2 columns of values; expected one"):
        read_white_reflectance(str(two), DEFAULT_GRID)
    percent = tmp_path / "percent.csv"
    percent.write_text("wavelength_nm,white\n" + "".join(f"{w},98\n" for w in range(380, 781, 10)))
    with pytest.raises(UsageError, match=r"percent.csv: reflectances span 98–98; expected reflectance factors 0–1"):
        read_white_reflectance(str(percent), DEFAULT_GRID)
    one = tmp_path / "one.csv"
    one.write_text("wavelength_nm,white\n" + "".join(f"{w},0.98\n" for w in range(380, 781, 10)))
    assert np.allclose(read_white_reflectance(str(one), DEFAULT_GRID).values, 0.98)
    assert resolve_light(str(one), DEFAULT_GRID).count == 1


@pytest.mark.parametrize("pattern", ["\\C", "(", "a{2,1}", "[z-a]"])
def test_a_camera_profile_whose_pattern_is_no_regular_expression_is_refused_on_reading(
    tmp_path: Path, pattern: str
) -> None:
    """Before: ``load_profiles`` took any string, and ``match_profile`` raised ``re.error`` when a camera was
    opened (exit 1, "a bug"); now the file is refused naming the profile and field."""
    from msflash.acquisition.devices.aravis.discovery import PROFILES_JSON
    from msflash.acquisition.devices.aravis.profiles import load_profiles
    from msflash.acquisition.errors import CameraSettingError

    document = json.loads(PROFILES_JSON.read_text())
    document["profiles"][1]["model"] = pattern
    edited = tmp_path / "profiles.json"
    edited.write_text(json.dumps(document))
    with pytest.raises(CameraSettingError, match=r"profiles.json: profiles\[1\]\.model is .*not a regular expression"):
        load_profiles(edited)


def test_a_table_scaled_by_1e_300_is_refused_naming_its_column(sequence: Path, tmp_path: Path) -> None:
    """Before: a calibration's ``leds.csv`` ×1e-300 made every LED-only image "empty" (exit 1, a runtime error
    blaming the booth), and a spectrometer response ×1e-300 made ``calibrate leds`` write LED energies of 1e301
    (exit 0) that every later command refused."""
    from msflash.processing.errors import SpectralDataError

    table = tmp_path / "leds.csv"
    table.write_text("wavelength_nm,led440,led520\n" + "".join(f"{w},{1e-300},0.5\n" for w in range(400, 701, 10)))
    with pytest.raises(SpectralDataError, match=r"leds.csv: column 'led440' peaks at 1e-300; expected values of"):
        datasets.load_spectra_csv(table, kind="spd", unit="energy")
    instrument = Instrument.typical(3)
    truth = datasets.paper_leds().select([0, 3, 6])
    rng = np.random.default_rng(1)
    files = []
    for index in range(3):
        column = truth.values[:, index] / truth.values[:, index].max()
        irradiance = np.interp(instrument.wavelengths_nm, truth.wavelengths_nm, column, left=0, right=0) * 250
        path = tmp_path / f"led{index}.txt"
        path.write_text(
            export_text("plain", instrument.wavelengths_nm, instrument.counts(irradiance, 0.01, 4, rng), 0.01)
        )
        files.append(str(path))
    response = tmp_path / "response.csv"
    response.write_text(
        "wavelength_nm,counts_per_s_per_irradiance\n"
        + "".join(f"{w:.4f},{r * 1e-300:.9g}\n" for w, r in zip(instrument.wavelengths_nm, instrument.response))
    )
    argv = ["calibrate", "leds", *files, "--no-dark", "--spectrometer-response", str(response)]
    refused([*argv, "--out", str(tmp_path / "cal")], "response.csv", "peaks at")
