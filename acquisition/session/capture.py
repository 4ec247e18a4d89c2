"""Run a capture plan: pair every frame with its step and write it to disk at once.

Three synchronisation modes (docs/architecture.md §4), chosen by ``plan.trigger``:

``"software"`` — *host paced* (the fallback)
    For each step the booth is set to the step's levels (``SET``, which replies once applied),
    then the camera is software-triggered and the frame awaited. Frames pair with steps in
    order; the camera's frame ids must be consecutive.

``"booth"`` — *booth master*
    The plan's levels are loaded as the booth's pattern table and armed in ``BOOTH`` mode with
    the plan's settle time and a period covering settle + trigger pulse + the longest exposure +
    deadtime; ``START`` runs it. The booth applies each step, waits ``settle``, pulses the
    camera's trigger input and reports ``TRIG <count> <step>``.

``"camera"`` — *camera master*
    The table is armed in ``CAMERA`` mode; the host triggers the camera (software trigger) and
    the camera's ExposureActive output advances the table: each exposure start counts a trigger
    (``TRIG <count> <step>``), each exposure end applies the next step. The host leaves at least
    ``settle_s`` between exposures.

Pairing (booth and camera master): a frame's trigger number comes from its frame id — the
first frame of the run is trigger 1 and later ones count on from its id (modulo 2^16, the
GigE Vision block-id wrap) — and its step is the one the booth reported for that trigger
(``TRIG`` event), never its position in the arrival order. A skipped frame id, a booth trigger
count ahead of the frames received when a frame times out, or a ``TRIG`` whose step is not the
plan's raises :class:`DroppedFrameError` naming the missing step. Frames already written stay on
disk (the writer keeps the sequence readable with ``complete: false``).

Retakes (:func:`_with_retakes`): a frame lost at its own step — incomplete, or its frame id
skipped (:class:`FrameLostError`) — is taken again, with the steps after it, up to
:data:`RETAKES` times in the same sync mode; only when every retake is lost too does the capture
fail. A lost frame costs a retake, not the sequence: a GigE Vision link under load drops packets
and the camera does not resend them.

The flash in the same run (:func:`run_capture_with_flash`): the plan gets one more step, a
placeholder ``flash`` step, and the camera keeps streaming from the ambient frame to the flash
frame. When the last LED frame arrives, ``decide(frames)`` computes the flash levels and
exposure; the camera's plan takes them and the booth gets them — host paced: ``SET`` then the
software trigger as for any step; booth and camera master: the table was loaded with the flash
step *held* (``PADD … HOLD``), and one ``PSET`` (one serial round trip) releases it with its
levels. A held step is never exposed with stale levels: the booth waits at it with the LEDs off
and no trigger (booth master) or reports an exposure during it as ``TRIG <n> HOLD`` (camera
master), which the pairing refuses (``docs/booth-protocol.md`` §5).
Booth master sends ``PSET … NOW``: the last LED frame is in, so its exposure is over and the flash
step starts at once (settle, pulse) instead of waiting for its scheduled slot. An
:class:`~acquisition.sequence.async_writer.AsyncSequenceWriter` is paused from the wait for the last LED
frame until the flash frame is in (frames stay queued, in order; nothing is dropped), so the disk
writes compete neither with the decision nor with the flash trigger for the CPU and the GIL.

The writer may be a :class:`~acquisition.sequence.format.SequenceWriter` or an
:class:`~acquisition.sequence.async_writer.AsyncSequenceWriter` (frames handed to a writer thread: the
loop never waits for the disk).

Whatever happens the LEDs go off (``OFF`` also aborts a running table) and the camera stops
(:func:`_leds_off_at_exit`); when the run ends in an error, a failure of that cleanup (the booth's
link is what failed) is logged and the original error is raised, not the cleanup's.

The booth's watchdog (``docs/booth-protocol.md`` §7) switches the LEDs off when the host has been
silent for its period, but a capture is silent on purpose for a whole booth- or camera-master
table or a whole host-paced exposure (:func:`host_silence_s`). When the watchdog is shorter, it is
raised for the sequence and set back afterwards (:meth:`led_controller.LedBooth.watchdog_covering`);
otherwise a long sequence was aborted half way, or a long LED exposure silently lit only in part.
"""

from __future__ import annotations

