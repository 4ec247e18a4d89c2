"""Chart detection, step 4: which placement of the chart over a lattice fits its colours under the LEDs.

Public objects
--------------
- :class:`ColourFrames`: the frames and lights the orientation test compares.
- :func:`placement_misfit`: the relative misfit of patch means to a prediction through any
  non-negative gain per column.
- The placements of a chart over a lattice (4 rotations × mirror, any shift), scored on the LED
  frames minus the ambient, for :mod:`calibration.chart_detection` (step 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msflash.calibration.chart_grid import ChartGrid
from msflash.calibration.chart_lattice import _Lattice
from msflash.calibration.chart_regions import _Candidates, _Planes
from msflash.processing.spectra import Spectra

SAMPLE_FRACTION = 0.6
"""Patch means for the orientation test average the central 60 % of each patch (per side)."""
COLOUR_MISFIT = 0.1
"""Largest accepted relative misfit of the best placement (see :func:`placement_misfit`)."""
MIN_COLOUR_SNR = 10.0
"""Least ratio of the LED differences' energy to their noise's for the orientation test."""


@dataclass(frozen=True)
class ColourFrames:
    """What the orientation test compares: LED frames minus the ambient, under known lights."""

    ambient: int
    """Index (into the frames given) of the ambient frame."""
    leds: tuple[int, ...]
    """Indices of the LED frames."""
    lights: Spectra
    """Each LED frame's illumination (LED spectra · levels), one column per LED frame."""


# -- 4. placement and orientation -------------------------------------------------------------
def placement_misfit(measured: np.ndarray, predicted: np.ndarray, variance: np.ndarray | None = None) -> float:
    """Relative misfit of patch means to a prediction through any non-negative gain per column.

    Parameters
    ----------
    measured
        (patches, columns): e.g. each LED frame minus the ambient, each channel a column.
    predicted
        (patches, columns): the chart's reflectances integrated against each column's light.
    variance
        (patches, columns): the noise variance of ``measured``, or None (noise-free).

    Returns
    -------
    float
        ``(Σ ‖m − g q‖² − N (n−1)/n) / (Σ ‖m‖² − N)`` with each column's
        ``g = max(0, ⟨m, q⟩ / ⟨q, q⟩)`` and ``N = Σ variance`` (the noise's expected share of
        each sum, n patches, one gain per column), clipped to [0, 1]: 0 is a perfect fit, 1 no fit.

    Examples
    --------
    >>> q = np.array([[1.0], [2.0], [3.0]])
    >>> placement_misfit(5 * q, q), placement_misfit(5 * q[::-1], q) > 0.2
    (0.0, True)
    """
    gains = np.maximum(np.sum(measured * predicted, axis=0) / np.maximum(np.sum(predicted**2, axis=0), 1e-300), 0)
    residual = measured - gains * predicted
    noise = 0.0 if variance is None else float(np.sum(variance))
    signal = float(np.sum(measured**2)) - noise
    if not signal > 0:
        return 1.0
    n = measured.shape[0]
    return float(np.clip((float(np.sum(residual**2)) - noise * (n - 1) / n) / signal, 0.0, 1.0))


_SYMMETRIES = tuple(
    np.array(m)
    for m in (
        ((1, 0), (0, 1)),
        ((0, -1), (1, 0)),
        ((-1, 0), (0, -1)),
        ((0, 1), (-1, 0)),
        ((-1, 0), (0, 1)),
        ((1, 0), (0, -1)),
        ((0, 1), (1, 0)),
        ((0, -1), (-1, 0)),
    )
)
"""The 8 maps of chart (column, row) steps onto lattice (i, j) steps: 4 rotations, then mirrored."""


@dataclass(frozen=True)
class _Placement:
    symmetry: np.ndarray
    base: np.ndarray
    misfit: float
    sites: frozenset[tuple[int, int]]


def _site_means(
    planes: _Planes, lattice: _Lattice, fraction: np.ndarray, frames: np.ndarray
) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """Mean of each plane of ``frames`` over the centre of every lattice site with ≥ 2 usable pixels,
    and the variance of that mean (from the pixels' spread)."""
    h, w = planes.values.shape[:2]
    y, x = np.mgrid[0:h, 0:w]
    coordinates = np.linalg.solve(
        lattice.basis, np.stack([x.ravel() - lattice.origin[0], y.ravel() - lattice.origin[1]])
    )
    nearest = np.rint(coordinates)
    central = np.all(np.abs(coordinates - nearest) < (SAMPLE_FRACTION / 2) * fraction[:, None], axis=0)
    central &= ~planes.excluded.ravel()
    keys = nearest[:, central].T.astype(np.int64)
    if keys.size == 0:
        return {}
    sites, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    values = planes.values.reshape(h * w, *planes.values.shape[2:])[central][:, frames].reshape(int(central.sum()), -1)
    counts = np.bincount(inverse, minlength=len(sites)).astype(float)
    sums = np.stack([np.bincount(inverse, values[:, c], len(sites)) for c in range(values.shape[1])], axis=1)
    means = sums / counts[:, None]
    squares = np.stack(
        [np.bincount(inverse, (values[:, c] - means[inverse, c]) ** 2, len(sites)) for c in range(values.shape[1])],
        axis=1,
    )
    spread = squares / np.maximum(counts - 1, 1)[:, None] / counts[:, None]
    return {(int(site[0]), int(site[1])): (means[s], spread[s]) for s, site in enumerate(sites) if counts[s] >= 2}


