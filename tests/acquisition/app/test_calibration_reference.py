"""Sequences captured with ``--calibration DIR`` (a ``msflash calibrate`` output) refer to it.

The hardware rig as a user opens it, without hardware: the Aravis in-process ``Fake_1`` camera on
the ``fake`` interface (nothing is broadcast) and the booth emulator on a pty as ``--port``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import sequence_spectra
from msflash.acquisition.session.rigs.hardware import hw_spectra
from msflash.calibration.files import CalibrationSet, load_calibration, save_calibration
from tests.acquisition.support.hw_rig import booth_on_pty, fake_camera_capture, nikon_d100, paper_leds


@pytest.fixture
def calibration(tmp_path: Path) -> Path:
    """A calibration directory as ``msflash calibrate`` writes it: the paper's 7 LEDs, a NikonD100."""
    directory = tmp_path / "lab" / "cal"
    save_calibration(CalibrationSet(led_spectra=paper_leds(), camera_responsivities=nikon_d100()), directory)
    return directory


@pytest.fixture
def booth_port(calibration: Path) -> Iterator[str]:
    with booth_on_pty(load_calibration(calibration).led_spectra) as port:
        yield port


@pytest.mark.aravis
def test_a_sequence_refers_to_the_calibration_it_was_captured_with(
    aravis: ModuleType, calibration: Path, booth_port: str, tmp_path: Path
) -> None:
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    out = tmp_path / "runs" / "c"
    assert (
        main(
            fake_camera_capture(booth_port, "--calibration", str(calibration), "--exposure", "10000", "--out", str(out))
        )
        == 0
    )
    sequence = read_sequence(out / "sequence")
    captured_with = load_calibration(calibration).id
    assert sequence.extra["calibration"] == {
        "id": captured_with,
        "file": os.path.relpath(calibration, out / "sequence"),
    }
    assert (sequence.directory / sequence.extra["calibration"]["file"]).resolve() == calibration.resolve()

    _, notes = sequence_spectra.apply_calibration(sequence)  # what estimate/flash do without --calibration
    assert any(captured_with in note and "LED spectra" in note for note in notes)
    assert not any("captured with" in note for note in notes)

    recalibrated = load_calibration(calibration).updated()  # re-calibrated since: a new id at the same place
    save_calibration(recalibrated, calibration)
    _, notes = sequence_spectra.apply_calibration(read_sequence(out / "sequence"))
    assert any(f"captured with calibration {captured_with}" in note and recalibrated.id in note for note in notes)


def test_only_msflash_calibrations_are_referenced(calibration: Path, tmp_path: Path) -> None:
    assert hw_spectra(calibration)[2] == (load_calibration(calibration).id, calibration)
    leds_csv = tmp_path / "csv" / "led_spectra.csv"
    leds_csv.parent.mkdir()
    leds_csv.write_text("wavelength_nm,led440\n400,0\n440,1\n480,0\n")
    assert hw_spectra(led_spectra=leds_csv)[2] is None  # no --calibration
    assert hw_spectra(leds_csv.parent)[2] is None  # led_spectra.csv folders carry no id


@pytest.mark.parametrize(
    ("section", "start_nm", "message"),
    [
        ("led_spectra", 500, "has LED spectra from 500 to 700 nm, but LED 'led440' puts"),
        ("camera_responsivities", 550, "has camera responsivities from 550 to 700 nm, but LED 'led4[48]0' puts"),
    ],
)
def test_a_calibration_that_misses_the_leds_light_is_refused(
    tmp_path: Path, section: str, start_nm: int, message: str
) -> None:
    """It used to be zero-filled outside its range: a 500–700 nm LED calibration gave led440 a
    spectrum of 0 below 490 nm, and estimate exited 0."""
    sequence = read_sequence(Path(__file__).resolve().parents[2] / "data" / "sequences" / "sim-macbeth-fluorescent")
    leds = sequence.led_spectra().to_unit("energy")
    camera = sequence.camera_responsivities().to_unit("energy")  # type: ignore[union-attr]
    spectra = {"led_spectra": leds, "camera_responsivities": camera}[section]
    from msflash.processing.spectra import WavelengthGrid

    narrow = spectra.resample(WavelengthGrid(start_nm, 700, 10), outside="zero")
    save_calibration(CalibrationSet(**{section: narrow}), tmp_path / "cal")
    with pytest.raises(RecordingError, match=message):
        sequence_spectra.apply_calibration(sequence, tmp_path / "cal")
    save_calibration(CalibrationSet(**{section: spectra}), tmp_path / "full")  # covering: accepted
    assert sequence_spectra.apply_calibration(sequence, tmp_path / "full")[1]
