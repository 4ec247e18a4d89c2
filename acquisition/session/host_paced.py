"""Host paced (``--sync host``, plan trigger ``"software"``): the host sets each step, then triggers.

For each step the booth is set to the step's levels (``SET``, which replies once applied), then
the camera is software-triggered and the frame awaited. Frames pair with steps in order; the
camera's frame ids must be consecutive (a gap is a frame lost at its step: :class:`FrameLostError`,
retaken by the runner). A :class:`~acquisition.session.engine.CaptureEngine`.
"""

from __future__ import annotations

import dataclasses
from contextlib import AbstractContextManager, ExitStack, nullcontext

from msflash.acquisition.devices.camera import Camera
from msflash.acquisition.errors import FrameLostError, FrameTimeoutError
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.acquisition.session.booth_guard import (
    booth_errors_at,
    check_watchdog,
    close_stack,
    sequence_watchdog,
    switch_off,
    watchdog_covering,
)
from msflash.acquisition.session.engine import FRAME_ID_MODULUS, Recorder, StepFrame
from msflash.led_controller.booth_interface import Booth


class HostPaced:
    """The host-paced engine. ``recorder`` only names what is on disk in messages; ``preview``
    names the steps as exposure previews (``preview step 0 (ambient)``)."""

    def __init__(self, camera: Camera, booth: Booth, recorder: Recorder | None = None, preview: bool = False) -> None:
        self.camera = camera
        self.booth = booth
        self._recorder = recorder
        self._prefix = "preview " if preview else ""
        self._plan: CapturePlan | None = None
        self._previous_id: int | None = None
        self._cover: AbstractContextManager[None] = nullcontext()
        self._watchdog = ExitStack()

    def _saved(self) -> str:
        return self._recorder.saved() if self._recorder is not None else ""

    def setup_sequence(self, plan: CapturePlan, flash_held: bool) -> None:
        """Cover the booth's watchdog for one step, prepare and start the camera."""
        self._plan, self._previous_id = plan, None
        self._watchdog = ExitStack()
        self._watchdog.enter_context(sequence_watchdog(self.booth, plan))
        self.camera.prepare(plan)
        self.camera.start()

    def set_flash_step(self, position: int, step: CaptureStep) -> CaptureStep:
        """The camera takes the decided flash step; the watchdog is covered for its exposure, which
        may be longer than any planned step."""
        assert self._plan is not None
        self._plan = dataclasses.replace(self._plan, steps=(*self._plan.steps[:position], step))
        self.camera.update_plan(self._plan, position)
        self._cover = watchdog_covering(self.booth, dataclasses.replace(self._plan, steps=(step,)))
        return step

    def exec_step(self, position: int, step: CaptureStep) -> StepFrame:
        """``SET`` the levels, trigger, wait for the frame and check its id follows the previous one."""
        assert self._plan is not None
        where = f"{self._prefix}step {step.index} ({step.label})"
        cover, self._cover = self._cover, nullcontext()
        with cover, booth_errors_at(where, self._saved()):
            self.booth.set_levels(step.led_levels)
            self.camera.trigger()
            try:
                frame = self.camera.next_frame(self._plan.frame_timeout_s)
            except FrameTimeoutError as err:
                saved = self._saved()
                raise FrameTimeoutError(f"{where}: {err}" + (f"; {saved}" if saved else "")) from err
        previous = self._previous_id
        if previous is not None and (frame.frame_id - previous) % FRAME_ID_MODULUS != 1:
            saved = self._saved()
            raise FrameLostError(
                f"{where}: camera frame id {frame.frame_id} follows {previous}; a frame was lost"
                + (f". {saved}" if saved else "")
            )
        check_watchdog(self.booth, where, self._saved())
        self._previous_id = frame.frame_id
        return StepFrame(step, frame)

    def finish_sequence(self) -> None:
        """Nothing owed: every step had its ``SET``."""

    def teardown_sequence(self, error: BaseException | None) -> None:
        """LEDs off and the camera stopped, then the watchdog set back."""
        try:
            switch_off(self.camera, self.booth, error)
        finally:
            self._cover = nullcontext()
            close_stack(self._watchdog, error)
