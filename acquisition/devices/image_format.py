"""A camera's image format — region of interest, binning, pixel format — and the one check of a request
against what the camera says it allows now.

The limits are GenICam's own features as the camera describes them (:class:`FeatureInfo`: ``Width``,
``Height``, ``OffsetX``, ``OffsetY``, ``BinningHorizontal``, ``BinningVertical``, ``PixelFormat``), read
from the device at run time (``AravisCamera``) or stated by a twin (``SimulatedCamera``), never from a
table of models. A request is checked in the order a camera applies it — binning, then the pixel format,
then the ROI (binning changes the sensor size the ROI is checked against) — and a value the camera would
refuse raises :class:`~acquisition.errors.CameraSettingError` whose one line names the camera, the
setting and what it allows: a feature the camera lacks, one it has locked (read-only now), a width off
its increment, an offset past the sensor, a pixel format it does not offer.

Cameras change the format only between acquisitions: ``set_image_format`` stops streaming, writes, reads
back, and the next ``prepare`` allocates buffers for the new payload.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from msflash.acquisition.devices.aravis.camera_features import FeatureInfo
from msflash.acquisition.errors import CameraSettingError

BINNING_FEATURES = ("BinningHorizontal", "BinningVertical")
ROI_FEATURES = ("OffsetX", "OffsetY", "Width", "Height")
IMAGE_FEATURES = (*BINNING_FEATURES, "PixelFormat", *ROI_FEATURES)
"""The features behind an image format, in the order a request is applied."""

Roi = tuple[int, int, int, int]


@dataclass(frozen=True)
class ImageFormat:
    """The image format in force, as the camera reads it back."""

    roi: Roi
    """(offset_x, offset_y, width, height) in pixels, after binning."""
    binning: tuple[int, int]
    """(horizontal, vertical) binning factors; (1, 1) for a camera that does not bin."""
    pixel_format: str
    """GenICam pixel format name."""

    def to_json(self) -> dict[str, Any]:
        """JSON form (the live page's ``camera.format``)."""
        return {"roi": list(self.roi), "binning": list(self.binning), "pixel_format": self.pixel_format}


@dataclass(frozen=True)
class ImageFormatRequest:
    """What to change; None keeps the camera's."""

    roi: Roi | None = None
    binning: tuple[int, int] | None = None
    pixel_format: str | None = None

    @property
    def empty(self) -> bool:
        """Whether nothing is asked for."""
        return self == ImageFormatRequest()


@dataclass(frozen=True)
class ImageLimits:
    """What a camera's image features allow now; a feature the camera lacks is absent from ``features``."""

    camera: str
    """How messages name the camera."""
    features: Mapping[str, FeatureInfo]
    """The image features the camera has, as it describes them now."""
    sensor: tuple[int, int]
    """(width, height) the ROI must fit in, after binning (``WidthMax``/``HeightMax``, or ``Width``'s maximum)."""
    locked: Mapping[str, str] = field(default_factory=dict)
    """Features the camera has but will not take now, with why (a twin's rule a real camera also has)."""

    def to_json(self) -> dict[str, Any]:
        """JSON form for the page: each feature's value, what it allows, and whether it can be set (and why not)."""
        out: dict[str, Any] = {}
        for name in IMAGE_FEATURES:
            info = self.features.get(name)
            why = self._why_locked(name)
            if info is None:
                out[name] = {"available": False, "why": why}
                continue
            entry: dict[str, Any] = {"available": why is None, "value": info.value, "allowed": info.allowed()}
            if why is not None:
                entry["why"] = why
            if info.kind == "enumeration":
                entry["entries"] = list(info.entries)
            else:
                entry.update(minimum=info.minimum, maximum=info.maximum, increment=info.increment or 1)
            out[name] = entry
        out["sensor"] = list(self.sensor)
        return out

    def _why_locked(self, feature: str) -> str | None:
        info = self.features.get(feature)
        if feature in self.locked:
            return self.locked[feature]
        if info is None:
            return f"the camera has no {feature}"
        if not info.writable:
            return f"{feature} is locked (access {info.access})"
        return None

    def _require(self, feature: str, setting: str) -> FeatureInfo:
        why = self._why_locked(feature)
        if why is not None:
            raise CameraSettingError(f"{self.camera}: {setting}: {why}; expected a setting this camera allows")
        return self.features[feature]

    def _check_integer(self, feature: str, setting: str, value: int, maximum: float | None = None) -> None:
        info = self._require(feature, setting)
        low = info.minimum if info.minimum is not None else 0
        high = info.maximum if maximum is None else maximum
        step = int(info.increment or 1)
        if value < low or (high is not None and value > high) or (step > 1 and (value - int(low)) % step):
            bounds = f" in {low:g} … {high:g}" if high is not None else f" ≥ {low:g}"
            steps = f" in steps of {step}" if step > 1 else ""
            raise CameraSettingError(
                f"{self.camera}: {setting}: {feature} {value} refused; expected a whole number{bounds}{steps}"
            )

    def check_binning(self, binning: tuple[int, int]) -> None:
        """Refuse binning factors the camera lacks, has locked, or does not offer."""
        text = "x".join(str(v) for v in binning)
        for feature, factor in zip(BINNING_FEATURES, binning):
            if factor == 1 and feature not in self.features and feature not in self.locked:
                continue  # a camera without binning is at 1×1
            self._check_integer(feature, f"binning {text}", int(factor))

    def check_pixel_format(self, pixel_format: str, decodable: tuple[str, ...]) -> None:
        """Refuse a pixel format the camera does not offer now, or one msflash cannot decode (``decodable``)."""
        info = self._require("PixelFormat", f"pixel format {pixel_format}")
        if pixel_format not in info.entries:
            raise CameraSettingError(
                f"{self.camera}: pixel format {pixel_format}: not offered by this camera; expected one of "
                f"{', '.join(info.entries)}"
            )
        if pixel_format not in decodable:
            usable = [entry for entry in info.entries if entry in decodable]
            raise CameraSettingError(
                f"{self.camera}: pixel format {pixel_format}: msflash cannot decode it; expected one of "
                f"{', '.join(usable)}"
            )

    def check_roi(self, roi: Roi) -> None:
        """Refuse an ROI off the features' increments or ranges, or one that does not fit in :attr:`sensor`."""
        x, y, width, height = roi
        text = f"ROI {x},{y},{width},{height}"
        sensor_w, sensor_h = self.sensor
        for feature, value, size in (("Width", width, sensor_w), ("Height", height, sensor_h)):
            info = self._require(feature, text)
            self._check_integer(feature, text, int(value), maximum=min(size, info.maximum or size))
        for feature, value, room in (("OffsetX", x, sensor_w - width), ("OffsetY", y, sensor_h - height)):
            if value == 0 and feature not in self.features:
                continue  # a camera without offsets reads out from the corner
            self._check_integer(feature, text, int(value), maximum=room)


def checked_request(limits: ImageLimits, request: ImageFormatRequest, decodable: tuple[str, ...]) -> ImageFormatRequest:
    """``request`` after every check that needs no write (binning and pixel format); the ROI is checked by the
    caller once binning is in force (it changes :attr:`ImageLimits.sensor`)."""
    if request.binning is not None:
        limits.check_binning(request.binning)
    if request.pixel_format is not None:
        limits.check_pixel_format(request.pixel_format, decodable)
    return request


@runtime_checkable
class ImageFormatControl(Protocol):
    """A camera whose image format can be changed between acquisitions (every camera of the rigs offers it; the
    replay camera refuses every change)."""

    @property
    def image_format(self) -> ImageFormat:
        """The format in force, read back."""
        ...

    def image_limits(self) -> ImageLimits:
        """What the camera allows now."""
        ...

    def set_image_format(self, request: ImageFormatRequest) -> ImageFormat:
        """Stop streaming, take ``request`` (``CameraSettingError`` if refused), return the format read back."""
        ...