import dataclasses
import gc
import logging
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager, ExitStack, contextmanager, nullcontext
from typing import TypeVar

from msflash.acquisition.devices.camera import Camera, RawFrame
from msflash.acquisition.errors import (
    BoothStepError,
    CaptureError,
    DroppedFrameError,
    FrameLostError,
    FrameTimeoutError,
    UsageError,
)
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.format import SequenceFrame, SequenceWriter
from msflash.led_controller.booth import ARM_TIME_MAX_US
from msflash.led_controller.booth_interface import Booth, SequencedBooth, unsupported_sync
from msflash.led_controller.errors import BoothError

log = logging.getLogger(__name__)

FrameWriter = SequenceWriter | AsyncSequenceWriter
"""Where captured frames go: written as they come, or handed to a writer thread."""

OnFrame = Callable[[CaptureStep, RawFrame, SequenceFrame], None]
"""Called with each frame written: its step, the raw frame and its entry in the sequence."""

FlashStep = Callable[[list[RawFrame]], CaptureStep]
"""The flash step, decided from the frames taken so far (:func:`run_capture_with_flash`)."""

FRAME_ID_MODULUS = 1 << 16
"""GigE Vision block ids wrap at 16 bits; continuity is checked modulo this."""

TRIGGER_PULSE_US = 100
"""Width of the booth's trigger pulse in booth-master mode."""

READOUT_US = 2_000
"""Camera readout / host slack added to each booth-master period beyond exposure and deadtime."""

WATCHDOG_SLACK_S = 0.5
"""Host pauses on top of a plan's scheduled silence towards the booth (writing a frame, the flash
decision, the OS scheduler), in seconds: see :func:`host_silence_s`."""


RETAKES = 2
"""How many times a capture takes a lost frame again before it gives up (:func:`_with_retakes`)."""

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


def booth_period_us(plan: CapturePlan) -> int:
    """Booth-master step period: settle + pulse + longest exposure + deadtime + readout, in µs."""
    longest = max((s.exposure_us for s in plan.steps), default=0.0)
    return int(math.ceil(plan.settle_s * 1e6 + TRIGGER_PULSE_US + longest + plan.deadtime_s * 1e6 + READOUT_US))


def host_silence_s(plan: CapturePlan) -> float:
    """The longest the host may send the booth nothing while it runs ``plan``, in seconds.

    The booth's watchdog must not fire meanwhile (``docs/booth-protocol.md`` §7: it switches the
    LEDs off and aborts the table). Host paced: one step — the ``SET``, the exposure and the wait
    for its frame, at most ``plan.frame_timeout_s`` before the host gives up and sends ``OFF``.
    Booth and camera master: the whole table runs without a command — one
    :func:`booth_period_us` per step, one more period and the frame timeout for the last frame
    (the wait of :func:`run_capture`). Both plus :data:`WATCHDOG_SLACK_S`.

    Examples
    --------
    >>> from msflash.acquisition.plan import CapturePlan
    >>> round(host_silence_s(CapturePlan.ambient_then_each_led(7, 10_000.0)), 3)
    1.513
    >>> round(host_silence_s(CapturePlan.ambient_then_each_led(7, 500_000.0, trigger="booth")), 3)
    6.549
    """
    if plan.trigger == "software":
        return plan.frame_timeout_s + WATCHDOG_SLACK_S
    return (len(plan.steps) + 1) * booth_period_us(plan) * 1e-6 + plan.frame_timeout_s + WATCHDOG_SLACK_S


def _check_watchdog(booth: Booth, where: str, saved: str = "") -> None:
    """Refuse the frame of ``where`` (a step) if the booth's watchdog switched the LEDs off meanwhile.

    The host was silent for longer than the booth's watchdog (a stall beyond
    :func:`host_silence_s`): the frame may have been exposed partly or wholly dark, and a host-paced
    sequence would not notice otherwise. ``saved`` says what is on disk.
    """
    fired = getattr(booth, "watchdog_fired", None)
    if fired is not None and fired():
        raise CaptureError(
            f"{where}: the booth's watchdog switched the LEDs off during this frame (the host was silent for "
            f"longer than its period); expected the LEDs on until the frame was in — the frame is not kept"
            + (f". {saved}" if saved else "")
        )


