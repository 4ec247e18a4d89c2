"""What a capture needs of an LED booth: the :class:`Booth` interface and its sync capabilities.

Capture code (``acquisition/session``) is typed against these protocols, never against one
driver, so a booth that speaks another protocol fits behind an adapter without touching it
(``docs/booth-adapters.md``). Two drivers implement them: :class:`led_controller.LedBooth` (the
msflash protocol, every sync mode) and :class:`led_controller.adapters.text_booth.TextBooth` (a
plain-text line protocol, host pacing only).

Sync modes are named as ``--sync`` names them:

``host``
    The host sets each step's levels (:meth:`Booth.set_levels`, which returns once they are
    applied) and then triggers the camera itself. Every booth supports it.
``booth``
    *Booth master*: the booth runs a pattern table and pulses the camera's trigger input.
``camera``
    *Camera master*: the camera's strobe output steps the booth through its pattern table.

The last two need :class:`SequencedBooth` (the pattern table and its events); a booth says which
it supports in :attr:`Booth.capabilities`, and capture refuses a plan the booth cannot run
(:func:`unsupported_sync`) before it opens an output folder.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any, Protocol

SYNC_MODES = ("host", "booth", "camera")
"""Every sync mode, as ``--sync`` names them."""


@dataclass(frozen=True)
class BoothCapabilities:
    """Which sync modes a booth can run (host pacing always).

    >>> BoothCapabilities().sync_modes
    ('host',)
    >>> BoothCapabilities(booth_master=True, camera_master=True).supports("camera")
    True
    """

    booth_master: bool = False
    """The booth runs a pattern table and pulses the camera's trigger (``--sync booth``)."""
    camera_master: bool = False
    """The camera's strobe steps the booth through its pattern table (``--sync camera``)."""

    @property
    def sync_modes(self) -> tuple[str, ...]:
        """The ``--sync`` modes this booth supports, ``host`` first."""
        return ("host",) + ("booth",) * self.booth_master + ("camera",) * self.camera_master

    def supports(self, sync: str) -> bool:
        """Whether the booth can run ``sync`` (``host``, ``booth`` or ``camera``)."""
        if sync not in SYNC_MODES:
            raise ValueError(f"sync mode {sync!r}: unknown; expected one of {', '.join(SYNC_MODES)}")
        return sync in self.sync_modes


HOST_PACED_ONLY = BoothCapabilities()
"""The capabilities of a booth that only sets levels when told (no pattern table, no trigger line)."""


class BoothIdentity(Protocol):
    """What a booth says it is (``Booth.info``); :class:`led_controller.BoothInfo` is one."""

    @property
    def firmware(self) -> str:
        """Firmware or device name and version, recorded in each sequence's metadata."""
        ...

    @property
    def channels(self) -> int:
        """Number of LED channels: :meth:`Booth.set_levels` takes one level per channel."""
        ...

    @property
    def names(self) -> tuple[str, ...]:
        """Channel names, one per channel (shown when channels and LED spectra disagree)."""
        ...


class Booth(Protocol):
    """What every capture needs of a booth: host-paced levels, its watchdog, identity, close.

    A booth without a watchdog (the text adapter) covers nothing (:meth:`watchdog_covering` is a
    null context) and never reports one fired.
    """

    @property
    def name(self) -> str:
        """The booth's port or name, used in every message about it."""
        ...

    @property
    def info(self) -> BoothIdentity:
        """What the booth said it is when it was opened."""
        ...

    @property
    def capabilities(self) -> BoothCapabilities:
        """The sync modes this booth can run."""
        ...

    def set_levels(self, levels: Sequence[float]) -> None:
        """Drive every channel to ``levels`` (one per channel, each 0–1); return once they are applied."""
        ...

    def all_off(self) -> None:
        """Switch every channel off; return once they are off."""
        ...

    def reported_levels(self) -> tuple[float, ...]:
        """The levels the booth reports it holds now (what a simulated camera renders with)."""
        ...

    def close(self) -> None:
        """Release the link (idempotent). Switching the LEDs off first is the caller's ``all_off``."""
        ...

    def watchdog_covering(self, silence_s: float) -> AbstractContextManager[None]:
        """A context keeping the booth's watchdog from firing while the host is silent on purpose for ``silence_s``."""
        ...

    def watchdog_fired(self) -> bool:
        """Whether the booth's watchdog switched the LEDs off since last asked."""
        ...


class SequencedIdentity(BoothIdentity, Protocol):
    """What a booth running a pattern table says of its dimming."""

    @property
    def pulse_dimming(self) -> bool:
        """The booth dims a step given its exposure by pulses inside it (``DIM=PULSE``), else by PWM."""
        ...


class SequencedBooth(Booth, Protocol):
    """What booth- and camera-master capture need on top: the pattern table and its events."""

    @property
    def info(self) -> SequencedIdentity:
        """What the booth said it is when it was opened, its dimming included."""
        ...

    def load_pattern(
        self,
        steps: Sequence[Sequence[float]],
        *,
        held: Sequence[int] = (),
        exposures_us: Sequence[float] | None = None,
    ) -> None:
        """Replace the pattern table; ``held`` steps wait for :meth:`set_step` (never exposed before);
        ``exposures_us``: each step's exposure, for a booth that pulses inside it."""
        ...

    def set_step(
        self, index: int, levels: Sequence[float], *, now: bool = False, exposure_us: float | None = None
    ) -> None:
        """Set one step's levels (also while running) and release it if held; ``now``: start it at once."""
        ...

    def set_roll(self, skew_us: float) -> None:
        """The camera's rolling-shutter skew in µs (a pulsing booth fits its pulses to the flash window)."""
        ...

    def delivered_levels(self, index: int, exposure_us: float) -> tuple[float, ...] | None:
        """What table step ``index`` gave each LED in ``exposure_us``, as a level; None when dimmed by PWM."""
        ...

    def pending_events(self) -> list[Any]:
        """Remove and return the events received but not yet waited for (an earlier table's)."""
        ...

    def arm(self, mode: str, *, settle_us: int = ..., pulse_us: int = ..., period_us: int = ...) -> None:
        """Arm the table in a sync mode (``BOOTH`` or ``CAMERA``)."""
        ...

    def start(self) -> None:
        """Start the armed table."""
        ...

    def trigger_count(self) -> int:
        """Triggers counted since :meth:`arm`."""
        ...

    def wait_event(self, kind: str | None = None, *, timeout_s: float | None = None) -> Any:
        """The next event (``TRIG``, ``DONE``…), with its ``.args``."""
        ...


def unsupported_sync(booth: Booth, sync: str) -> str | None:
    """Why ``booth`` cannot run ``sync``, in one line naming both, or None when it can.

    The line reads ``booth NAME (FIRMWARE) supports --sync host only; --sync booth needs …``.
    """
    capabilities = booth.capabilities
    if capabilities.supports(sync):
        return None
    needs = {
        "booth": "a booth that runs a pattern table and pulses the camera's trigger (booth master)",
        "camera": "a booth that steps through a pattern table on the camera's strobe (camera master)",
    }[sync]
    return (
        f"booth {booth.name} ({booth.info.firmware}) supports --sync {'/'.join(capabilities.sync_modes)} only; "
        f"--sync {sync} needs {needs}; expected --sync {capabilities.sync_modes[0]}"
    )
