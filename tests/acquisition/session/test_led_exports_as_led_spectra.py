"""``--led-spectra`` given the spectrometer exports of the booth's LEDs, one per channel (the option repeated), as
the instrument's program writes them (tests/calibration/spectrometer_writers.py, through the booth writer of
tests/calibration/test_spectrometer_exports.py): the rig takes the LED spectra ``msflash calibrate leds`` stores from
the same exports — one reading of an export for both. Before, ``--led-spectra`` took one table only: an export was
refused ("header is 'Data from …'").
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from msflash.acquisition.sequence.reader import read_sequence
from msflash.calibration.files import load_calibration
from msflash.processing.spectra import DEFAULT_GRID, Spectra
from tests.acquisition.support.hw_rig import booth_on_pty, fake_camera_capture
from tests.calibration.test_spectrometer_exports import LEDS, _write_booth, run


def _calibrated(files: list[str], out: Path) -> Spectra:
    """What ``msflash calibrate leds FILES`` (no dark: the out-of-band tail) stores, on the default grid."""
    status, _, err = run(["calibrate", "leds", *files, "--out", str(out)])
    assert status == 0, err
    stored = load_calibration(out).led_spectra
    assert stored is not None
    return stored.resample(DEFAULT_GRID, outside="zero").to_unit("energy")


def _options(files: list[str]) -> list[str]:
    return [word for file in files for word in ("--led-spectra", file)]


def _recorded_leds(out: Path) -> Spectra:
    return read_sequence(out / "sequence").led_spectra().to_unit("energy")


@pytest.mark.parametrize("form", ["oceanview", "avasoft"])
def test_the_sim_rig_takes_the_led_exports_calibrate_leds_reads(form: str, tmp_path: Path) -> None:
    files, _, _ = _write_booth(tmp_path, form, dark=False, seed=11, text={"decimal_comma": form == "avasoft"})
    expected = _calibrated(files, tmp_path / "cal")
    out = tmp_path / "capture"
    status, _, err = run(["capture", "--rig", "sim", "--seed", "0", *_options(files), "--out", str(out)])
    assert status == 0, err
    leds = _recorded_leds(out)
    assert leds.names == LEDS
    # The sim scales its booth to the flash power it simulates: one factor for all LEDs, their ratios kept.
    np.testing.assert_allclose(leds.values / leds.values.max(), expected.values / expected.values.max(), rtol=1e-9)
    warned = [line for line in err.splitlines() if "raw spectrometer counts" in line]
    assert len(warned) == 1 and warned[0].startswith("msflash: warning: "), err


@pytest.mark.aravis
def test_the_hw_rig_takes_the_led_exports_calibrate_leds_reads(aravis: ModuleType, tmp_path: Path) -> None:
    """The Aravis Fake camera and the booth emulator for those three LEDs on a pty, as a user opens them."""
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    files, _, _ = _write_booth(tmp_path, "spectrawiz", dark=False, seed=12, bytes={"crlf": True})
    expected = _calibrated(files, tmp_path / "cal")
    out = tmp_path / "capture"
    with booth_on_pty(expected) as port:
        status, _, err = run(fake_camera_capture(port, *_options(files), "--exposure", "10000", "--out", str(out)))
    assert status == 0, err
    leds = _recorded_leds(out)
    assert leds.names == LEDS
    np.testing.assert_allclose(leds.values, expected.values, rtol=1e-12, atol=1e-12 * expected.values.max())


def test_an_export_among_led_files_that_is_refused_names_its_file_and_line(tmp_path: Path) -> None:
    files, _, _ = _write_booth(tmp_path, "oceanview", dark=False, seed=13)
    lines = Path(files[1]).read_text().splitlines()
    first = lines.index(">>>>>Begin Spectral Data<<<<<") + 1
    lines[first + 99] = lines[first + 99].split("\t")[0] + "\tNaN"
    Path(files[1]).write_text("\n".join(lines) + "\n")
    status, _, err = run(["capture", "--rig", "sim", *_options(files), "--out", str(tmp_path / "c")])
    assert status == 2
    errors = [line for line in err.splitlines() if not line.startswith("msflash: warning: ")]  # the first export's
    assert len(errors) == 1 and errors[0].startswith(
        f"msflash: error: {files[1]}:{first + 100}: column 2 is 'NaN'; expected a finite number"
    ), err


def test_a_table_of_several_leds_among_led_files_is_refused_saying_what_is_expected(tmp_path: Path) -> None:
    files, _, _ = _write_booth(tmp_path, "oceanview", dark=False, seed=14)
    table = tmp_path / "leds.csv"
    table.write_text("wavelength_nm,a,b\n400,1,0\n500,0,1\n600,0,0\n")
    status, _, err = run(["capture", "--rig", "sim", *_options([*files[:2], str(table)]), "--out", str(tmp_path / "c")])
    assert status == 2
    assert err.splitlines() == [
        f"msflash: error: --led-spectra {table}: a table of 2 LEDs among 3 files; expected that table alone, or one "
        "spectrometer export (or one-LED table) per channel"
    ]
    assert not (tmp_path / "c").exists()
