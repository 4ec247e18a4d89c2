"""The camera's view of a white reference under each LED: the LEDs' true power ratios.

A spectrometer measures each LED's *shape* well, but the ratios between LEDs it reports depend on
where its probe sat. What the flash needs is the ratio at the scene, as the camera sees it. A
sequence of a white (or any spectrally neutral, uniform) reference — one ``ambient`` frame and
``led`` frames — gives, over a region of interest, each LED's linear camera response ``m_k`` at
full drive; :func:`calibration.led_spectra.relative_power_through_camera` turns them into power
factors.

Public objects
--------------
- :class:`WhiteResponses`, :func:`white_led_responses`: the per-LED responses of the reference
  and how uniform it looked.
- :func:`parse_roi`: ``X,Y,W,H`` of the command line.

Checks (each a :class:`~calibration.errors.CalibrationError` naming the sequence and frame):
no ambient or LED frames, LED levels that do not separate the LEDs, a region outside the frame,
more than half the region saturated, an LED whose response is within 3 standard errors of zero,
and a region that is not a uniform neutral reference. On a neutral target each LED's *share* of
the LEDs' total light is the same everywhere, whatever the overall falloff; on coloured surfaces
(a chart, a scene) it changes from surface to surface (a red patch returns more of the red
LED). The spread of each share over the region's sub-blocks
(:attr:`WhiteResponses.share_spread`, noise removed) must stay below :data:`MAX_SHARE_SPREAD`;
above :data:`SHARE_WARNING` the ratios are said to hold for this position only (LEDs at different
places in the booth light the reference unevenly). A narrowband LED's colour (channel ratios)
would not do: it hardly depends on the surface.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from msflash.calibration.chart_sequence import patch_statistics
from msflash.calibration.errors import CalibrationError
from msflash.processing.user_numbers import plain_whole_number

SUB_BLOCKS = 8
"""The region is split into ``SUB_BLOCKS × SUB_BLOCKS`` sub-blocks for the uniformity checks."""
MAX_SHARE_SPREAD = 0.08
"""Largest relative spread of an LED's share of the light over the sub-blocks: above it the region
is not a uniform neutral reference (``docs/measurements.md``)."""
SHARE_WARNING = 0.02
"""Share spread above which the ratios are said to depend on the reference's position."""
MIN_SIGNIFICANCE = 3.0
"""An LED's summed response must exceed this many standard errors."""


@dataclass(frozen=True)
class WhiteResponses:
    """Linear responses of a white reference to each LED at full drive (per µs · gain)."""

    responses: np.ndarray
    """(k, channels) mean over the region, LED frame minus ambient, unmixed to one LED at level 1."""
    std: np.ndarray
    """(k, channels) their standard errors."""
    led_names: tuple[str, ...]
    roi: tuple[int, int, int, int]
    """x, y, width, height in pixels."""
    pixels: int
    """Unsaturated pixels used (smallest over the frames)."""
    share_spread: tuple[float, ...]
    """Per LED: relative spread of its share of the LEDs' total light over the sub-blocks (noise removed)."""
    warnings: tuple[str, ...]

    def report(self) -> dict[str, Any]:
        """A JSON-ready summary."""
        return {
            "roi_xywh": list(self.roi),
            "pixels": self.pixels,
            "share_spread": dict(zip(self.led_names, self.share_spread, strict=True)),
            "responses": self.responses.tolist(),
            "warnings": list(self.warnings),
        }


