"""An Aravis camera's image: pixel format, region of interest, exposure, profile and noise model."""

from __future__ import annotations

import logging
import math

from msflash.acquisition.devices.aravis.feature_access import FeatureAccess
from msflash.acquisition.devices.aravis.gi_typelib import Aravis, GLib
from msflash.acquisition.devices.aravis.pixel_layouts import (
    PIXEL_FORMATS,
)
from msflash.acquisition.devices.aravis.profiles import (
    CameraProfile,
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
        if pixel_format not in PIXEL_FORMATS:
            raise CameraSettingError(
                f"{self._name}: pixel format {pixel_format!r} cannot be decoded by msflash; "
                f"expected one of {', '.join(PIXEL_FORMATS)}"
            )
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

    @property
    def roi(self) -> tuple[int, int, int, int]:
        """(offset_x, offset_y, width, height) as the camera reports them."""
        x = int(self._number("OffsetX")) if self._has("OffsetX") else 0
        y = int(self._number("OffsetY")) if self._has("OffsetY") else 0
        return x, y, int(self._number("Width")), int(self._number("Height"))

    def set_exposure_us(self, exposure_us: float) -> float:
        """Set the exposure time; returns the value read back (microseconds)."""
        feature = self._exposure_feature
        if self._is_integer(feature) or self._profile.integer_exposure:
            exposure_us = float(round(exposure_us))
        if isinstance(self._live().get_feature(feature), Aravis.GcInteger):
            self._set_int(feature, int(exposure_us))
        else:
            self._set_float(feature, float(exposure_us))
        return self.exposure_us

    def _is_integer(self, feature: str) -> bool:
        return isinstance(self._live().get_feature(feature), Aravis.GcInteger)

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
