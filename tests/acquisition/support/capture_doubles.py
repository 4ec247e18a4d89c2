"""Frame handlers and flash deciders for tests of the capture engine (not mocks: they only watch or decide)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from msflash.acquisition.session.engine import CaptureResult, FlashChoice, FrameEvent


class Watch:
    """A frame handler calling ``seen(step, frame, entry)`` for every frame, and keeping the events."""

    def __init__(self, seen: Callable[[Any, Any, Any], None] | None = None) -> None:
        self.seen = seen
        self.events: list[FrameEvent] = []
        self.finished: list[CaptureResult] = []

    def frame_ready(self, event: FrameEvent) -> None:
        self.events.append(event)
        if self.seen is not None:
            self.seen(event.step, event.frame, event.entry)

    def sequence_finished(self, result: CaptureResult) -> None:
        self.finished.append(result)


class FixedFlash:
    """A flash decider (and frame handler) giving fixed levels and exposure.

    ``seen`` records how many ambient + LED frames it had been handed at each decision; ``check``
    runs at each decision (an assertion about the rig's state then, or an error to raise).
    """

    def __init__(self, levels: Sequence[float], exposure_us: float, check: Callable[[], None] | None = None) -> None:
        self.levels = tuple(float(v) for v in levels)
        self.exposure_us = float(exposure_us)
        self.check = check
        self.frames: list[Any] = []
        self.seen: list[int] = []

    def frame_ready(self, event: FrameEvent) -> None:
        if event.step.role != "flash":
            self.frames.append(event.frame)

    def sequence_finished(self, result: CaptureResult) -> None:
        """Nothing to do."""

    def decide_flash(self) -> FlashChoice:
        self.seen.append(len(self.frames))
        if self.check is not None:
            self.check()
        return FlashChoice(self.levels, self.exposure_us)
