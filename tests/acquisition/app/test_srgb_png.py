"""PNG files msflash writes: the sRGB chunks a viewer reads, and previews enlarged without invented colours."""

from __future__ import annotations

import io
import struct

import numpy as np
import pytest
from PIL import Image

from msflash.acquisition.app.srgb_png import PREVIEW_LONG_SIDE_PX, enlarged, enlargement, srgb_png_bytes
from tests.acquisition.support.png_files import png_chunks


def test_pillow_reads_the_srgb_chunks_and_the_pixels_back() -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, size=(5, 7, 3), dtype=np.uint8)
    data = srgb_png_bytes(image, {"Software": "msflash"})
    read = Image.open(io.BytesIO(data))
    assert read.info["srgb"] == 0  # perceptual intent
    assert read.info["gamma"] == pytest.approx(0.45455)
    assert read.info["chromaticity"] == pytest.approx((0.3127, 0.329, 0.64, 0.33, 0.3, 0.6, 0.15, 0.06))
    assert read.info["Software"] == "msflash"
    np.testing.assert_array_equal(np.asarray(read), image)
    chunks = png_chunks(data)
    assert "iCCP" not in chunks  # sRGB and iCCP must not both be present
    assert list(chunks)[:4] == ["IHDR", "sRGB", "gAMA", "cHRM"]  # before the image data


def test_a_small_preview_is_enlarged_by_whole_pixels_to_the_long_side() -> None:
    image = np.arange(106 * 112 * 3, dtype=np.uint32).reshape(106, 112, 3).astype(np.uint8)
    big = enlarged(image)
    factor = enlargement(image.shape)
    assert factor == 10 and big.shape == (1060, 1120, 3)
    assert max(big.shape[:2]) >= PREVIEW_LONG_SIDE_PX
    # Every camera pixel is a factor × factor block of its own colour: nothing interpolated.
    np.testing.assert_array_equal(big[::factor, ::factor], image)
    np.testing.assert_array_equal(big[factor - 1 :: factor, factor - 1 :: factor], image)
    width, height = struct.unpack(">2I", png_chunks(srgb_png_bytes(big))["IHDR"][:8])
    assert (width, height) == (1120, 1060)


def test_a_large_image_is_kept_as_it_is() -> None:
    image = np.zeros((800, 1500, 3), dtype=np.uint8)
    assert enlarged(image) is image


def test_refuses_what_is_not_an_8_bit_rgb_image() -> None:
    with pytest.raises(ValueError, match="expected uint8"):
        srgb_png_bytes(np.zeros((4, 4), dtype=np.uint8))
    with pytest.raises(ValueError, match="missing signature"):
        png_chunks(b"GIF89a")
