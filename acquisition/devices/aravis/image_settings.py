"""An Aravis camera's image: pixel format, region of interest, exposure, profile and noise model."""

from __future__ import annotations

import logging
import math

from msflash.acquisition.devices.aravis.feature_access import FeatureAccess
from msflash.acquisition.devices.aravis.gi_typelib import Aravis, GLib
from msflash.acquisition.devices.aravis.pixel_layouts import PIXEL_FORMATS, pixel_layout
from msflash.acquisition.devices.aravis.profiles import CameraProfile
from msflash.acquisition.devices.image_format import (
    BINNING_FEATURES,
    IMAGE_FEATURES,
    ImageFormat,
    ImageFormatRequest,
    ImageLimits,
    checked_request,
)
from msflash.acquisition.errors import (
    CameraError,
    CameraSettingError,
)

log = logging.getLogger(__name__)


class ImageSettings(FeatureAccess):
    """Pixel format, ROI and exposure, written and read back; the per-model profile."""

    # -- image format, exposure, gain ----------------------------------------------------------

    def set_pixel_format(self, pixel_format: str) -> str:
        """Set PixelFormat; refuses formats the camera lacks or msflash cannot decode (``CameraSettingError``)."""
        pixel_layout(pixel_format, self._name)
        offered = self.enum_entries("PixelFormat")
        if pixel_format not in offered:
            raise CameraSettingError(
                f"{self._name}: PixelFormat {pixel_format!r} is not offered by this camera; "
                f"expected one of {', '.join(offered)}"
            )
        self._set_enum("PixelFormat", pixel_format)
        return str(self.get_feature("PixelFormat"))

    def set_roi(self, offset_x: int, offset_y: int, width: int, height: int) -> tuple[int, int, int, int]:
        """Set the region of interest; returns it as read back (x, y, width, height)."""
        has_offsets = self._has("OffsetX") and self._has("OffsetY")
        if has_offsets:  # shrink offsets first so the new size fits
            self._set_int("OffsetX", 0)
            self._set_int("OffsetY", 0)
        elif (offset_x, offset_y) != (0, 0):
            raise CameraError(f"{self._name}: has no feature OffsetX/OffsetY; expected offsets (0, 0)")
        self._set_int("Width", int(width))
        self._set_int("Height", int(height))
        if has_offsets:
            self._set_int("OffsetX", int(offset_x))
            self._set_int("OffsetY", int(offset_y))
        return self.roi

    # -- the image format from the live page, between acquisitions ---------------------------

    def image_limits(self) -> ImageLimits:
        """What the camera's image features allow now, as it describes them (``WidthMax``/``HeightMax``, else
        ``SensorWidth``/``SensorHeight``, else ``Width``'s and ``Height``'s maxima, bound the ROI)."""
        features = {name: self.describe_feature(name) for name in IMAGE_FEATURES if self._has(name)}
        sensor = []
        for axis, size in (("Width", "WidthMax"), ("Height", "HeightMax")):
            bound = next((name for name in (size, f"Sensor{axis}") if self._has(name)), None)
            high = features[axis].maximum if axis in features else None
            sensor.append(int(self._number(bound)) if bound is not None else int(high or 0))
        return ImageLimits(self._name, features, (sensor[0], sensor[1]))

    @property
    def image_format(self) -> ImageFormat:
        """ROI, binning (1×1 for a camera without it) and pixel format, read back."""
        binning = tuple(int(self._number(name)) if self._has(name) else 1 for name in BINNING_FEATURES)
        return ImageFormat(self.roi, (binning[0], binning[1]), str(self.get_feature("PixelFormat")))

    def set_image_format(self, request: ImageFormatRequest) -> ImageFormat:
        """Stop streaming, then write binning, pixel format and ROI, each checked first against what the camera
        reports it allows; the format as read back. The next ``prepare`` re-allocates the buffers for the new
        payload (a kept stream whose payload or layout differs is released, ``Streaming._build_stream``).

        Raises
        ------
        CameraSettingError
            A value the camera lacks, has locked or refuses; the message names the feature and what it allows.
        """
        self.stop()  # type: ignore[attr-defined]  # Streaming's, below in the camera's stack
        checked_request(self.image_limits(), request, tuple(PIXEL_FORMATS))
        try:
            if request.binning is not None:
                for name, factor in zip(BINNING_FEATURES, request.binning):
                    if self._has(name):
                        self.set_feature(name, int(factor))
            if request.pixel_format is not None:
                self.set_pixel_format(request.pixel_format)
            if request.roi is not None:
                self.image_limits().check_roi(request.roi)
                self.set_roi(*request.roi)
        except CameraSettingError:
            raise
        except CameraError as err:
            raise CameraSettingError(
                f"{self._name}: the camera refused the image format ({str(err).removeprefix(self._name + ': ')}); "
                "expected a setting it allows — `msflash devices --features` lists them"
            ) from err
        return self.image_format

    @property
    def roi(self) -> tuple[int, int, int, int]:
        """(offset_x, offset_y, width, height) as the camera reports them."""
        x = int(self._number("OffsetX")) if self._has("OffsetX") else 0
        y = int(self._number("OffsetY")) if self._has("OffsetY") else 0
        return x, y, int(self._number("Width")), int(self._number("Height"))

    def set_exposure_us(self, exposure_us: float) -> float:
        """Set the exposure time; returns the value read back (microseconds)."""
        feature = self._exposure_feature
        integer = isinstance(self._live().get_feature(feature), Aravis.GcInteger)
        if integer or self._profile.integer_exposure:
            exposure_us = float(round(exposure_us))
        if integer:
            self._set_int(feature, int(exposure_us))
        else:
            self._set_float(feature, float(exposure_us))
        return self.exposure_us

    @property
    def exposure_us(self) -> float:
        """Exposure time read back from the camera, microseconds."""
        return self._number(self._exposure_feature)

    @property
    def exposure_range_us(self) -> tuple[float, float] | None:
        """(min, max) of the exposure feature in microseconds, or None when the camera does not say."""
        try:
            node = self._live().get_feature(self._exposure_feature)
            low, high = float(node.get_min()), float(node.get_max())
        except (GLib.Error, AttributeError, TypeError):
            return None
        return (low, high) if 0 <= low < high and math.isfinite(high) else None

    @property
    def profile(self) -> CameraProfile:
        """The per-model profile in use."""
        return self._profile

    @property
    def noise_model(self) -> tuple[float, float] | None:
        """(electrons per DN at 0 dB, read noise in electrons) from the profile, or None when unknown."""
        if self._profile.electrons_per_dn is None or self._profile.read_noise_e is None:
            return None
        return float(self._profile.electrons_per_dn), float(self._profile.read_noise_e)
