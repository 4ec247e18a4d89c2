"""Run a capture plan: pair every frame with its step and write it to disk at once.

The entry points of the capture engine (:mod:`acquisition.session.engine`): each builds the engine of
the plan's sync mode (:func:`engine_for`; docs/architecture.md §4) and runs it with one
:class:`~acquisition.session.engine.CaptureRunner`.

Frames already written stay on disk whatever fails (the writer keeps the sequence readable with
``complete: false``); the LEDs go off and the camera stops on every exit path
(:mod:`~acquisition.session.booth_guard`, which also keeps the booth's watchdog covered).

The flash in the same run (:func:`run_capture_with_flash`): the plan gets a placeholder ``flash`` step and
the camera streams on from the ambient frame to the flash frame; host paced the flash is ``SET`` then
triggered, booth and camera master one ``PSET`` releases the held step. An
:class:`~acquisition.sequence.async_writer.AsyncSequenceWriter` is paused from the last LED frame until the
flash frame is in (frames stay queued, nothing is dropped), and Python's cyclic collector waits until the
sequence is over, so neither competes with the decision or the flash trigger.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from typing import cast

from msflash.acquisition.devices.camera import Camera, RawFrame
from msflash.acquisition.errors import UsageError
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.format import SequenceFrame
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.acquisition.session.engine import (
    RETAKES,
    Cancellation,
    CaptureEngine,
    CaptureRunner,
    FlashDecider,
    FrameHandler,
    StepFrame,
    collector_paused,
)
from msflash.acquisition.session.host_paced import HostPaced
from msflash.acquisition.session.table_paced import TablePaced
from msflash.led_controller.booth_interface import Booth, SequencedBooth, unsupported_sync

log = logging.getLogger(__name__)

FrameWriter = SequenceWriter | AsyncSequenceWriter
"""Where captured frames go: written as they come, or handed to a writer thread."""

SYNC_OF_TRIGGER = {"software": "host", "booth": "booth", "camera": "camera"}
"""The ``--sync`` mode (:mod:`led_controller.booth_interface`) each plan trigger needs of the booth."""


def check_booth_runs(booth: Booth, plan: CapturePlan) -> None:
    """Refuse a plan whose sync mode ``booth`` cannot run (its :attr:`~Booth.capabilities`).

    Raises
    ------
    UsageError
        One line naming the booth and the sync mode (``--sync booth`` on a host-paced-only booth).
    """
    why = unsupported_sync(booth, SYNC_OF_TRIGGER.get(plan.trigger, "host"))
    if why is not None:
        raise UsageError(why)


class SequenceRecorder:
    """The writer as the runner's :class:`~acquisition.session.engine.Recorder`: each frame written
    with what the capture knows of it (frame id, timestamp, trigger, delivered levels, retake, gain)."""

    def __init__(self, writer: FrameWriter) -> None:
        self.writer = writer
        self._count = 0

    def record(self, paired: StepFrame, retake: int) -> SequenceFrame:
        """Write ``paired``'s frame (role, levels asked for, exposure and gain read back); its entry."""
        step, frame = paired.step, paired.frame
        extra: dict = {"frame_id": frame.frame_id, "timestamp_ns": frame.timestamp_ns}
        if paired.trigger is not None:
            extra["trigger"] = paired.trigger
        if paired.delivered_levels is not None:
            # Pulse dimming: each LED's on-time ÷ this frame's exposure, as the booth quantised it
            # (docs/flash-energy.md); ``leds`` stays the level asked for.
            extra["delivered_levels"] = [round(float(v), 7) for v in paired.delivered_levels]
        if retake:
            extra["retake"] = retake
        if frame.camera_gain is not None:  # the gain feature behind frame.gain, in the camera's unit
            extra["camera_gain"] = frame.camera_gain.to_dict()
        entry = self.writer.add_frame(
            frame.pixels, step.role, step.led_levels, frame.exposure_us, frame.gain, extra=extra
        )
        self._count += 1
        log.info("step %d (%s): frame %d saved as %s", step.index, step.label, frame.frame_id, entry.file)
        return entry

    def hold(self) -> None:
        """Pause a writer thread (frames stay queued, in order); a plain writer writes as it goes."""
        if isinstance(self.writer, AsyncSequenceWriter):
            self.writer.pause()

    def release(self) -> None:
        """Resume a paused writer thread (idempotent)."""
        if isinstance(self.writer, AsyncSequenceWriter):
            self.writer.resume()

    def saved(self) -> str:
        """``N frame(s) already saved in DIR``: what an error message says is on disk."""
        return f"{self._count} frame(s) already saved in {self.writer.path.parent}"


