"""Sequence format v1: round trip, the shared samples, every validation error, crash safety."""

from __future__ import annotations

import copy
import dataclasses
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.format import SequenceCamera, SequenceFrame, SequenceLed
from msflash.acquisition.sequence.image_files import read_image, read_image_header, write_image
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import SequenceWriter, write_sequence
from tests.helpers import forget_digests

REPOSITORY = Path(__file__).resolve().parents[3]
SAMPLES = REPOSITORY.parent / "shared" / "samples"
WAVELENGTHS = np.arange(400.0, 701.0, 10.0)
N_LEDS = 3
HEIGHT, WIDTH = 6, 8
RNG = np.random.default_rng(11)


def _camera(cfa: str | None = None, responsivity: bool = True, **extra: object) -> SequenceCamera:
    curves = None
    if responsivity:
        curves = {c: np.exp(-(((WAVELENGTHS - p) / 40.0) ** 2)) for c, p in (("R", 600), ("G", 540), ("B", 450))}
    return SequenceCamera(
        model="TestCam",
        serial="SN-1",
        pixel_format="BayerRG16" if cfa else "RGB16",
        cfa=cfa,
        black_level=64,
        white_level=4095,
        responsivity=curves,
        extra=dict(extra),
    )


def _leds(**extra: object) -> list[SequenceLed]:
    return [
        SequenceLed(f"led{peak}", np.exp(-(((WAVELENGTHS - peak) / 15.0) ** 2)), dict(extra) if i == 0 else {})
        for i, peak in enumerate((450, 530, 620))
    ]


def _pixels(cfa: str | None = None, shape: tuple[int, int] = (HEIGHT, WIDTH)) -> np.ndarray:
    full = shape if cfa else (*shape, 3)
    return RNG.integers(64, 4096, size=full, dtype=np.uint16)


def _writer(directory: Path, cfa: str | None = None, **kwargs: object) -> SequenceWriter:
    return SequenceWriter(
        directory,
        wavelengths_nm=WAVELENGTHS,
        spectral_unit=kwargs.pop("spectral_unit", "energy"),
        camera=kwargs.pop("camera", _camera(cfa)),
        leds=kwargs.pop("leds", _leds()),
        **kwargs,  # type: ignore[arg-type]
    )


def _levels(led: int | None) -> tuple[float, ...]:
    return tuple(1.0 if i == led else 0.0 for i in range(N_LEDS))


def _paper_sequence(directory: Path, cfa: str | None = None) -> list[np.ndarray]:
    """Ambient, then ambient + each LED: the paper's sequence; returns the pixels written."""
    written = []
    with _writer(directory, cfa) as writer:
        for led in (None, *range(N_LEDS)):
            written.append(_pixels(cfa))
            writer.add_frame(written[-1], "ambient" if led is None else "led", _levels(led), 10000 + 100 * len(written))
    return written


@pytest.fixture(scope="module")
def _valid_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("template") / "seq"
    _paper_sequence(directory)
    return directory


@pytest.fixture
def valid(_valid_template: Path, tmp_path: Path) -> Path:
    """A complete, valid RGB sequence with 3 LEDs and 4 frames, for this test alone to edit."""
    # Copied from one written sequence: the writer fsyncs every file, which is slow to repeat per test.
    return Path(shutil.copytree(_valid_template, tmp_path / "seq"))


def _edit(directory: Path, change: Callable[[dict], object]) -> Path:
    path = directory / "sequence.json"
    document = json.loads(path.read_text())
    change(document)
    path.write_text(json.dumps(document))
    return path


