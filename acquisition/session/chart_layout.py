"""Which pixels of a chart sequence belong to which chart patch: given (the sim rig's layout) or detected.

A sequence does not record its chart layout. :func:`sequence_layout` detects the chart
(:mod:`msflash.calibration.chart_detection`: anywhere in the frames, any scale, a small rotation,
either orientation, RGB or Bayer) unless a patch and border size are given, in which case
:func:`chart_layout` rebuilds the sim rig's chart at the top-left pixel. :func:`check_layout` then
tests that the label map fits the ambient image. ``msflash evaluate`` and ``msflash calibrate
camera --sequence`` both find their patches here (one source of truth for the layout options).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from msflash.acquisition.errors import UsageError
from msflash.acquisition.sequence.format import Sequence
from msflash.calibration import chart_detection
from msflash.calibration.chart_grid import MACBETH_GRID, ChartDetectionError, ChartGrid
from msflash.processing import colour_metrics, datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.names import unknown_name
from msflash.processing.scenes import chart_scene, chart_shape
from msflash.processing.spectra import Spectra, WavelengthGrid

CHARTS = ("macbeth",)
"""Charts ``evaluate`` knows the layout and reference of."""
ChartName = Literal["chart110", "macbeth"]
"""The chart layouts of :func:`processing.scenes.chart_scene`."""
MACBETH_NEUTRALS = (3, 7, 11, 15, 19, 23)
"""The gray series of the Macbeth chart in ISET order (white … black), 0-based."""
LAYOUT_UNIFORMITY_LIMIT = 0.25
"""Largest accepted ratio of within-patch to between-patch spread of the ambient image."""
NEUTRAL_SPREAD = 0.1
"""A patch of a user's chart is neutral (grey) when its reflectance varies less than this share of its mean."""


# -- the chart's reference data ----------------------------------------------------------------
@dataclass(frozen=True)
class ChartReference:
    """A chart: the reflectance of each patch and how the patches are arranged.

    Patches are in chart order, column by column (ISET's Macbeth order: patch ``k`` sits in column
    ``k // rows``, row ``k % rows``); chart detection also tries the file read row by row.
    """

    name: str
    """``macbeth`` (ISETCam's measurement, shipped) or the file or calibration it came from."""
    reflectances: Spectra
    """One column per patch, on the file's own grid (resample before use)."""
    rows: int
    columns: int
    neutrals: tuple[int, ...]
    """The grey patches (0-based), for noise measures and reports."""

    @property
    def builtin(self) -> bool:
        """Whether this is the shipped Macbeth chart (the sim rig's layout can be rebuilt for it)."""
        return self.name == "macbeth"

    def on(self, grid: WavelengthGrid) -> Spectra:
        """The reflectances on ``grid`` (constant beyond the measured range)."""
        return self.reflectances.resample(grid, outside="edge")

    def patch_name(self, patch: int) -> str:
        """``'3 (column 1, row 3)'`` or the file's column name with its place."""
        place = f"column {patch // self.rows + 1}, row {patch % self.rows + 1}"
        name = self.reflectances.names[patch]
        return f"'{name}' ({place})" if not re.fullmatch(r"\D{0,12}\d+", name) else f"patch {patch + 1} ({place})"


def chart_reference_grid(count: int, given: str | None = None) -> tuple[int, int]:
    """Rows and columns of a chart of ``count`` patches (``--chart-grid`` or the default; see :func:`chart_reference`)."""
    return _grid_shape(count, given, f"a {count}-patch chart")


