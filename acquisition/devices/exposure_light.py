"""Light over time, integrated over a simulated camera's exposure: the time-resolved half of the ``sim`` rig.

A frame does not see "the LED levels": each row of the sensor collects what each LED emits during
*its* exposure window ``[t_r, t_r + T]`` — a PWM waveform cut at some phase, a pulse placed by the
booth, a level change half way (docs/flash-energy.md). One mechanism serves every source:

- the camera describes the exposure (:class:`ExposureRequest`: exposure, rows, rolling-shutter line
  time, trigger latency, whether the booth's trigger line started it);
- an :class:`ExposureLight` — the booth emulator's drive model (:class:`EmulatorLight`) or the
  firmware's pins in simavr (:class:`FirmwareLight`) — answers each row's mean LED levels over its
  window (:class:`RowLight`);
- an ambient modulation ``a(t)`` (:data:`AmbientModulation`, mains flicker; none by default) is
  integrated over the same windows by :func:`ambient_over_rows`.

Row ``r`` of a rolling shutter starts ``r · line_time`` after row 0; a global shutter has line time 0.
The *flash window* (every row exposing) runs from the last row's start to the first row's end; that
is what the camera drives on its ExposureActive/FlashWindow output for a camera-master booth.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from msflash.acquisition.errors import CameraError

if TYPE_CHECKING:
    from msflash.led_controller import BoothEmulator
    from msflash.led_controller.firmware_sim import SimulatedBooth

AmbientModulation = Callable[[np.ndarray, float], np.ndarray]
"""``a(row_starts_s, duration_s)``: the ambient's mean relative intensity over each row's window
(1 = steady), on the light's clock. The hook for mains flicker; None means steady."""


@dataclass(frozen=True)
class Shutter:
    """How a simulated sensor exposes.

    Attributes
    ----------
    line_time_us
        Rolling shutter: row ``r`` starts ``r · line_time_us`` after row 0 (0: a global shutter).
    latency_us, latency_jitter_us
        From the trigger (software or the booth's line) to the first row's start: ``latency_us``
        plus a uniform draw in ``[0, latency_jitter_us]`` per frame.
    readout_us
        The least time from one exposure's last row end to the next exposure's start.
    """

    line_time_us: float = 0.0
    latency_us: float = 2.0
    latency_jitter_us: float = 1.0
    readout_us: float = 100.0

    def __post_init__(self) -> None:
        values = (self.line_time_us, self.latency_us, self.latency_jitter_us, self.readout_us)
        if not all(math.isfinite(v) and v >= 0 for v in values):
            raise CameraError(f"shutter {self}: expected finite times ≥ 0 µs")

    def skew_us(self, rows: int) -> float:
        """First row's start to the last row's, µs (0 for a global shutter)."""
        return (rows - 1) * self.line_time_us


@dataclass(frozen=True)
class ExposureRequest:
    """One exposure as the camera makes it."""

    exposure_us: float
    rows: int
    line_time_us: float
    latency_us: float
    """This frame's trigger latency (already drawn)."""
    hardware_trigger: bool
    """Started by the booth's trigger line (booth master), not by the host."""

    @property
    def skew_us(self) -> float:
        """First row's start to the last row's, µs."""
        return (self.rows - 1) * self.line_time_us

    def row_offsets_s(self) -> np.ndarray:
        """Each row's start after row 0, seconds."""
        return np.arange(self.rows) * (self.line_time_us * 1e-6)


@dataclass(frozen=True)
class RowLight:
    """What an exposure collected: the first row's start on the light's clock, and (rows, k) mean LED levels."""

    start_s: float
    led_levels: np.ndarray


class ExposureLight(Protocol):
    """A source of LED light over time that a simulated camera exposes under."""

    def expose(self, request: ExposureRequest) -> RowLight:
        """Make the exposure (raising the booth's ExposureActive line over its flash window) and
        return each row's mean LED levels."""
        ...


