"""Dark and linearity: black level per channel, read noise, linearity, saturation level.

Public objects
--------------
- :func:`channel_planes`: the pixels of each channel of an RGB frame, a Bayer mosaic or a mono frame.
- :class:`DarkResult`, :func:`measure_dark`: black level, temporal read noise and fixed-pattern
  noise per channel from a series of frames taken with no light.
- :class:`LinearityResult`, :func:`measure_linearity`: response against exposure (times gain) of
  a uniformly lit target, per channel: slope, deviation from linear, the signal up to which the
  sensor is linear within a tolerance, the saturation level, and a polynomial that linearises.

Frames come in as arrays (the acquisition side reads the files); nothing here reads images.

How linearity is judged
-----------------------
The reference line goes through the black level with the small-signal slope (the linear term of
a cubic through the origin fitted to the unsaturated points): a sensor that compresses highlights
is judged against its own small-signal gain, which is what "linear" means for the ratio-based processing of eq.
4–6. The deviation of a point is ``signal / (slope · exposure) − 1``. (EMVA 1288 instead fits a
line over 5–95 % of the range and reports the spread of the residuals, which halves the number
for a smooth compression; both are reported: ``max_relative_deviation`` and
``emva_nonlinearity``.)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from msflash.calibration.errors import CalibrationError
from msflash.processing.sensor import CFA_PATTERNS, cfa_channel_map

LINEARITY_TOLERANCE = 0.01
"""Relative deviation from linear accepted for :attr:`LinearityResult.linear_limit_dn`."""
SATURATED_FRACTION = 0.001
"""A frame with more than this fraction of pixels at the top value of the series counts as saturated."""


def channel_planes(frame: np.ndarray, cfa: str | None = None) -> list[np.ndarray]:
    """The pixel values of each channel: 3 for RGB frames or Bayer mosaics, 1 for mono frames.

    Raises
    ------
    CalibrationError
        For a frame that is neither (H, W) nor (H, W, C), or an unknown CFA.
    """
    frame = np.asarray(frame)
    if frame.ndim == 3:
        return [frame[..., c].ravel() for c in range(frame.shape[2])]
    if frame.ndim != 2:
        raise CalibrationError(f"frame of shape {frame.shape}; expected (H, W) or (H, W, channels)")
    if cfa is None:
        return [frame.ravel()]
    if cfa not in CFA_PATTERNS:
        raise CalibrationError(f"cfa '{cfa}'; expected None or one of {', '.join(CFA_PATTERNS)}")
    channels = cfa_channel_map(cfa, frame.shape)
    return [frame[channels == c] for c in range(3)]


def _stack(frames: Sequence[np.ndarray], what: str) -> np.ndarray:
    if len(frames) == 0:
        raise CalibrationError(f"{what}: no frames; expected a series of at least one frame")
    shapes = {np.shape(f) for f in frames}
    if len(shapes) != 1:
        raise CalibrationError(f"{what}: frames of different shapes {sorted(shapes)}; expected one size")
    stack = np.stack([np.asarray(f, dtype=np.float64) for f in frames])
    if not np.all(np.isfinite(stack)):
        raise CalibrationError(f"{what}: frames hold non-finite values; expected raw pixel values")
    return stack


@dataclass(frozen=True)
class DarkResult:
    """Black level and noise per channel from dark frames."""

    black_level: tuple[float, ...]
    """Mean dark value per channel (R, G, B or one for mono), digital numbers."""
    read_noise_dn: tuple[float, ...]
    """Temporal noise per channel: std of frame-to-frame differences / √2 (needs ≥ 2 frames; else the spatial std)."""
    fixed_pattern_dn: tuple[float, ...]
    """Spatial std of the mean dark frame per channel (offset non-uniformity plus residual temporal noise)."""
    hot_pixel_fraction: float
    """Fraction of pixels whose mean dark value exceeds the channel's black level by 10 read-noise σ."""
    n_frames: int
    """Frames used."""

    def as_dict(self) -> dict:
        """The ``dark`` section of a calibration file."""
        return {
            "black_level": list(self.black_level),
            "read_noise_dn": list(self.read_noise_dn),
            "fixed_pattern_dn": list(self.fixed_pattern_dn),
            "hot_pixel_fraction": self.hot_pixel_fraction,
            "n_frames": self.n_frames,
        }