def _placements(lattice: _Lattice, rows: int, columns: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every (symmetry, base site) putting the chart over all the lattice's found sites, or inside them."""
    low, high = lattice.sites.min(axis=0), lattice.sites.max(axis=0)
    chart = np.array([[c, r] for c in range(columns) for r in range(rows)])  # chart order: column by column
    placements = []
    for symmetry in _SYMMETRIES:
        mapped = chart @ symmetry.T
        span_low, span_high = mapped.min(axis=0), mapped.max(axis=0)
        # Per lattice coordinate, base + span contains [low, high] or lies inside it (a larger grid).
        ends = [sorted((int(high[a] - span_high[a]), int(low[a] - span_low[a]))) for a in (0, 1)]
        ranges = [range(first, last + 1) for first, last in ends]
        placements += [(symmetry, np.array([bi, bj])) for bi in ranges[0] for bj in ranges[1]]
    return placements


def _patch_fraction(candidates: _Candidates, members: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Median patch size of the lattice's regions along each lattice vector, as a fraction of it."""
    inverse = np.linalg.inv(basis)
    lattice_covariance = inverse @ candidates.covariances[members] @ inverse.T
    pixel = np.sum(inverse**2, axis=1)  # one pixel, in lattice units², per coordinate
    sides = np.sqrt(12 * np.diagonal(lattice_covariance, axis1=1, axis2=2) + pixel)
    return np.minimum(np.median(sides, axis=0), 0.95)


def _charts_on(
    planes: _Planes,
    lattice: _Lattice,
    fraction: np.ndarray,
    colour: ColourFrames,
    predicted: np.ndarray,
    rows: int,
    columns: int,
    minimum: int,
) -> tuple[list[ChartGrid], float, float]:
    """Non-overlapping placements of the chart on ``lattice`` that fit its colours, the best misfit, and
    the lowest signal-to-noise of placements too noisy to test (inf if none)."""
    n_patches = rows * columns
    frames = np.array([colour.ambient, *colour.leds])
    means = _site_means(planes, lattice, fraction, frames)
    found = {(int(i), int(j)) for i, j in lattice.sites}
    results, weak = [], math.inf
    for symmetry, base in _placements(lattice, rows, columns):
        sites = [
            (int(i), int(j))
            for i, j in base + np.array([[c, r] for c in range(columns) for r in range(rows)]) @ symmetry.T
        ]
        if not all(site in means for site in sites) or len(found.intersection(sites)) < minimum:
            continue
        per_frame = np.array([means[site][0] for site in sites]).reshape(n_patches, len(frames), -1)
        spread = np.array([means[site][1] for site in sites]).reshape(n_patches, len(frames), -1)
        measured = (per_frame[:, 1:] - per_frame[:, :1]).reshape(n_patches, -1)
        variance = (spread[:, 1:] + spread[:, :1]).reshape(n_patches, -1)
        snr = float(np.sum(measured**2) / max(np.sum(variance), 1e-300))
        if snr < MIN_COLOUR_SNR:
            weak = min(weak, snr)
            continue
        misfit = placement_misfit(measured, np.repeat(predicted, per_frame.shape[2], axis=1), variance)
        results.append(_Placement(symmetry, base, misfit, frozenset(sites)))
    results.sort(key=lambda p: p.misfit)
    accepted: list[_Placement] = []
    for placement in results:
        if placement.misfit <= COLOUR_MISFIT and not any(placement.sites & a.sites for a in accepted):
            accepted.append(placement)
    grids = []
    for placement in accepted:
        runner_up = min(
            (q.misfit for q in results if q is not placement and q.sites & placement.sites), default=math.inf
        )
        grids.append(
            _grid(planes, lattice, fraction, placement, runner_up, len(found & placement.sites), rows, columns)
        )
    return grids, (results[0].misfit if results else math.inf), weak


def _grid(
    planes: _Planes,
    lattice: _Lattice,
    fraction: np.ndarray,
    placement: _Placement,
    runner_up: float,
    found: int,
    rows: int,
    columns: int,
) -> ChartGrid:
    basis = lattice.basis @ placement.symmetry  # columns: the chart's column and row steps (detection pixels)
    origin = lattice.origin + lattice.basis @ placement.base
    chart_fraction = np.abs(placement.symmetry.T) @ fraction  # a swap of axes swaps the fractions
    full_origin = planes.scale * origin + planes.offset
    full_basis = planes.scale * basis
    return ChartGrid(
        rows,
        columns,
        (float(full_origin[0]), float(full_origin[1])),
        (float(full_basis[0, 0]), float(full_basis[1, 0])),
        (float(full_basis[0, 1]), float(full_basis[1, 1])),
        (float(chart_fraction[0]), float(chart_fraction[1])),
        placement.misfit,
        runner_up,
        found,
    )
