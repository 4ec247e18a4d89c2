"""What other tools write that format v1 allows, or that measurement gives, read as it is (unseen-sequence sweep).

- Frame paths with ``\\`` separators: a tool on Windows writing ``str(Path("img") / name)``. The
  reader took them as one file name and refused the sequence ("… is missing").
- LED spectra and camera responsivities as measured (a spectrometer's dark-subtracted readings):
  small negative values in the tails. The reader refused any negative value, so a sequence with
  measured spectra could not be read at all; they are clipped now, as the spectrometer reader
  clips them (down to 5 % of the peak or 5 noise σ, processing/negative_values.py), and a value beyond that is still refused.
- Float frames (EXR, normalised to white 1): ``--out x.tiff`` wrote a 16-bit raw TIFF whose every
  sample was 0 or 1, with exit 0; refused now before any work.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.image_files import read_image
from msflash.acquisition.sequence.reader import read_sequence
from tests.processing.unseen_sequences import Case, check_case, expected_synthesis, render_case, run_cli


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
    with pytest.raises(
        RecordingError,
        match=r"leds\[2\]\.spd\[4\] is -.*; expected a non-negative value, or "
        r"measurement noise down to −.* \(the larger of 5% of the peak",
    ):
        read_sequence(rendered.directory)


def test_a_raw_tiff_of_a_float_sequence_is_refused_before_any_work(tmp_path: Path) -> None:
    """Float (EXR) frames normalised to a white level of 1: the 16-bit raw TIFF rounded every sample to 0
    or 1 (100 % reported clipped, exit 0). It is refused now, naming the frame; the EXR output works."""
    rendered = render_case(Case("float", container="exr", cfa="RGGB"), tmp_path / "float")
    weights = ",".join(["0.5"] * rendered.led_spd.shape[1])
    for args in (
        ["synthesize", str(rendered.directory), "--weights", weights],
        ["flash", str(rendered.directory), "--mode", "matching"],
    ):
        status, out, err, caught = run_cli([*args, "--out", str(tmp_path / "raw.tiff")])
        assert (status, out, caught) == (2, "", [])
        assert err.count("\n") == 1 and err.startswith("msflash: error: --out ")
        assert "img/00_ambient.exr" in err and "expected .exr" in err
        assert not (tmp_path / "raw.tiff").exists()
    assert (
        run_cli(["synthesize", str(rendered.directory), "--weights", weights, "--out", str(tmp_path / "x.exr")])[0] == 0
    )


def test_a_raw_tiff_of_an_integer_sequence_holds_the_frames_encoding(tmp_path: Path) -> None:
    rendered = render_case(Case("counts", cfa="GRBG", bits=12, black=256, exposures="varying"), tmp_path / "counts")
    weights = np.full(rendered.led_spd.shape[1], 0.3)
    out = tmp_path / "raw.tiff"
    assert (
        run_cli(
            ["synthesize", str(rendered.directory), "--weights", ",".join(["0.3"] * weights.size), "--out", str(out)]
        )[0]
        == 0
    )
    ambient = next(entry for entry in rendered.frames if entry["role"] == "ambient")
    expected = np.clip(
        np.rint(rendered.black + expected_synthesis(rendered, weights) * ambient["exposure_us"] * ambient["gain"]),
        0,
        rendered.white,
    )
    np.testing.assert_array_equal(read_image(out), expected)