def measure_dark(frames: Sequence[np.ndarray], cfa: str | None = None) -> DarkResult:
    """Black level, read noise and fixed-pattern noise per channel from frames taken without light.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> frames = [np.round(64 + rng.normal(0, 2, (40, 40, 3))) for _ in range(4)]
    >>> r = measure_dark(frames)
    >>> [round(b) for b in r.black_level], [round(n) for n in r.read_noise_dn]
    ([64, 64, 64], [2, 2, 2])
    """
    stack = _stack(frames, "dark frames")
    mean_frame = stack.mean(axis=0)
    mean_planes = channel_planes(mean_frame, cfa)
    black = [float(np.mean(p)) for p in mean_planes]
    if stack.shape[0] >= 2:
        differences = [channel_planes(stack[i + 1] - stack[i], cfa) for i in range(stack.shape[0] - 1)]
        noise = [float(np.sqrt(np.mean([np.var(d[c]) for d in differences]) / 2)) for c in range(len(black))]
    else:
        noise = [float(np.std(p)) for p in mean_planes]
    pattern = [float(np.std(p)) for p in mean_planes]
    flat = [c for c in range(len(black)) if noise[c] == 0 and pattern[c] == 0]
    if flat:
        value = black[flat[0]]
        raise CalibrationError(
            f"dark frames: channel {flat[0]} holds the one value {value:g} in every pixel of every frame; expected "
            "the sensor's noise about its black level — the frames are clipped (at 0 or at saturation) or not the "
            "camera's raw output"
        )
    hot = sum(int(np.count_nonzero(p > b + 10 * max(n, 0.5))) for p, b, n in zip(mean_planes, black, noise))
    return DarkResult(tuple(black), tuple(noise), tuple(pattern), hot / mean_frame.size, int(stack.shape[0]))


@dataclass(frozen=True)
class LinearityResult:
    """Response against exposure of a uniformly lit target, per channel."""

    exposures: tuple[float, ...]
    """Exposure · gain of each frame (the x axis), sorted."""
    signals_dn: tuple[tuple[float, ...], ...]
    """Mean black-subtracted signal per frame (rows) and channel (columns); NaN for a saturated frame."""
    slope_dn_per_exposure: tuple[float, ...]
    """Small-signal slope per channel."""
    deviation: tuple[tuple[float, ...], ...]
    """``signal / (slope · exposure) − 1`` per frame and channel (NaN for saturated frames)."""
    max_relative_deviation: float
    """Largest |deviation| over unsaturated frames and channels."""
    emva_nonlinearity: float
    """EMVA 1288 style: half the spread of the residuals of a free line fit over 5–95 %, relative to the fitted top."""
    linear_limit_dn: float | None
    """Highest black-subtracted signal up to which every channel stays within :data:`LINEARITY_TOLERANCE`."""
    saturation_level: float | None
    """Raw value at which pixels clip (the top value of the series when it is reached by many pixels), else None."""
    saturated_frames: tuple[int, ...]
    """Indices (in sorted order) of frames excluded because they clip."""
    linearisation: tuple[tuple[float, ...], ...]
    """Per channel, polynomial coefficients (highest power first, ``np.polyval``) mapping a
    measured black-subtracted signal to the linear one."""

    def as_dict(self) -> dict:
        """The ``linearity`` section of a calibration file."""
        return {
            "slope_dn_per_exposure": list(self.slope_dn_per_exposure),
            "max_relative_deviation": self.max_relative_deviation,
            "emva_nonlinearity": self.emva_nonlinearity,
            "linear_limit_dn": self.linear_limit_dn,
            "saturation_level": self.saturation_level,
            "linearisation": [list(c) for c in self.linearisation],
            "exposures": list(self.exposures),
            "signals_dn": [[None if math.isnan(v) else v for v in row] for row in self.signals_dn],
        }