# -- round trip --------------------------------------------------------------------------------------
@pytest.mark.parametrize("cfa", [None, "GRBG"])
def test_round_trip_keeps_every_field_and_pixel(tmp_path: Path, cfa: str | None) -> None:
    directory = tmp_path / "seq"
    camera = _camera(cfa, lens="f/2.8", temperature_c=41.5)
    leds = _leds(maker="Luxeon", driver={"channel": 0})
    pixels = [_pixels(cfa) for _ in range(4)]
    with _writer(directory, camera=camera, leds=leds, extra={"operator": "ab", "scene": {"id": 7}}) as writer:
        writer.add_frame(pixels[0], "ambient", (0, 0, 0), 10000, 1.0, extra={"frame_id": 17})
        writer.add_frame(pixels[1], "led", (1, 0, 0), 8000, 2.0)
        writer.add_frame(pixels[2], "led", (0, 0.5, 0), 12500.5, 1.5)
        writer.add_frame(pixels[3], "dark", (0, 0, 0), 10000)
        expected = writer.sequence

    sequence = read_sequence(directory)
    assert sequence.complete and not sequence.partial
    assert sequence == dataclasses.replace(expected, complete=True)
    assert sequence != expected  # equality is field by field, arrays by value
    np.testing.assert_array_equal(sequence.wavelengths_nm, WAVELENGTHS)
    assert sequence.spectral_unit == "energy"
    assert sequence.camera == camera
    assert sequence.camera.extra == {"lens": "f/2.8", "temperature_c": 41.5}
    assert sequence.leds == tuple(leds)
    assert sequence.leds[0].extra == {"maker": "Luxeon", "driver": {"channel": 0}}
    assert sequence.extra == {"operator": "ab", "scene": {"id": 7}}
    assert [f.file for f in sequence.frames] == [
        "frames/000-ambient.tiff",
        "frames/001-led.tiff",
        "frames/002-led.tiff",
        "frames/003-dark.tiff",
    ]
    assert sequence.frames[1] == SequenceFrame("frames/001-led.tiff", "led", (1.0, 0.0, 0.0), 8000.0, 2.0)
    assert sequence.frames[2].led_levels == (0.0, 0.5, 0.0)
    assert sequence.frames[2].exposure_us == 12500.5
    assert sequence.frames[0].extra == {"frame_id": 17}
    for i, expected_pixels in enumerate(pixels):
        loaded = sequence.load_frame(i)
        assert loaded.dtype == np.uint16
        np.testing.assert_array_equal(loaded, expected_pixels)
    # Each frame file describes itself.
    attributes = read_image_header(sequence.frame_path(2)).attributes
    assert attributes["msflash:role"] == "led"
    assert attributes["msflash:led_levels"] == [0.0, 0.5, 0.0]
    assert attributes["msflash:exposure_us"] == 12500.5
    assert attributes["msflash:gain"] == 1.5


def test_unknown_keys_written_by_another_tool_survive_a_rewrite(valid: Path, tmp_path: Path) -> None:
    def add_unknown(document: dict) -> None:
        document["future_top"] = [1, 2]
        document["camera"]["sensor"] = {"name": "IMX"}
        document["camera"]["responsivity"]["IR"] = [0.0] * len(WAVELENGTHS)
        document["leds"][2]["fwhm_nm"] = 20
        document["frames"][1]["timestamp_ns"] = 123

    _edit(valid, add_unknown)
    original = read_sequence(valid)
    copy_dir = tmp_path / "copy"
    written = write_sequence(copy_dir, original, [original.load_frame(i) for i in range(len(original.frames))])
    document = json.loads((copy_dir / "sequence.json").read_text())
    assert document["future_top"] == [1, 2]
    assert document["camera"]["sensor"] == {"name": "IMX"}
    assert document["camera"]["responsivity"]["IR"] == [0.0] * len(WAVELENGTHS)
    assert document["leds"][2]["fwhm_nm"] == 20
    assert document["frames"][1]["timestamp_ns"] == 123
    assert written.extra == original.extra and written.camera == original.camera
    assert written.leds == original.leds and written.frames == original.frames
    assert written.directory == copy_dir


def test_accessors(valid: Path) -> None:
    sequence = read_sequence(valid / "sequence.json")  # the file itself is accepted too
    assert sequence.directory == valid
    assert sequence.indices("ambient") == (0,)
    assert sequence.indices("led") == (1, 2, 3)
    assert sequence.indices("flash") == ()
    with pytest.raises(RecordingError, match="role 'bogus' is unknown"):
        sequence.indices("bogus")  # type: ignore[arg-type]
    assert sequence.frame_path(1) == valid / "frames" / "001-led.tiff"
    assert sequence.grid.size == len(WAVELENGTHS) and sequence.grid.step_nm == 10.0
    spectra = sequence.led_spectra()
    assert (spectra.kind, spectra.unit, spectra.names) == ("spd", "energy", ("led450", "led530", "led620"))
    assert spectra.source == str(valid / "sequence.json")
    np.testing.assert_array_equal(spectra.values[:, 1], sequence.leds[1].spd)
    responsivities = sequence.camera_responsivities()
    assert responsivities is not None
    assert (responsivities.kind, responsivities.unit, responsivities.names) == (
        "responsivity",
        "energy",
        ("R", "G", "B"),
    )
    np.testing.assert_array_equal(responsivities.values[:, 0], sequence.camera.responsivity["R"])


