"""Frame values the declared black and white levels cannot produce are refused, on every route.

Real files throughout: sequences written to a temporary directory as 16-bit TIFF (OpenImageIO,
through :func:`acquisition.sequence.writer.write_sequence`) or float EXR, read back by the CLI.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.frame_integrity import black_margin, check_frame_levels
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import write_sequence
from tests.helpers import SAMPLES_DIR

BAYER_12BIT = SAMPLES_DIR / "sample-bayer-fluorescent-12bit"
RGB_16BIT = SAMPLES_DIR / "sample-rgb-tungsten"


def _sample(directory: Path):
    if not (directory / "sequence.json").exists():
        pytest.skip(f"sample sequence {directory} is absent (shared samples not mounted)")
    return read_sequence(directory)


def _rewritten(tmp_path: Path, source: Path, change, camera_changes: dict | None = None) -> Path:
    """A copy of a sample whose frames pass through ``change(index, pixels)``, written as real files."""
    sequence = _sample(source)
    if camera_changes:
        sequence = replace(sequence, camera=replace(sequence.camera, **camera_changes))
    frames = [change(i, sequence.load_frame(i, check_levels=False)) for i in range(len(sequence.frames))]
    out = tmp_path / "sequence"
    write_sequence(out, sequence, frames)
    return out


def _error(capsys: pytest.CaptureFixture, *argv: str) -> str:
    status = main(list(argv))
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2, lines
    assert len(lines) >= 1 and lines[-1].startswith("msflash: error: ")
    return lines[-1]


def _twelve_bit_times_16(index: int, pixels: np.ndarray) -> np.ndarray:
    # 12-bit counts written as if left-aligned in 16 bits, while white_level still says 4095.
    return (pixels.astype(np.uint32) * 16).clip(0, 65535).astype(np.uint16) if index == 3 else pixels


@pytest.fixture
def left_aligned(tmp_path: Path) -> Path:
    return _rewritten(tmp_path, BAYER_12BIT, _twelve_bit_times_16)


@pytest.mark.parametrize(
    "route",
    [
        ("estimate",),
        ("flash", "--mode", "matching"),
        ("synthesize", "--weights", "1,0,0,0,0,0,0", "--out", "{tmp}/s.exr"),
        ("evaluate", "--chart", "macbeth", "--out", "{tmp}/eval"),
    ],
)
def test_every_processing_route_refuses_values_above_white(
    left_aligned: Path, tmp_path: Path, capsys: pytest.CaptureFixture, route: tuple[str, ...]
) -> None:
    argv = [route[0], str(left_aligned), *(a.format(tmp=tmp_path) for a in route[1:])]
    line = _error(capsys, *argv)
    assert f"{left_aligned / 'sequence.json'}: frames[3].file 'frames/003-led.tiff'" in line
    assert "of 12288 pixels above camera.white_level 4095" in line
    assert "expected values in" in line and "12-bit data in a 16-bit file" in line


def test_replay_refuses_a_corrupt_recording_before_capturing(
    left_aligned: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    line = _error(capsys, "run", "--rig", f"replay:{left_aligned}", "--out", str(tmp_path / "run"))
    assert "frames[3].file 'frames/003-led.tiff'" in line and "above camera.white_level 4095" in line
    assert not (tmp_path / "run" / "sequence").exists()


def test_the_count_and_range_are_exact(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    def three_hot_pixels(index: int, pixels: np.ndarray) -> np.ndarray:
        if index == 0:
            pixels = pixels.copy()
            pixels[0, :3] = (4096, 5000, 4095)  # 4095 is saturation, legitimate
            pixels[1, 0] = 4200
        return pixels

    sequence = _rewritten(tmp_path, BAYER_12BIT, three_hot_pixels)
    line = _error(capsys, "estimate", str(sequence))
    assert "frames[0].file 'frames/000-ambient.tiff': 3 of 12288 pixels above camera.white_level 4095" in line
    assert "…5000)" in line


@pytest.mark.parametrize(
    "route",
    [
        ("estimate",),
        ("synthesize", "--weights", "1,0,0,0,0,0,0", "--out", "{tmp}/s.exr"),
        ("export", "--to", "dng", "--out", "{tmp}/export"),
        ("export", "--to", "exr", "--out", "{tmp}/export"),
    ],
)
def test_a_white_level_no_frame_value_can_reach_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture, route: tuple[str, ...]
) -> None:
    # white_level 1e30 on 16-bit frames: saturation could never be seen, and the DNG export failed
    # with "unexpected error: argument out of range" (exit 1) writing it into its 32-bit WhiteLevel.
    sequence = _rewritten(tmp_path, BAYER_12BIT, lambda i, p: p, {"white_level": 1e30})
    argv = [route[0], str(sequence), *(a.format(tmp=tmp_path) for a in route[1:])]
    line = _error(capsys, *argv)
    assert "frames[0].file 'frames/000-ambient.tiff': camera.white_level 1e+30 is above the largest value" in line
    assert "16-bit frame (65535)" in line
    assert not (tmp_path / "export").exists() and not (tmp_path / "s.exr").exists()


def test_a_black_level_declared_for_other_data_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # The 12-bit sample's data have black 256; declaring 1024 puts most dark pixels ~768 DN below it.
    sequence = _rewritten(tmp_path, BAYER_12BIT, lambda i, p: p, {"black_level": 1024})
    line = _error(capsys, "estimate", str(sequence))
    assert "frames[0].file 'frames/000-ambient.tiff'" in line
    assert "below camera.black_level 1024 by more than read noise allows" in line
    assert "values 255…" in line


def test_the_shared_samples_read_as_they_are() -> None:
    for directory in (BAYER_12BIT, RGB_16BIT):
        sequence = _sample(directory)
        for index in range(len(sequence.frames)):
            sequence.load_frame(index)  # the RGB sample goes 15 DN below its black level 64: read noise


def test_saturation_and_read_noise_below_black_are_accepted(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    def legit(index: int, pixels: np.ndarray) -> np.ndarray:
        pixels = pixels.copy()
        pixels[0, 0] = 4095  # exactly white: saturated
        pixels[0, 1] = 256 - 70  # within the read-noise margin below black 256 (76.8 DN at gain 1)
        return pixels

    sequence = _rewritten(tmp_path, BAYER_12BIT, legit)
    assert black_margin(256, 4095) > 70
    assert main(["estimate", str(sequence), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["spectrum"]


def _float_sequence(tmp_path: Path, change) -> Path:
    """The 16-bit RGB sample as float EXR frames normalised to white 1.0 (black 0)."""
    sequence = _sample(RGB_16BIT)
    black, white = sequence.camera.black_level, sequence.camera.white_level
    camera = replace(sequence.camera, black_level=0.0, white_level=1.0)
    frames = [
        change(i, ((sequence.load_frame(i).astype(np.float32) - black) / (white - black)))
        for i in range(len(sequence.frames))
    ]
    out = tmp_path / "exr"
    write_sequence(out, replace(sequence, camera=camera), frames)
    assert all(frame.file.endswith(".exr") for frame in read_sequence(out).frames)
    return out


def test_float_frames_normalised_to_white_one(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # Slightly negative values (black subtracted, read noise) and values at 1.0 are fine.
    sequence = _float_sequence(tmp_path, lambda i, p: p)
    assert min(float(read_sequence(sequence).load_frame(i).min()) for i in range(8)) < 0
    assert main(["estimate", str(sequence), "--json"]) == 0
    capsys.readouterr()


def test_float_frames_above_white_or_not_finite_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    def damaged(index: int, pixels: np.ndarray) -> np.ndarray:
        if index == 2:
            pixels = pixels.copy()
            pixels[5, 5, 1] = np.nan
            pixels[6, 6, 0] = 1.5
        return pixels

    line = _error(capsys, "estimate", str(_float_sequence(tmp_path, damaged)))
    assert (
        "frames[2].file 'frames/002-led.exr': 1 of 36864 pixels not finite (NaN or ±inf) and 1 of 36864 "
        "pixels above camera.white_level 1" in line
    )
    assert "…1.5)" in line


def test_a_file_written_by_another_tool_is_checked(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # Replace one frame file with a TIFF written by OpenImageIO directly (no msflash attributes).
    sequence = _sample(BAYER_12BIT)
    copy = tmp_path / "copy"
    shutil.copytree(BAYER_12BIT, copy)
    copy.chmod(0o755)
    target = copy / sequence.frames[5].file
    target.parent.chmod(0o755)
    target.unlink()
    pixels = np.full((96, 128), 300, dtype=np.uint16)
    pixels[10:12, 20:30] = 65535
    output = oiio.ImageOutput.create(str(target))
    assert output.open(str(target), oiio.ImageSpec(128, 96, 1, "uint16"))
    assert output.write_image(pixels.reshape(96, 128, 1))  # (H, W, C): a 2-D array would be read transposed
    output.close()
    line = _error(capsys, "flash", str(copy), "--mode", "complementary")
    assert (
        "frames[5].file 'frames/005-led.tiff': 20 of 12288 pixels above camera.white_level 4095 (values 300…65535)"
        in line
    )


def test_the_margin_grows_with_gain() -> None:
    pixels = np.array([256 - 100, 1000], dtype=np.uint16)
    with pytest.raises(RecordingError, match="1 of 2 pixels below camera.black_level 256"):
        check_frame_levels(pixels, 256, 4095, gain=1.0, where="f.tiff")
    check_frame_levels(pixels, 256, 4095, gain=2.0, where="f.tiff")  # margin 153.6 DN at gain 2


def test_calibrate_dark_measures_the_black_level_instead_of_trusting_it(tmp_path: Path) -> None:
    sequence = _sample(BAYER_12BIT)
    dark = replace(
        sequence,
        camera=replace(sequence.camera, black_level=2048.0),
        frames=tuple(replace(f, role="dark", led_levels=(0.0,) * 7) for f in sequence.frames[:1]) + sequence.frames[:1],
    )
    rng = np.random.default_rng(0)
    frames = [np.rint(rng.normal(256, 3, (96, 128))).astype(np.uint16) for _ in range(2)]  # black 256, 3 DN noise
    out = write_sequence(tmp_path / "dark", dark, frames)
    with pytest.raises(RecordingError, match="below camera.black_level 2048"):
        out.load_frame(0)
    assert main(["calibrate", "dark", str(out.directory), "--out", str(tmp_path / "cal")]) == 0
