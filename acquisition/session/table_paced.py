"""Table paced: the booth runs the plan as its pattern table (booth master, camera master).

``"booth"`` — *booth master*
    The plan's levels are loaded as the booth's pattern table and armed in ``BOOTH`` mode with
    the plan's settle time and a period covering settle + trigger pulse + the longest exposure +
    deadtime (:func:`~acquisition.session.booth_guard.booth_period_us`); ``START`` runs it. The
    booth applies each step, waits ``settle``, pulses the camera's trigger input and reports
    ``TRIG <count> <step>``.
``"camera"`` — *camera master*
    The table is armed in ``CAMERA`` mode; the host triggers the camera (software trigger) and
    the camera's ExposureActive output advances the table: each exposure start counts a trigger,
    each exposure end applies the next step. The host leaves at least ``settle_s`` between exposures.

Pairing (:class:`TriggerPairing`): a frame's trigger number comes from its frame id — the first
frame of the attempt is trigger 1 and later ones count on from its id (modulo 2^16, the GigE
Vision block-id wrap) — and its step is the one the booth reported for that trigger (``TRIG``
event), never its position in the arrival order. A skipped frame id is a frame lost at its step
(:class:`FrameLostError`, retaken); a booth trigger count ahead of the frames received when a frame
times out, or a ``TRIG`` whose step is not the plan's, raises :class:`DroppedFrameError` naming the
missing step (never retaken: later frames may be paired with the wrong steps).

The flash in the same stream: the table is loaded with the flash step *held* (``PADD … HOLD``), and one
``PSET`` releases it with its levels once they are decided (:meth:`TablePaced.set_flash_step`; a held step is
never exposed with stale levels, docs/booth-protocol.md §5). Booth master sends ``PSET … NOW`` (the last LED
frame is in) and caps the flash exposure at the longest planned one, the period fixed when the table was armed.

A booth that pulses (``DIM=PULSE``) gets each step's exposure with its levels and the camera's
rolling-shutter skew, and each frame records the levels it delivered (docs/flash-energy.md).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from contextlib import ExitStack

from msflash.acquisition.devices.camera import Camera, RawFrame
from msflash.acquisition.errors import CaptureError, DroppedFrameError, FrameLostError, FrameTimeoutError
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.acquisition.session.booth_guard import (
    TRIGGER_PULSE_US,
    booth_errors_at,
    booth_period_us,
    check_watchdog,
    close_stack,
    sequence_watchdog,
    switch_off,
    watchdog_covering,
)
from msflash.acquisition.session.engine import FRAME_ID_MODULUS, Recorder, StepFrame
from msflash.led_controller.booth_interface import SequencedBooth
from msflash.led_controller.booth_table import ARM_TIME_MAX_US

log = logging.getLogger(__name__)


class TriggerPairing:
    """Which table step a frame belongs to: its trigger number (from its frame id) and the booth's
    ``TRIG <count> <step>`` report for that trigger (see the module notes)."""

    def __init__(self, booth: SequencedBooth) -> None:
        self.booth = booth
        self.first_id: int | None = None

    def trigger_of(self, frame: RawFrame, number: int, step: CaptureStep, saved: str) -> int:
        """The frame's trigger number; :class:`FrameLostError` if it is not ``number`` (a frame skipped)."""
        if self.first_id is None:
            self.first_id = frame.frame_id
        trigger = 1 + (frame.frame_id - self.first_id) % FRAME_ID_MODULUS
        if trigger != number:
            raise FrameLostError(
                f"step {step.index} ({step.label}): no frame for trigger {number}; the next frame "
                f"(id {frame.frame_id}) is trigger {trigger}. {saved}"
            )
        return trigger

    def table_step_of(self, trigger: int, timeout_s: float, step: CaptureStep) -> int:
        """The table step the booth reported for ``trigger`` (``TRIG`` events arrive in order)."""
        while True:
            event = self.booth.wait_event("TRIG", timeout_s=timeout_s)
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


