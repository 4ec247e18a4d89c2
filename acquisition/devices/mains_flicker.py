"""Mains flicker of the simulated ambient: the ``sim`` rig's lamp on a 50/60 Hz supply (issue 30, item 5).

A lamp on the mains modulates at twice the supply frequency (100 Hz on 50 Hz, 120 Hz on 60 Hz), how deeply and
in what shape depending on how it makes light:

- ``sine``: a filament's thermal mass smooths the heating into a near-sinusoid (tungsten: about 10 % flicker);
- ``rectified``: a discharge lamp on a magnetic ballast follows the rectified supply, its phosphor's afterglow
  filling the troughs (fluorescent: 20–40 %);
- ``clipped``: a cheap LED driver's current follows the rectified supply until its regulator caps it, a flat
  top with deep valleys (20–100 %).

Depth is the *percent flicker* of IES RP-16 and IEEE 1789, ``(max − min) / (max + min)`` of the light; the waveform
is scaled to mean 1, so the ambient's mean spectrum is the one the sim names. The supply is not the nominal
frequency: grids hold ±1 % at most (:data:`MAINS_TOLERANCE`), so the true frequency is drawn within it, and the
phase at the light clock's zero is drawn too; a frame then sees its waveform's mean over its own exposure window
(each row its own, on a rolling shutter), the frames spaced on the lamp's clock as host pacing spaces them, drawn
from the seed (:meth:`acquisition.devices.simulated_camera.SimulatedCamera._mains_start`): a run is reproducible.

This is the simulator's model of the lamp, not the estimator's: the estimate never reads it
(:mod:`processing.flicker` measures each frame's ambient gain from the pixels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from msflash.processing.user_numbers import plain_number

FLICKER_WAVEFORMS = ("sine", "rectified", "clipped")
"""The waveforms the simulated lamp can have (module notes)."""

MAINS_TOLERANCE = 0.01
"""The largest relative departure of the supply from its nominal frequency the sim draws (±1 %)."""

CLIP_CEILING = 0.5
"""``clipped``: the regulator caps the rectified supply at this share of its peak."""

_TABLE = 4096
"""Samples of one period in the cumulative waveform table (window means to ~1e-7)."""


def _shape(waveform: str, x: np.ndarray) -> np.ndarray:
    """One period of the raw waveform over ``x`` in [0, 1) (any offset and scale)."""
    if waveform == "sine":
        return np.cos(2.0 * np.pi * x)
    rectified = np.abs(np.sin(np.pi * x))  # the rectified supply: one hump per flicker period
    if waveform == "rectified":
        return rectified
    if waveform == "clipped":
        return np.minimum(rectified, CLIP_CEILING)
    raise ValueError(f"flicker waveform {waveform!r}; expected one of {', '.join(FLICKER_WAVEFORMS)}")


@dataclass(frozen=True)
class MainsFlicker:
    """A lamp's light over time: ``w(t)``, periodic at ``frequency_hz``, mean 1, percent flicker ``depth``.

    Attributes
    ----------
    frequency_hz
        The true flicker frequency (twice the supply's).
    depth
        Percent flicker, ``(max − min) / (max + min)``, in (0, 1].
    phase
        Where in its period the waveform is at the light clock's zero, in cycles [0, 1).
    nominal_hz
        The frequency asked for (100 or 120 for the mains); ``frequency_hz`` is within :data:`MAINS_TOLERANCE` of it.
    """

    frequency_hz: float
    depth: float
    waveform: str = "sine"
    phase: float = 0.0
    nominal_hz: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.frequency_hz) and self.frequency_hz > 0):
            raise ValueError(f"flicker frequency {self.frequency_hz} Hz; expected a positive frequency")
        if not (math.isfinite(self.depth) and 0.0 < self.depth <= 1.0):
            raise ValueError(f"flicker depth {self.depth}; expected a percent flicker in (0, 1]")
        _shape(self.waveform, np.zeros(1))  # refuses an unknown waveform

    @cached_property
    def _cumulative(self) -> np.ndarray:
        """∫₀ˣ w over one period at ``_TABLE + 1`` points (the last is 1: mean 1)."""
        x = (np.arange(_TABLE) + 0.5) / _TABLE
        raw = _shape(self.waveform, x)
        low, high = float(raw.min()), float(raw.max())
        # w = b + (raw − low) with (high − low) / (2 b + high − low) = depth; then scaled to mean 1.
        offset = ((high - low) / self.depth - (high - low)) / 2.0
        values = offset + raw - low
        values = values / values.mean()
        return np.concatenate([[0.0], np.cumsum(values) / _TABLE])

    def window_means(self, starts_s: np.ndarray, duration_s: float) -> np.ndarray:
        """The mean of ``w`` over ``[t, t + duration]`` for each start ``t`` (the instant's value for 0)."""
        starts = np.asarray(starts_s, dtype=float)
        cumulative = self._cumulative
        grid = np.linspace(0.0, 1.0, _TABLE + 1)

        def integral(cycles: np.ndarray) -> np.ndarray:
            whole = np.floor(cycles)
            return whole + np.interp(cycles - whole, grid, cumulative)

        begin = starts * self.frequency_hz + self.phase
        span = duration_s * self.frequency_hz
        if span <= 1e-9:
            step = 1.0 / _TABLE
            return (integral(begin + step / 2) - integral(begin - step / 2)) / step
        return (integral(begin + span) - integral(begin)) / span

    def __call__(self, row_starts_s: np.ndarray, duration_s: float) -> np.ndarray:
        """:data:`acquisition.devices.exposure_light.AmbientModulation`: each row's mean relative intensity."""
        return self.window_means(row_starts_s, duration_s)

    def to_dict(self) -> dict[str, Any]:
        """What the sequence records as the true flicker (``msflash.true_flicker``)."""
        return {
            "frequency_hz": self.frequency_hz,
            "nominal_hz": self.nominal_hz,
            "depth": self.depth,
            "waveform": self.waveform,
            "phase_cycles": self.phase,
            "clock": "frame timestamp_ns (exposure start of row 0, on the light's clock)",
        }


def parse_flicker(text: str) -> tuple[float, float, str]:
    """``--ambient-flicker HZ:DEPTH[:WAVEFORM]`` as (nominal Hz, depth, waveform); ``ValueError`` naming what is wrong.

    >>> parse_flicker("100:0.3"), parse_flicker("120:1:clipped")
    ((100.0, 0.3, 'sine'), (120.0, 1.0, 'clipped'))
    """
    parts = text.split(":")
    if len(parts) not in (2, 3):
        raise ValueError(f"{text!r}: expected HZ:DEPTH[:WAVEFORM], e.g. 100:0.3 or 120:0.5:rectified")
    try:
        hz, depth = plain_number(parts[0]), plain_number(parts[1])
    except ValueError:
        raise ValueError(f"{text!r}: expected numbers in HZ:DEPTH, e.g. 100:0.3") from None
    if not (math.isfinite(hz) and 1.0 <= hz <= 10_000.0):
        raise ValueError(
            f"{text!r}: frequency {parts[0]}; expected the flicker's Hz (100 on 50 Hz mains, 120 on 60 Hz)"
        )
    if not (math.isfinite(depth) and 0.0 < depth <= 1.0):
        raise ValueError(f"{text!r}: depth {parts[1]}; expected a percent flicker in (0, 1] (0.3 for 30 %)")
    waveform = parts[2].strip().lower() if len(parts) == 3 else "sine"
    if waveform not in FLICKER_WAVEFORMS:
        raise ValueError(f"{text!r}: waveform {parts[2]!r}; expected one of {', '.join(FLICKER_WAVEFORMS)}")
    return hz, depth, waveform


def drawn_flicker(nominal_hz: float, depth: float, waveform: str, seed: int) -> MainsFlicker:
    """The sim's lamp: the true frequency within ±:data:`MAINS_TOLERANCE` of ``nominal_hz`` and the phase drawn from ``seed``."""
    rng = np.random.default_rng([seed, 0x0F11C7E5])
    return MainsFlicker(
        frequency_hz=float(nominal_hz * (1.0 + rng.uniform(-MAINS_TOLERANCE, MAINS_TOLERANCE))),
        depth=float(depth),
        waveform=waveform,
        phase=float(rng.uniform(0.0, 1.0)),
        nominal_hz=float(nominal_hz),
    )
