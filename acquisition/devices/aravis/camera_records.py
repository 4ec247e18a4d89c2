"""What a camera is told and what it reports: trigger and strobe configuration, settings, statistics, frame timing."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal

log = logging.getLogger(__name__)

TriggerMode = Literal["software", "line", "free"]
"""How frames are started: a software trigger, a hardware line, or the camera's own clock."""


@dataclass(frozen=True)
class TriggerConfig:
    """How frames are started."""

    mode: TriggerMode = "software"
    """``software`` (TriggerSoftware), ``line`` (a hardware input) or ``free`` (the camera's clock)."""
    line: str = "Line0"
    """Input line for ``line`` mode (a TriggerSource entry)."""
    activation: str = "RisingEdge"
    """TriggerActivation entry for ``line`` mode."""
    delay_us: float = 0.0
    """TriggerDelay in microseconds (``line`` mode); needs the feature when non-zero."""
    frame_rate_hz: float | None = None
    """AcquisitionFrameRate for ``free`` mode, when given."""


@dataclass(frozen=True)
class StrobeConfig:
    """An output line that follows the exposure (camera-master synchronisation)."""

    line: str = "Line1"
    """LineSelector entry of the output."""
    source: str = "ExposureActive"
    """LineSource entry driving it: ``ExposureActive``, or a user output such as ``UserOutput1``."""
    inverted: bool = False
    """LineInverter, when the booth expects an active-low signal."""


@dataclass(frozen=True)
class CameraSettings:
    """Settings as read back from the camera after writing them."""

    exposure_us: float
    """Exposure time actually set, microseconds."""
    gain: float
    """Linear gain actually set (1.0 = 0 dB)."""
    gain_db: float
    """The same gain in dB."""
    roi: tuple[int, int, int, int]
    """(offset_x, offset_y, width, height) in pixels."""
    pixel_format: str
    """GenICam pixel format."""
    trigger: TriggerConfig
    """Trigger configuration in effect."""
    strobe: StrobeConfig | None
    """Strobe output in effect, if any."""
    exposure_feature: str
    """Feature used for exposure."""
    gain_feature: str | None
    """Feature used for gain (None when the camera has none and gain stays 1)."""


@dataclass(frozen=True)
class AcquisitionStats:
    """What happened to the frames of one acquisition."""

    frames_good: int = 0
    """Complete frames delivered."""
    frames_incomplete: int = 0
    """Buffers that arrived with a status other than success (never delivered as data)."""
    frames_missing: int = 0
    """Frame ids skipped by the counter (frames that never reached the host)."""
    statuses: dict[str, int] = field(default_factory=dict)
    """Count of each non-success buffer status (``missing-packets``, ``timeout``, …)."""
    n_buffers: int = 0
    """Size of the buffer pool."""
    buffers_unfilled: int = 0
    """Buffers Aravis returned never filled (status ``cleared``): no frame, pushed back unseen."""


@dataclass(frozen=True)
class FrameTiming:
    """When one frame passed each stage on its way to :meth:`AravisCamera.next_frame`.

    ``received_ns``, ``popped_ns`` and ``delivered_ns`` are host ``CLOCK_REALTIME`` nanoseconds
    (what ``time.time_ns`` and Aravis's ``g_get_real_time`` read); ``device_ns`` is the camera's
    clock, which for the in-process GigE Vision fake is that same host clock.
    """

    device_ns: int
    """The buffer's timestamp: frame start on the camera's clock (the fake stamps it as it fills the image)."""
    received_ns: int
    """Aravis's system timestamp: when its stream thread received the frame's leader packet."""
    popped_ns: int
    """When the buffer thread got the completed buffer from the stream."""
    delivered_ns: int
    """When :meth:`AravisCamera.next_frame` returned the frame."""