def _sequence_watchdog(booth: Booth, plan: CapturePlan) -> AbstractContextManager[None]:
    """At the start of a sequence: a ``WDOG`` event from before it (LEDs left on by earlier code,
    then forgotten) is dropped — it says nothing of this sequence's frames, which
    :func:`_check_watchdog` judges — and the watchdog is covered for ``plan`` (:func:`_watchdog_covering`)."""
    fired = getattr(booth, "watchdog_fired", None)
    if fired is not None and fired():
        log.info("the booth's watchdog had switched the LEDs off before this sequence")
    return _watchdog_covering(booth, plan)


def _watchdog_covering(booth: Booth, plan: CapturePlan) -> AbstractContextManager[None]:
    """The booth's watchdog kept from firing while ``plan`` runs (:meth:`LedBooth.watchdog_covering`),
    or nothing for a booth without one. Leaves the ``WDOG`` events alone: within a sequence (the
    flash step) they are this sequence's, for :func:`_check_watchdog`."""
    cover = getattr(booth, "watchdog_covering", None)
    return cover(host_silence_s(plan)) if cover is not None else nullcontext()


FlashDecide = Callable[[list[RawFrame]], tuple[Sequence[float], float]]
"""``decide(frames) -> (levels, exposure_us)``: the flash step from the frames captured so far."""


def run_capture_with_flash(
    camera: Camera,
    booth: Booth,
    plan: CapturePlan,
    writer: FrameWriter,
    decide: FlashDecide,
    on_frame: OnFrame | None = None,
    retakes: int = RETAKES,
) -> list[SequenceFrame]:
    """Capture ``plan`` and then a flash frame whose levels ``decide`` computes, in one stream.

    ``decide`` runs on the capturing thread right after the last frame of ``plan`` arrived; it
    returns the flash levels and exposure. Booth master: the step period is fixed when the table
    is armed, so the flash exposure is capped at the plan's longest exposure (logged). Returns the
    entries of every frame, the flash last. Errors and ``retakes`` as :func:`run_capture` (a retake
    that reaches the flash step decides it again, from the same frames).
    """
    if not plan.steps:
        raise ValueError("run_capture_with_flash: the plan has no steps; expected ambient + LED steps")
    longest = max(s.exposure_us for s in plan.steps)
    placeholder = CaptureStep(len(plan.steps), "flash", (0.0,) * plan.n_leds, longest, plan.steps[0].gain)
    full = dataclasses.replace(plan, steps=(*plan.steps, placeholder))

    def flash_step(frames: list[RawFrame]) -> CaptureStep:
        levels, exposure_us = decide(frames)
        levels = tuple(float(v) for v in levels)
        exposure_us = float(exposure_us)
        if plan.trigger == "booth" and exposure_us > longest:
            log.warning(
                "flash exposure %.0f µs capped at %.0f µs: the booth's period was fixed for the "
                "longest step when the table was armed",
                exposure_us,
                longest,
            )
            exposure_us = longest
        return dataclasses.replace(placeholder, led_levels=levels, exposure_us=exposure_us)

    if plan.trigger not in ("software", "booth", "camera"):
        raise ValueError(f"run_capture_with_flash: plan trigger {plan.trigger!r}; expected software, booth or camera")
    check_booth_runs(booth, plan)
    paced = _host_paced if plan.trigger == "software" else _table_paced
    with collector_paused():
        return _with_retakes(paced, camera, booth, full, writer, on_frame, flash_step, retakes).written  # type: ignore[arg-type]


