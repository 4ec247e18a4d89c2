"""Capture plans as data: the steps of a sequence and how they are triggered.

A :class:`CapturePlan` is what a camera is prepared with and what the booth's pattern table is
loaded from; one function (the capture runner) executes it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, TypedDict, Unpack

StepRole = Literal["ambient", "led", "flash", "dark"]
TriggerSource = Literal["software", "booth", "camera"]


@dataclass(frozen=True)
class CaptureStep:
    """One frame of a sequence."""

    index: int
    """Position in the sequence, from 0."""
    role: StepRole
    """``ambient`` (LEDs off), ``led`` (ambient + LEDs at ``led_levels``), ``flash`` or ``dark``."""
    led_levels: tuple[float, ...]
    """Drive level of each LED channel in [0, 1] during this frame."""
    exposure_us: float
    """Exposure time in microseconds."""
    gain: float = 1.0
    """Linear analogue gain (1.0 = 0 dB)."""

    @property
    def label(self) -> str:
        """A short human label: ``ambient``, ``led:3`` (1-based channel), ``flash``, ``dark``."""
        if self.role == "led":
            lit = [i + 1 for i, level in enumerate(self.led_levels) if level > 0]
            return "led:" + "+".join(str(i) for i in lit) if lit else "led:none"
        return self.role


class PlanTiming(TypedDict, total=False):
    """The timing fields of a :class:`CapturePlan`, as its constructors pass them through."""

    trigger: TriggerSource
    settle_s: float
    deadtime_s: float
    timeout_margin_s: float


@dataclass(frozen=True)
class CapturePlan:
    """The steps of a sequence and its timing."""

    steps: tuple[CaptureStep, ...]
    """The frames to capture, in order."""
    trigger: TriggerSource = "software"
    """Who paces the frames: host software trigger, the booth's trigger line, or the camera's strobe."""
    settle_s: float = 0.001
    """Time the LEDs need to reach a new level before an exposure starts."""
    deadtime_s: float = 0.002
    """Minimum time between the end of one exposure and the next trigger."""
    timeout_margin_s: float = 1.0
    """Slack added to each frame's timeout for transport and scheduling."""

    @property
    def n_leds(self) -> int:
        """Number of LED channels the plan drives."""
        return len(self.steps[0].led_levels) if self.steps else 0

    @property
    def frame_timeout_s(self) -> float:
        """How long to wait for any one frame: longest exposure + settle + deadtime + margin."""
        longest = max((s.exposure_us for s in self.steps), default=0.0) * 1e-6
        return longest + self.settle_s + self.deadtime_s + self.timeout_margin_s

    @classmethod
    def ambient_then_each_led(
        cls,
        n_leds: int,
        exposure_us: float,
        level: float = 1.0,
        gain: float = 1.0,
        led_exposures_us: Sequence[float] | None = None,
        led_gains: Sequence[float] | None = None,
        **timing: Unpack[PlanTiming],
    ) -> CapturePlan:
        """The paper's sequence: one ambient frame, then ambient + each LED alone.

        ``gain`` is the ambient frame's (and every LED frame's unless ``led_gains`` gives each its own).
        """
        steps = [CaptureStep(0, "ambient", (0.0,) * n_leds, float(exposure_us), gain)]
        for led in range(n_leds):
            levels = tuple(level if i == led else 0.0 for i in range(n_leds))
            exposure = float(led_exposures_us[led]) if led_exposures_us is not None else float(exposure_us)
            steps.append(
                CaptureStep(led + 1, "led", levels, exposure, float(led_gains[led]) if led_gains is not None else gain)
            )
        return cls(tuple(steps), **timing)

    @classmethod
    def single(
        cls,
        levels: Sequence[float],
        exposure_us: float,
        role: StepRole = "flash",
        gain: float = 1.0,
        **timing: Unpack[PlanTiming],
    ) -> CapturePlan:
        """One frame with the LEDs at ``levels`` (the flash re-capture)."""
        return cls((CaptureStep(0, role, tuple(float(v) for v in levels), float(exposure_us), gain),), **timing)
