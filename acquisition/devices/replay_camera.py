"""``ReplayCamera``: serves the frames of a recorded sequence, checked against the plan (``--rig replay:DIR``).

pymeasure's expected-protocol idea applied to images: the recording is what the camera *must* be
asked for. :meth:`ReplayCamera.prepare` compares each step of the plan with the next recorded
frames (role, LED levels, exposure, gain) and raises :class:`ReplayMismatchError` naming the first
differing step and field; :meth:`ReplayCamera.next_frame` then serves those frames in order, with
the exposure and gain recorded for them. Successive plans consume the recording in order (``run``:
the ambient + LED plan, then the one-frame flash plan).

Triggering follows :class:`~acquisition.devices.simulated_camera.SimulatedCamera`: ``trigger()`` releases
the next frame for software- and camera-paced plans (and drives :attr:`exposure_line` high then
low around it, so a booth in camera-master mode advances); booth-paced plans are released by
:meth:`trigger_line` (the booth emulator's trigger output).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from msflash.acquisition.devices.camera import CameraInfo, RawFrame
from msflash.acquisition.devices.frame_queue import TriggeredFrames
from msflash.acquisition.devices.image_format import IMAGE_FEATURES, ImageFormat, ImageFormatRequest, ImageLimits
from msflash.acquisition.errors import CameraError, CameraSettingError, ReplayMismatchError
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.reader import read_sequence

LEVEL_TOLERANCE = 2.0 / 0xFFFF
"""LED levels match when within two 16-bit wire steps."""
Levels = tuple[float, ...] | list[float] | np.ndarray
"""LED levels as plans, recorded frames and solvers hold them."""
EXPOSURE_RTOL = 0.01
"""Exposures (and gains) match within 1 % (cameras round exposure to their own steps)."""


class ReplayCamera(TriggeredFrames):
    """A camera that serves the frames of the sequence in ``directory``.

    Use :meth:`open`. Frames are served in recording order; each ``prepare(plan)`` checks the plan
    against the recorded frames not yet served.
    """

    def __init__(self, sequence: Sequence) -> None:
        if not sequence.frames:
            raise ReplayMismatchError(f"{sequence.directory}: the recording has no frames; expected at least one")
        self.sequence = sequence
        self.exposure_line: Callable[[bool], None] | None = None
        """The camera's ExposureActive output (camera-master sync); the rig wires it to the booth."""
        super().__init__()
        self._label = "replay camera"
        self._cursor = 0
        self._released = 0
        # Every frame is read (and its values checked against the recorded levels) before the
        # rig opens, so a corrupt recording is refused before anything is captured or written;
        # the frames are then served from memory.
        self._pixels = tuple(sequence.load_frame(index) for index in range(len(sequence.frames)))
        self._shape = self._pixels[0].shape

    @classmethod
    def open(cls, directory: str | Path) -> ReplayCamera:
        """Read the recorded sequence (``RecordingError`` naming the file and field if malformed)."""
        return cls(read_sequence(Path(directory)))

    # -- identity -------------------------------------------------------------------------
    @property
    def info(self) -> CameraInfo:
        """The recorded camera."""
        camera = self.sequence.camera
        return CameraInfo(
            vendor="replay",
            model=camera.model,
            serial=camera.serial or "",
            pixel_format=camera.pixel_format,
            cfa=camera.cfa,
            black_level=camera.black_level,
            white_level=camera.white_level,
            width=int(self._shape[1]),
            height=int(self._shape[0]),
            extra={"replay": str(self.sequence.directory)},
        )

    # -- the image format: the recording's, fixed ------------------------------------------
    @property
    def image_format(self) -> ImageFormat:
        """The recorded frames' size and pixel format (binning as recorded is not known: 1×1)."""
        return ImageFormat((0, 0, int(self._shape[1]), int(self._shape[0])), (1, 1), self.sequence.camera.pixel_format)

    def image_limits(self) -> ImageLimits:
        """Nothing can be set: every image feature is locked to the recording's."""
        why = "a replay serves the recorded frames as they are"
        return ImageLimits("replay camera", {}, self.image_format.roi[2:], {name: why for name in IMAGE_FEATURES})

    def set_image_format(self, request: ImageFormatRequest) -> ImageFormat:
        """Refused: a replay cannot change the recorded frames' ROI, binning or pixel format."""
        image = self.image_format
        raise CameraSettingError(
            f"replay camera: {self.sequence.directory}: its frames are {image.roi[2]} × {image.roi[3]} "
            f"{image.pixel_format} as recorded; a replay cannot change ROI, binning or pixel format — "
            "expected a live camera (--rig sim, aravis-fake or hw)"
        )

    @property
    def suggested_exposure_us(self) -> float:
        """The exposure of the first recorded frame (what ``run`` must ask for to match)."""
        return float(self.sequence.frames[0].exposure_us)

    # -- the Camera protocol --------------------------------------------------------------
    def prepare(self, plan: CapturePlan) -> None:
        """Check ``plan`` against the next recorded frames.

        Raises
        ------
        ReplayMismatchError
            Naming the first step (and field) that differs from the recording, or a step the
            recording has no frame for.
        """
        self._check_open()
        where = self.sequence.directory / "sequence.json"
        for offset, step in enumerate(plan.steps):
            mismatch = self._mismatch(self._cursor + offset, step)
            if mismatch is not None:
                if not self.sequence.complete:  # the likely reason: a capture that was cut short
                    mismatch += (
                        f" (the recording is incomplete: complete: false, {len(self.sequence.frames)} "
                        "frame(s), as a capture that was interrupted leaves it)"
                    )
                raise ReplayMismatchError(f"{where}: step {step.index} ({step.label}): {mismatch}")
        with self._condition:
            self._plan = plan
            self._released = 0
            self._queue.clear()

    def start(self) -> None:
        """Start serving the prepared plan's frames."""
        self._check_open()
        if self._plan is None:
            raise CameraError("replay camera: start() before prepare(plan); expected a plan")
        with self._condition:
            self._started = True

    def trigger(self) -> None:
        """Release the next frame (software/camera pacing); a no-op for booth-paced plans."""
        plan = self._require_started()
        if plan.trigger == "booth":
            return
        line = self.exposure_line
        if line is not None:
            line(True)
        try:
            self._release(plan)
        finally:
            if line is not None:
                line(False)

    def trigger_line(self) -> None:
        """The hardware trigger input (booth master): release the next frame."""
        self._release(self._require_started())

    # -- internals ------------------------------------------------------------------------
    def _mismatch(self, index: int, step: CaptureStep) -> str | None:
        """How ``step`` differs from recorded frame ``index`` (the first differing field), or None."""
        if index >= len(self.sequence.frames):
            return self._nothing_left(index, step.role)
        frame = self.sequence.frames[index]
        recorded = f"frames[{index}]"
        if frame.role != step.role:
            return f"role '{step.role}' but {recorded}.role is '{frame.role}'; expected the recorded role"
        if not levels_match(frame.led_levels, step.led_levels):
            return (
                f"led_levels {format_levels(step.led_levels)} but {recorded}.led_levels is "
                f"{format_levels(frame.led_levels)}; "
                f"expected them within {LEVEL_TOLERANCE:.1e}"
            )
        if not math.isclose(frame.exposure_us, step.exposure_us, rel_tol=EXPOSURE_RTOL):
            return (
                f"exposure_us {step.exposure_us:g} but {recorded}.exposure_us is {frame.exposure_us:g}; "
                f"expected it within {EXPOSURE_RTOL:.0%}"
            )
        if not math.isclose(frame.gain, step.gain, rel_tol=EXPOSURE_RTOL):
            return f"gain {step.gain:g} but {recorded}.gain is {frame.gain:g}; expected it within {EXPOSURE_RTOL:.0%}"
        return None

    def _nothing_left(self, index: int, role: str) -> str:
        """Why a step at recorded frame ``index`` cannot be served (the recording is used up)."""
        roles = [frame.role for frame in self.sequence.frames]
        held = ", ".join(f"{roles.count(r)} {r}" for r in dict.fromkeys(roles))
        text = (
            f"the recording has no frame {index}: its {len(roles)} frames ({held}) are all served; "
            "expected the plan to ask only for the frames that were recorded"
        )
        if role == "flash" and "flash" not in roles:
            text += (
                " — this recording has no flash frame, so 'run' cannot replay its flash (record with "
                "'msflash run'; for a sequence from 'msflash capture' use 'msflash estimate', 'flash' or "
                "'synthesize' on it)"
            )
        return text

    def _timeout_message(self, timeout_s: float, why: str) -> str:
        return (
            f"replay camera: no frame within {timeout_s:g} s for recorded frame {self._cursor}: {why}; "
            "expected trigger() (or the booth's trigger line) before next_frame()"
        )

    def _release(self, plan: CapturePlan) -> None:
        with self._condition:
            if self._released >= len(plan.steps):
                raise CameraError(
                    f"replay camera: trigger {self._released + 1} but the plan has {len(plan.steps)} "
                    "steps; expected one trigger per step"
                )
            index = self._cursor
            self._cursor += 1
            self._released += 1
            self._begin_frame()
        try:
            recorded = self.sequence.frames[index]
            pixels = self._pixels[index]
            timestamp = recorded.extra.get("timestamp_ns", 0)
            frame = RawFrame(
                np.asarray(pixels),
                index + 1,
                int(timestamp) if isinstance(timestamp, int) else 0,
                recorded.exposure_us,
                recorded.gain,
            )
        except BaseException as err:
            self._fail_frame(err)  # next_frame raises it in this frame's place (booth's trigger line)
            raise
        self._end_frame(frame)


def levels_match(recorded: Levels, asked: Levels) -> bool:
    """Whether LED levels asked for are the recorded ones (same count, each within :data:`LEVEL_TOLERANCE`)."""
    return len(recorded) == len(asked) and all(
        math.isclose(a, b, abs_tol=LEVEL_TOLERANCE) for a, b in zip(recorded, asked, strict=True)
    )


def format_levels(levels: Levels) -> str:
    """LED levels as replay's messages show them, e.g. ``[0, 0.6467, 0.3736]``."""
    return "[" + ", ".join(f"{float(v):.4g}" for v in levels) + "]"