@contextmanager
def collector_paused() -> Iterator[None]:
    """Pause Python's automatic (cyclic) garbage collection while a flash sequence streams.

    A collection stops every thread of the process; on the capture bench collections came many
    times per sequence, and one landing between the last LED frame and the flash trigger doubled
    that latency (docs/architecture.md §10). A sequence lasts
    k + 2 frame periods and leaves almost no cyclic garbage (reference counting frees the rest),
    so collection waits until it is over. The previous state is restored on every exit path.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


@contextmanager
def _leds_off_at_exit(camera: Camera, booth: Booth) -> Iterator[None]:
    """LEDs off (``OFF`` also aborts a running table), then the camera stopped, on every exit path.

    Leaving through an error, a failure to switch off or to stop (when the booth's link is what
    failed, ``OFF`` cannot get through either) is logged, and the original error goes on: it is
    the one that says what went wrong (and the booth's watchdog switches off a silent host's LEDs).
    """
    try:
        yield
    except BaseException:
        try:
            booth.all_off()
        except Exception as off_err:  # noqa: BLE001 - the original error matters more
            log.warning(
                "LEDs not confirmed off after the error: %s; the booth's watchdog switches them off "
                "once the host has been silent for its period",
                off_err,
            )
        try:
            camera.stop()
        except Exception as stop_err:  # noqa: BLE001 - the original error matters more
            log.warning("stopping the camera after the error failed: %s", stop_err)
        raise
    try:
        booth.all_off()
    finally:
        camera.stop()


@contextmanager
def _booth_errors_at(where: str, saved: str = "") -> Iterator[None]:
    """A booth failure within the block raised as :class:`BoothStepError` naming ``where`` (a step).

    The driver's message names the port and the command, not what the capture was doing; the user
    needs both. ``saved`` says what is on disk.
    """
    try:
        yield
    except BoothError as err:
        raise BoothStepError(f"{where}: {err}" + (f". {saved}" if saved else "")) from err


def _replan(camera: Camera, plan: CapturePlan, index: int) -> None:
    """Give a streaming camera its plan with step ``index`` filled in, before that step's trigger.

    The Camera protocol has no call for it yet: the implementations read their prepared plan
    (``_plan``) when a step is triggered (Aravis with software trigger, the simulated camera) or,
    with a hardware trigger line, right after the previous frame (Aravis): that step is then
    re-applied here. ``WiredFakeCamera`` (the aravis-fake rig) wraps an ``AravisCamera`` as
    ``.aravis``. A camera offering ``update_plan(plan, index)`` is asked instead.
    """
    update = getattr(camera, "update_plan", None)
    if update is not None:
        update(plan, index)
        return
    targets = [t for t in (camera, getattr(camera, "aravis", None)) if t is not None and hasattr(t, "_plan")]
    if not targets:
        raise TypeError(
            f"{type(camera).__name__}: cannot change a step of a prepared plan; expected a camera "
            "with update_plan(plan, index) (or use two captures for the flash)"
        )
    for target in targets:
        with getattr(target, "_condition", None) or nullcontext():
            target._plan = plan
        trigger = getattr(target, "_trigger", None)
        if (
            trigger is not None
            and getattr(trigger, "mode", "software") != "software"
            and getattr(target, "_n_consumed", None) == index
            and hasattr(target, "_apply_step")
        ):
            target._apply_step(index, plan)  # the line-triggered step was set up after the previous frame


def run_capture(
    camera: Camera,
    booth: Booth,
    plan: CapturePlan,
    writer: FrameWriter,
    on_frame: OnFrame | None = None,
    retakes: int = RETAKES,
) -> list[SequenceFrame]:
    """Capture every step of ``plan`` in its sync mode, writing each frame as it arrives.

    A frame lost at its own step (:class:`FrameLostError`: incomplete, or its frame id skipped)
    is taken again up to ``retakes`` times: the steps from the lost one on are captured anew in
    the same sync mode (:func:`_with_retakes`); the frames already written stay.

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
    UsageError
        The booth cannot run the plan's sync mode (:func:`check_booth_runs`); nothing was captured.
    """
    if plan.trigger in SYNC_OF_TRIGGER:
        check_booth_runs(booth, plan)
    if plan.trigger == "software":
        return _with_retakes(_host_paced, camera, booth, plan, writer, on_frame, None, retakes).written
    if plan.trigger in ("booth", "camera"):
        return _with_retakes(_table_paced, camera, booth, plan, writer, on_frame, None, retakes).written  # type: ignore[arg-type]
    raise ValueError(f"run_capture: plan trigger {plan.trigger!r}; expected software, booth or camera")


@dataclasses.dataclass
class _Progress:
    """What a capture has taken so far, across retakes (:func:`_with_retakes`)."""

    written: list[SequenceFrame] = dataclasses.field(default_factory=list)
    """The entries written, in step order (none for previews, which write nothing)."""
    frames: list[RawFrame] = dataclasses.field(default_factory=list)
    """The raw frames of the steps done (the flash is decided from them; previews return them)."""
    steps_done: int = 0
    """Steps finished: their frame written (a capture) or kept (previews). A retake starts after them."""
    retake: int = 0
    """0 on the first attempt, then the number of the retake running."""


WriterOrNone = TypeVar("WriterOrNone", FrameWriter, None)
"""A capture's writer, or None for previews (which write nothing)."""