def _grid_shape(count: int, given: str | None, where: str) -> tuple[int, int]:
    if given is not None:
        match = re.fullmatch(r"\s*(\d+)\s*[x×X]\s*(\d+)\s*", given, re.ASCII)  # not ١٢: ASCII digits only
        if not match or int(match.group(1)) < 1 or int(match.group(2)) < 1:
            raise UsageError(f"--chart-grid '{given}': expected ROWSxCOLUMNS, e.g. 4x6")
        rows, columns = int(match.group(1)), int(match.group(2))
        if rows * columns != count:
            raise UsageError(
                f"--chart-grid {rows}x{columns}: {rows * columns} patches but {where} has {count}; expected "
                "rows × columns = the number of reflectance columns"
            )
        return rows, columns
    if count == 24:
        return 4, 6  # the ColorChecker
    shapes = [(r, count // r) for r in range(2, count) if count % r == 0 and r <= count // r and count // r <= 4 * r]
    if not shapes:
        raise UsageError(f"{where}: {count} patches make no grid of at most 1:4; expected --chart-grid ROWSxCOLUMNS")
    return min(shapes, key=lambda shape: abs(shape[1] / shape[0] - 1.5))


def _neutrals(reflectances: Spectra) -> tuple[int, ...]:
    values = reflectances.values
    spread = values.std(axis=0) / np.maximum(values.mean(axis=0), 1e-12)
    return tuple(int(i) for i in np.flatnonzero(spread < NEUTRAL_SPREAD))


def chart_reference(
    spec: str | None, measured: Spectra | None = None, measured_from: str = "", grid: str | None = None
) -> ChartReference:
    """The chart named by ``--chart`` (built-in name or CSV file), else a calibration's measured one, else Macbeth.

    Parameters
    ----------
    spec
        ``macbeth``, or a CSV file ``wavelength_nm, <one reflectance per patch>`` (0–1, uniform
        grid, patches column by column) — the vendor's data or a lab's own measurement; None: the
        ``measured`` chart if there is one, else Macbeth.
    measured, measured_from
        The chart a calibration holds (``calibrate chart``) and where it is.
    grid
        ``--chart-grid ROWSxCOLUMNS`` (default: 4×6 for 24 patches, else the grid nearest 2:3).

    Raises
    ------
    UsageError
        Naming ``--chart`` or the file: an unknown name, a file the table reader refuses,
        reflectances outside 0–1.5 (percentages), a grid that does not hold the patches.
    """
    if spec is None and measured is not None:
        rows, columns = _grid_shape(measured.count, grid, measured_from)
        return ChartReference(measured_from, measured, rows, columns, _neutrals(measured))
    if spec is None or spec == "macbeth":
        reflectances = datasets.macbeth()
        rows, columns = _grid_shape(reflectances.count, grid, "macbeth")
        return ChartReference("macbeth", reflectances, rows, columns, MACBETH_NEUTRALS)
    path = Path(spec)
    if not (path.suffix.lower() in (".csv", ".txt") or path.exists()):
        raise UsageError(f"--chart '{spec}': unknown; expected macbeth or a CSV file of the chart's reflectances")
    try:
        reflectances = datasets.load_spectra_csv(path, kind="reflectance", unit="none")
    except SpectralDataError as err:
        raise UsageError(f"--chart {err}; expected 'wavelength_nm, one reflectance per patch' (0–1)") from err
    peak = float(np.max(reflectances.values))
    if not np.all(np.isfinite(reflectances.values)) or np.min(reflectances.values) < -0.05 or peak > 1.5:
        raise UsageError(
            f"--chart {spec}: reflectances span {float(np.min(reflectances.values)):g}–{peak:g}; expected reflectance "
            "factors 0–1 (divide percentages by 100)"
        )
    if reflectances.count < 4:
        raise UsageError(f"--chart {spec}: {reflectances.count} patches; expected at least 4 reflectance columns")
    rows, columns = _grid_shape(reflectances.count, grid, spec)
    return ChartReference(str(spec), reflectances.replace(source=str(spec)), rows, columns, _neutrals(reflectances))


# -- the chart layout -------------------------------------------------------------------------
@dataclass(frozen=True)
class ChartLayout:
    """Which pixels of an image belong to which chart patch."""

    labels: np.ndarray
    """Patch index of every usable pixel, −1 elsewhere, (H, W)."""
    n_patches: int
    """Number of patches (labels 0 … n − 1)."""
    neutrals: tuple[int, ...]
    """The gray patches (for noise measures)."""
    description: str
    """How the layout was obtained."""


def chart_layout(
    shape: tuple[int, int],
    chart: ChartName = "macbeth",
    patch_px: int = 8,
    border_px: int = 2,
    margin_px: int = 1,
    excluded: np.ndarray | None = None,
) -> ChartLayout:
    """The label map of a simulated chart of ``chart_scene(chart, patch_px, border_px)`` at the top left."""
    if chart not in CHARTS:
        raise UsageError(unknown_name("--chart", chart, CHARTS))
    if patch_px < 1 or border_px < 0 or margin_px < 0:
        raise UsageError(
            f"--patch-px {patch_px}, --border-px {border_px}, --margin-px {margin_px}: expected "
            "patch ≥ 1 and the others ≥ 0"
        )
    if 2 * margin_px >= patch_px:
        raise UsageError(
            f"--margin-px {margin_px} leaves nothing of {patch_px}-pixel patches; expected margin < patch/2"
        )
    # Checked before the chart is drawn: --patch-px 100000 asked for a label map of hundreds of GiB.
    height, width = chart_shape(MACBETH_GRID[0] * MACBETH_GRID[1], patch_px, border_px)
    if height > shape[0] or width > shape[1]:
        raise UsageError(
            f"--patch-px {patch_px} --border-px {border_px}: the {chart} chart is {height}×{width} pixels "
            f"but the image is {shape[0]}×{shape[1]}; expected the sim rig's layout"
        )
    scene = chart_scene(chart, patch_px=patch_px, border_px=border_px)
    n_patches = scene.reflectances.count - 1  # the last surface is the border
    labels = np.full(shape, -1, dtype=np.int64)
    chart_labels = np.asarray(scene.labels, dtype=np.int64)
    labels[:height, :width] = np.where(chart_labels == n_patches, -1, chart_labels)
    # The border counts as its own surface for the edge margin, then is dropped.
    with_border = np.full(shape, n_patches + 1, dtype=np.int64)
    with_border[:height, :width] = chart_labels
    usable = colour_metrics.usable_labels(with_border, margin_px, excluded)
    usable[(usable >= n_patches)] = -1
    return ChartLayout(
        usable,
        n_patches,
        MACBETH_NEUTRALS,
        f"{chart} chart rebuilt with chart_scene(patch_px={patch_px}, border_px={border_px}) at the "
        f"top-left pixel, {margin_px}-pixel margin",
    )


@dataclass(frozen=True)
class SequenceLayout:
    """How a sequence's patches are found: a given sim-rig layout or a detected chart."""

    build: Callable[..., ChartLayout]
    """``build(shape, excluded=None)``: the label map for an image shape, dropping excluded pixels."""
    report: dict[str, Any]
    """For JSON output: ``detected`` and the layout's parameters."""
    grid: ChartGrid | None = None
    """The detected chart (None for a given layout): where each patch lies, for the light-field fit."""

    def patch_positions(self, n_patches: int, rows: int) -> np.ndarray:
        """Each patch's place in the chart (column, row) in patch pitches, shape (n_patches, 2).

        A detected chart's own lattice (its rows may be the file's columns); a given layout's
        column-by-column order otherwise.
        """
        rows = self.grid.rows if self.grid is not None else rows
        k = np.arange(n_patches)
        return np.column_stack([k // rows, k % rows]).astype(float)


def sequence_layout(
    sequence: Sequence,
    chart: ChartName | ChartReference = "macbeth",
    patch_px: int | None = None,
    border_px: int | None = None,
    margin_px: int = 1,
) -> SequenceLayout:
    """The chart layout of ``sequence``: detected when neither ``patch_px`` nor ``border_px`` is given.

    Detection (:func:`calibration.chart_detection.detect_in_sequence`) finds the chart anywhere in
    the frames, at any scale and a small rotation; given options rebuild the sim rig's chart at the
    top left (:func:`chart_layout`, the other option at its sim-rig default; a 4 × 6 chart only).
    A user's chart (``ChartReference``) is looked for as its rows × columns and, failing that, as
    columns × rows (a file listing the patches row by row).

    Raises
    ------
    UsageError
        An unknown chart, or no single chart found (naming the sequence and the layout options).
    """
    reference = chart if isinstance(chart, ChartReference) else None
    name = "macbeth" if reference is not None else chart
    if reference is None and chart not in CHARTS:
        raise UsageError(unknown_name("--chart", chart, CHARTS))
    if patch_px is not None or border_px is not None:
        if reference is not None and (reference.rows, reference.columns) != MACBETH_GRID:
            raise UsageError(
                f"--patch-px/--border-px rebuild the sim rig's 4×6 chart but --chart {reference.name} is "
                f"{reference.rows}×{reference.columns}; expected no layout options (the chart is detected)"
            )
        patch, border = (8 if patch_px is None else patch_px), (2 if border_px is None else border_px)
        return SequenceLayout(
            lambda shape, excluded=None: chart_layout(shape, name, patch, border, margin_px, excluded),  # type: ignore[arg-type]
            {"detected": False, "patch_px": patch, "border_px": border, "margin_px": margin_px},
        )
    if margin_px < 0:
        raise UsageError(f"--margin-px {margin_px}: expected ≥ 0")
    reference = reference or chart_reference("macbeth")
    reflectances = reference.on(sequence.grid)
    try:
        grid = chart_detection.detect_in_sequence(sequence, reflectances, reference.rows, reference.columns)
    except ChartDetectionError as err:
        if reference.builtin or reference.rows == reference.columns:
            raise UsageError(str(err)) from err
        try:  # the file may list the patches row by row: the same chart, transposed
            grid = chart_detection.detect_in_sequence(sequence, reflectances, reference.columns, reference.rows)
        except ChartDetectionError:
            raise UsageError(str(err)) from err
    patch = min(grid.as_dict()["patch_px"])
    if 2 * margin_px >= patch:
        raise UsageError(
            f"--margin-px {margin_px} leaves nothing of the {patch:.1f}-pixel patches of the chart "
            f"detected in {sequence.path}; expected margin < patch/2"
        )
    description = f"{grid.describe()}, {margin_px}-pixel margin"
    neutrals = reference.neutrals
    return SequenceLayout(
        lambda shape, excluded=None: ChartLayout(
            grid.labels(shape, margin_px, excluded), grid.rows * grid.columns, neutrals, description
        ),
        {"detected": True, **grid.as_dict(), "margin_px": margin_px},
        grid,
    )


def check_layout(
    image: np.ndarray, layout: ChartLayout, cfa: str | None, *, worst_patch_limit: float = 1.0, twin_z: float = 4.0
) -> float:
    """Check that ``layout`` fits the chart in ``image``; return the median within/between spread ratio.

    Three tests, each aimed at one way a wrong ``--patch-px/--border-px/--margin-px`` shows:

    - the median patch's within-patch spread (green) must stay below
      :data:`LAYOUT_UNIFORMITY_LIMIT` × the spread between patch means (most patches misplaced);
    - the worst patch's within spread must stay below ``worst_patch_limit`` × the between spread
      (a patch straddling two chart patches or a border);
    - at most a quarter of the patches may read the same colour as another patch, i.e. differ
      from it by less than ``twin_z`` standard errors in every channel (a layout of smaller pitch
      that samples parts of the chart several times while every sampled area is uniform).

    Raises
    ------
    UsageError
        Naming the failed test and the options to check.
    """
    green = 1 if (image.ndim == 3 or cfa is not None) else 0
    within, means, errors = [], [], []
    for patch in range(layout.n_patches):
        channels = colour_metrics.patch_pixels(image, layout.labels, patch, cfa)
        samples = channels[green]
        if samples.size < 2:
            raise UsageError(
                f"chart layout: patch {patch} has {samples.size} usable pixels; expected a layout that "
                "fits the image (--patch-px/--border-px/--margin-px)"
            )
        within.append(samples.std())
        means.append([c.mean() if c.size else np.nan for c in channels])
        errors.append([c.std(ddof=1) / np.sqrt(c.size) if c.size > 1 else np.nan for c in channels])
    patch_means, standard_errors = np.array(means), np.array(errors)
    between = float(np.std(patch_means[:, green]))
    if not between > 0:  # a blank frame: every ratio below would be inf and say nothing
        raise UsageError(
            f"chart layout: every patch reads the same value ({patch_means[0, green]:.6g}) in the ambient "
            "image; expected the chart in view — the ambient frame is blank (black, saturated or uniform)"
        )
    spread = np.array(within) / between
    ratio = float(np.median(spread))
    if not ratio <= LAYOUT_UNIFORMITY_LIMIT:
        raise UsageError(
            f"chart layout: patches are not uniform in the ambient image (within/between spread "
            f"{ratio:.2f} > {LAYOUT_UNIFORMITY_LIMIT}); expected the sim rig's chart with these "
            "--patch-px/--border-px (a real photograph needs its own patch map)"
        )
    worst = int(np.argmax(spread))
    if not spread[worst] <= worst_patch_limit:
        raise UsageError(
            f"chart layout: patch {worst} is not uniform in the ambient image (within/between spread "
            f"{spread[worst]:.2f} > {worst_patch_limit}); expected every patch inside one chart patch "
            "(check --patch-px/--border-px/--margin-px)"
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.abs(patch_means[:, None] - patch_means[None]) / np.hypot(standard_errors[:, None], standard_errors[None])
    z = np.where(np.isfinite(z), z, -np.inf).max(axis=2)  # the most distinct channel with ≥ 2 samples each
    np.fill_diagonal(z, np.inf)
    twins = int(np.sum((z < twin_z).any(axis=1)))
    if twins > layout.n_patches / 4:
        raise UsageError(
            f"chart layout: {twins} of {layout.n_patches} patches read the same colour as another patch "
            f"(< {twin_z:g} standard errors apart); expected {layout.n_patches} distinct chart patches — "
            "the layout samples parts of the chart several times (check --patch-px/--border-px)"
        )
    return ratio
