"""Find a chart of rows × columns uniform patches in a sequence's frames, with no layout given.

Public objects
--------------
- :class:`ChartGrid`: a detected chart — the centre of patch 1, the steps to the next column and
  row of the chart (pixels), the patch size, rotation, mirroring and the image corner of patch 1 —
  and its label map (:meth:`ChartGrid.labels`, the map :mod:`calibration.chart_sequence` and
  ``msflash evaluate`` consume).
- :func:`detect_chart`: the grid in linear frames (RGB or a Bayer mosaic).
- :func:`detect_in_sequence`: the same on a format-v1 sequence's ambient and LED frames.
- :class:`ChartDetectionError`: no chart, two charts, patches too small or blurred, or colours
  that are not the chart's.

The steps live beside it, one module each: the grid (:mod:`calibration.chart_grid`), planes and
uniform regions (:mod:`calibration.chart_regions`), the lattice (:mod:`calibration.chart_lattice`)
and the placement (:mod:`calibration.chart_placement`).

Method
------
All frames are stacked as channels (a Bayer mosaic as its four per-site planes at half resolution,
large frames binned, :data:`calibration.chart_regions.DETECTION_MAX_SIDE`); then 1. uniform regions
(neighbours linked by a noise-normalised χ² test, :data:`calibration.chart_regions.LINK_FALSE_CUT`),
2. patch candidates (filled rectangles of a common size), 3. the lattice (an affine grid fitted to
their centres, :data:`MIN_OCCUPANCY` of the patches found), 4. the placement (which corner is patch
1, :func:`calibration.chart_placement.placement_misfit` against :data:`COLOUR_MISFIT` and
:data:`AMBIGUITY_RATIO`). Each step, its thresholds and the references: ``docs/calibration.md``
("Chart detection"). The caller still checks the label map like a given layout (``check_layout``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from msflash.calibration.chart_grid import ChartDetectionError, ChartGrid
from msflash.calibration.chart_lattice import _lattices
from msflash.calibration.chart_placement import (
    COLOUR_MISFIT,
    MIN_COLOUR_SNR,
    ColourFrames,
    _charts_on,
    _patch_fraction,
)
from msflash.calibration.chart_regions import _detection_planes, _rectangular_regions, uniform_regions
from msflash.processing.spectra import Spectra

MIN_OCCUPANCY = 0.75
"""Fewest chart patches that must be found as regions (the rest may merge with the border)."""
AMBIGUITY_RATIO = 2.0
"""The best placement's misfit must be this many times smaller than the runner-up's."""


def detect_chart(
    images: Sequence[np.ndarray],
    excluded: np.ndarray,
    cfa: str | None,
    colour: ColourFrames,
    reflectances: Spectra,
    rows: int,
    columns: int,
    where: str = "frames",
    quanta: Sequence[float] | None = None,
) -> ChartGrid:
    """The single rows × columns chart of ``reflectances`` in linear frames of one geometry.

    Parameters
    ----------
    images
        Linear frames (H, W, 3) or Bayer mosaics (H, W), all of the same scene.
    excluded
        Pixels to ignore (saturated in some frame), bool (H, W).
    colour
        The frames and lights of the orientation test.
    reflectances
        The chart's patches in chart order (column by column), on the lights' grid.
    quanta
        Per image, the linear value of one raw step (``1 / (exposure · gain)``), or None for
        unquantised frames.

    Raises
    ------
    ChartDetectionError
        No chart (or one too small or blurred to show uniform patches), a grid of another size,
        two charts, colours that are not the chart's, or an orientation the colours cannot tell.
    """
    _check_request(reflectances, colour, rows, columns, where)
    advice = (
        "; expected one chart in view, in focus, with patches of ≥ 4 pixels (8 on a Bayer mosaic) — or give "
        "its layout with --patch-px/--border-px (chart at the top-left)"
    )
    planes = _detection_planes(images, excluded, cfa, quanta)
    candidates = _rectangular_regions(uniform_regions(planes.values, planes.excluded, planes.floor))
    minimum = math.ceil(MIN_OCCUPANCY * rows * columns)
    lattices = _lattices(candidates, minimum)
    if not lattices:
        raise ChartDetectionError(
            f"{where}: no {rows}×{columns} chart found: fewer than {minimum} uniform, equally "
            f"sized, rectangular regions on a lattice{advice}"
        )
    predicted = reflectances.values.T @ colour.lights.to_unit("photons").values  # (patches, LED frames)
    grids, misfits, extents, weak = [], [], [], math.inf
    for lattice, members in lattices:
        fraction = _patch_fraction(candidates, members, lattice.basis)
        found, best, noisy = _charts_on(planes, lattice, fraction, colour, predicted, rows, columns, minimum)
        grids += found
        misfits.append(best)
        weak = min(weak, noisy)
        extents.append(lattice.sites.max(axis=0)[::-1] + 1)
    if len(grids) > 1:
        places = " and ".join(f"({g.origin_xy[0]:.0f}, {g.origin_xy[1]:.0f})" for g in grids)
        raise ChartDetectionError(
            f"{where}: {len(grids)} {rows}×{columns} charts found, patch 1 at {places}; "
            "expected one chart in view (or give the layout with --patch-px/--border-px)"
        )
    if not grids:
        raise ChartDetectionError(f"{where}: no {rows}×{columns} chart found: {_seen(misfits, extents, weak)}{advice}")
    grid = grids[0]
    if not grid.runner_up_misfit >= AMBIGUITY_RATIO * grid.misfit:
        raise ChartDetectionError(
            f"{where}: the chart's orientation is ambiguous: two placements fit its colours "
            f"(misfit {grid.misfit:.3f} and {grid.runner_up_misfit:.3f}){advice}"
        )
    return grid


def _check_request(reflectances: Spectra, colour: ColourFrames, rows: int, columns: int, where: str) -> None:
    """Refuse a chart whose patch count is not rows × columns, or frames without an LED frame."""
    if reflectances.count != rows * columns:
        raise ChartDetectionError(
            f"{where}: the chart has {reflectances.count} patches; expected rows × columns = {rows}×{columns}"
        )
    if not colour.leds:
        raise ChartDetectionError(
            f"{where}: no LED frame; chart detection needs LED frames to tell the chart's "
            "orientation (give --patch-px/--border-px)"
        )


def _seen(misfits: list[float], extents: list[np.ndarray], weak: float) -> str:
    """What was seen instead of a chart: the closest grid, why its colours were refused."""
    which = int(np.argmin(misfits))
    extent = "×".join(map(str, extents[which]))
    if math.isfinite(misfits[which]):
        return (
            f"a grid of {extent} uniform patches whose colours under the LEDs do not match the chart's in "
            f"any placement (misfit {misfits[which]:.2f} > {COLOUR_MISFIT})"
        )
    if math.isfinite(weak):
        return (
            f"a grid of {extent} uniform patches, but the LED frames minus the ambient are too noisy to tell "
            f"its colours (signal {weak:.1f}× the noise, expected ≥ {MIN_COLOUR_SNR:g}×: dim the ambient or "
            "lengthen the LED exposures)"
        )
    return f"a grid of {extent} uniform patches that does not hold the whole chart inside the frames"


def detect_in_sequence(sequence: Any, reflectances: Spectra, rows: int, columns: int) -> ChartGrid:
    """:func:`detect_chart` on a format-v1 sequence's ambient and LED frames (linearised).

    ``sequence`` is an :class:`acquisition.sequence.format.Sequence` (its ``frames``,
    ``load_frame``, ``camera``, ``indices``, ``led_spectra`` and ``path``).
    """
    where = str(sequence.path)
    ambient_indices, led_indices = sequence.indices("ambient"), sequence.indices("led")
    if not ambient_indices:
        raise ChartDetectionError(
            f"{where}: no 'ambient' frame; chart detection compares the LED frames with it "
            "(or give the layout with --patch-px/--border-px)"
        )
    indices = [ambient_indices[0], *led_indices]
    images, excluded, quanta = [], None, []
    for index in indices:
        frame = sequence.frames[index]
        image, saturated = sequence.load_linear_frame(index)
        images.append(image)
        quanta.append(1.0 / (frame.exposure_us * frame.gain))
        excluded = saturated if excluded is None else excluded | saturated
    assert excluded is not None  # the ambient frame's mask at least
    leds = sequence.led_spectra()
    levels = np.array([sequence.frames[i].led_levels for i in led_indices], dtype=float).reshape(len(led_indices), -1)
    lights = leds.replace(values=leds.values @ levels.T, names=tuple(str(sequence.frames[i].file) for i in led_indices))
    colour = ColourFrames(0, tuple(range(1, len(indices))), lights)
    return detect_chart(images, excluded, sequence.camera.cfa, colour, reflectances, rows, columns, where, quanta)
