"""What other tools write that format v1 allows, or that measurement gives, read as it is (unseen-sequence sweep).

- Frame paths with ``\\`` separators: a tool on Windows writing ``str(Path("img") / name)``. The
  reader took them as one file name and refused the sequence ("… is missing").
- LED spectra and camera responsivities as measured (a spectrometer's dark-subtracted readings):
  small negative values in the tails. The reader refused any negative value, so a sequence with
  measured spectra could not be read at all; they are clipped now, as the spectrometer reader
  clips them (down to 5 % of the peak), and a value beyond that is still refused.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from acquisition.errors import RecordingError
from acquisition.sequence_format import read_sequence
from tests.processing.unseen_sequences import Case, check_case, render_case


def test_windows_separators_in_frame_paths_are_read(tmp_path: Path) -> None:
    rendered = render_case(Case("windows", quirks=("windows_paths",)), tmp_path / "windows")
    assert "\\" in json.loads((rendered.directory / "sequence.json").read_text())["frames"][0]["file"]
    sequence = read_sequence(rendered.directory)
    assert sequence.frames[0].file == "img/00_ambient.tif"
    assert sequence.load_frame(0).shape == sequence.load_frame(len(sequence.frames) - 1).shape
    assert check_case(Case("windows-cli", quirks=("windows_paths",)), tmp_path).defects == ()


def test_a_windows_path_leaving_the_directory_is_still_refused(tmp_path: Path) -> None:
    rendered = render_case(Case("escape"), tmp_path / "inside" / "escape")
    (tmp_path / "inside" / "outside.tif").write_bytes((rendered.directory / "img" / "01_led.tif").read_bytes())
    document = json.loads((rendered.directory / "sequence.json").read_text())
    document["frames"][1]["file"] = "..\\outside.tif"
    (rendered.directory / "sequence.json").write_text(json.dumps(document))
    with pytest.raises(RecordingError, match=r"frames\[1\]\.file '\.\./outside\.tif' points outside"):
        read_sequence(rendered.directory)


def test_measured_spectra_with_noise_below_zero_are_read_and_clipped(tmp_path: Path) -> None:
    case = Case("measured", quirks=("measured_spectra",), leds="booth8", unit="photons", seed=4)
    rendered = render_case(case, tmp_path / "measured")
    written = json.loads((rendered.directory / "sequence.json").read_text())
    assert min(min(led["spd"]) for led in written["leds"]) < 0
    assert min(min(v) for v in written["camera"]["responsivity"].values()) < 0
    sequence = read_sequence(rendered.directory)
    spectra = sequence.led_spectra().values
    assert spectra.min() == 0.0
    np.testing.assert_allclose(spectra, np.maximum(np.column_stack([led["spd"] for led in written["leds"]]), 0.0))
    assert check_case(case, tmp_path / "cli").defects == ()


def test_a_negative_value_beyond_noise_is_refused_naming_the_tolerance(tmp_path: Path) -> None:
    rendered = render_case(Case("negative"), tmp_path / "negative")
    document = json.loads((rendered.directory / "sequence.json").read_text())
    peak = max(document["leds"][2]["spd"])
    document["leds"][2]["spd"][4] = -0.06 * peak
    (rendered.directory / "sequence.json").write_text(json.dumps(document))
    with pytest.raises(RecordingError, match=r"leds\[2\]\.spd\[4\] is -.*; expected a non-negative value \(or "
                                             r"measurement noise down to 5% of the peak"):
        read_sequence(rendered.directory)
