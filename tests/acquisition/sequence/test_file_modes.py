"""Files msflash writes get the permissions the umask allows (mkstemp alone would give 0600)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np

from msflash.acquisition.sequence.image_files import write_image
from msflash.calibration.file_modes import _read_umask, default_file_mode
from msflash.calibration.files import CalibrationSet, save_calibration
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_the_umask_is_read_without_changing_it() -> None:
    before = os.umask(0o027)
    os.umask(before)
    assert _read_umask() == before and default_file_mode() == 0o666 & ~before


def test_frames_sequences_and_calibrations_are_readable_as_the_umask_allows(tmp_path: Path) -> None:
    expected = default_file_mode()
    assert expected & 0o044  # the usual 022 umask: readable by group and others
    frame = write_image(tmp_path / "frame.tiff", np.zeros((4, 6, 3), dtype=np.uint16))
    assert _mode(frame) == expected
    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero")
    written = save_calibration(CalibrationSet(led_spectra=leds), tmp_path / "cal")
    assert {_mode(p) for p in (tmp_path / "cal").iterdir() if p.is_file()} == {expected}
    assert _mode(written) == expected


def test_a_captured_sequence_is_readable_as_the_umask_allows(tmp_path: Path) -> None:
    from msflash.acquisition.app.cli import main

    assert main(["capture", "--rig", "sim", "--out", str(tmp_path / "c")]) == 0
    sequence = tmp_path / "c" / "sequence"
    files = [sequence / "sequence.json", *(sequence / "frames").iterdir()]
    assert len(files) == 9 and {_mode(p) for p in files} == {default_file_mode()}