def parse_roi(text: str) -> tuple[int, int, int, int]:
    """``"X,Y,W,H"`` → a tuple of ints (x, y ≥ 0; w, h ≥ 2).

    >>> parse_roi("10, 20, 64, 48")
    (10, 20, 64, 48)
    """
    parts = [p.strip() for p in text.split(",")]
    try:
        values = tuple(plain_whole_number(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4 or values[0] < 0 or values[1] < 0 or values[2] < 2 or values[3] < 2:
        raise CalibrationError(f"--white-roi '{text}': expected X,Y,W,H in pixels (X, Y ≥ 0; W, H ≥ 2)")
    return values


def _default_roi(height: int, width: int) -> tuple[int, int, int, int]:
    """The central half of the frame in each direction."""
    return width // 4, height // 4, max(width // 2, 2), max(height // 2, 2)


def _sub_block_labels(shape: tuple[int, int], roi: tuple[int, int, int, int]) -> np.ndarray:
    """(H, W) labels: ``SUB_BLOCKS × SUB_BLOCKS`` sub-blocks of the region numbered row by row, −1 outside it."""
    x, y, w, h = roi
    labels = np.full(shape, -1, dtype=int)
    for i, rows in enumerate(np.array_split(np.arange(y, y + h), SUB_BLOCKS)):
        for j, columns in enumerate(np.array_split(np.arange(x, x + w), SUB_BLOCKS)):
            labels[np.ix_(rows, columns)] = i * SUB_BLOCKS + j
    return labels


def white_led_responses(sequence: Any, roi: tuple[int, int, int, int] | None = None) -> WhiteResponses:
    """Each LED's linear response on a white reference recorded as a format-v1 sequence.

    Parameters
    ----------
    sequence
        An :class:`acquisition.sequence.format.Sequence` with an ``ambient`` frame and ``led``
        frames whose levels separate the LEDs (one LED per frame is the usual case; any levels of
        full column rank are unmixed by least squares).
    roi
        x, y, width, height of the reference in the frame; default the central half.

    Raises
    ------
    CalibrationError
        See the module notes.
    """
    where = str(sequence.path)
    led_indices, names, levels = _led_frames(sequence, where)
    ambient, ambient_saturated = sequence.load_linear_frame(sequence.indices("ambient")[0])
    height, width = ambient.shape[:2]
    roi = roi if roi is not None else _default_roi(height, width)
    x, y, w, h = roi
    if x + w > width or y + h > height:
        raise CalibrationError(
            f"{where}: --white-roi {x},{y},{w},{h} reaches outside the {width}×{height} frame; "
            "expected X+W ≤ width and Y+H ≤ height"
        )
    frame_means, frame_errors, block_means, smallest = _frame_means(
        sequence, led_indices, ambient, ambient_saturated, roi
    )
    unmixing = np.linalg.pinv(levels)  # (k, frames)
    responses = unmixing @ frame_means
    std = np.sqrt((unmixing**2) @ frame_errors**2)
    for k, name in enumerate(names):
        total, total_std = responses[k].sum(), np.sqrt(np.sum(std[k] ** 2))
        if not total > MIN_SIGNIFICANCE * total_std:
            raise CalibrationError(
                f"{where}: LED '{name}' adds {total:.3g} ± {total_std:.2g} on the white reference; "
                f"expected a response above {MIN_SIGNIFICANCE:g} standard errors (is it on? "
                "is the exposure long enough?)"
            )
    per_block = np.einsum("kf,fbc->kbc", unmixing, block_means)  # (k, blocks, channels)
    spread = _share_spread(per_block, std, SUB_BLOCKS * SUB_BLOCKS)
    worst = int(np.argmax(spread))
    if spread[worst] > MAX_SHARE_SPREAD:
        raise CalibrationError(
            f"{where}: in the region {x},{y},{w},{h} LED '{names[worst]}''s share of the light "
            f"varies {100 * spread[worst]:.0f} % (> {100 * MAX_SHARE_SPREAD:.0f} %); expected a "
            "uniform, neutral white reference there (choose it with --white-roi X,Y,W,H)"
        )
    warnings = tuple(
        f"{where}: LED '{name}' lights the reference unevenly relative to the others (its share varies "
        f"{100 * value:.1f} % over the region): its ratio holds for this position only"
        for name, value in zip(names, spread, strict=True)
        if value > SHARE_WARNING
    )
    return WhiteResponses(responses, std, names, (x, y, w, h), int(smallest), spread, warnings)


def _led_frames(sequence: Any, where: str) -> tuple[list[int], tuple[str, ...], np.ndarray]:
    """The LED frames, the LEDs' names and the frames' levels (which must separate the LEDs); an ambient frame."""
    ambient_indices = sequence.indices("ambient")
    led_indices = sequence.indices("led")
    if not ambient_indices or not led_indices:
        raise CalibrationError(
            f"{where}: the white reference needs an 'ambient' frame and 'led' frames; found "
            f"{len(ambient_indices)} and {len(led_indices)}"
        )
    names = tuple(led.name for led in sequence.leds)
    levels = np.array([sequence.frames[i].led_levels for i in led_indices], dtype=float)
    if np.linalg.matrix_rank(levels) < len(names):
        raise CalibrationError(
            f"{where}: the 'led' frames' led_levels (rank {np.linalg.matrix_rank(levels)}) do "
            f"not separate the {len(names)} LEDs; expected a frame per LED"
        )
    return list(led_indices), names, levels


def _frame_means(
    sequence: Any,
    led_indices: list[int],
    ambient: np.ndarray,
    ambient_saturated: np.ndarray,
    roi: tuple[int, int, int, int],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Per LED frame minus the ambient over the region: the means and errors per channel, the sub-blocks'
    means, and the fewest samples a channel had."""
    where = str(sequence.path)
    height, width = ambient.shape[:2]
    x, y, w, h = roi
    roi_mask = np.zeros((height, width), dtype=bool)
    roi_mask[y : y + h, x : x + w] = True
    block_labels = _sub_block_labels((height, width), roi)
    cfa = sequence.camera.cfa
    frame_means, frame_errors, block_means, smallest = [], [], [], roi_mask.sum()
    for i in led_indices:
        image, saturated = sequence.load_linear_frame(i)
        usable = roi_mask & ~saturated & ~ambient_saturated
        if usable.sum() < 0.5 * roi_mask.sum():
            raise CalibrationError(
                f"{where}: {sequence.frames[i].file}: {100 * (1 - usable.sum() / roi_mask.sum()):.0f} % "
                "of the white reference's region is saturated; expected a shorter exposure or a "
                "lower LED level"
            )
        difference = image - ambient
        means, errors, counts = patch_statistics(difference, np.where(usable, 0, -1), 1, cfa)
        smallest = min(smallest, int(counts[0]))
        frame_means.append(means[0])
        frame_errors.append(errors[0])
        n_blocks = SUB_BLOCKS * SUB_BLOCKS
        block_means.append(patch_statistics(difference, np.where(usable, block_labels, -1), n_blocks, cfa)[0])
    return np.array(frame_means), np.array(frame_errors), np.array(block_means), int(smallest)


def _share_spread(per_block: np.ndarray, std: np.ndarray, n_blocks: int) -> tuple[float, ...]:
    """Per LED: relative spread of its share of the LEDs' light over the sub-blocks, noise removed.

    ``per_block`` is (k, blocks, channels); a sub-block's relative standard error is about
    ``√n_blocks`` times the region's (``std``), and that much spread is taken as noise.
    """
    totals = per_block.sum(axis=2)  # (k, b)
    valid = np.all(np.isfinite(totals), axis=0) & np.all(totals > 0, axis=0)
    if valid.sum() < 2:
        return tuple(0.0 for _ in range(per_block.shape[0]))
    totals = totals[:, valid]
    share = totals / totals.sum(axis=0)
    relative_noise = np.sqrt(n_blocks) * np.sqrt(np.sum(std**2, axis=1)) / totals.mean(axis=1)
    relative_spread = share.std(axis=1, ddof=1) / share.mean(axis=1)
    return tuple(float(v) for v in np.sqrt(np.clip(relative_spread**2 - relative_noise**2, 0, None)))