def test_arrays_are_read_only_and_no_responsivity_is_none(tmp_path: Path) -> None:
    with _writer(tmp_path / "s", camera=_camera(responsivity=False)) as writer:
        writer.add_frame(_pixels(), "ambient", (0, 0, 0), 1000)
    sequence = read_sequence(tmp_path / "s")
    assert sequence.camera_responsivities() is None
    assert json.loads((tmp_path / "s" / "sequence.json").read_text())["camera"]["responsivity"] is None
    for array in (sequence.wavelengths_nm, sequence.leds[0].spd):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 1.0


def test_photons_unit_and_float_frames(tmp_path: Path) -> None:
    writer = SequenceWriter(
        tmp_path / "f",
        wavelengths_nm=WAVELENGTHS,
        spectral_unit="photons",
        camera=_camera("BGGR"),
        leds=_leds(),
    )
    pixels = RNG.random((HEIGHT, WIDTH)).astype(np.float32)
    frame = writer.add_frame(pixels, "ambient", (0, 0, 0), 500, gain=np.float64(2.0))
    assert frame.file == "frames/000-ambient.exr"
    sequence = writer.finish()
    assert sequence.led_spectra().unit == "photons"
    np.testing.assert_array_equal(sequence.load_frame(0), pixels)


# -- the independent samples ---------------------------------------------------------------------------
def _sample(name: str) -> Path:
    directory = SAMPLES / name
    if not (directory / "sequence.json").is_file():
        pytest.skip(f"shared sample {directory} is absent (CI puts shared/ beside the clone)")
    return directory


def test_sample_rgb_tungsten_reads_as_is() -> None:
    sequence = read_sequence(_sample("sample-rgb-tungsten"))
    assert sequence.complete
    assert (sequence.camera.cfa, sequence.camera.black_level, sequence.camera.white_level) == (None, 64, 65535)
    assert sequence.camera.pixel_format == "RGB16" and sequence.camera.serial is None
    assert [led.name for led in sequence.leds] == [f"ch{i}" for i in range(7)]
    assert sequence.indices("ambient") == (0,) and sequence.indices("led") == tuple(range(1, 8))
    assert {f.exposure_us for f in sequence.frames} == {10000.0}
    for i, frame in enumerate(sequence.frames):
        if frame.role == "led":
            assert frame.led_levels == _one_hot(i - 1, 7)
        pixels = sequence.load_frame(i)
        assert pixels.shape == (96, 128, 3) and pixels.dtype == np.uint16
    assert sequence.led_spectra().values.shape == (31, 7)
    assert sequence.camera_responsivities().values.shape == (31, 3)  # type: ignore[union-attr]


