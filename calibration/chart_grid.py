"""A detected chart's grid: where patch 1 is, the steps to the next column and row, and its label map.

Public objects
--------------
- :class:`ChartGrid`: the grid in full-resolution pixels and its label map (:meth:`ChartGrid.labels`,
  the map :mod:`calibration.chart_sequence` and ``msflash evaluate`` consume).
- :data:`MACBETH_GRID`; :class:`ChartDetectionError`, raised by :mod:`calibration.chart_detection`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from msflash.calibration.errors import CalibrationError
from msflash.processing.colour_metrics import usable_labels

MACBETH_GRID = (4, 6)
"""Rows × columns of the Macbeth chart, patches numbered column by column (ISET order, as
:func:`processing.scenes.chart_scene` lays it out)."""


class ChartDetectionError(CalibrationError):
    """No single chart could be found; the message says why and which layout options to give."""


# -- the detected grid ------------------------------------------------------------------------
@dataclass(frozen=True)
class ChartGrid:
    """A detected chart in full-resolution pixel coordinates (x right, y down, pixel centres integer).

    Examples
    --------
    >>> grid = ChartGrid(4, 6, (5.5, 5.5), (10.0, 0.0), (0.0, 10.0), (0.8, 0.8), 0.004, 0.44, 24)
    >>> grid.corner, grid.rotation_deg, grid.mirrored
    ('top-left', 0.0, False)
    >>> int(grid.labels((46, 62))[5, 5]), int(grid.labels((46, 62))[15, 5]), int(grid.labels((46, 62))[0, 0])
    (0, 1, -1)
    """

    rows: int
    columns: int
    origin_xy: tuple[float, float]
    """Centre of patch 1 (chart row 0, column 0)."""
    column_step_xy: tuple[float, float]
    """From a patch to the next column of the chart."""
    row_step_xy: tuple[float, float]
    """From a patch to the next row of the chart."""
    patch_fraction: tuple[float, float]
    """Patch size as a fraction of the column and row pitch."""
    misfit: float
    """Relative colour misfit of this placement (:func:`calibration.chart_placement.placement_misfit`)."""
    runner_up_misfit: float
    """That of the next best placement (inf if there was none)."""
    found_patches: int
    """Patches found as uniform regions (the rest were placed by the lattice)."""

    @property
    def pitch_px(self) -> tuple[float, float]:
        """Lengths of the column and row steps."""
        return (float(np.hypot(*self.column_step_xy)), float(np.hypot(*self.row_step_xy)))

    @property
    def rotation_deg(self) -> float:
        """Angle of the column step from the +x axis, counter-clockwise as displayed."""
        return math.degrees(math.atan2(-self.column_step_xy[1], self.column_step_xy[0])) + 0.0  # no −0

    @property
    def mirrored(self) -> bool:
        """True if the chart is seen mirrored (rows run counter-clockwise from the columns)."""
        return bool(np.linalg.det(self._basis()) < 0)

    @property
    def corner(self) -> str:
        """The chart corner where patch 1 lies, named by the image's sides (e.g. ``top-left``)."""
        centre = self.centre_xy
        vertical = "top" if self.origin_xy[1] < centre[1] else "bottom"
        horizontal = "left" if self.origin_xy[0] < centre[0] else "right"
        return f"{vertical}-{horizontal}"

    @property
    def centre_xy(self) -> tuple[float, float]:
        """Centre of the chart."""
        middle = self._basis() @ np.array([(self.columns - 1) / 2, (self.rows - 1) / 2]) + np.asarray(self.origin_xy)
        return (float(middle[0]), float(middle[1]))

    def _basis(self) -> np.ndarray:
        return np.column_stack([self.column_step_xy, self.row_step_xy]).astype(float)

    def labels(self, shape: tuple[int, int], margin_px: int = 1, excluded: np.ndarray | None = None) -> np.ndarray:
        """Patch index of every usable pixel (−1 elsewhere), like a given layout's label map.

        A pixel belongs to a patch if it lies within the patch's size around its centre (in the
        lattice's own coordinates, so a rotated or sheared patch stays one); pixels within
        ``margin_px`` of another patch, the border or an ``excluded`` pixel are dropped
        (:func:`processing.colour_metrics.usable_labels`).
        """
        usable = usable_labels(_patch_map(self, (int(shape[0]), int(shape[1]))), margin_px, excluded)
        usable[usable >= self.rows * self.columns] = -1
        return usable

    def as_dict(self) -> dict[str, Any]:
        """The layout as reported in JSON output."""
        return {
            "rows": self.rows,
            "columns": self.columns,
            "origin_xy": list(self.origin_xy),
            "column_step_xy": list(self.column_step_xy),
            "row_step_xy": list(self.row_step_xy),
            "pitch_px": list(self.pitch_px),
            "patch_px": [f * p for f, p in zip(self.patch_fraction, self.pitch_px, strict=True)],
            "rotation_deg": self.rotation_deg,
            "mirrored": self.mirrored,
            "corner": self.corner,
            "found_patches": self.found_patches,
            "colour_misfit": self.misfit,
            "runner_up_misfit": self.runner_up_misfit if math.isfinite(self.runner_up_misfit) else None,
        }

    def describe(self) -> str:
        """One line for reports."""
        return (
            f"{self.rows}×{self.columns} chart detected: patch 1 at ({self.origin_xy[0]:.1f}, "
            f"{self.origin_xy[1]:.1f}) px, {self.corner} corner, pitch {self.pitch_px[0]:.1f}×{self.pitch_px[1]:.1f} "
            f"px, rotated {round(self.rotation_deg, 1) + 0.0:.1f}°"  # + 0.0: no "-0.0°" for round-off
            + (", mirrored" if self.mirrored else "")
        )


@lru_cache(maxsize=8)
def _patch_map(grid: ChartGrid, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) patch index of every pixel within its patch's size around the centre (rows·columns
    elsewhere), before margins and exclusions; read-only and kept, since a sequence's label
    maps (one per frame) differ only in their excluded pixels."""
    n_patches = grid.rows * grid.columns
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]]
    offsets = np.stack([x.ravel() - grid.origin_xy[0], y.ravel() - grid.origin_xy[1]])
    column, row = np.linalg.solve(grid._basis(), offsets)
    nearest_column, nearest_row = np.rint(column), np.rint(row)
    inside = (
        (np.abs(column - nearest_column) < grid.patch_fraction[0] / 2)
        & (np.abs(row - nearest_row) < grid.patch_fraction[1] / 2)
        & (nearest_column >= 0)
        & (nearest_column < grid.columns)
        & (nearest_row >= 0)
        & (nearest_row < grid.rows)
    )
    full = np.where(inside, nearest_column * grid.rows + nearest_row, n_patches).astype(np.int64).reshape(shape)
    full.flags.writeable = False
    return full
