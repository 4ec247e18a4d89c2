"""Packed pixel formats through the real Aravis path, on the fake cameras.

msflash's SFNC XML (``genicam/fake_sfnc.xml``) offers Mono12p, Mono12Packed, BayerRG12p and
Mono10p with their PFNC codes. The Aravis fakes select them and size the payload from the code's
bits-per-pixel, but their pattern generator (``arv_fake_camera_diagonal_ramp``, Aravis 0.8.26)
fills only Mono8/Mono16/Bayer8/RGB8 — and its ``set_fill_pattern`` callback is ``scope call``, so
Python cannot install one that outlives the call. What these tests can check is therefore the
route (format chosen and read back, payload size, frame shape, dtype, white level, the refusal
of a short payload), not pixel values: the values are checked bit-exactly in
``test_pixel_formats.py`` against an independent packer.
"""

from __future__ import annotations

from types import ModuleType

import numpy as np
import pytest

from msflash.acquisition.devices.aravis.discovery import FAKE_SFNC_XML
from msflash.acquisition.devices.aravis.gv_fake import AravisGvFake
from msflash.acquisition.errors import CameraError
from msflash.acquisition.plan import CapturePlan
from tests.acquisition.support.fake_genicam import use_fake_genicam

pytestmark = pytest.mark.aravis


def _one_frame(camera) -> np.ndarray:
    camera.prepare(CapturePlan.single([0.0], 1000.0, role="ambient", trigger="software"))
    camera.start()
    try:
        camera.trigger()
        return camera.next_frame(10.0).pixels
    finally:
        camera.stop()


@pytest.mark.parametrize(
    ("pixel_format", "bits", "cfa"),
    [("Mono12p", 12, None), ("Mono12Packed", 12, None), ("BayerRG12p", 12, "RGGB"), ("Mono10p", 10, None)],
)
def test_gige_fake_streams_packed_frames_of_the_right_size(
    aravis: ModuleType, pixel_format: str, bits: int, cfa: str | None
) -> None:
    with (
        AravisGvFake(serial="MSFPACK1") as fake,
        aravis.AravisCamera(fake.address, interfaces="gige", pixel_format=pixel_format, roi=(0, 0, 128, 96)) as camera,
    ):
        assert camera.get_feature("PixelFormat") == pixel_format
        assert camera.get_feature("PayloadSize") == 128 * 96 * bits // 8
        info = camera.info
        assert (info.cfa, info.white_level) == (cfa, float(2**bits - 1))
        pixels = _one_frame(camera)
        assert pixels.shape == (96, 128) and pixels.dtype == np.uint16
        assert int(pixels.max()) <= 2**bits - 1
        assert camera.stats.frames_good == 1


def test_in_process_fake_sends_no_packed_pixels_and_the_frame_is_refused(aravis: ModuleType) -> None:
    """The in-process Fake leaves a packed frame empty (0 bytes received): a clear error, not garbage."""
    use_fake_genicam(FAKE_SFNC_XML)
    try:
        camera = aravis.AravisCamera("Fake_1", interfaces="fake", pixel_format="Mono12p", roi=(0, 0, 128, 96))
    finally:
        use_fake_genicam(None)
    with (
        camera,
        pytest.raises(
            CameraError,
            match=r"payload of 0 bytes is too short for 128x96 Mono12p; "
            r"expected 18432 bytes",
        ),
    ):
        _one_frame(camera)
