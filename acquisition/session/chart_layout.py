"""Which pixels of a chart sequence belong to which chart patch: given (the sim rig's layout) or detected.

A sequence does not record its chart layout. :func:`sequence_layout` detects the chart
(:mod:`msflash.calibration.chart_detection`: anywhere in the frames, any scale, a small rotation,
either orientation, RGB or Bayer) unless a patch and border size are given, in which case
:func:`chart_layout` rebuilds the sim rig's chart at the top-left pixel. :func:`check_layout` then
tests that the label map fits the ambient image. ``msflash evaluate`` and ``msflash calibrate
camera --sequence`` both find their patches here (one source of truth for the layout options).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from msflash.acquisition.errors import UsageError
from msflash.acquisition.sequence.format import Sequence
from msflash.calibration import chart_detection
from msflash.processing import colour_metrics, datasets
from msflash.processing.image_formation import chart_scene

CHARTS = ("macbeth",)
"""Charts ``evaluate`` knows the layout and reference of."""
ChartName = Literal["chart110", "macbeth"]
"""The chart layouts of :func:`processing.image_formation.chart_scene`."""
MACBETH_NEUTRALS = (3, 7, 11, 15, 19, 23)
"""The gray series of the Macbeth chart in ISET order (white … black), 0-based."""
LAYOUT_UNIFORMITY_LIMIT = 0.25
"""Largest accepted ratio of within-patch to between-patch spread of the ambient image."""


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
        raise UsageError(f"--chart '{chart}': unknown; expected one of {', '.join(CHARTS)}")
    if patch_px < 1 or border_px < 0 or margin_px < 0:
        raise UsageError(
            f"--patch-px {patch_px}, --border-px {border_px}, --margin-px {margin_px}: expected "
            "patch ≥ 1 and the others ≥ 0"
        )
    if 2 * margin_px >= patch_px:
        raise UsageError(
            f"--margin-px {margin_px} leaves nothing of {patch_px}-pixel patches; expected margin < patch/2"
        )
    scene = chart_scene(chart, patch_px=patch_px, border_px=border_px)
    n_patches = scene.reflectances.count - 1  # the last surface is the border
    height, width = scene.shape
    if height > shape[0] or width > shape[1]:
        raise UsageError(
            f"--patch-px {patch_px} --border-px {border_px}: the {chart} chart is {height}×{width} pixels "
            f"but the image is {shape[0]}×{shape[1]}; expected the sim rig's layout"
        )
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


def sequence_layout(
    sequence: Sequence,
    chart: ChartName = "macbeth",
    patch_px: int | None = None,
    border_px: int | None = None,
    margin_px: int = 1,
) -> SequenceLayout:
    """The chart layout of ``sequence``: detected when neither ``patch_px`` nor ``border_px`` is given.

    Detection (:func:`calibration.chart_detection.detect_in_sequence`) finds the chart anywhere in
    the frames, at any scale and a small rotation; given options rebuild the sim rig's chart at the
    top left (:func:`chart_layout`, the other option at its sim-rig default).

    Raises
    ------
    UsageError
        An unknown chart, or no single chart found (naming the sequence and the layout options).
    """
    if chart not in CHARTS:
        raise UsageError(f"--chart '{chart}': unknown; expected one of {', '.join(CHARTS)}")
    if patch_px is not None or border_px is not None:
        patch, border = (8 if patch_px is None else patch_px), (2 if border_px is None else border_px)
        return SequenceLayout(
            lambda shape, excluded=None: chart_layout(shape, chart, patch, border, margin_px, excluded),
            {"detected": False, "patch_px": patch, "border_px": border, "margin_px": margin_px},
        )
    if margin_px < 0:
        raise UsageError(f"--margin-px {margin_px}: expected ≥ 0")
    reflectances = datasets.macbeth().resample(sequence.grid, outside="edge")
    try:
        grid = chart_detection.detect_in_sequence(sequence, reflectances, *chart_detection.MACBETH_GRID)
    except chart_detection.ChartDetectionError as err:
        raise UsageError(str(err)) from err
    patch = min(grid.as_dict()["patch_px"])
    if 2 * margin_px >= patch:
        raise UsageError(
            f"--margin-px {margin_px} leaves nothing of the {patch:.1f}-pixel patches of the chart "
            f"detected in {sequence.path}; expected margin < patch/2"
        )
    description = f"{grid.describe()}, {margin_px}-pixel margin"
    return SequenceLayout(
        lambda shape, excluded=None: ChartLayout(
            grid.labels(shape, margin_px, excluded), grid.rows * grid.columns, MACBETH_NEUTRALS, description
        ),
        {"detected": True, **grid.as_dict(), "margin_px": margin_px},
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