def measure_linearity(
    frames: Sequence[np.ndarray],
    exposures: Sequence[float],
    black_level: Sequence[float] | float,
    cfa: str | None = None,
    white_level: float | None = None,
) -> LinearityResult:
    """Linearity and saturation of a sensor from frames of a uniform target at several exposures.

    Parameters
    ----------
    frames
        Raw frames, all the same shape.
    exposures
        Exposure time · gain of each frame (any unit; the slope is per that unit).
    black_level
        Per channel (from :func:`measure_dark`) or one number.
    cfa
        Bayer layout of mosaic frames, or None.
    white_level
        Known clip value; by default it is detected from the series.

    Raises
    ------
    CalibrationError
        For fewer than 3 frames, mismatched lengths, non-positive exposures, or fewer than 2
        unsaturated frames with signal.
    """
    stack, exposures_array = _exposure_series(frames, exposures)
    n_channels = len(channel_planes(stack[0], cfa))
    blacks = (
        np.broadcast_to(np.asarray(black_level, dtype=float), (n_channels,))
        if np.ndim(black_level)
        else np.full(n_channels, float(np.asarray(black_level)))
    )
    if blacks.shape != (n_channels,):
        raise CalibrationError(f"linearity: {blacks.size} black levels for {n_channels} channels")
    clip = white_level
    if clip is None:
        top = float(stack.max())
        clip = top if np.mean(stack[-1] >= top) > SATURATED_FRACTION else None
    signals, saturated = _unsaturated_signals(stack, cfa, blacks, clip)
    usable = ~np.isnan(signals[:, 0])
    if np.count_nonzero(usable) < 2 or np.nanmax(signals) <= 0:
        raise CalibrationError(
            f"linearity: {np.count_nonzero(usable)} unsaturated frames with signal; expected at least 2 — "
            "shorten the longest exposures or dim the target"
        )
    distinct = np.unique(exposures_array[usable])
    if distinct.size < 2:
        # One abscissa: the slope fit is degenerate (numpy RankWarnings, 'deviation 2.0, linear up to 0 DN').
        raise CalibrationError(
            f"linearity: every unsaturated frame has exposure·gain {distinct[0]:g}; expected at least 2 different "
            "exposures of the same target"
        )
    slopes, deviations, polys = [], np.full_like(signals, np.nan), []
    limit = math.inf
    emva = 0.0
    for c in range(n_channels):
        channel = _ChannelLinearity.fit(exposures_array[usable], signals[usable, c], min(3, distinct.size - 1))
        slopes.append(channel.slope)
        deviations[usable, c] = channel.deviation
        limit = min(limit, channel.linear_limit)
        emva = max(emva, channel.emva_nonlinearity)
        polys.append(channel.linearisation)
    finite = deviations[~np.isnan(deviations)]
    return LinearityResult(
        exposures=tuple(float(v) for v in exposures_array),
        signals_dn=tuple(tuple(float(v) for v in row) for row in signals),
        slope_dn_per_exposure=tuple(slopes),
        deviation=tuple(tuple(float(v) for v in row) for row in deviations),
        max_relative_deviation=float(np.max(np.abs(finite))),
        emva_nonlinearity=emva,
        linear_limit_dn=None if not math.isfinite(limit) else limit,
        saturation_level=None if clip is None else float(clip),
        saturated_frames=tuple(saturated),
        linearisation=tuple(polys),
    )


def _exposure_series(frames: Sequence[np.ndarray], exposures: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """The frames stacked and sorted by exposure, with their exposures: at least 3, finite and > 0."""
    stack = _stack(frames, "linearity frames")
    exposures_array = np.asarray(exposures, dtype=float)
    if exposures_array.shape != (stack.shape[0],):
        raise CalibrationError(
            f"linearity: {exposures_array.size} exposures for {stack.shape[0]} frames; expected one exposure per frame"
        )
    if stack.shape[0] < 3:
        raise CalibrationError(f"linearity: {stack.shape[0]} frames; expected at least 3 exposures")
    if not np.all(np.isfinite(exposures_array)) or np.any(exposures_array <= 0):
        raise CalibrationError("linearity: exposures must be finite and > 0")
    order = np.argsort(exposures_array, kind="stable")
    return stack[order], exposures_array[order]


def _unsaturated_signals(
    stack: np.ndarray, cfa: str | None, blacks: np.ndarray, clip: float | None
) -> tuple[np.ndarray, list[int]]:
    """Mean signal above black per frame and channel (NaN for saturated frames), and the saturated frames."""
    signals = np.full((stack.shape[0], len(blacks)), np.nan)
    saturated: list[int] = []
    for i, frame in enumerate(stack):
        planes = channel_planes(frame, cfa)
        if clip is not None and np.mean(frame >= clip) > SATURATED_FRACTION:
            saturated.append(i)
            continue
        signals[i] = [float(np.mean(p)) - b for p, b in zip(planes, blacks)]
    return signals, saturated


@dataclass(frozen=True)
class _ChannelLinearity:
    """One channel's small-signal slope, deviation from it, linear limit, EMVA non-linearity and linearisation."""

    slope: float
    deviation: np.ndarray
    linear_limit: float
    emva_nonlinearity: float
    linearisation: tuple[float, ...]

    @classmethod
    def fit(cls, x: np.ndarray, y: np.ndarray, degree: int) -> _ChannelLinearity:
        """Fit signals ``y`` at exposures ``x`` (unsaturated frames)."""
        # Small-signal slope: the linear term of a polynomial through the origin (black level),
        # so a smooth compression of the highlights does not bend the reference line.
        powers = np.column_stack([x ** (p + 1) for p in range(degree)]) / x.max() ** np.arange(1, degree + 1)
        slope = float(np.linalg.lstsq(powers, y, rcond=None)[0][0] / x.max())
        deviation = y / (slope * x) - 1
        bad = np.abs(deviation) > LINEARITY_TOLERANCE
        if bad.any():
            below = y[y < y[bad].min()]
            limit = float(below.max()) if below.size else 0.0
        else:
            limit = float(y.max())
        emva = 0.0
        span = (y >= 0.05 * y.max()) & (y <= 0.95 * y.max())
        if np.count_nonzero(span) >= 2:
            fitted = np.polyfit(x[span], y[span], 1)
            residual = y[span] - np.polyval(fitted, x[span])
            emva = float((residual.max() - residual.min()) / 2 / np.polyval(fitted, x[span]).max())
        return cls(slope, deviation, limit, emva, tuple(float(v) for v in np.polyfit(y, slope * x, degree)))
