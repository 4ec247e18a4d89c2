"""The capture engine: one runner, engines that pace the steps, handlers that take the frames.

The idea is pymmcore-plus's acquisition engine (an engine protocol run by one runner, which emits
each frame to handlers) and ophyd-async's detector made of small parts; no code is taken from
either (docs/decisions/capture-engine.md).

:class:`CaptureEngine`
    How a sync mode paces a plan (docs/architecture.md §4): :meth:`~CaptureEngine.setup_sequence`
    (prepare the camera, load and arm the booth's table), :meth:`~CaptureEngine.exec_step` (one
    step: trigger, wait for the frame, pair it with its step and check it),
    :meth:`~CaptureEngine.finish_sequence` (the booth's ``DONE``) and
    :meth:`~CaptureEngine.teardown_sequence` (LEDs off, camera stopped, on every exit path).
    :class:`~acquisition.session.host_paced.HostPaced` and
    :class:`~acquisition.session.table_paced.TablePaced` (booth and camera master) are the two.
:class:`CaptureRunner`
    Runs a plan on an engine, once: the cancellation checks between steps, the flash step asked of a
    :class:`FlashDecider` when it is due, the writer held from the last LED frame to the flash frame,
    the frames handed to the :class:`Recorder` and then to every :class:`FrameHandler`
    (``frame_ready``, then ``sequence_finished``), and the retakes of lost frames (:meth:`CaptureRunner.run`).

Nothing is handed down to steer the loop: the recorder (the sequence writer), the flash decider
(the run's flash session) and the handlers (progress, the live page) are objects with typed
methods, and the runner owns the order in which they are called.
"""

from __future__ import annotations

import dataclasses
import gc
import logging
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Protocol

from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.errors import CaptureCancelled, FrameLostError, FrameTimeoutError
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.acquisition.sequence.format import SequenceFrame

log = logging.getLogger(__name__)

RETAKES = 2
"""How many times a capture takes a lost frame again before it gives up (:meth:`CaptureRunner.run`)."""

FRAME_ID_MODULUS = 1 << 16
"""GigE Vision block ids wrap at 16 bits; continuity is checked modulo this."""


@dataclass(frozen=True)
class StepFrame:
    """A frame paired with the plan step it belongs to, as an engine returns it."""

    step: CaptureStep
    """The plan's step (booth and camera master: the one the booth reported for the frame's trigger)."""
    frame: RawFrame
    trigger: int | None = None
    """The booth's trigger number (booth and camera master), else None."""
    delivered_levels: tuple[float, ...] | None = None
    """Each LED's on-time ÷ the exposure, as a pulsing booth quantised it (docs/flash-energy.md), else None."""


@dataclass(frozen=True)
class FrameEvent:
    """``frame_ready``'s argument: a frame, its step, where it was written and which retake took it."""

    step: CaptureStep
    frame: RawFrame
    entry: SequenceFrame | None
    """Its entry in the sequence (None when nothing is recorded: exposure previews)."""
    retake: int = 0
    """0 on the first attempt, else the retake that took it."""


@dataclass(frozen=True)
class CaptureResult:
    """What :meth:`CaptureRunner.run` took: every step's frame, in plan order."""

    entries: tuple[SequenceFrame, ...]
    """The entries written (empty when nothing is recorded)."""
    frames: tuple[RawFrame, ...]
    """The raw frames, one per step."""
    retakes: int = 0
    """Retakes it took (0: no frame was lost)."""


@dataclass(frozen=True)
class FlashChoice:
    """The flash step's LED levels and exposure, decided from the frames taken so far."""

    levels: tuple[float, ...]
    exposure_us: float


class CaptureEngine(Protocol):
    """How one sync mode paces a plan (see the module notes). One attempt is
    ``setup_sequence`` → ``exec_step``… → ``finish_sequence``, then ``teardown_sequence`` always."""

    def setup_sequence(self, plan: CapturePlan, flash_held: bool) -> None:
        """Prepare and start the camera (and the booth's table) for ``plan``; ``flash_held``: its
        last step is the flash, whose levels come later (:meth:`set_flash_step`)."""
        ...

    def set_flash_step(self, position: int, step: CaptureStep) -> CaptureStep:
        """Give the camera and the booth the decided flash ``step`` at ``position``; the step as it will
        be exposed (booth master caps its exposure at the armed period's)."""
        ...

    def exec_step(self, position: int, step: CaptureStep) -> StepFrame:
        """Expose ``step`` (at ``position`` of the attempt's plan) and return its frame, paired and checked.

        Raises :class:`FrameLostError` for a frame lost at its own step (retaken), other capture
        errors for everything else, each naming the step."""
        ...

    def finish_sequence(self) -> None:
        """After the last frame: what the pacing still owes (booth and camera master: the ``DONE``)."""
        ...

    def teardown_sequence(self, error: BaseException | None) -> None:
        """LEDs off and the camera stopped, on every exit path; after an ``error`` a failure here is
        logged, not raised over it."""
        ...