PacedSteps = Callable[
    [
        Camera,
        Booth,
        CapturePlan,
        WriterOrNone,
        OnFrame | None,
        FlashStep | None,
        _Progress,
    ],
    None,
]
"""A sync mode's capture loop (:func:`_host_paced`, :func:`_table_paced`, :func:`_preview_steps`): runs
the plan's steps and adds each one it finishes to the progress."""


def _vanished(plan: CapturePlan, progress: _Progress) -> bool:
    """Whether a frame timeout is a frame lost on the link rather than a trigger never taken.

    Host paced, one software trigger is out and its frame alone is awaited, so a timeout pairs
    nothing wrongly; once this capture has had frames (whole or not) the trigger path works and
    the frame vanished on its way (every packet of it, its leader among them, dropped). A timeout
    before any frame is the trigger or the wiring: taken again it would time out again. Booth and
    camera master time out only when the booth counted no trigger for the frame (a booth that
    counted one raises :class:`DroppedFrameError`): that is never retaken.
    """
    return plan.trigger == "software" and bool(progress.steps_done or progress.retake)


def _with_retakes(
    paced: PacedSteps[WriterOrNone],
    camera: Camera,
    booth: Booth,
    plan: CapturePlan,
    writer: WriterOrNone,
    on_frame: OnFrame | None,
    flash: FlashStep | None,
    retakes: int,
) -> _Progress:
    """Run ``paced`` over ``plan``; after a lost frame, run it again over the steps not yet done.

    A frame lost on its way (:class:`FrameLostError`: incomplete — a GigE Vision link dropped
    packets, which the camera never resends — or missing, its frame id skipped; host paced, a
    frame that vanished after earlier ones came, :func:`_vanished`) is a transport failure found at
    its own step, before any later frame was written: the scene and the LEDs are as they were, so
    the same step taken again gives the frame the sequence needs.
    The loop that lost it has already switched the LEDs off, aborted the booth's table and stopped
    the camera (:func:`_leds_off_at_exit`); the retake prepares the camera and loads the booth
    (its table, in booth and camera master) with the remaining steps, which keep their indices,
    and pairs and checks their frames exactly as the first attempt did. The frames written before
    the loss stay, in order, so the sequence on disk is the plan's whether or not a step was
    retaken (the entry of each frame taken in a retake records ``retake``: 1, 2…). ``retakes`` 0
    gives up at the first loss. Other failures are not retaken: no frame at all (a trigger the
    camera never saw is found only once the booth has counted more triggers than frames arrived,
    and the frames in between may already be paired with the wrong steps), a booth's table step
    other than the plan's, the booth's link, the disk — taking them again would repeat them or
    hide them.
    """
    if retakes < 0:
        raise ValueError(f"retakes {retakes}; expected 0 or more")
    progress = _Progress()
    while True:
        rest = dataclasses.replace(plan, steps=plan.steps[progress.steps_done :])
        try:
            paced(camera, booth, rest, writer, on_frame, flash, progress)
            return progress
        except (FrameLostError, FrameTimeoutError) as err:
            del progress.frames[progress.steps_done :]  # a frame kept but not written goes with it
            if isinstance(err, FrameTimeoutError) and not _vanished(plan, progress):
                raise
            if progress.retake >= retakes:
                if progress.retake:
                    raise type(err)(f"{err} (after {progress.retake} retake(s) of lost frames)") from err
                raise
            progress.retake += 1
            lost = plan.steps[progress.steps_done]
            log.warning(
                "%s; taking step %d (%s) again, with the %d step(s) after it (retake %d of %d)",
                err,
                lost.index,
                lost.label,
                len(plan.steps) - progress.steps_done - 1,
                progress.retake,
                retakes,
            )


def _saved(writer: FrameWriter, written: list[SequenceFrame]) -> str:
    return f"{len(written)} frame(s) already saved in {writer.path.parent}"