def test_sample_bayer_fluorescent_reads_as_is() -> None:
    sequence = read_sequence(_sample("sample-bayer-fluorescent-12bit"))
    assert sequence.complete
    camera = sequence.camera
    assert (camera.cfa, camera.black_level, camera.white_level, camera.pixel_format) == ("RGGB", 256, 4095, "BayerRG16")
    assert [f.exposure_us for f in sequence.frames] == [5000, 8000, 10000, 10000, 12500, 5000, 12500, 8000]
    assert [f.gain for f in sequence.frames] == [1.5, 1.5, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
    for i in range(len(sequence.frames)):
        pixels = sequence.load_frame(i)
        assert pixels.shape == (96, 128) and pixels.dtype == np.uint16
        assert pixels.min() >= 0 and pixels.max() <= 4095  # 12-bit data in a 16-bit container


@pytest.mark.parametrize("name", ["sample-rgb-tungsten", "sample-bayer-fluorescent-12bit"])
def test_sample_survives_a_rewrite(tmp_path: Path, name: str) -> None:
    original = read_sequence(_sample(name))
    pixels = [original.load_frame(i) for i in range(len(original.frames))]
    copied = write_sequence(tmp_path / name, original, pixels)
    assert copied.camera == original.camera and copied.leds == original.leds
    np.testing.assert_array_equal(copied.wavelengths_nm, original.wavelengths_nm)
    assert [(f.role, f.led_levels, f.exposure_us, f.gain) for f in copied.frames] == [
        (f.role, f.led_levels, f.exposure_us, f.gain) for f in original.frames
    ]
    for i, expected in enumerate(pixels):
        np.testing.assert_array_equal(copied.load_frame(i), expected)
    # The sample omits camera.serial; the rewrite keeps it omitted rather than inventing a null.
    assert "serial" not in json.loads((tmp_path / name / "sequence.json").read_text())["camera"]


def _one_hot(index: int, size: int) -> tuple[float, ...]:
    return tuple(1.0 if i == index else 0.0 for i in range(size))


# -- validation: every error names the file and the field ---------------------------------------------
def _set(path: str, value: object) -> Callable[[dict], None]:
    """A document edit setting the dotted/indexed ``path`` (``frames.2.gain``) to ``value``."""

    def change(document: dict) -> None:
        *parents, last = path.split(".")
        target: object = document
        for key in parents:
            target = target[int(key)] if isinstance(target, list) else target[key]  # type: ignore[index]
        if value is _DELETE:
            del target[int(last) if isinstance(target, list) else last]  # type: ignore[union-attr, arg-type]
        else:
            target[int(last) if isinstance(target, list) else last] = value  # type: ignore[index]

    return change


_DELETE = object()
_N = len(WAVELENGTHS)

INVALID = {
    "version newer": (_set("version", 2), "version 2 is newer than this msflash reads (1); upgrade msflash"),
    "version older": (_set("version", 0), "version 0 is not a version of this format; expected 1"),
    "version string": (_set("version", "1"), "version is '1'; expected the integer 1"),
    "format": (_set("format", "other"), "format is 'other'; expected 'msflash-sequence'"),
    "format missing": (_set("format", _DELETE), "format is missing; expected 'msflash-sequence'"),
    "complete": (_set("complete", "yes"), "complete is 'yes'; expected true or false"),
    "unit": (_set("spectral_unit", "watts"), "spectral_unit is 'watts'; expected one of 'energy', 'photons'"),
    "wavelengths uneven": (
        _set("wavelengths_nm", [400, 410, 425, *range(430, 701, 10)][:_N]),
        "wavelengths_nm: wavelengths are not uniformly spaced",
    ),
    "wavelengths decreasing": (
        _set("wavelengths_nm", list(range(700, 399, -10))),
        "wavelengths_nm: wavelengths must increase",
    ),
    "wavelength string": (_set("wavelengths_nm.3", "430"), "wavelengths_nm[3] is '430'; expected a number"),
    "wavelengths scalar": (_set("wavelengths_nm", 400), "wavelengths_nm is a number; expected a list of numbers"),
    "camera missing": (_set("camera", _DELETE), "camera is missing; expected an object"),
    "camera list": (_set("camera", []), "camera is a list; expected an object"),
    "model": (_set("camera.model", 5), "camera.model is a number; expected a non-empty string"),
    "cfa": (_set("camera.cfa", "RGBG"), "camera.cfa is 'RGBG'; expected null (RGB frames) or one of RGGB"),
    "black missing": (_set("camera.black_level", _DELETE), "camera.black_level is missing; expected a number"),
    "black negative": (_set("camera.black_level", -1), "camera.black_level is -1; expected a number ≥ 0"),
    "white below black": (_set("camera.white_level", 64), "camera.white_level is 64, not above black_level 64"),
    "white string": (_set("camera.white_level", "4095"), "camera.white_level is '4095'; expected a number"),
    "responsivity length": (
        _set("camera.responsivity.G", [0.5] * (_N - 1)),
        f"camera.responsivity.G has {_N - 1} values; expected {_N} (one per wavelength)",
    ),
    "responsivity channel": (
        _set("camera.responsivity.B", _DELETE),
        "camera.responsivity lacks B; expected R, G and B",
    ),
    "responsivity negative": (
        _set("camera.responsivity.R.4", -0.2),
        "camera.responsivity.R[4] is -0.2; expected a non-negative",
    ),
    "leds object": (_set("leds", {}), "leds is an object; expected a list of LED objects"),
    "led name": (_set("leds.1.name", ""), "leds[1].name is ''; expected a non-empty string"),
    "led duplicate": (_set("leds.2.name", "led450"), "leds[2].name 'led450' repeats leds[0].name; expected unique"),
    "spd length": (_set("leds.1.spd", [0.1] * 30), f"leds[1].spd has 30 values; expected {_N} (one per wavelength)"),
    "spd negative": (_set("leds.0.spd.5", -0.1), "leds[0].spd[5] is -0.1; expected a non-negative value"),
    "spd missing": (_set("leds.0.spd", _DELETE), "leds[0].spd is missing"),
    "frames object": (_set("frames", {}), "frames is an object; expected a list of frame objects"),
    "frame file missing": (
        _set("frames.3.file", "frames/003-gone.tiff"),
        "frames[3].file 'frames/003-gone.tiff' is missing",
    ),
    "frame outside": (
        _set("frames.1.file", "../x.tiff"),
        "frames[1].file '../x.tiff' points outside the sequence directory",
    ),
    "frame absolute": (
        _set("frames.1.file", "/etc/passwd"),
        "frames[1].file '/etc/passwd' is absolute; expected a path relative",
    ),
    "frame file type": (_set("frames.1.file", 3), "frames[1].file is a number; expected a relative file path"),
    "frame directory": (
        _set("frames.1.file", "frames"),
        "frames[1].file 'frames': is a directory; expected a frame image, a regular file",
    ),
    # Two LEDs given one image (an edit gone wrong) was read, and estimated from, without a word.
    "frame file repeated": (
        _set("frames.3.file", "frames/./001-led.tiff"),
        "frames[3].file 'frames/./001-led.tiff' is also frames[1].file; expected one file per frame",
    ),
    "levels count": (
        _set("frames.2.led_levels", [0, 1]),
        "frames[2].led_levels has 2 values; expected 3 (one per LED)",
    ),
    "level above 1": (
        _set("frames.2.led_levels", [0, 1.5, 0]),
        "frames[2].led_levels[1] is 1.5; expected a level in [0, 1]",
    ),
    "level negative": (
        _set("frames.2.led_levels", [0, -0.1, 0]),
        "frames[2].led_levels[1] is -0.1; expected a level in [0, 1]",
    ),
    "ambient lit": (
        _set("frames.0.led_levels", [0, 0.2, 0]),
        "frames[0].led_levels are [0.0, 0.2, 0.0] for role 'ambient'",
    ),
    "role": (
        _set("frames.1.role", "flashy"),
        "frames[1].role is 'flashy'; expected one of 'ambient', 'led', 'flash', 'dark'",
    ),
    "exposure zero": (_set("frames.1.exposure_us", 0), "frames[1].exposure_us is 0; expected a number > 0"),
    "exposure string": (_set("frames.1.exposure_us", "10"), "frames[1].exposure_us is '10'; expected a number > 0"),
    "exposure bool": (_set("frames.1.exposure_us", True), "frames[1].exposure_us is a boolean; expected a number > 0"),
    # Found by the sequence fuzzer (issue 19 item 6): > 0 but its reciprocal is infinite (estimate exited 1).
    "exposure denormal": (
        _set("frames.1.exposure_us", 5e-324),
        "frames[1].exposure_us × gain is 4.94066e-324 × 1, "
        "too small to divide by; expected exposure_us × gain of at least 5.56e-309",
    ),
    "exposure times gain underflows": (_set("frames.1.gain", 1e-315), "frames[1].exposure_us × gain is "),
    "gain zero": (_set("frames.2.gain", 0), "frames[2].gain is 0; expected a number > 0"),
    "gain missing": (_set("frames.2.gain", _DELETE), "frames[2].gain is missing; expected a number > 0"),
    "frame not object": (_set("frames.2", "x"), "frames[2] is a string; expected an object"),
    "no ambient": (_set("frames.0.role", "dark"), "frames has no frame with role 'ambient'; expected at least one"),
}


@pytest.mark.parametrize("case", list(INVALID))
def test_invalid_sequence_error_names_file_and_field(valid: Path, case: str) -> None:
    change, message = INVALID[case]
    path = _edit(valid, change)
    with pytest.raises(RecordingError) as caught:
        read_sequence(valid)
    assert str(caught.value).startswith(f"{path}: ")
    assert message in str(caught.value)


@pytest.mark.parametrize(
    ("literal", "field"),
    [("NaN", "leds[0].spd[2] is nan"), ("Infinity", "camera.responsivity.G[2] is inf")],
)
def test_non_finite_values_are_refused(valid: Path, literal: str, field: str) -> None:
    # Python's json writes NaN/Infinity literals (other tools may too); they must not slip through.
    path = valid / "sequence.json"
    document = json.loads(path.read_text())
    target = document["leds"][0]["spd"] if "leds" in field else document["camera"]["responsivity"]["G"]
    target[2] = float(literal.replace("Infinity", "inf"))
    path.write_text(json.dumps(document))
    with pytest.raises(RecordingError, match=rf"^{re.escape(str(path))}: {re.escape(field)}; expected a finite"):
        read_sequence(valid)


def test_malformed_json_names_line_and_column(valid: Path) -> None:
    path = valid / "sequence.json"
    path.write_text('{\n "format": "msflash-sequence",\n "version": 1,,\n}\n')
    with pytest.raises(RecordingError, match=rf"^{path}: line 3 column 15: Expecting property name"):
        read_sequence(valid)


def test_duplicate_keys_and_non_object_and_encoding(valid: Path) -> None:
    path = valid / "sequence.json"
    path.write_text('{"format": "msflash-sequence", "format": "x"}')
    with pytest.raises(RecordingError, match=rf"^{path}: key 'format' appears twice"):
        read_sequence(valid)
    path.write_text("[1, 2]")
    with pytest.raises(RecordingError, match=rf"^{path}: the document is a list; expected an object"):
        read_sequence(valid)
    path.write_bytes(b'{"format": "\xff"}')
    with pytest.raises(RecordingError, match=rf"^{path}: is not UTF-8 text"):
        read_sequence(valid)


def test_missing_sequence_json(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=rf"^{tmp_path}/sequence.json: file is missing"):
        read_sequence(tmp_path)


def test_symlink_escaping_the_directory_is_refused(valid: Path, tmp_path: Path) -> None:
    outside = write_image(tmp_path / "outside.tiff", _pixels())
    (valid / "frames" / "link.tiff").symlink_to(outside)
    _edit(valid, _set("frames.1.file", "frames/link.tiff"))
    with pytest.raises(RecordingError, match=r"frames\[1\].file 'frames/link.tiff' points outside"):
        read_sequence(valid)


# -- frame checks at load time -----------------------------------------------------------------------
def test_frames_of_different_sizes_name_both_files(valid: Path) -> None:
    forget_digests(valid)  # replaced behind the writer's back: a digest would refuse it first
    write_image(valid / "frames" / "002-led.tiff", _pixels(shape=(HEIGHT + 2, WIDTH)))
    sequence = read_sequence(valid)  # sizes are checked lazily, when a frame is loaded
    sequence.load_frame(1)
    with pytest.raises(RecordingError) as caught:
        sequence.load_frame(2)
    message = str(caught.value)
    assert "frames[2].file 'frames/002-led.tiff' is 8×8 pixels" in message
    assert "frames[0].file 'frames/000-ambient.tiff' is 8×6" in message
    assert "expected one size for all frames" in message


def test_channel_count_must_match_cfa(valid: Path, tmp_path: Path) -> None:
    forget_digests(valid)
    write_image(valid / "frames" / "001-led.tiff", _pixels(cfa="RGGB"))
    with pytest.raises(
        RecordingError, match=r"frames\[1\].file 'frames/001-led.tiff' has 1 channel but camera.cfa is null"
    ):
        read_sequence(valid).load_frame(1)
    mosaic = tmp_path / "mosaic"
    _paper_sequence(mosaic, cfa="RGGB")
    forget_digests(mosaic)
    write_image(mosaic / "frames" / "003-led.tiff", _pixels())
    with pytest.raises(
        RecordingError, match=r"frames\[3\].file 'frames/003-led.tiff' has 3 channels but camera.cfa is 'RGGB'"
    ):
        read_sequence(mosaic).load_frame(3)


def test_unreadable_frame_file_is_named(valid: Path) -> None:
    forget_digests(valid)
    (valid / "frames" / "001-led.tiff").write_bytes(b"broken")
    with pytest.raises(RecordingError, match=r"001-led.tiff: cannot be read as an image"):
        read_sequence(valid).load_frame(1)


# -- the writer ----------------------------------------------------------------------------------------
def test_sequence_json_lists_each_frame_as_soon_as_it_is_written(tmp_path: Path) -> None:
    directory = tmp_path / "live"
    with _writer(directory) as writer:
        assert read_sequence(directory).frames == ()
        assert read_sequence(directory).partial
        writer.add_frame(_pixels(), "ambient", (0, 0, 0), 1000)
        during = read_sequence(directory)
        assert during.partial and len(during.frames) == 1
        writer.add_frame(_pixels(), "led", (0, 0, 1), 1000)
        assert len(read_sequence(directory).frames) == 2
    after = read_sequence(directory)
    assert after.complete and len(after.frames) == 2
    assert sorted(p.name for p in directory.iterdir()) == ["frames", "sequence.json"]  # no temporaries left


def test_exception_inside_with_leaves_a_readable_partial_sequence(tmp_path: Path) -> None:
    directory = tmp_path / "crash"
    pixels = [_pixels() for _ in range(2)]
    with pytest.raises(RuntimeError, match="camera fell over"), _writer(directory) as writer:
        writer.add_frame(pixels[0], "ambient", (0, 0, 0), 1000)
        writer.add_frame(pixels[1], "led", (1, 0, 0), 1000)
        raise RuntimeError("camera fell over")
    sequence = read_sequence(directory)
    assert sequence.partial and not sequence.complete
    assert [f.file for f in sequence.frames] == ["frames/000-ambient.tiff", "frames/001-led.tiff"]
    for i, expected in enumerate(pixels):
        np.testing.assert_array_equal(sequence.load_frame(i), expected)


_CHILD = textwrap.dedent(
    """
    import sys
    import numpy as np
    from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
    from msflash.acquisition.sequence.writer import SequenceWriter

    wavelengths = np.arange(400.0, 701.0, 10.0)
    camera = SequenceCamera("Kill", "0", "RGB16", None, 0, 65535)
    leds = [SequenceLed("a", np.ones(31)), SequenceLed("b", np.ones(31))]
    rng = np.random.default_rng(0)
    with SequenceWriter(sys.argv[1], wavelengths_nm=wavelengths, spectral_unit="energy",
                        camera=camera, leds=leds) as writer:
        for index in range(10_000):
            role = "ambient" if index == 0 else "led"
            levels = (0.0, 0.0) if index == 0 else (1.0, 0.0)
            writer.add_frame(rng.integers(0, 65535, (64, 64, 3), dtype=np.uint16), role, levels, 1000)
            print(index, flush=True)
    """
)


def test_sigkill_mid_sequence_leaves_a_readable_partial_sequence(tmp_path: Path) -> None:
    directory = tmp_path / "killed"
    env = {**os.environ, "PYTHONPATH": str(REPOSITORY)}
    child = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(directory)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=REPOSITORY,
    )
    try:
        for expected in range(3):
            line = child.stdout.readline()  # type: ignore[union-attr]
            assert line.strip() == str(expected), child.stderr.read()  # type: ignore[union-attr]
        # The child keeps writing frames, so the kill lands at an arbitrary point of a write.
        child.send_signal(signal.SIGKILL)
    finally:
        child.kill()
        child.wait(timeout=30)
        child.stdout.close()  # type: ignore[union-attr]
        child.stderr.close()  # type: ignore[union-attr]
    assert child.returncode == -signal.SIGKILL
    sequence = read_sequence(directory)
    assert sequence.partial
    assert len(sequence.frames) >= 3
    for i in range(len(sequence.frames)):
        assert sequence.load_frame(i).shape == (64, 64, 3)
    assert sequence.frames[0].role == "ambient"


