"""Frames made on a trigger and handed to ``next_frame``: what the simulated and replay cameras share.

Both cameras produce a frame when they are triggered (software ``trigger()`` or the hardware
``trigger_line()`` the booth emulator pulses), queue it, and serve it from ``next_frame``. This
base class holds the queue, the open/started state and the waiting rules, so the two cameras
only say how a frame is made and how they describe themselves in messages.
"""

from __future__ import annotations

import threading
from collections import deque

from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.errors import CameraDisconnectedError, CameraError, FrameTimeoutError
from msflash.acquisition.plan import CapturePlan


class _Failed:
    """Queue item: making the frame of a trigger failed; ``next_frame`` raises ``error`` in its place."""

    def __init__(self, error: BaseException) -> None:
        self.error = error


class TriggeredFrames:
    """The queue, state and waiting rules of a camera whose frames follow its triggers.

    Subclasses set ``self._label`` (how messages name the camera) and may override
    :meth:`_timeout_message`; they produce frames between :meth:`_begin_frame` and
    :meth:`_end_frame` and hand each to :meth:`_deliver`.
    """

    _label = "camera"

    def __init__(self) -> None:
        self._condition = threading.Condition()
        self._queue: deque[RawFrame | _Failed] = deque()
        self._plan: CapturePlan | None = None
        self._started = False
        self._closed = False
        self._producing = 0
        """Frames being made right now (a trigger that has not delivered yet)."""
        self._unplugged: str | None = None
        """Why the device is gone (:meth:`unplug`), None while it is there."""

    def unplug(self, reason: str = "the cable was pulled") -> None:
        """The twin of a camera that goes away mid-stream: every later call raises
        :class:`~acquisition.errors.CameraDisconnectedError` naming ``reason`` (frames already queued stay
        readable, as frames a host has received do) until :meth:`replug`."""
        with self._condition:
            self._unplugged = reason
            self._condition.notify_all()

    def replug(self) -> None:
        """The device is back: calls work again (the caller prepares and starts again, as after a real loss)."""
        with self._condition:
            self._unplugged = None

    def next_frame(self, timeout_s: float) -> RawFrame:
        """The oldest queued frame; ``FrameTimeoutError`` if none arrives within ``timeout_s``.

        Without a pending trigger (and when the booth does not pace the plan) nothing can arrive,
        so the error is raised at once rather than after ``timeout_s``. A frame that could not be
        made (:meth:`_fail_frame`) raises its error here, in its place: on the booth's trigger line
        nobody else would see it, and the capture would report a lost frame instead of the cause.
        """
        with self._condition:
            while not self._queue:
                self._check_open()
                plan = self._plan
                external = plan is not None and plan.trigger == "booth"
                if not external and self._producing == 0:
                    raise FrameTimeoutError(self._timeout_message(timeout_s, "no trigger was issued"))
                if not self._condition.wait_for(
                    lambda: bool(self._queue) or self._closed or self._unplugged is not None, timeout=timeout_s
                ):
                    raise FrameTimeoutError(self._timeout_message(timeout_s, "the trigger did not arrive"))
            item = self._queue.popleft()
        if isinstance(item, _Failed):
            raise item.error
        return item

    def update_plan(self, plan: CapturePlan, index: int) -> None:
        """Take ``plan``, whose step ``index`` changed: its frame is made from it when triggered."""
        with self._condition:
            self._plan = plan

    @property
    def readout_skew_us(self) -> float:
        """0: every row exposed at once (a global shutter) unless a subclass says otherwise."""
        return 0.0

    def stop(self) -> None:
        """Stop acquisition; idempotent. Queued frames stay readable until the next start."""
        with self._condition:
            self._started = False

    def close(self) -> None:
        """Release the camera; idempotent."""
        with self._condition:
            self._started = False
            self._closed = True
            self._queue.clear()
            self._condition.notify_all()

    # -- for subclasses -------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise CameraError(f"{self._label}: used after close(); expected an open camera")
        if self._unplugged is not None:
            raise CameraDisconnectedError(
                f"{self._label}: the device is gone ({self._unplugged}); expected it connected — check the cable "
                "and power, then reconnect"
            )

    def _require_started(self) -> CapturePlan:
        self._check_open()
        if not self._started or self._plan is None:
            raise CameraError(f"{self._label}: triggered before start(); expected prepare() then start()")
        return self._plan

    def _timeout_message(self, timeout_s: float, why: str) -> str:
        return (
            f"{self._label}: no frame within {timeout_s:g} s: {why}; expected trigger() (or the booth's "
            "trigger line) before next_frame()"
        )

    def _begin_frame(self) -> None:
        """A trigger was accepted: ``next_frame`` now waits for its frame (call under ``_condition``)."""
        self._producing += 1

    def _fail_frame(self, error: BaseException) -> None:
        """Making the frame of a trigger failed: ``next_frame`` raises ``error`` where the frame would be."""
        with self._condition:
            self._queue.append(_Failed(error))
            self._producing -= 1
            self._condition.notify_all()

    def _end_frame(self, frame: RawFrame) -> None:
        """The frame of a trigger is made: queue it and wake waiters (a failure goes to :meth:`_fail_frame`)."""
        with self._condition:
            self._queue.append(frame)
            self._producing -= 1
            self._condition.notify_all()