def _pulses_steps(booth: Booth) -> bool:
    """Whether the booth dims steps given their exposure by pulses inside it (``DIM=PULSE``, booth and camera master)."""
    info = getattr(booth, "info", None)
    return bool(getattr(info, "pulse_dimming", False)) and hasattr(booth, "delivered_levels")


def _write(
    writer: FrameWriter,
    step: CaptureStep,
    frame: RawFrame,
    progress: _Progress,
    on_frame: OnFrame | None,
    trigger: int | None = None,
    delivered: Sequence[float] | None = None,
) -> None:
    extra: dict = {"frame_id": frame.frame_id, "timestamp_ns": frame.timestamp_ns}
    if trigger is not None:
        extra["trigger"] = trigger
    if delivered is not None:
        # Pulse dimming: each LED's on-time ÷ this frame's exposure, as the booth quantised it
        # (docs/flash-energy.md); ``leds`` stays the level asked for.
        extra["delivered_levels"] = [round(float(v), 7) for v in delivered]
    if progress.retake:
        extra["retake"] = progress.retake
    if frame.camera_gain is not None:  # the gain feature behind frame.gain, in the camera's unit
        extra["camera_gain"] = frame.camera_gain.to_dict()
    entry = writer.add_frame(frame.pixels, step.role, step.led_levels, frame.exposure_us, frame.gain, extra=extra)
    progress.written.append(entry)
    progress.steps_done += 1
    log.info("step %d (%s): frame %d saved as %s", step.index, step.label, frame.frame_id, entry.file)
    if on_frame is not None:
        on_frame(step, frame, entry)


def _host_paced(
    camera: Camera,
    booth: Booth,
    plan: CapturePlan,
    writer: FrameWriter,
    on_frame: OnFrame | None,
    flash: FlashStep | None,
    progress: _Progress,
) -> None:
    written, frames = progress.written, progress.frames
    previous_id: int | None = None
    last = len(plan.steps) - 1
    with _sequence_watchdog(booth, plan), _leds_off_at_exit(camera, booth):
        camera.prepare(plan)
        camera.start()
        for position, step in enumerate(plan.steps):
            cover: AbstractContextManager[None] = nullcontext()
            if flash is not None and position == last:
                step = flash(frames)
                plan = dataclasses.replace(plan, steps=(*plan.steps[:-1], step))
                _replan(camera, plan, position)
                # The flash exposure is decided now and may be longer than any planned step.
                cover = _watchdog_covering(booth, dataclasses.replace(plan, steps=(step,)))
            with cover, _booth_errors_at(f"step {step.index} ({step.label})", _saved(writer, written)):
                booth.set_levels(step.led_levels)
                camera.trigger()
                try:
                    frame = camera.next_frame(plan.frame_timeout_s)
                except FrameTimeoutError as err:
                    raise FrameTimeoutError(
                        f"step {step.index} ({step.label}): {err}; {_saved(writer, written)}"
                    ) from err
            if previous_id is not None and (frame.frame_id - previous_id) % FRAME_ID_MODULUS != 1:
                raise FrameLostError(
                    f"step {step.index} ({step.label}): camera frame id {frame.frame_id} follows {previous_id}; "
                    f"a frame was lost. {_saved(writer, written)}"
                )
            _check_watchdog(booth, f"step {step.index} ({step.label})", _saved(writer, written))
            previous_id = frame.frame_id
            frames.append(frame)
            _write(writer, step, frame, progress, on_frame)


