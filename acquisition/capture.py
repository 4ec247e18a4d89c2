"""Run a capture plan: pair every frame with its step and write it to disk at once.

Host-paced synchronisation (DESIGN §4): for each step the booth is set to the step's levels, then
the camera is triggered and the frame awaited. Whatever happens, the LEDs go off and the camera
stops in ``finally``; frames already written stay on disk (the writer keeps the sequence readable
with ``complete: false`` until it is finished).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Protocol

from acquisition.camera import Camera, RawFrame
from acquisition.errors import DroppedFrameError, FrameTimeoutError
from acquisition.plan import CapturePlan, CaptureStep
from acquisition.sequence_format import SequenceFrame, SequenceWriter

log = logging.getLogger(__name__)

FRAME_ID_MODULUS = 1 << 16
"""GigE Vision block ids wrap at 16 bits; continuity is checked modulo this."""


class LedControl(Protocol):
    """What the capture runner needs of the booth (``led_controller.LedBooth`` provides it)."""

    def set_levels(self, levels: Sequence[float]) -> None:
        """Drive every channel to ``levels`` (0–1)."""
        ...

    def all_off(self) -> None:
        """Switch every channel off."""
        ...


def run_capture(
    camera: Camera,
    booth: LedControl,
    plan: CapturePlan,
    writer: SequenceWriter,
    on_frame: Callable[[CaptureStep, RawFrame, SequenceFrame], None] | None = None,
) -> list[SequenceFrame]:
    """Capture every step of ``plan`` host-paced, writing each frame as it arrives.

    Raises
    ------
    FrameTimeoutError
        No frame within ``plan.frame_timeout_s``; names the step.
    DroppedFrameError
        The camera's frame ids skipped (a frame was lost); names the step.
    """
    written: list[SequenceFrame] = []
    previous_id: int | None = None
    try:
        camera.prepare(plan)
        camera.start()
        for step in plan.steps:
            booth.set_levels(step.led_levels)
            camera.trigger()
            try:
                frame = camera.next_frame(plan.frame_timeout_s)
            except FrameTimeoutError as err:
                raise FrameTimeoutError(
                    f"step {step.index} ({step.label}): {err}; {len(written)} frame(s) already saved in {writer.path.parent}"
                ) from err
            if previous_id is not None and (frame.frame_id - previous_id) % FRAME_ID_MODULUS != 1:
                raise DroppedFrameError(
                    f"step {step.index} ({step.label}): camera frame id {frame.frame_id} follows {previous_id}; "
                    f"a frame was lost. {len(written)} frame(s) already saved in {writer.path.parent}"
                )
            previous_id = frame.frame_id
            entry = writer.add_frame(
                frame.pixels, step.role, step.led_levels, frame.exposure_us, frame.gain,
                extra={"frame_id": frame.frame_id, "timestamp_ns": frame.timestamp_ns},
            )
            written.append(entry)
            log.info("step %d (%s): frame %d saved as %s", step.index, step.label, frame.frame_id, entry.file)
            if on_frame is not None:
                on_frame(step, frame, entry)
    finally:
        try:
            booth.all_off()
        finally:
            camera.stop()
    return written