def test_writer_refuses_invalid_frames_before_writing_anything(tmp_path: Path) -> None:
    directory = tmp_path / "w"
    writer = _writer(directory)
    path = directory / "sequence.json"
    cases = [
        (lambda: writer.add_frame(_pixels(), "flashy", (0, 0, 0), 1000), r"frames\[0\].role is 'flashy'"),  # type: ignore[arg-type]
        (lambda: writer.add_frame(_pixels(), "led", (0, 1), 1000), r"frames\[0\].led_levels has 2 values; expected 3"),
        (lambda: writer.add_frame(_pixels(), "led", (0, 1, 0), -5), r"frames\[0\].exposure_us is -5"),
        (lambda: writer.add_frame(_pixels(), "led", (0, 1, 0), 5, gain=0), r"frames\[0\].gain is 0"),
        (
            lambda: writer.add_frame(_pixels("RGGB"), "led", (0, 1, 0), 5),
            "pixels have 1 channel but camera.cfa is null",
        ),
        (lambda: writer.add_frame(np.zeros((2, 2, 4), np.uint16), "led", (0, 1, 0), 5), r"shape \(2, 2, 4\)"),
        (
            lambda: writer.add_frame(_pixels(), "led", (0, 1, 0), 5, extra={"file": "../x"}),
            r"extra keys \['file'\] clash",
        ),
        (lambda: writer.add_frame(_pixels(), "ambient", (0, 0, 0), 5, extra={"t": object()}), "cannot be written"),
    ]
    for call, message in cases:
        with pytest.raises(RecordingError, match=rf"^{path}: .*{message}"):
            call()
    assert not (directory / "frames").exists() or not any((directory / "frames").iterdir())
    writer.add_frame(_pixels(), "ambient", (0, 0, 0), 1000)
    with pytest.raises(
        RecordingError,
        match=r"frames\[1\]: pixels for 'frames/001-led.tiff' have shape \(7, 8, 3\) but 'frames/000-ambient.tiff' has \(6, 8, 3\)",
    ):
        writer.add_frame(_pixels(shape=(7, 8)), "led", (1, 0, 0), 1000)
    assert read_sequence(directory).frames[0].file == "frames/000-ambient.tiff"
    assert len(read_sequence(directory).frames) == 1