def _table_paced(
    camera: Camera,
    booth: SequencedBooth,
    plan: CapturePlan,
    writer: FrameWriter,
    on_frame: OnFrame | None,
    flash: FlashStep | None,
    progress: _Progress,
) -> None:
    written, frames = progress.written, progress.frames
    last = len(plan.steps) - 1
    mode = plan.trigger
    settle_us = int(round(plan.settle_s * 1e6))
    period_us = booth_period_us(plan) if mode == "booth" else 0
    # Booth master: frames come one period apart, so waiting for any one frame may take a period
    # on top of the usual timeout.
    frame_timeout_s = plan.frame_timeout_s + period_us * 1e-6
    longest_us = max(step.exposure_us for step in plan.steps)
    if period_us > ARM_TIME_MAX_US:
        longest_allowed_us = longest_us - (period_us - ARM_TIME_MAX_US)
        raise CaptureError(
            f"booth master: step period {period_us * 1e-6:.4g} s (settle, trigger pulse, longest exposure "
            f"{longest_us * 1e-6:.4g} s, deadtime and readout) is longer than the booth's longest period "
            f"{ARM_TIME_MAX_US * 1e-6:g} s; expected exposures up to {longest_allowed_us * 1e-6:.4g} s "
            "when the booth paces the frames (or host pacing)"
        )
    first_id: int | None = None
    pause, resume = getattr(writer, "pause", None), getattr(writer, "resume", None)
    with ExitStack() as watchdog:
        watchdog.enter_context(_sequence_watchdog(booth, plan))
        watchdog.enter_context(_leds_off_at_exit(camera, booth))
        doing = "loading the booth's table"  # what a booth failure is reported at
        try:
            booth.all_off()  # idle the booth (a previous table may be DONE) before editing the table
            drain = getattr(booth, "pending_events", None)
            if drain is not None:
                drain()  # events of an earlier, aborted table must not pair with this one's frames
            pulsing = _pulses_steps(booth)
            timed: dict = {}
            if pulsing:  # each step's exposure: the booth pulses w·T inside it (docs/flash-energy.md)
                booth.set_roll(float(getattr(camera, "readout_skew_us", 0.0) or 0.0))  # type: ignore[attr-defined]
                timed["exposures_us"] = [step.exposure_us for step in plan.steps]
            if flash is not None:  # the flash step is held until its levels are known (PSET)
                booth.load_pattern([step.led_levels for step in plan.steps], held=(last,), **timed)
            else:
                booth.load_pattern([step.led_levels for step in plan.steps], **timed)
            booth.arm(mode, settle_us=settle_us, pulse_us=TRIGGER_PULSE_US, period_us=period_us)
            camera.prepare(plan)
            camera.start()
            booth.start()
            for number, step in enumerate(plan.steps, start=1):
                position = number - 1  # in this table (a retake's table starts at the lost step)
                doing = f"step {step.index} ({step.label})"
                if flash is not None and position == last - 1 and pause is not None:
                    pause()  # the writer thread waits from the last LED frame until the flash frame is in
                if flash is not None and position == last:
                    step = flash(frames)
                    plan = dataclasses.replace(plan, steps=(*plan.steps[:-1], step))
                    _replan(camera, plan, position)
                    if step.exposure_us > longest_us:  # camera master: the flash exposure is not capped
                        flash_plan = dataclasses.replace(plan, steps=(step,))
                        frame_timeout_s = max(frame_timeout_s, flash_plan.frame_timeout_s)
                        watchdog.enter_context(_watchdog_covering(booth, flash_plan))
                    # The last LED frame is in, so its exposure is over: the flash step need not
                    # wait for its scheduled slot (booth master, PSET … NOW).
                    # (A booth firmware without NOW refuses it; LedBooth.set_step then falls back to plain PSET.)
                    if pulsing:
                        booth.set_step(position, step.led_levels, now=mode == "booth", exposure_us=step.exposure_us)  # type: ignore[call-arg]
                    else:
                        booth.set_step(position, step.led_levels, now=mode == "booth")
                if mode == "camera":
                    if number > 1:
                        time.sleep(plan.settle_s)  # the next step's LEDs settle between exposures
                    camera.trigger()
                try:
                    frame = camera.next_frame(frame_timeout_s)
                except FrameTimeoutError as err:
                    # The booth stops the table when its watchdog fires: say so rather than 'no frame'.
                    _check_watchdog(booth, f"step {step.index} ({step.label})", _saved(writer, written))
                    counted = booth.trigger_count()
                    if counted >= number:
                        raise DroppedFrameError(
                            f"step {step.index} ({step.label}): the booth counted trigger {number} but no frame "
                            f"arrived within {frame_timeout_s:.3g} s; the frame was lost. {_saved(writer, written)}"
                        ) from err
                    raise FrameTimeoutError(
                        f"step {step.index} ({step.label}): {err}; the booth counted {counted} trigger(s) "
                        f"({mode} master); {_saved(writer, written)}"
                    ) from err
                if first_id is None:
                    first_id = frame.frame_id
                trigger = 1 + (frame.frame_id - first_id) % FRAME_ID_MODULUS
                if trigger != number:
                    missing = plan.steps[number - 1]
                    raise FrameLostError(
                        f"step {missing.index} ({missing.label}): no frame for trigger {number}; the next frame "
                        f"(id {frame.frame_id}) is trigger {trigger}. {_saved(writer, written)}"
                    )
                table_step = _booth_step_of(booth, trigger, frame_timeout_s, step)
                paired = plan.steps[table_step]
                if paired.index != step.index:
                    raise DroppedFrameError(
                        f"step {step.index} ({step.label}): the booth exposed table step {paired.index} on trigger "
                        f"{trigger}; expected step {step.index} — a trigger was missed or doubled. {_saved(writer, written)}"
                    )
                frames.append(frame)
                if flash is not None and position == last and resume is not None:
                    # Only now: a writer resumed at the PSET took the GIL for its queued frames while
                    # the booth's thread was due to pulse the flash trigger (seen up to ~8 ms late).
                    resume()
                delivered = booth.delivered_levels(table_step, frame.exposure_us) if pulsing else None  # type: ignore[attr-defined]
                _write(writer, paired, frame, progress, on_frame, trigger=trigger, delivered=delivered)
            doing = "after the last step (waiting for DONE)"
            done = booth.wait_event("DONE", timeout_s=frame_timeout_s)
            log.info("booth %s-master sequence done after %s trigger(s)", mode, " ".join(done.args))
        except BoothError as err:
            if isinstance(err, BoothStepError):
                raise
            raise BoothStepError(f"{doing}: {err}. {_saved(writer, written)}") from err
        finally:
            if resume is not None:
                resume()


