"""The camera contract: a small Protocol with Aravis, simulated and replay implementations."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from msflash.acquisition.plan import CapturePlan


@dataclass(frozen=True)
class CameraInfo:
    """What a camera is and how its pixel values are to be read."""

    vendor: str
    """Manufacturer name as the device reports it."""
    model: str
    """Model name."""
    serial: str
    """Serial number (or device id for fakes)."""
    pixel_format: str
    """GenICam pixel format name: Mono8, Mono16, BayerRG16, RGB8, RGB16…"""
    cfa: str | None
    """Colour filter array layout of a raw mosaic (RGGB, BGGR, GRBG, GBRG) or None."""
    black_level: float
    """Pixel value of no light."""
    white_level: float
    """Pixel value at or above which a pixel is saturated."""
    width: int
    """Image width in pixels."""
    height: int
    """Image height in pixels."""
    extra: dict = field(default_factory=dict, compare=False)
    """Anything else worth recording (firmware, interface, link speed…)."""


@dataclass(frozen=True)
class NativeGain:
    """A camera's gain feature as it read back, in the camera's own unit (recorded per frame)."""

    feature: str
    """The feature (``Gain``, ``GainRaw``…)."""
    value: float
    """Its value as read back."""
    unit: str
    """``dB``, ``x`` (a linear factor) or ``raw`` (the camera's own units)."""
    selector: str | None = None
    """The ``GainSelector`` entry it was read under, if any."""

    def to_dict(self) -> dict:
        """JSON form: the sequence's ``frames[].camera_gain`` (docs/architecture.md §6)."""
        value: float | int = int(self.value) if float(self.value).is_integer() else float(self.value)
        out: dict = {"feature": self.feature, "value": value, "unit": self.unit}
        if self.selector is not None:
            out["selector"] = self.selector
        return out


@dataclass(frozen=True)
class RawFrame:
    """One frame as the camera delivered it, before it is paired with a plan step."""

    pixels: np.ndarray
    """Owned pixel values, (H, W) for mono/mosaic or (H, W, 3) for RGB; read-only."""
    frame_id: int
    """The camera's frame counter (may wrap, e.g. at 16 bits on GigE Vision)."""
    timestamp_ns: int
    """Device or host timestamp in nanoseconds."""
    exposure_us: float
    """Exposure actually used, as read back from the camera."""
    gain: float
    """Linear gain actually used, as read back from the camera."""
    camera_gain: NativeGain | None = None
    """The gain feature's value behind ``gain``, in the camera's unit (cameras that have one)."""

    def __post_init__(self) -> None:
        pixels = np.asarray(self.pixels)
        if pixels.flags.writeable:
            pixels = pixels.copy() if not pixels.flags.owndata else pixels
            pixels.flags.writeable = False
        object.__setattr__(self, "pixels", pixels)


@runtime_checkable
class Camera(Protocol):
    """What the capture runner needs from a camera.

    Implementations: ``AravisCamera`` (real devices and the Aravis fakes), ``SimulatedCamera``
    (renders a spectral scene), ``ReplayCamera`` (serves a recorded sequence).
    """

    @property
    def info(self) -> CameraInfo:
        """The camera's identity and pixel encoding."""
        ...

    def prepare(self, plan: CapturePlan) -> None:
        """Configure trigger mode and source, exposure, gain and the buffer pool for ``plan``."""
        ...

    def start(self) -> None:
        """Start acquisition; frames then follow triggers (or the camera's clock)."""
        ...

    def trigger(self) -> None:
        """Issue a software trigger (a no-op for cameras paced by a hardware line)."""
        ...

    def next_frame(self, timeout_s: float) -> RawFrame:
        """The next frame; raises ``FrameTimeoutError`` after ``timeout_s``."""
        ...

    def update_plan(self, plan: CapturePlan, index: int) -> None:
        """Take ``plan``, whose step ``index`` (not yet triggered) changed, while streaming (the flash step)."""
        ...

    @property
    def readout_skew_us(self) -> float:
        """First row's exposure start to the last row's (a rolling shutter), µs; 0 for a global shutter."""
        ...

    def stop(self) -> None:
        """Stop acquisition; idempotent."""
        ...

    def close(self) -> None:
        """Release the device; idempotent."""
        ...
