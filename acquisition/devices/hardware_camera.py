"""The hardware rig's camera: an Aravis camera behind the :class:`~acquisition.devices.camera.Camera` protocol."""

from __future__ import annotations

import logging
from typing import Any

from msflash.acquisition.devices.camera import CameraInfo, RawFrame
from msflash.acquisition.devices.image_format import ImageFormat, ImageFormatRequest, ImageLimits
from msflash.acquisition.plan import CapturePlan

log = logging.getLogger(__name__)


class HardwareCamera:
    """An :class:`~acquisition.devices.aravis.camera.AravisCamera` as the hardware rig's camera.

    Forwards the :class:`~acquisition.devices.camera.Camera` protocol; mono frames come as (H, W) and
    the writer records them as three identical channels (:attr:`Rig.mono`; format v1 holds RGB
    or raw mosaics, and the sequence's ``camera.extra`` says so). Offers what exposure planning
    asks of a camera: :attr:`exposure_range_us` and :attr:`noise_model` (from the camera's
    profile, when it knows the conversion gain).
    """

    suggested_exposure_us = 10_000.0

    def __init__(self, camera: Any, setup: Any = None) -> None:
        self.aravis = camera
        self.setup = setup
        """The :class:`~acquisition.devices.aravis.camera_features.CameraSetup` applied when the rig opened, or None."""

    @property
    def info(self) -> CameraInfo:
        """The camera's identity (a mono camera has ``cfa`` None and (H, W) frames)."""
        return self.aravis.info

    @property
    def exposure_range_us(self) -> tuple[float, float] | None:
        """The camera's exposure limits in microseconds, if it reports them."""
        return getattr(self.aravis, "exposure_range_us", None)

    @property
    def noise_model(self) -> Any:
        """Conversion gain and read noise from the camera profile, or None."""
        return getattr(self.aravis, "noise_model", None)

    @property
    def image_format(self) -> ImageFormat:
        """ROI, binning and pixel format in force (``AravisCamera.image_format``)."""
        return self.aravis.image_format

    def image_limits(self) -> ImageLimits:
        """What the camera's image features allow now (``AravisCamera.image_limits``)."""
        return self.aravis.image_limits()

    def set_image_format(self, request: ImageFormatRequest) -> ImageFormat:
        """Stop streaming and write ``request`` (``AravisCamera.set_image_format``; ``CameraSettingError`` if refused)."""
        return self.aravis.set_image_format(request)

    def check_step_gain(self, gain: float) -> None:
        """Refuse a plan step's linear ``gain`` the camera cannot take (``AravisCamera.check_step_gain``)."""
        self.aravis.check_step_gain(gain)

    def prepare(self, plan: CapturePlan) -> None:
        """Prepare the camera for ``plan`` (each step's gain multiplies ``--gain``'s, which the camera holds)."""
        self.aravis.prepare(plan)

    def update_plan(self, plan: CapturePlan, index: int) -> None:
        """Take ``plan`` with step ``index`` changed, before its trigger."""
        self.aravis.update_plan(plan, index)

    @property
    def readout_skew_us(self) -> float:
        """The camera's rolling-shutter skew, µs (0: a global shutter)."""
        return float(self.aravis.readout_skew_us)

    def start(self) -> None:
        """Start acquisition."""
        self.aravis.start()

    def trigger(self) -> None:
        """Software trigger (a no-op when a line paces the camera)."""
        self.aravis.trigger()

    def next_frame(self, timeout_s: float) -> RawFrame:
        """The next frame as the camera delivers it ((H, W) for mono and mosaics)."""
        return self.aravis.next_frame(timeout_s)

    def stop(self) -> None:
        """Stop acquisition."""
        self.aravis.stop()

    def close(self) -> None:
        """Release the camera."""
        self.aravis.close()