class Recorder(Protocol):
    """Where frames are written (:class:`~acquisition.session.capture.SequenceRecorder`): called
    before the handlers, which see the entry it returns."""

    def record(self, paired: StepFrame, retake: int) -> SequenceFrame:
        """Write ``paired``'s frame and return its entry."""
        ...

    def hold(self) -> None:
        """Keep frames queued, unwritten, until :meth:`release` (the flash decision's CPU is not shared)."""
        ...

    def release(self) -> None:
        """Write the queued frames again (idempotent)."""
        ...

    def saved(self) -> str:
        """What is on disk, for an error message (``N frame(s) already saved in DIR``)."""
        ...


class FrameHandler(Protocol):
    """Takes the frames of a run as they are paired and written (the flash session, progress, the live page)."""

    def frame_ready(self, event: FrameEvent) -> None:
        """One frame, paired with its step and written (called on the capturing thread: be brief)."""
        ...

    def sequence_finished(self, result: CaptureResult) -> None:
        """Every step has its frame (not called when the capture fails or is cancelled)."""
        ...


class FlashDecider(Protocol):
    """Decides the flash step from the frames it was handed as a :class:`FrameHandler`."""

    def decide_flash(self) -> FlashChoice:
        """The flash levels and exposure, right after the last LED frame (between frames: be quick)."""
        ...


class Cancellation:
    """A request to stop a capture between frames, from another thread (``msflash live`` on SIGTERM).

    The runner checks it before every step: a cancelled capture raises :class:`CaptureCancelled`,
    its engine switches the LEDs off and stops the camera, and the frames already written stay
    (the sequence is left ``complete: false``).
    """

    def __init__(self) -> None:
        self._event = threading.Event()
        self.reason = ""

    def cancel(self, reason: str = "cancelled") -> None:
        """Ask the capture to stop before its next step (idempotent; the first reason is kept)."""
        if not self._event.is_set():
            self.reason = reason
        self._event.set()

    @property
    def cancelled(self) -> bool:
        """Whether :meth:`cancel` was called."""
        return self._event.is_set()

    def check(self, step: CaptureStep) -> None:
        """Raise :class:`CaptureCancelled` naming ``step`` (the one not taken) if cancelled."""
        if self._event.is_set():
            raise CaptureCancelled(f"before step {step.index} ({step.label}): {self.reason}")