class TablePaced:
    """The booth- and camera-master engine (``plan.trigger`` ``"booth"`` or ``"camera"``)."""

    def __init__(self, camera: Camera, booth: SequencedBooth, recorder: Recorder) -> None:
        self.camera = camera
        self.booth = booth
        self._recorder = recorder
        self._plan: CapturePlan | None = None
        self._frame_timeout_s = 0.0
        self._longest_us = 0.0
        self._pulsing = False
        self._touched = False
        self._pairing = TriggerPairing(booth)
        self._watchdog = ExitStack()

    @property
    def _mode(self) -> str:
        assert self._plan is not None
        return self._plan.trigger

    def setup_sequence(self, plan: CapturePlan, flash_held: bool) -> None:
        """Load the table (the flash step held), arm it, start the camera and the table."""
        period_us = booth_period_us(plan) if plan.trigger == "booth" else 0
        self._longest_us = max(step.exposure_us for step in plan.steps)
        if period_us > ARM_TIME_MAX_US:
            allowed_us = self._longest_us - (period_us - ARM_TIME_MAX_US)
            raise CaptureError(
                f"booth master: step period {period_us * 1e-6:.4g} s (settle, trigger pulse, longest exposure "
                f"{self._longest_us * 1e-6:.4g} s, deadtime and readout) is longer than the booth's longest period "
                f"{ARM_TIME_MAX_US * 1e-6:g} s; expected exposures up to {allowed_us * 1e-6:.4g} s "
                "when the booth paces the frames (or host pacing)"
            )
        self._plan = plan
        # Booth master: frames come one period apart, so waiting for any one frame may take a period
        # on top of the usual timeout.
        self._frame_timeout_s = plan.frame_timeout_s + period_us * 1e-6
        self._pairing = TriggerPairing(self.booth)
        self._touched = True
        self._watchdog = ExitStack()
        self._watchdog.enter_context(sequence_watchdog(self.booth, plan))
        with booth_errors_at("loading the booth's table", self._recorder.saved()):
            self.booth.all_off()  # idle the booth (a previous table may be DONE) before editing the table
            self.booth.pending_events()  # events of an earlier, aborted table must not pair with this one's frames
            self._pulsing = self.booth.info.pulse_dimming
            levels = [step.led_levels for step in plan.steps]
            held = (len(plan.steps) - 1,) if flash_held else ()
            if self._pulsing:  # each step's exposure: the booth pulses w·T inside it (docs/flash-energy.md)
                self.booth.set_roll(float(self.camera.readout_skew_us))
                self.booth.load_pattern(levels, held=held, exposures_us=[step.exposure_us for step in plan.steps])
            else:
                self.booth.load_pattern(levels, held=held)
            settle_us = int(round(plan.settle_s * 1e6))
            self.booth.arm(plan.trigger, settle_us=settle_us, pulse_us=TRIGGER_PULSE_US, period_us=period_us)
            self.camera.prepare(plan)
            self.camera.start()
            self.booth.start()

    def set_flash_step(self, position: int, step: CaptureStep) -> CaptureStep:
        """Release the held flash step with its levels (one ``PSET``; ``NOW`` in booth master)."""
        assert self._plan is not None
        mode = self._mode
        if mode == "booth" and step.exposure_us > self._longest_us:
            log.warning(
                "flash exposure %.0f µs capped at %.0f µs: the booth's period was fixed for the "
                "longest step when the table was armed",
                step.exposure_us,
                self._longest_us,
            )
            step = dataclasses.replace(step, exposure_us=self._longest_us)
        self._plan = dataclasses.replace(self._plan, steps=(*self._plan.steps[:position], step))
        self.camera.update_plan(self._plan, position)
        if step.exposure_us > self._longest_us:  # camera master: the flash exposure is not capped
            flash_plan = dataclasses.replace(self._plan, steps=(step,))
            self._frame_timeout_s = max(self._frame_timeout_s, flash_plan.frame_timeout_s)
            self._watchdog.enter_context(watchdog_covering(self.booth, flash_plan))
        # The last LED frame is in, so its exposure is over: the flash step need not wait for its
        # scheduled slot (booth master, PSET … NOW; a firmware without NOW gets a plain PSET).
        with booth_errors_at(f"step {step.index} ({step.label})", self._recorder.saved()):
            if self._pulsing:
                self.booth.set_step(position, step.led_levels, now=mode == "booth", exposure_us=step.exposure_us)
            else:
                self.booth.set_step(position, step.led_levels, now=mode == "booth")
        return step

    def exec_step(self, position: int, step: CaptureStep) -> StepFrame:
        """Wait for the step's frame (camera master: trigger it), pair it with the booth's report."""
        assert self._plan is not None
        number = position + 1  # the trigger number in this table (a retake's table starts at the lost step)
        with booth_errors_at(f"step {step.index} ({step.label})", self._recorder.saved()):
            if self._mode == "camera":
                if number > 1:
                    time.sleep(self._plan.settle_s)  # the next step's LEDs settle between exposures
                self.camera.trigger()
            frame = self._next_frame(number, step)
            trigger = self._pairing.trigger_of(frame, number, step, self._recorder.saved())
            table_step = self._pairing.table_step_of(trigger, self._frame_timeout_s, step)
            paired = self._plan.steps[table_step]
            if paired.index != step.index:
                raise DroppedFrameError(
                    f"step {step.index} ({step.label}): the booth exposed table step {paired.index} on trigger "
                    f"{trigger}; expected step {step.index} — a trigger was missed or doubled. "
                    f"{self._recorder.saved()}"
                )
            delivered = self.booth.delivered_levels(table_step, frame.exposure_us) if self._pulsing else None
        return StepFrame(paired, frame, trigger, delivered)

    def _next_frame(self, number: int, step: CaptureStep) -> RawFrame:
        try:
            return self.camera.next_frame(self._frame_timeout_s)
        except FrameTimeoutError as err:
            saved = self._recorder.saved()
            # The booth stops the table when its watchdog fires: say so rather than 'no frame'.
            check_watchdog(self.booth, f"step {step.index} ({step.label})", saved)
            counted = self.booth.trigger_count()
            if counted >= number:
                raise DroppedFrameError(
                    f"step {step.index} ({step.label}): the booth counted trigger {number} but no frame "
                    f"arrived within {self._frame_timeout_s:.3g} s; the frame was lost. {saved}"
                ) from err
            raise FrameTimeoutError(
                f"step {step.index} ({step.label}): {err}; the booth counted {counted} trigger(s) "
                f"({self._mode} master); {saved}"
            ) from err

    def finish_sequence(self) -> None:
        """Wait for the table's ``DONE``."""
        with booth_errors_at("after the last step (waiting for DONE)", self._recorder.saved()):
            done = self.booth.wait_event("DONE", timeout_s=self._frame_timeout_s)
        log.info("booth %s-master sequence done after %s trigger(s)", self._mode, " ".join(done.args))

    def teardown_sequence(self, error: BaseException | None) -> None:
        """LEDs off (``OFF`` aborts a running table) and the camera stopped, then the watchdog set back."""
        if not self._touched:
            return
        self._touched = False
        try:
            switch_off(self.camera, self.booth, error)
        finally:
            close_stack(self._watchdog, error)