def test_writer_header_is_validated_like_the_reader(tmp_path: Path) -> None:
    path = tmp_path / "h" / "sequence.json"
    with pytest.raises(RecordingError, match=rf"^{path}: wavelengths_nm: wavelengths are not uniformly spaced"):
        SequenceWriter(path.parent, wavelengths_nm=[400, 410, 430], spectral_unit="energy", camera=_camera(), leds=[])
    with pytest.raises(RecordingError, match=rf"^{path}: leds\[1\].spd has 5 values; expected {_N}"):
        _writer(path.parent, leds=[_leds()[0], SequenceLed("short", np.ones(5))])
    bad = [SequenceLed("nan", np.full(_N, np.nan))]
    with pytest.raises(RecordingError, match=rf"^{path}: leds\[0\].spd\[0\] is nan; expected a finite number"):
        _writer(path.parent, leds=bad)
    with pytest.raises(RecordingError, match=rf"^{path}: spectral_unit is 'lux'"):
        _writer(path.parent, spectral_unit="lux")
    with pytest.raises(RecordingError, match=rf"^{path}: camera.white_level is 10, not above black_level 64"):
        _writer(path.parent, camera=SequenceCamera("m", "s", "RGB16", None, 64, 10))
    with pytest.raises(RecordingError, match="extra keys \\['cfa'\\] clash with format keys"):
        SequenceCamera("m", "s", "RGB16", None, 0, 1, extra={"cfa": 1})
    assert not path.exists()