def engine_for(camera: Camera, booth: Booth, plan: CapturePlan, recorder: SequenceRecorder) -> CaptureEngine:
    """The engine of ``plan``'s sync mode, once the booth is known to run it (:func:`check_booth_runs`)."""
    if plan.trigger not in SYNC_OF_TRIGGER:
        raise ValueError(f"capture: plan trigger {plan.trigger!r}; expected software, booth or camera")
    check_booth_runs(booth, plan)
    if plan.trigger == "software":
        return HostPaced(camera, booth, recorder)
    # The booth's capabilities say it runs a pattern table: it is a SequencedBooth.
    return TablePaced(camera, cast(SequencedBooth, booth), recorder)


def run_capture(
    camera: Camera,
    booth: Booth,
    plan: CapturePlan,
    writer: FrameWriter,
    handlers: Sequence[FrameHandler] = (),
    retakes: int = RETAKES,
    cancel: Cancellation | None = None,
) -> list[SequenceFrame]:
    """Capture every step of ``plan`` in its sync mode, writing each frame as it arrives, then handing it to
    ``handlers``; a frame lost at its own step is taken again up to ``retakes`` times
    (:meth:`CaptureRunner.run`). Returns the entries written.

    Raises
    ------
    FrameTimeoutError
        No frame within the frame timeout (and the booth counted no trigger for it); names the step.
    FrameLostError
        A frame was lost at its step and so was every retake of it; names the step.
    DroppedFrameError
        The booth triggered a frame that never came, or exposed a step other than the plan's (not
        retaken: the frames since may be paired with the wrong steps); names the step. Frames
        already written stay on disk.
    CaptureCancelled
        ``cancel`` was cancelled; the frames already written stay.
    UsageError
        The booth cannot run the plan's sync mode (:func:`check_booth_runs`); nothing was captured.
    """
    recorder = SequenceRecorder(writer)
    engine = engine_for(camera, booth, plan, recorder)
    runner = CaptureRunner(engine, recorder, handlers, retakes=retakes, cancel=cancel)
    return list(runner.run(plan).entries)


def run_capture_with_flash(
    camera: Camera,
    booth: Booth,
    plan: CapturePlan,
    writer: FrameWriter,
    flash: FlashDecider,
    handlers: Sequence[FrameHandler] = (),
    retakes: int = RETAKES,
    cancel: Cancellation | None = None,
) -> list[SequenceFrame]:
    """Capture ``plan`` and then a flash frame whose step ``flash`` decides, in one stream.

    ``flash.decide_flash()`` runs on the capturing thread right after the last frame of ``plan``
    was handed to the handlers (``flash`` is usually one of them: it decides from the frames it was
    given). Booth master: the step period is fixed when the table is armed, so the flash exposure
    is capped at the plan's longest exposure (logged). Returns the entries of every frame, the
    flash last. Errors and ``retakes`` as :func:`run_capture` (a retake that reaches the flash step
    decides it again, from the same frames).
    """
    if not plan.steps:
        raise ValueError("run_capture_with_flash: the plan has no steps; expected ambient + LED steps")
    longest = max(s.exposure_us for s in plan.steps)
    placeholder = CaptureStep(len(plan.steps), "flash", (0.0,) * plan.n_leds, longest, plan.steps[0].gain)
    full = dataclasses.replace(plan, steps=(*plan.steps, placeholder))
    recorder = SequenceRecorder(writer)
    engine = engine_for(camera, booth, full, recorder)
    runner = CaptureRunner(engine, recorder, handlers, flash=flash, retakes=retakes, cancel=cancel)
    with collector_paused():
        return list(runner.run(full).entries)


def preview_frames(
    camera: Camera, booth: Booth, plan: CapturePlan, retakes: int = RETAKES, cancel: Cancellation | None = None
) -> list[RawFrame]:
    """Capture ``plan`` host paced and return the frames in memory, writing nothing (exposure previews).

    Frames pair with steps in order (host pacing). A frame lost at its step is taken again as in a
    capture (a lossy link must not fail the metering); a skipped frame id then raises
    :class:`FrameLostError`. LEDs off and camera stopped at the end, as for :func:`run_capture`.
    """
    runner = CaptureRunner(HostPaced(camera, booth, preview=True), retakes=retakes, cancel=cancel)
    return list(runner.run(plan).frames)
