"""Frame files in the encodings other tools write: each is read exactly or refused by name.

The list is docs/architecture.md §6 ("Frame file encodings"); every row there is a case here. Files
are written by OpenImageIO where its writer produces the encoding, and byte by byte
(:mod:`tests.acquisition.support.tiff_files`) where it does not (big-endian, float16, uint32).
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.image_files import read_image, read_image_header
from tests.acquisition.support.tiff_files import write_baseline_tiff
from tests.helpers import forget_digests, write_test_sequence

COUNTS = (np.arange(5 * 7 * 3).reshape(5, 7, 3) * 611 % 65536).astype(np.uint16)
"""An RGB frame of 16-bit counts, every value distinct enough to catch a swapped byte or channel."""


def _oiio_write(
    path: Path, pixels: np.ndarray, type_name: str, format_name: str = "tiff", pages: int = 1, **attributes: object
) -> Path:
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2] if pixels.ndim == 3 else 1, type_name)
    for name, value in attributes.items():
        spec.attribute(name, value)
    output = oiio.ImageOutput.create(format_name)
    assert output is not None, oiio.geterror()
    try:
        assert output.open(str(path), spec), output.geterror()
        assert output.write_image(pixels), output.geterror()
        for _ in range(pages - 1):
            assert output.open(str(path), spec, "AppendSubimage"), output.geterror()
            assert output.write_image(pixels), output.geterror()
    finally:
        output.close()
    return path


def _attribute(path: Path, name: str) -> object:
    image = oiio.ImageInput.open(str(path))
    try:
        return image.spec().getattribute(name)
    finally:
        image.close()


READ: dict[str, tuple[Callable[[Path], Path], np.ndarray, tuple[str, object] | None]] = {
    # name: (writer, the pixels read_image must return, an attribute proving the file is that encoding)
    "lzw_tiff": (lambda p: _oiio_write(p, COUNTS, "uint16", compression="lzw"), COUNTS, ("tiff:Compression", 5)),
    "deflate_tiff": (lambda p: _oiio_write(p, COUNTS, "uint16", compression="zip"), COUNTS, ("tiff:Compression", 8)),
    "planar_tiff": (
        lambda p: _oiio_write(p, COUNTS, "uint16", planarconfig="separate"),
        COUNTS,
        ("tiff:PlanarConfiguration", 2),
    ),
    "big_endian_tiff": (lambda p: write_baseline_tiff(p, COUNTS, big_endian=True), COUNTS, None),
    "big_endian_mosaic_tiff": (
        lambda p: write_baseline_tiff(p, COUNTS[:, :, 1], big_endian=True),
        COUNTS[:, :, 1],
        None,
    ),
    "float32_tiff": (
        lambda p: _oiio_write(p, COUNTS.astype(np.float32), "float"),
        COUNTS.astype(np.float32),
        ("oiio:BitsPerSample", 32),
    ),
    "float64_tiff": (
        lambda p: _oiio_write(p, COUNTS.astype(np.float64), "double"),
        COUNTS.astype(np.float32),
        ("oiio:BitsPerSample", 64),
    ),
    "float16_tiff": (
        lambda p: write_baseline_tiff(p, (COUNTS / 65535).astype(np.float16)),
        (COUNTS / 65535).astype(np.float16).astype(np.float32),
        ("oiio:BitsPerSample", 16),
    ),
    "uint8_tiff": (
        lambda p: _oiio_write(p, (COUNTS % 256).astype(np.uint8), "uint8"),
        (COUNTS % 256).astype(np.uint8),
        None,
    ),
    "png16": (lambda p: _oiio_write(p, COUNTS, "uint16", "png"), COUNTS, None),
    "png_named_tiff": (lambda p: _oiio_write(p, COUNTS, "uint16", "png"), COUNTS, None),
}

REFUSED: dict[str, tuple[Callable[[Path], Path], str]] = {
    "uint32_tiff": (lambda p: write_baseline_tiff(p, COUNTS.astype(np.uint32)), "pixel type 'uint32' is not supported"),
    "int16_tiff": (
        lambda p: _oiio_write(p, COUNTS.astype(np.int16) // 2, "int16"),
        "pixel type 'int16' is not supported",
    ),
    "multi_page_tiff": (lambda p: _oiio_write(p, COUNTS, "uint16", pages=3), "holds more than one image"),
    "two_channel_tiff": (lambda p: _oiio_write(p, COUNTS[:, :, :2].copy(), "uint16"), "image has 2 channels"),
    "rgba_tiff": (lambda p: _oiio_write(p, np.dstack([COUNTS, COUNTS[:, :, :1]]), "uint16"), "image has 4 channels"),
}


def _suffix(name: str) -> str:
    return ".png" if name == "png16" else ".tiff"


@pytest.mark.parametrize("name", sorted(READ))
def test_encodings_read_exactly(tmp_path: Path, name: str) -> None:
    write, expected, proof = READ[name]
    path = write(tmp_path / f"{name}{_suffix(name)}")
    if proof is not None:  # the file really is in that encoding, not OpenImageIO's default
        assert _attribute(path, proof[0]) == proof[1]
    pixels = read_image(path)
    assert pixels.dtype == expected.dtype and pixels.shape == expected.shape
    np.testing.assert_array_equal(pixels, expected)
    assert read_image_header(path).shape == expected.shape


def test_a_png_named_tiff_is_a_png(tmp_path: Path) -> None:
    path = READ["png_named_tiff"][0](tmp_path / "frame.tiff")
    assert path.read_bytes()[:4] == b"\x89PNG"  # read by its content, whatever its suffix says


def test_big_endian_file_is_big_endian(tmp_path: Path) -> None:
    assert READ["big_endian_tiff"][0](tmp_path / "frame.tiff").read_bytes()[:2] == b"MM"


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_encodings_refused_by_name(tmp_path: Path, name: str) -> None:
    write, said = REFUSED[name]
    path = write(tmp_path / f"{name}.tiff")
    for reader in (read_image, read_image_header):
        with pytest.raises(RecordingError) as caught:
            reader(path)
        message = str(caught.value)
        assert message.startswith(str(path)) and said in message and "expected" in message


def test_a_multi_page_frame_in_a_sequence_is_one_error_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    sequence = write_test_sequence(tmp_path / "seq")
    forget_digests(sequence)  # another tool's file put in place of frame 2
    frame = sequence / "frames" / "002-led.tiff"
    pixels = read_image(frame)
    frame.unlink()
    _oiio_write(frame, pixels, "uint16", pages=2)
    assert main(["estimate", str(sequence)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "002-led.tiff: holds more than one image (a multi-page TIFF?)" in err[0]


def test_compressed_big_endian_frames_estimate_as_the_originals(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A sequence whose frames another tool re-encoded (LZW, big-endian) gives the same estimate."""
    original = write_test_sequence(tmp_path / "original")
    assert main(["estimate", str(original), "--json"]) == 0
    expected = capsys.readouterr().out
    recoded = tmp_path / "recoded"
    shutil.copytree(original, recoded)
    forget_digests(recoded)
    for index, frame in enumerate(sorted((recoded / "frames").iterdir())):
        pixels = read_image(frame)
        frame.unlink()
        if index % 2:
            write_baseline_tiff(frame, pixels, big_endian=True)
        else:
            _oiio_write(frame, pixels, "uint16", compression="lzw")
    assert main(["estimate", str(recoded), "--json"]) == 0
    assert capsys.readouterr().out == expected.replace(str(original), str(recoded))
