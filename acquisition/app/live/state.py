"""What the live server remembers between requests: the view's options, the sequence in progress, the last error.

The page holds no state of its own: it draws what :meth:`LiveState.to_json` says, fetched when it loads
and pushed on every change, so a reload shows the same sliders, the same sequence's progress and the same
last run. Mutated on the server's event loop only (the rig thread hands its news over with
``call_soon_threadsafe``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

JobStatus = Literal["idle", "running", "done", "failed", "stopped"]


@dataclass
class SequenceJob:
    """The last sequence fired from the page: its run folder, phase and the frames landed so far."""

    status: JobStatus = "idle"
    run: str | None = None
    """The run folder's name under the runs directory."""
    phase: str = ""
    steps: list[dict[str, Any]] = field(default_factory=list)
    """One entry per planned frame: ``label`` and, once it has landed, ``file``."""
    message: str = ""
    """The error of a failed sequence, or what a finished one scored."""

    def to_json(self) -> dict[str, Any]:
        landed = sum(1 for step in self.steps if step.get("file"))
        return {
            "status": self.status,
            "run": self.run,
            "phase": self.phase,
            "steps": list(self.steps),
            "landed": landed,
            "total": len(self.steps),
            "message": self.message,
        }


@dataclass
class LiveState:
    """The server's state besides the rig's own (settings and booth levels live in the stream)."""

    overlay: bool = True
    """Paint saturated pixels on the live image."""
    sequence_exposure: Literal["auto", "live"] = "auto"
    """The fired sequence's exposure: metered (``auto``, ``msflash run``'s default) or the live exposure."""
    mode: Literal["complementary", "matching"] = "complementary"
    """The flash re-captured at the end of the sequence (both are synthesised)."""
    job: SequenceJob = field(default_factory=SequenceJob)
    frames: int = 0
    """Live frames sent since the server started."""
    error: str | None = None
    """The last error that switched the LEDs off, until the next setting succeeds."""
    error_source: str | None = None
    """What failed: ``camera`` (the stream's device went or timed out), ``booth`` or ``other``."""
