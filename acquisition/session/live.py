"""The live stream of ``msflash live``: a rig's camera streaming at the live exposure and gain, the booth at
the live LED levels (docs/architecture.md §5.4).

A :class:`LiveStream` owns no thread: its caller (the live server's one rig thread) calls it, so the camera
and the booth are driven from one place at a time. Frames are captured host paced as any capture is
(``prepare`` a plan, ``start``, ``trigger``, ``next_frame``), from a plan of :data:`STREAM_STEPS` identical
steps prepared again when the steps run out or the exposure or gain changes. The LED levels are the booth's
own: :meth:`LiveStream.set_levels` sends them and the page shows what the booth reports
(:meth:`LiveStream.booth_levels`, read at most every :data:`READ_BACK_S`, which also keeps a booth's
watchdog fed while the levels sit still).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.devices.image_format import ImageFormat, ImageFormatControl, ImageFormatRequest, ImageLimits
from msflash.acquisition.errors import CameraSettingError, FrameLostError, UsageError
from msflash.acquisition.plan import CapturePlan, CaptureStep, StepRole
from msflash.acquisition.session.exposure import camera_exposure_range
from msflash.acquisition.session.rig import Rig

STREAM_STEPS = 256
"""Steps in one streaming plan: the camera is prepared again after this many frames."""

READ_BACK_S = 0.2
"""How often, at most, the booth's levels are read back while streaming (seconds)."""


@dataclass(frozen=True)
class LiveSettings:
    """What the live image is taken with: the exposure, the analogue gain and each LED's drive level."""

    exposure_us: float
    gain: float
    levels: tuple[float, ...]


