"""ROI, binning and pixel format set between acquisitions on every camera of the rigs (issue 33): the simulated
camera refuses what a machine-vision camera refuses, the Aravis fakes are checked against their own features'
limits and stream at the new size, the replay camera refuses with a reason."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from msflash.acquisition.devices.image_format import ImageFormatControl, ImageFormatRequest
from msflash.acquisition.devices.simulated_camera import SimulatedCamera
from msflash.acquisition.errors import CameraSettingError
from msflash.acquisition.plan import CapturePlan, CaptureStep


def one_frame(camera: Any, n_leds: int = 7) -> np.ndarray:
    plan = CapturePlan((CaptureStep(0, "ambient", (0.0,) * n_leds, 10_000.0, 1.0),), trigger="software")
    camera.prepare(plan)
    camera.start()
    camera.trigger()
    try:
        return camera.next_frame(plan.frame_timeout_s).pixels
    finally:
        camera.stop()


def test_the_simulated_camera_reads_out_its_roi_binning_and_pixel_format() -> None:
    camera = SimulatedCamera.default(noise=False)
    assert isinstance(camera, ImageFormatControl)
    full = one_frame(camera)
    assert full.shape == (106, 112) and camera.info.pixel_format == "BayerRG12"

    image = camera.set_image_format(ImageFormatRequest(roi=(8, 4, 32, 20)))
    assert image.roi == (8, 4, 32, 20) and (camera.info.width, camera.info.height) == (32, 20)
    np.testing.assert_array_equal(one_frame(camera), full[4:24, 8:40])  # the same scene, cut (noise-free)

    camera.set_image_format(ImageFormatRequest(pixel_format="BayerRG8"))
    eight = one_frame(camera)
    assert eight.dtype == np.uint8 and camera.info.white_level == 255
    np.testing.assert_array_equal(eight, full[4:24, 8:40] >> 4)  # the top 8 of the ADC's 12 bits
    assert camera.info.black_level == pytest.approx(240 / 16)

    image = camera.set_image_format(ImageFormatRequest(binning=(2, 2), pixel_format="BayerRG12"))
    assert image.roi == (0, 0, 56, 52)  # binning resets the ROI to the binned sensor
    binned = one_frame(camera).astype(float)
    red = full[0::2, 0::2][:52, :56].astype(float)  # like colours binned: the CFA stays RGGB
    np.testing.assert_allclose(binned[0::2, 0::2], np.round(red.reshape(26, 2, 28, 2).mean(axis=(1, 3))))


@pytest.mark.parametrize(
    ("request_", "why"),
    [
        (
            ImageFormatRequest(roi=(0, 0, 100, 50)),
            "Width 100 refused; expected a whole number in 8 … 112 in steps of 8",
        ),
        (ImageFormatRequest(roi=(1, 0, 64, 50)), "OffsetX 1 refused; expected a whole number in 0 … 48 in steps of 2"),
        (ImageFormatRequest(roi=(64, 0, 64, 50)), "OffsetX 64 refused; expected a whole number in 0 … 48"),
        (ImageFormatRequest(binning=(3, 3)), "BinningHorizontal 3 refused; expected a whole number in 1 … 2"),
        (ImageFormatRequest(pixel_format="Mono8"), "not offered by this camera; expected one of BayerRG8, BayerRG12"),
    ],
)
def test_the_simulated_camera_refuses_what_a_camera_refuses(request_: ImageFormatRequest, why: str) -> None:
    camera = SimulatedCamera.default(noise=False)
    before = camera.image_format
    with pytest.raises(CameraSettingError, match=why):
        camera.set_image_format(request_)
    assert camera.image_format == before  # nothing changed


def test_the_replay_camera_refuses_every_change_naming_the_recording(tmp_path: Path) -> None:
    from msflash.acquisition.app.live.run_job import SequenceRequest, run_sequence
    from msflash.acquisition.devices.replay_camera import ReplayCamera
    from msflash.acquisition.session.rig import open_rig

    with open_rig("sim") as rig:
        run_sequence(rig, tmp_path / "run", SequenceRequest())
    camera = ReplayCamera.open(tmp_path / "run" / "sequence")
    assert camera.image_format.roi == (0, 0, 112, 106)
    assert not camera.image_limits().to_json()["Width"]["available"]
    with pytest.raises(CameraSettingError, match="a replay cannot change ROI, binning or pixel format"):
        camera.set_image_format(ImageFormatRequest(roi=(0, 0, 64, 64)))


@pytest.mark.aravis
def test_the_aravis_fake_is_checked_against_its_own_limits_and_streams_the_new_size(
    sfnc_fake_camera: Any, aravis: ModuleType
) -> None:
    camera = sfnc_fake_camera
    limits = camera.image_limits()
    assert set(limits.features) >= {"Width", "Height", "PixelFormat", "BinningHorizontal"}
    plan = CapturePlan((CaptureStep(0, "ambient", (), 1000.0, 1.0),), trigger="software")

    def frame() -> np.ndarray:
        camera.prepare(plan)
        camera.start()
        camera.trigger()
        try:
            return camera.next_frame(5.0).pixels
        finally:
            camera.stop()

    assert frame().shape == (96, 128)
    camera.set_image_format(ImageFormatRequest(roi=(16, 8, 64, 48), pixel_format="Mono16"))
    assert camera.image_format.roi == (16, 8, 64, 48) and camera.info.pixel_format == "Mono16"
    pixels = frame()  # the buffers re-allocated for the new payload
    assert pixels.shape == (48, 64) and pixels.dtype == np.uint16
    sensor_width = limits.sensor[0]
    with pytest.raises(CameraSettingError, match=rf"Width {sensor_width + 8} refused; expected a whole number in 1"):
        camera.set_image_format(ImageFormatRequest(roi=(0, 0, sensor_width + 8, 48)))
    with pytest.raises(CameraSettingError, match="BinningHorizontal 32 refused; expected a whole number in 1 … 16"):
        camera.set_image_format(ImageFormatRequest(binning=(32, 32)))
    with pytest.raises(CameraSettingError, match="PixelFormat|not offered by this camera"):
        camera.set_image_format(ImageFormatRequest(pixel_format="RGB16"))
    assert frame().shape == (48, 64)  # a refusal changed nothing