def ambient_over_rows(
    modulation: AmbientModulation | None, light: RowLight, request: ExposureRequest
) -> np.ndarray | None:
    """The ambient's mean relative intensity in each row's window, or None when steady."""
    if modulation is None:
        return None
    values = np.asarray(modulation(light.start_s + request.row_offsets_s(), request.exposure_us * 1e-6), dtype=float)
    if values.shape != (request.rows,) or not np.all(np.isfinite(values)) or np.any(values < 0):
        raise CameraError(
            f"ambient modulation gave shape {values.shape}; expected {request.rows} finite values ≥ 0 (one per row)"
        )
    return values


class EmulatorLight:
    """:class:`ExposureLight` of the booth emulator in this process: its drive model, on its clock.

    The exposure starts at the emulator's clock now plus the trigger latency (never before the
    previous exposure's last row ended plus the readout), or — booth master — at its last trigger
    pulse plus the latency. Its flash window is raised on the emulator's ExposureActive line (a
    camera-master booth fires its pulses and, when the window ends, applies the next step),
    dated to the exposure rather than to the call: the render does not wait out the exposure.
    """

    def __init__(self, emulator: BoothEmulator, readout_us: float = 100.0) -> None:
        self.emulator = emulator
        self._readout_s = readout_us * 1e-6
        self._last_end = -math.inf
        self._lock = threading.Lock()

    def expose(self, request: ExposureRequest) -> RowLight:
        """Each row's mean levels from the emulator's drive trace."""
        emulator = self.emulator
        with self._lock:
            latency = request.latency_us * 1e-6
            trigger = emulator.last_trigger_s if request.hardware_trigger else None
            if trigger is not None:
                start = trigger + latency
            else:
                start = max(emulator.clock_s() + latency, self._last_end + self._readout_s)
            exposure = request.exposure_us * 1e-6
            skew = request.skew_us * 1e-6
            window = skew < exposure
            if window:
                emulator.exposure_active(True, at_s=start + skew)
            offsets = request.row_offsets_s() if request.rows > 1 and request.line_time_us > 0 else np.zeros(1)
            levels = np.asarray(emulator.mean_levels(list(start + offsets), exposure), dtype=float)
            if window:
                emulator.exposure_active(False, at_s=start + exposure)
            self._last_end = start + skew + exposure
        if levels.shape[0] != request.rows:
            levels = np.repeat(levels, request.rows, axis=0)
        return RowLight(start, np.clip(levels, 0.0, 1.0))  # integration's rounding: 1 + 1e-16


class FirmwareLight:
    """:class:`ExposureLight` of the firmware in simavr: its LED pins integrated by the harness.

    Host-triggered exposures run in simulated time (``expose``: the harness drives ExposureActive
    over the flash window and integrates every pin over every row's window). Booth master: the rig
    hands each trigger pulse's simulated time to :meth:`triggered` before the camera renders; the
    windows then start the latency after it (``integrate``).
    """

    def __init__(self, booth: SimulatedBooth) -> None:
        self.booth = booth
        self._pulses: deque[float] = deque()
        self._lock = threading.Lock()

    def triggered(self, time_us: float) -> None:
        """The booth's trigger output rose at ``time_us`` (simulated): the next hardware-triggered exposure's."""
        with self._lock:
            self._pulses.append(time_us)

    def expose(self, request: ExposureRequest) -> RowLight:
        """Each row's LED on-time ÷ exposure, from the harness's pin trace."""
        if request.hardware_trigger:
            with self._lock:
                if not self._pulses:
                    raise CameraError(
                        "simavr camera: a hardware-triggered frame but no trigger pulse seen; expected one"
                    )
                pulse_us = self._pulses.popleft()
            done = self.booth.integrate(
                pulse_us + request.latency_us, request.exposure_us, request.rows, request.line_time_us
            )
        else:
            if request.skew_us >= request.exposure_us:
                raise CameraError(
                    f"simavr camera: rolling-shutter skew {request.skew_us:g} µs ≥ exposure {request.exposure_us:g} µs; "
                    "expected an exposure with a flash window"
                )
            done = self.booth.expose(request.exposure_us, request.rows, request.line_time_us, request.latency_us)
        levels = np.asarray(done.fractions(), dtype=float)
        return RowLight(done.start_us * 1e-6, np.clip(levels, 0.0, 1.0))