def _booth_step_of(booth: SequencedBooth, trigger: int, timeout_s: float, step: CaptureStep) -> int:
    """The table step the booth reported for ``trigger`` (``TRIG <count> <step>`` events arrive in order)."""
    while True:
        event = booth.wait_event("TRIG", timeout_s=timeout_s)
        try:
            count, index = int(event.args[0]), int(event.args[1])
        except (IndexError, ValueError) as err:
            raise DroppedFrameError(
                f"step {step.index} ({step.label}): booth event {event.args!r}; expected 'TRIG <count> <step>'"
            ) from err
        if count == trigger:
            return index
        if count > trigger:
            raise DroppedFrameError(
                f"step {step.index} ({step.label}): the booth reported trigger {count} before {trigger}; "
                "expected one TRIG event per trigger"
            )
        # count < trigger: an event of an earlier trigger left over; skip it.


def preview_frames(camera: Camera, booth: Booth, plan: CapturePlan, retakes: int = RETAKES) -> list[RawFrame]:
    """Capture ``plan`` host paced and return the frames in memory, writing nothing (exposure previews).

    Frames pair with steps in order (host pacing). A frame lost at its step is taken again as in a
    capture (:func:`_with_retakes`: a lossy link must not fail the metering); a skipped frame id
    then raises :class:`FrameLostError`. LEDs off and camera stopped at the end, as for
    :func:`run_capture`.
    """
    return _with_retakes(_preview_steps, camera, booth, plan, None, None, None, retakes).frames


def _preview_steps(
    camera: Camera,
    booth: Booth,
    plan: CapturePlan,
    _writer: None,
    _on_frame: OnFrame | None,
    _flash: FlashStep | None,
    progress: _Progress,
) -> None:
    previous_id: int | None = None
    with _sequence_watchdog(booth, plan), _leds_off_at_exit(camera, booth):
        camera.prepare(plan)
        camera.start()
        for step in plan.steps:
            with _booth_errors_at(f"preview step {step.index} ({step.label})"):
                booth.set_levels(step.led_levels)
                camera.trigger()
            try:
                frame = camera.next_frame(plan.frame_timeout_s)
            except FrameTimeoutError as err:
                raise FrameTimeoutError(f"preview step {step.index} ({step.label}): {err}") from err
            if previous_id is not None and (frame.frame_id - previous_id) % FRAME_ID_MODULUS != 1:
                raise FrameLostError(
                    f"preview step {step.index} ({step.label}): camera frame id "
                    f"{frame.frame_id} follows {previous_id}; a frame was lost"
                )
            _check_watchdog(booth, f"preview step {step.index} ({step.label})")
            previous_id = frame.frame_id
            progress.frames.append(frame)
            progress.steps_done += 1
