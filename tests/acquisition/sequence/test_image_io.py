"""Frame image I/O: native types, channel checks, self-describing attributes, atomic writes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.image_files import image_suffix, read_image, read_image_header, write_image

RNG = np.random.default_rng(7)


def _write_raw(path: Path, pixels: np.ndarray, type_name: str) -> None:
    """Write a file with OpenImageIO directly (formats msflash itself never writes)."""
    height, width, channels = pixels.shape
    output = oiio.ImageOutput.create(str(path))
    assert output.open(str(path), oiio.ImageSpec(width, height, channels, type_name))
    assert output.write_image(pixels)
    output.close()


@pytest.mark.parametrize("shape", [(6, 9), (6, 9, 3)])
def test_uint16_round_trip_keeps_counts_shape_and_type(tmp_path: Path, shape: tuple[int, ...]) -> None:
    pixels = RNG.integers(0, 65536, size=shape, dtype=np.uint16)
    path = write_image(tmp_path / "frame.tiff", pixels)
    back = read_image(path)
    assert back.dtype == np.uint16
    assert back.shape == shape
    np.testing.assert_array_equal(back, pixels)


def test_integer_counts_are_not_rescaled(tmp_path: Path) -> None:
    # uint8 255 must stay 255 in the 16-bit file, not become 65535 (OpenImageIO's normalised conversion).
    pixels = np.array([[0, 1, 255], [12, 200, 254]], dtype=np.uint8)
    back = read_image(write_image(tmp_path / "counts.tiff", pixels))
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back, pixels.astype(np.uint16))
    wide = np.array([[0, 4095], [65535, 7]], dtype=np.int64)
    np.testing.assert_array_equal(read_image(write_image(tmp_path / "wide.tif", wide)), wide)


def test_one_channel_third_axis_is_dropped(tmp_path: Path) -> None:
    pixels = RNG.integers(0, 4096, size=(4, 5, 1), dtype=np.uint16)
    assert read_image(write_image(tmp_path / "mono.tiff", pixels)).shape == (4, 5)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.float16])
def test_float_pixels_go_to_float_exr(tmp_path: Path, dtype: type) -> None:
    pixels = RNG.random((5, 7, 3)).astype(dtype)
    assert image_suffix(pixels) == ".exr"
    back = read_image(write_image(tmp_path / "derived.exr", pixels))
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, pixels.astype(np.float32))
    image = oiio.ImageInput.open(str(tmp_path / "derived.exr"))
    assert image.spec().format == oiio.TypeDesc("float")
    image.close()


def test_half_exr_and_8bit_png_from_other_tools(tmp_path: Path) -> None:
    half = RNG.random((3, 4, 3)).astype(np.float16)
    _write_raw(tmp_path / "half.exr", half, "half")
    back = read_image(tmp_path / "half.exr")
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, half.astype(np.float32))
    png = RNG.integers(0, 256, size=(3, 4, 1), dtype=np.uint8)
    _write_raw(tmp_path / "mono8.png", png, "uint8")
    back8 = read_image(tmp_path / "mono8.png")
    assert back8.dtype == np.uint8
    np.testing.assert_array_equal(back8, png[:, :, 0])


@pytest.mark.parametrize("suffix", [".tiff", ".exr"])
def test_attributes_make_a_frame_describe_itself(tmp_path: Path, suffix: str) -> None:
    pixels = np.ones((4, 4, 3), dtype=np.uint16 if suffix == ".tiff" else np.float32)
    attributes = {
        "msflash:role": "led",
        "msflash:exposure_us": 1250.5,
        "msflash:led_levels": [1.0, 0.0, 0.25],
        "msflash:index": 3,
    }
    path = write_image(tmp_path / f"frame{suffix}", pixels, attributes)
    header = read_image_header(path)
    assert header.attributes == attributes
    assert (header.width, header.height, header.channels, header.shape) == (4, 4, 3, (4, 4, 3))
    assert header.dtype == pixels.dtype


def test_files_without_msflash_attributes_have_none(tmp_path: Path) -> None:
    path = write_image(tmp_path / "plain.tiff", np.zeros((2, 2), np.uint16))
    assert read_image_header(path).attributes == {}


def test_missing_file_is_named(tmp_path: Path) -> None:
    missing = tmp_path / "nope.tiff"
    with pytest.raises(RecordingError, match="nope.tiff: image file is missing"):
        read_image(missing)
    with pytest.raises(RecordingError, match="nope.tiff: image file is missing"):
        read_image_header(missing)


def test_unreadable_file_is_named(tmp_path: Path) -> None:
    bad = tmp_path / "garbage.tiff"
    bad.write_bytes(b"not an image at all")
    with pytest.raises(RecordingError, match=r"garbage.tiff: cannot be read as an image .*; expected"):
        read_image(bad)
    with pytest.raises(RecordingError, match="is a directory; expected a frame image, a regular file"):
        read_image(tmp_path)


@pytest.mark.parametrize("channels", [2, 4])
def test_wrong_channel_count_is_named(tmp_path: Path, channels: int) -> None:
    path = tmp_path / f"c{channels}.png"
    _write_raw(path, np.zeros((3, 3, channels), np.uint16), "uint16")
    with pytest.raises(RecordingError, match=rf"c{channels}.png: image has {channels} channels; expected 1 .* or 3"):
        read_image(path)


@pytest.mark.parametrize(
    ("name", "pixels", "message"),
    [
        ("neg.tiff", np.array([[-1, 0]], dtype=np.int32), r"span -1…0; expected counts in 0…65535"),
        ("big.tiff", np.array([[70000, 0]], dtype=np.int64), r"span 0…70000"),
        ("float.tiff", np.zeros((2, 2), np.float32), r"float pixels need a float format; expected a \.exr"),
        ("int.exr", np.zeros((2, 2), np.uint16), r"stored as 16-bit TIFF; expected a \.tiff"),
        ("shape.tiff", np.zeros((2, 2, 4), np.uint16), r"shape \(2, 2, 4\); expected \(H, W\)"),
        ("flat.tiff", np.zeros(5, np.uint16), r"shape \(5,\)"),
        ("bool.tiff", np.zeros((2, 2), bool), r"pixel type bool is not supported"),
    ],
)
def test_bad_pixels_are_refused_naming_the_file(tmp_path: Path, name: str, pixels: np.ndarray, message: str) -> None:
    with pytest.raises(RecordingError, match=rf"{name}: .*{message}"):
        write_image(tmp_path / name, pixels)
    assert list(tmp_path.iterdir()) == []


def test_bad_attribute_names_and_values_are_refused(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="attribute name 'role'; expected a name starting with 'msflash:'"):
        write_image(tmp_path / "a.tiff", np.zeros((2, 2), np.uint16), {"role": "led"})
    with pytest.raises(RecordingError, match="attributes cannot be stored"):
        write_image(tmp_path / "a.tiff", np.zeros((2, 2), np.uint16), {"msflash:x": object()})
    assert list(tmp_path.iterdir()) == []


def test_write_replaces_atomically_and_leaves_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "frame.tiff"
    write_image(path, np.full((3, 3), 5, np.uint16))
    write_image(path, np.full((3, 3), 9, np.uint16))
    np.testing.assert_array_equal(read_image(path), np.full((3, 3), 9))
    assert [p.name for p in path.parent.iterdir()] == ["frame.tiff"]
    # A refused write leaves the previous file untouched.
    with pytest.raises(RecordingError):
        write_image(path, np.full((3, 3), -1, np.int32))
    np.testing.assert_array_equal(read_image(path), np.full((3, 3), 9))
    assert [p.name for p in path.parent.iterdir()] == ["frame.tiff"]


@pytest.mark.parametrize(
    "description",
    ['{"msflash:x": ' * 50_000 + "1" + "}" * 50_000, '{"msflash:gain": NaN, "msflash:x": 1e999}', "{not json"],
)
def test_another_tools_hostile_description_is_ignored_not_a_crash(tmp_path: Path, description: str) -> None:
    # Another writer's ImageDescription that opens like JSON: nested past the recursion limit, holding
    # NaN, or malformed. It carries no attributes of ours; the pixels still read.
    import tifffile

    path = tmp_path / "other.tiff"
    pixels = np.arange(12, dtype=np.uint16).reshape(3, 4)
    tifffile.imwrite(path, pixels, description=description, metadata=None)
    header = read_image_header(path)
    assert header.attributes == {} and (header.height, header.width) == (3, 4)
    assert np.array_equal(read_image(path), pixels)