def test_writer_refuses_an_existing_sequence_and_writes_after_finish(valid: Path, tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=rf"^{valid}/sequence.json: already exists"):
        _writer(valid)
    writer = _writer(tmp_path / "once")
    writer.add_frame(_pixels(), "ambient", (0, 0, 0), 1000)
    writer.finish()
    with pytest.raises(RecordingError, match="the sequence is finished"):
        writer.add_frame(_pixels(), "led", (1, 0, 0), 1000)


def test_writer_refuses_frame_files_without_a_sequence(tmp_path: Path) -> None:
    """Frame files are named by index: a frames/ folder left without its sequence.json (copied,
    half deleted) would have been overwritten without a word."""
    stray = tmp_path / "s" / "frames" / "000-ambient.tiff"
    stray.parent.mkdir(parents=True)
    stray.write_bytes(b"someone's frame")
    with pytest.raises(
        RecordingError,
        match=rf"^{stray.parent}: holds files but there is no sequence.json; "
        "expected a new or empty directory",
    ):
        _writer(tmp_path / "s")
    assert stray.read_bytes() == b"someone's frame" and not (tmp_path / "s" / "sequence.json").exists()
    (tmp_path / "t" / "frames").mkdir(parents=True)  # an empty frames/ folder is fine
    _writer(tmp_path / "t").add_frame(_pixels(), "ambient", (0, 0, 0), 1000)


def test_finish_without_ambient_keeps_the_sequence_partial(tmp_path: Path) -> None:
    directory = tmp_path / "noamb"
    writer = _writer(directory)
    writer.add_frame(_pixels(), "led", (1, 0, 0), 1000)
    with pytest.raises(
        RecordingError, match="frames has no frame with role 'ambient'; expected at least one before finish"
    ):
        writer.finish()
    assert read_sequence(directory).partial


def test_write_sequence_needs_one_pixel_array_per_frame(valid: Path, tmp_path: Path) -> None:
    sequence = read_sequence(valid)
    with pytest.raises(RecordingError, match="1 pixel arrays for 4 frames; expected one per frame"):
        write_sequence(tmp_path / "short", sequence, [sequence.load_frame(0)])


def test_pixels_written_are_exactly_what_was_given(tmp_path: Path) -> None:
    written = _paper_sequence(tmp_path / "p", cfa="RGGB")
    sequence = read_sequence(tmp_path / "p")
    for i, pixels in enumerate(written):
        np.testing.assert_array_equal(read_image(sequence.frame_path(i)), pixels)
    assert copy.deepcopy(sequence) == sequence