@contextmanager
def collector_paused() -> Iterator[None]:
    """Pause Python's automatic (cyclic) garbage collection while a flash sequence streams.

    A collection stops every thread of the process; one landing between the last LED frame and the
    flash trigger doubled that latency (docs/architecture.md §10). A sequence leaves almost no
    cyclic garbage, so collection waits until it is over; the previous state is restored on every
    exit path.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


@dataclass
class _Taken:
    """What a run has taken so far, across retakes."""

    entries: list[SequenceFrame] = field(default_factory=list)
    frames: list[RawFrame] = field(default_factory=list)
    retake: int = 0

    @property
    def steps_done(self) -> int:
        return len(self.frames)


class CaptureRunner:
    """Runs a plan on a :class:`CaptureEngine`, handing each frame to ``recorder`` (None: frames kept in memory
    only) and then to ``handlers``; ``flash`` decides the plan's last step once the frames before it are in;
    a lost frame is taken again up to ``retakes`` times; ``cancel`` is checked before every step."""

    def __init__(
        self,
        engine: CaptureEngine,
        recorder: Recorder | None = None,
        handlers: Sequence[FrameHandler] = (),
        flash: FlashDecider | None = None,
        retakes: int = RETAKES,
        cancel: Cancellation | None = None,
    ) -> None:
        if retakes < 0:
            raise ValueError(f"retakes {retakes}; expected 0 or more")
        self.engine = engine
        self.recorder = recorder
        self.handlers = tuple(handlers)
        self.flash = flash
        self.retakes = retakes
        self.cancel = cancel if cancel is not None else Cancellation()

    def run(self, plan: CapturePlan) -> CaptureResult:
        """Capture every step of ``plan``; after a lost frame, the steps not yet done again.

        A frame lost on its way (:class:`FrameLostError`: incomplete, its frame id skipped, or host paced
        vanished after earlier ones came, :func:`_vanished`) is found at its own step before any later frame
        was written, so the same step taken again gives the frame the sequence needs: the retake sets the engine
        up with the remaining steps (same indices, same pairing and checks); frames written before stay, each
        retaken one records ``retake``: 1, 2…. Other failures are not retaken (a trigger never seen, a booth
        table step other than the plan's, the booth's link, the disk, a cancellation): docs/decisions/capture-engine.md.
        """
        taken = _Taken()
        while True:
            rest = dataclasses.replace(plan, steps=plan.steps[taken.steps_done :])
            try:
                self._attempt(rest, taken)
                break
            except (FrameLostError, FrameTimeoutError) as err:
                if isinstance(err, FrameTimeoutError) and not _vanished(plan, taken):
                    raise
                if taken.retake >= self.retakes:
                    if taken.retake:
                        raise type(err)(f"{err} (after {taken.retake} retake(s) of lost frames)") from err
                    raise
                taken.retake += 1
                lost = plan.steps[taken.steps_done]
                log.warning(
                    "%s; taking step %d (%s) again, with the %d step(s) after it (retake %d of %d)",
                    err,
                    lost.index,
                    lost.label,
                    len(plan.steps) - taken.steps_done - 1,
                    taken.retake,
                    self.retakes,
                )
        result = CaptureResult(tuple(taken.entries), tuple(taken.frames), taken.retake)
        for handler in self.handlers:
            handler.sequence_finished(result)
        return result

    def _attempt(self, plan: CapturePlan, taken: _Taken) -> None:
        """One attempt over ``plan`` (the steps not yet done): set up, every step, finish, tear down."""
        last = len(plan.steps) - 1
        flash_held = self.flash is not None and plan.steps[last].role == "flash"
        error: BaseException | None = None
        self.cancel.check(plan.steps[0])
        try:
            self.engine.setup_sequence(plan, flash_held)
            for position, step in enumerate(plan.steps):
                self.cancel.check(step)
                if flash_held and position == last - 1 and self.recorder is not None:
                    self.recorder.hold()  # from the wait for the last LED frame until the flash frame is in
                if flash_held and position == last:
                    step = self._flash_step(position, step)
                paired = self.engine.exec_step(position, step)
                if flash_held and position == last and self.recorder is not None:
                    # Only now: a writer released at the flash decision took the GIL for its queued
                    # frames while the booth's thread was due to pulse the flash trigger.
                    self.recorder.release()
                self._emit(paired, taken)
            self.engine.finish_sequence()
        except BaseException as err:
            error = err
            raise
        finally:
            try:
                self.engine.teardown_sequence(error)
            finally:
                if flash_held and self.recorder is not None:
                    self.recorder.release()

    def _flash_step(self, position: int, placeholder: CaptureStep) -> CaptureStep:
        assert self.flash is not None
        choice = self.flash.decide_flash()
        step = dataclasses.replace(
            placeholder,
            led_levels=tuple(float(v) for v in choice.levels),
            exposure_us=float(choice.exposure_us),
        )
        return self.engine.set_flash_step(position, step)

    def _emit(self, paired: StepFrame, taken: _Taken) -> None:
        entry = self.recorder.record(paired, taken.retake) if self.recorder is not None else None
        taken.frames.append(paired.frame)
        if entry is not None:
            taken.entries.append(entry)
        event = FrameEvent(paired.step, paired.frame, entry, taken.retake)
        for handler in self.handlers:
            handler.frame_ready(event)


def _vanished(plan: CapturePlan, taken: _Taken) -> bool:
    """Whether a frame timeout is a frame lost on the link rather than a trigger never taken.

    Host paced, one software trigger is out and its frame alone is awaited, so a timeout pairs
    nothing wrongly; once this capture has had frames (whole or not) the trigger path works and
    the frame vanished on its way (every packet of it, its leader among them, dropped). A timeout
    before any frame is the trigger or the wiring: taken again it would time out again. Booth and
    camera master time out only when the booth counted no trigger for the frame (a booth that
    counted one raises :class:`DroppedFrameError`): that is never retaken.
    """
    return plan.trigger == "software" and bool(taken.steps_done or taken.retake)