class LiveStream:
    """A rig's camera streaming host paced at the live settings, and the booth at the live LED levels.

    The stream never closes ``rig`` (the caller's ``with rig`` does, LEDs off). ``exposure_us`` None starts at
    the camera's suggestion (the simulated cameras') or 10 ms.
    """

    def __init__(self, rig: Rig, exposure_us: float | None = None) -> None:
        self.rig = rig
        self.exposure_range_us = camera_exposure_range(rig.camera)
        suggested = float(getattr(rig.camera, "suggested_exposure_us", None) or 10_000.0)
        first = suggested if exposure_us is None else float(exposure_us)
        self.settings = LiveSettings(self._checked_exposure(first), 1.0, (0.0,) * rig.led_spectra.count)
        self._plan: CapturePlan | None = None
        self._next_step = 0
        self._streaming = False
        self._booth_levels: tuple[float, ...] = self.settings.levels
        self._read_at = 0.0
        self.lost_frames = 0
        """Live frames that arrived incomplete and were taken again."""

    # -- settings ---------------------------------------------------------------------------
    def _checked_exposure(self, exposure_us: float) -> float:
        low, high = self.exposure_range_us
        if not (low <= exposure_us <= high):
            raise UsageError(f"exposure_us {exposure_us:g}: outside the camera's range {low:g}–{high:g} µs")
        return float(exposure_us)

    def set_exposure(self, exposure_us: float, gain: float) -> LiveSettings:
        """Take the next frames at ``exposure_us`` and linear ``gain`` (> 0); the settings now in force."""
        if not gain > 0 or gain > 64:
            raise UsageError(f"gain {gain:g}: expected a linear gain in (0, 64]")
        check = getattr(self.rig.camera, "check_step_gain", None)  # a GenICam camera's range, in its units
        if check is not None:
            try:
                check(float(gain))
            except CameraSettingError as err:
                raise UsageError(f"gain {gain:g}: {err}") from err
        exposure = self._checked_exposure(exposure_us)
        if (exposure, gain) != (self.settings.exposure_us, self.settings.gain):
            self.settings = LiveSettings(exposure, float(gain), self.settings.levels)
            self.pause()  # the next frame prepares a plan at the new exposure
        return self.settings

    def set_levels(self, levels: Sequence[float]) -> tuple[float, ...]:
        """Drive the booth's LEDs at ``levels`` (one per LED, 0–1); the levels the booth reports back."""
        count = self.rig.led_spectra.count
        values = tuple(float(v) for v in levels)
        if len(values) != count or not all(0.0 <= v <= 1.0 for v in values):
            raise UsageError(f"levels {list(values)}: expected {count} values in [0, 1], one per LED")
        self.rig.booth.set_levels(values)
        self.settings = LiveSettings(self.settings.exposure_us, self.settings.gain, values)
        return self.booth_levels(fresh=True)

    def all_off(self) -> None:
        """Switch every LED off (the live levels become 0)."""
        self.settings = LiveSettings(self.settings.exposure_us, self.settings.gain, (0.0,) * self.rig.led_spectra.count)
        self.rig.booth.all_off()
        self._booth_levels = self.settings.levels

    def booth_levels(self, fresh: bool = False) -> tuple[float, ...]:
        """The levels the booth reports it holds (read again when ``fresh`` or after :data:`READ_BACK_S`)."""
        now = time.monotonic()
        if fresh or now - self._read_at >= READ_BACK_S:
            self._booth_levels = tuple(float(v) for v in self.rig.booth.reported_levels())
            self._read_at = now
        return self._booth_levels

    @property
    def last_booth_levels(self) -> tuple[float, ...]:
        """The levels the booth reported when last asked (no I/O: any thread may read it)."""
        return self._booth_levels

    # -- the image format (ROI, binning, pixel format), between acquisitions ------------------
    def image_limits(self) -> ImageLimits | None:
        """What the camera allows now; None for a camera that cannot say."""
        camera = self.rig.camera
        return camera.image_limits() if isinstance(camera, ImageFormatControl) else None

    def set_image_format(self, request: ImageFormatRequest) -> ImageFormat:
        """Stop streaming and set ``request`` on the camera; the next frame prepares a plan (and buffers) for it, and
        what the rig records of the camera follows the change (:meth:`~acquisition.session.rigs.rig.Rig.image_format_changed`).

        Raises
        ------
        UsageError
            The camera refused (its one-line reason) or cannot change its format at all.
        """
        camera = self.rig.camera
        if not isinstance(camera, ImageFormatControl):
            raise UsageError(f"camera {camera.info.model}: msflash cannot change its image format")
        self.pause()
        before = camera.image_format
        try:
            return camera.set_image_format(request)
        except CameraSettingError as err:
            raise UsageError(str(err)) from err
        finally:
            if (
                camera.image_format != before
            ):  # later sequences record the camera as it is now (a refusal changed nothing)
                self.rig.image_format_changed()

    # -- frames -----------------------------------------------------------------------------
    def _prepare(self) -> CapturePlan:
        settings = self.settings
        role: StepRole = "led" if any(settings.levels) else "ambient"
        plan = CapturePlan(
            tuple(
                CaptureStep(i, role, settings.levels, settings.exposure_us, settings.gain) for i in range(STREAM_STEPS)
            )
        )
        self.rig.camera.prepare(plan)
        self.rig.camera.start()
        self._streaming = True
        self._plan = plan
        self._next_step = 0
        return plan

    def grab(self) -> RawFrame:
        """The next live frame (host paced: one software trigger), at the settings in force.

        A frame that arrives incomplete (:class:`FrameLostError`) is counted in :attr:`lost_frames` and
        taken again once on a restarted stream; a second loss is raised.
        """
        try:
            frame = self._trigger_and_wait()
        except FrameLostError:
            self.lost_frames += 1
            self.pause()
            frame = self._trigger_and_wait()
        self.booth_levels()
        return frame

    def _trigger_and_wait(self) -> RawFrame:
        plan = self._plan
        if not self._streaming or plan is None or self._next_step >= len(plan.steps):
            self.pause()
            plan = self._prepare()
        self._next_step += 1
        self.rig.camera.trigger()
        return self.rig.camera.next_frame(plan.frame_timeout_s)

    def pause(self) -> None:
        """Stop streaming (before a sequence takes the camera, or when nobody watches)."""
        if self._streaming:
            self._streaming = False
            self.rig.camera.stop()
