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

Method
------
All frames see the same geometry, so they are stacked as channels: RGB frames as they are, a
Bayer mosaic as its four per-site planes at half resolution (each 2 × 2 quad one pixel, no
demosaicking), large frames binned so the longer side is ≤ :data:`DETECTION_MAX_SIDE`.

1. *Uniform regions.* Two neighbouring pixels are linked when they read the same in every
   channel: ``χ² = Σ_c (a_c − b_c)² / var_c`` below the ``1 −`` :data:`LINK_FALSE_CUT` quantile of
   χ² with one degree of freedom per channel. ``var_c`` is the noise of a difference as a function
   of the signal, measured on the frames themselves (per signal bin; iterated on the pairs that
   test uniform, see :func:`_link_chi2`), never below the raw quantisation. Regions are the
   connected components of the links: no erosion, so an 8-pixel patch stays an 8-pixel region.
2. *Patch candidates.* Regions that are filled rectangles (area = product of the sides implied
   by their second moments, ±:data:`RECTANGLE_TOLERANCE`; aspect ≤ :data:`MAX_ASPECT`) and of a
   common size (within a factor :data:`SIZE_TOLERANCE`: a chart's patches are all alike).
3. *Lattice.* The dominant nearest-neighbour displacement gives one lattice vector, the nearest
   neighbour off that direction the other (Lagrange-reduced); integer sites by rounding, then
   ``centre = origin + i u + j v`` by least squares on the centres within
   :data:`SITE_TOLERANCE` of a site (an affine lattice: scale, rotation, shear of a slightly
   oblique view), keeping the largest connected block of sites and the coarsest well-filled
   sub-lattice (:func:`_coarsest`). At least :data:`MIN_OCCUPANCY` of the chart's patches must
   be found; leftover regions are searched for more lattices.
4. *Placement: which corner is patch 1.* Each placement of the chart over the found sites (4
   rotations × mirror; any shift when edge patches are missing; any window of a larger grid)
   predicts the patch means of every LED frame minus the ambient: under a narrowband LED ``k`` a
   channel reads ``g_kc ∫ ρ_p E_k`` for some gain ``g_kc ≥ 0`` whatever the camera. The relative
   misfit (:func:`placement_misfit`, corrected for the noise of the means) of the best placement
   must be ≤ :data:`COLOUR_MISFIT` and :data:`AMBIGUITY_RATIO` times below the best overlapping
   alternative; two fitting placements that do not overlap are two charts (refused).

The caller still checks the label map like a given layout (``check_layout``: patches uniform,
distinct). References: the lattice fit is the usual checkerboard/ColorChecker grid fit (e.g.
OpenCV's ``mcc`` module finds patch quadrilaterals and fits the chart's grid to their centres);
here the patches are found by a noise-normalised uniformity test instead of contours.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from msflash.calibration.errors import CalibrationError
from msflash.processing.block_sums import cfa_planes
from msflash.processing.colour_metrics import usable_labels
from msflash.processing.image_formation import CFA_PATTERNS
from msflash.processing.spectra import Spectra

MACBETH_GRID = (4, 6)
"""Rows × columns of the Macbeth chart, patches numbered column by column (ISET order, as
:func:`processing.image_formation.chart_scene` lays it out)."""
DETECTION_MAX_SIDE = 512
"""Frames are binned until their longer side (after the Bayer quads) is at most this."""
LINK_FALSE_CUT = 1e-3
"""Probability that two pixels of one uniform patch are not linked (the χ² test's size)."""
NOISE_BINS = 24
"""Signal bins of the difference-noise model of each channel."""
NOISE_SAMPLE = 20_000
"""Neighbour pairs (evenly spaced) the noise model is estimated from."""
NOISE_ITERATIONS = 6
"""Re-estimates of the noise model from the pairs it finds uniform."""
MIN_REGION_PX = 4
"""Smallest region (detection pixels) that can be a patch."""
RECTANGLE_TOLERANCE = 0.2
"""A filled rectangle's area is the product of its moment-implied sides within ±20 %."""
MAX_ASPECT = 4.0
"""Longest patch side over shortest."""
SIZE_TOLERANCE = 2.0
"""Patches of one chart have areas within this factor of a reference patch (a small patch may gain or
lose a row and a column of edge pixels: 3 × 3 against 4 × 4)."""
MAX_SIZE_GROUPS = 8
"""Most size groups (largest first) searched for a lattice."""
SUBLATTICE_GAIN = 1.25
"""A sub-lattice (every 2nd or 3rd site) replaces a lattice it fills this many times better."""
SITE_TOLERANCE = 0.2
"""A centre belongs to a lattice site if within 0.2 pitch of it (both lattice coordinates)."""
MIN_OCCUPANCY = 0.75
"""Fewest chart patches that must be found as regions (the rest may merge with the border)."""
SAMPLE_FRACTION = 0.6
"""Patch means for the orientation test average the central 60 % of each patch (per side)."""
COLOUR_MISFIT = 0.1
"""Largest accepted relative misfit of the best placement (see :func:`placement_misfit`)."""
MIN_COLOUR_SNR = 10.0
"""Least ratio of the LED differences' energy to their noise's for the orientation test."""
AMBIGUITY_RATIO = 2.0
"""The best placement's misfit must be this many times smaller than the runner-up's."""


class ChartDetectionError(CalibrationError):
    """No single chart could be found; the message says why and which layout options to give."""


# -- the detected grid ------------------------------------------------------------------------
@dataclass(frozen=True)
class ChartGrid:
    """A detected chart in full-resolution pixel coordinates (x right, y down, pixel centres integer).

    Examples
    --------
    >>> grid = ChartGrid(4, 6, (5.5, 5.5), (10.0, 0.0), (0.0, 10.0), (0.8, 0.8), 0.004, 0.44, 24)
    >>> grid.corner, grid.rotation_deg, grid.mirrored, grid.patch_centres()[1].tolist()
    ('top-left', 0.0, False, [5.5, 15.5])
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
    """Relative colour misfit of this placement (:func:`placement_misfit`)."""
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

    def patch_centres(self) -> np.ndarray:
        """Centres (x, y) of the patches in chart order (column by column), shape (rows·columns, 2)."""
        k = np.arange(self.rows * self.columns)
        lattice = np.column_stack([k // self.rows, k % self.rows]).astype(float)
        return lattice @ self._basis().T + np.asarray(self.origin_xy)

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


# -- detection planes -------------------------------------------------------------------------
@dataclass(frozen=True)
class _Planes:
    """Frames stacked as channels at detection resolution; ``full = scale · detection + offset``."""

    values: np.ndarray
    """(h, w, frames, planes per frame)."""
    excluded: np.ndarray
    floor: np.ndarray
    """Least variance of a neighbour difference, per frame and plane (quantisation)."""
    scale: int
    offset: float


def _bin(values: np.ndarray, factor: int) -> np.ndarray:
    if factor == 1:
        return values
    h, w = values.shape[0] // factor * factor, values.shape[1] // factor * factor
    blocks = values[:h, :w].reshape(h // factor, factor, w // factor, factor, *values.shape[2:])
    return blocks.mean(axis=(1, 3)) if values.dtype != bool else np.any(blocks, axis=(1, 3))


def _detection_planes(
    images: Sequence[np.ndarray], excluded: np.ndarray, cfa: str | None, quanta: Sequence[float] | None
) -> _Planes:
    if cfa is not None:
        if cfa not in CFA_PATTERNS:
            raise ChartDetectionError(f"cfa '{cfa}': unknown; expected one of {', '.join(CFA_PATTERNS)}")
        # One pixel per 2 × 2 quad, its four sites as four planes (no demosaicking).
        h, w = images[0].shape[0] // 2 * 2, images[0].shape[1] // 2 * 2
        mask = _bin(excluded[:h, :w], 2)
        quad = 2
    else:
        mask, quad = excluded, 1
    stack = np.stack([cfa_planes(image, quad) for image in images], axis=2)
    factor = max(1, math.ceil(max(stack.shape[:2]) / DETECTION_MAX_SIDE))
    scale = quad * factor
    steps = np.zeros(len(images)) if quanta is None else np.asarray(quanta, dtype=float)
    floor = np.repeat(steps**2 / 6 / factor**2, stack.shape[3])  # a difference of two roundings, binned
    return _Planes(_bin(stack.astype(np.float64), factor), _bin(mask, factor), floor, scale, (scale - 1) / 2)


# -- 1. uniform regions -----------------------------------------------------------------------
def _noise_model(
    difference: np.ndarray, level: np.ndarray, estimate: str, correction: float
) -> tuple[np.ndarray, np.ndarray]:
    """Variance of one channel's neighbour differences against the signal: bin centres and values."""
    from scipy.stats import chi2

    n_bins = min(NOISE_BINS, max(1, level.size // 32))
    size = level.size // n_bins
    bins = np.argsort(level)[: n_bins * size].reshape(n_bins, size)  # equal counts, by signal
    centres = np.median(level[bins], axis=1)
    squares = difference[bins] ** 2
    if estimate == "median":  # an overestimate where many pairs straddle edges
        return centres, np.median(squares, axis=1) / chi2.ppf(0.5, 1)
    return centres, squares.mean(axis=1) / correction


def _link_pairs(channels: np.ndarray, excluded: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Horizontal, then vertical neighbour pairs: first pixels, second pixels, excluded links."""
    return [
        (channels[:, :-1], channels[:, 1:], excluded[:, :-1] | excluded[:, 1:]),
        (channels[:-1], channels[1:], excluded[:-1] | excluded[1:]),
    ]


def _link_chi2(planes: np.ndarray, excluded: np.ndarray, floor: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """χ² of every horizontal and vertical neighbour pair over all channels (inf where excluded).

    The noise model of each channel comes from the pairs inside uniform areas, found by iterating:
    start from each signal bin's median ``d²`` (too large where many pairs straddle edges), then
    keep the pairs whose χ² (all channels) is below the median of χ²_C and re-estimate from their
    mean ``d²``, corrected for the truncation (``E[χ²_C | χ²_C < q] / C = F_{C+2}(q) / F_C(q)``).
    From above this converges to the noise of uniform areas: edges, strong in many channels at
    once, drop out of the kept pairs. ``floor`` (per channel) bounds the variance below: the
    quantisation of the raw values (a difference of two roundings: step²/6).
    """
    from scipy.stats import chi2

    h, w = planes.shape[:2]
    channels = planes.reshape(h, w, -1)
    n_channels = channels.shape[2]
    pairs = _link_pairs(channels, excluded)
    first = np.concatenate([a[~out] for a, _, out in pairs])
    second = np.concatenate([b[~out] for _, b, out in pairs])
    if len(first) > NOISE_SAMPLE:
        take = np.linspace(0, len(first) - 1, NOISE_SAMPLE).astype(np.int64)
        first, second = first[take], second[take]
    difference, level = first - second, (first + second) / 2
    if len(level):  # noise-free frames: exact equality must still link
        floor = np.maximum(floor, (1e-4 * np.maximum(np.percentile(np.abs(level), 99, axis=0), 1e-300)) ** 2)
    models: list[tuple[np.ndarray, np.ndarray]] = []
    kept = np.ones(len(difference), dtype=bool)
    clean = chi2.ppf(0.5, n_channels)
    correction = chi2.cdf(clean, n_channels + 2) / chi2.cdf(clean, n_channels)
    for iteration in range(NOISE_ITERATIONS if len(difference) >= 64 else 0):
        models = [
            _noise_model(difference[kept, c], level[kept, c], "median" if iteration == 0 else "mean", correction)
            for c in range(n_channels)
        ]
        sample_chi = sum(
            difference[:, c] ** 2 / np.maximum(np.interp(level[:, c], *models[c]), floor[c]) for c in range(n_channels)
        )
        kept = sample_chi < clean
        if kept.sum() < 64:
            break
    results = []
    for a, b, out in pairs:
        if not models:
            results.append(np.where(out, np.inf, 0.0))
            continue
        chi = np.zeros(out.shape)
        for c in range(n_channels):
            d, m = a[..., c] - b[..., c], (a[..., c] + b[..., c]) / 2
            chi += d**2 / np.maximum(np.interp(m, *models[c]), floor[c])
        results.append(np.where(out, np.inf, chi))
    return results[0], results[1], n_channels


def uniform_regions(planes: np.ndarray, excluded: np.ndarray, floor: np.ndarray | None = None) -> np.ndarray:
    """Region index of every pixel of ``planes`` (h, w, …): components of statistically equal neighbours.

    Excluded pixels get −1; ``floor`` is the least noise variance of a neighbour difference per
    channel (default 0). See the module docstring (step 1).
    """
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components
    from scipy.stats import chi2

    h, w = planes.shape[:2]
    n = int(np.prod(planes.shape[2:]))
    floor = np.zeros(n) if floor is None else np.broadcast_to(np.asarray(floor, dtype=float), (n,))
    horizontal, vertical, n_channels = _link_chi2(planes, excluded, floor)
    threshold = chi2.isf(LINK_FALSE_CUT, n_channels)
    index = np.arange(h * w).reshape(h, w)
    link_h, link_v = horizontal < threshold, vertical < threshold
    sources = np.concatenate([index[:, :-1][link_h], index[:-1][link_v]])
    targets = np.concatenate([index[:, 1:][link_h], index[1:][link_v]])
    graph = sparse.coo_matrix((np.ones(sources.size, dtype=np.int8), (sources, targets)), shape=(h * w, h * w))
    _, regions = connected_components(graph, directed=False)
    regions = regions.reshape(h, w).astype(np.int64)
    regions[excluded] = -1
    return regions


# -- 2. patch candidates ----------------------------------------------------------------------
@dataclass(frozen=True)
class _Candidates:
    centres: np.ndarray
    """(n, 2) x, y in detection pixels."""
    areas: np.ndarray
    covariances: np.ndarray
    """(n, 2, 2) of x, y."""


def _rectangular_regions(regions: np.ndarray) -> _Candidates:
    usable = regions >= 0
    ids = regions[usable]
    y, x = np.nonzero(usable)
    x, y = x.astype(float), y.astype(float)
    n = int(ids.max()) + 1 if ids.size else 0
    area = np.bincount(ids, minlength=n).astype(float)
    keep = area >= MIN_REGION_PX
    safe = np.maximum(area, 1)
    mx, my = np.bincount(ids, x, n) / safe, np.bincount(ids, y, n) / safe
    sxx = np.bincount(ids, x * x, n) / safe - mx**2
    syy = np.bincount(ids, y * y, n) / safe - my**2
    sxy = np.bincount(ids, x * y, n) / safe - mx * my
    covariances = np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2)
    eigen = np.linalg.eigvalsh(covariances)  # ascending
    sides = np.sqrt(12 * np.maximum(eigen, 0) + 1)  # a discrete side of s pixels has variance (s² − 1)/12
    filled = area / (sides[:, 0] * sides[:, 1])
    keep &= (np.abs(filled - 1) <= RECTANGLE_TOLERANCE) & (sides[:, 1] <= MAX_ASPECT * sides[:, 0])
    return _Candidates(np.column_stack([mx, my])[keep], area[keep], covariances[keep])


def _size_groups(candidates: _Candidates, minimum: int) -> list[np.ndarray]:
    """Indices of candidates of a common size, largest groups first, each at least ``minimum``."""
    log_area = np.log(candidates.areas)
    close = np.abs(log_area[:, None] - log_area[None]) <= math.log(SIZE_TOLERANCE)
    groups, seen = [], set()
    for reference in np.argsort(-close.sum(axis=1), kind="stable"):
        members = np.flatnonzero(close[reference])
        key = tuple(members)
        if members.size >= minimum and key not in seen:
            seen.add(key)
            groups.append(members)
    return groups


# -- 3. the lattice ---------------------------------------------------------------------------
def _folded(vectors: np.ndarray) -> np.ndarray:
    """Vectors flipped into the upper half plane (a lattice direction and its opposite are one)."""
    flip = (vectors[:, 1] < 0) | ((vectors[:, 1] == 0) & (vectors[:, 0] < 0))
    return np.where(flip[:, None], -vectors, vectors)


def _dominant(vectors: np.ndarray) -> np.ndarray | None:
    """The most common direction and length among folded displacement vectors (their median)."""
    if len(vectors) == 0:
        return None
    angles = np.arctan2(vectors[:, 1], vectors[:, 0])
    lengths = np.hypot(vectors[:, 0], vectors[:, 1])
    turn = np.abs((angles[:, None] - angles[None] + np.pi / 2) % np.pi - np.pi / 2)
    alike = (turn < math.radians(12)) & (np.abs(np.log(lengths[:, None] / lengths[None])) < math.log(1.25))
    best = int(np.argmax(alike.sum(axis=1)))
    members = vectors[alike[best]]
    aligned = np.where((members @ vectors[best] < 0)[:, None], -members, members)
    return np.median(aligned, axis=0)


def _reduced(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lagrange–Gauss reduction: the shortest basis of the lattice spanned by ``u`` and ``v``."""
    for _ in range(32):
        if u @ u > v @ v:
            u, v = v, u
        step = round(float(u @ v) / float(u @ u))
        if step == 0:
            break
        v = v - step * u
    return u, v


@dataclass(frozen=True)
class _Lattice:
    origin: np.ndarray
    basis: np.ndarray
    """(2, 2), columns u and v (detection pixels)."""
    sites: np.ndarray
    """(m, 2) integer sites of the members."""
    members: np.ndarray
    """Indices (into the points given) on the lattice."""


def _lattice(points: np.ndarray, minimum: int) -> _Lattice | None:
    """The affine lattice through most of ``points`` (and the largest connected block of its sites).

    Of lattices holding at least ``minimum`` points, the coarsest: small regions between the
    patches (edge pixels of a mosaic) must not halve the pitch.
    """
    if len(points) < 4:
        return None
    distance = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1))
    np.fill_diagonal(distance, np.inf)
    nearest = np.argmin(distance, axis=1)
    u = _dominant(_folded(points[nearest] - points))
    if u is None or not np.hypot(*u) > 0:
        return None
    displacement = points[None] - points[:, None]
    cosine = np.abs(displacement @ u) / (np.hypot(*u) * np.maximum(distance, 1e-12))
    off_axis = np.where(cosine < math.cos(math.radians(30)), distance, np.inf)
    second = np.argmin(off_axis, axis=1)
    has_second = np.isfinite(off_axis[np.arange(len(points)), second])
    v = _dominant(_folded(displacement[np.arange(len(points)), second][has_second]))
    if v is None:
        return None
    u, v = _reduced(u, v)
    basis = np.column_stack([u, v])
    if abs(np.linalg.det(basis)) < 0.1 * (u @ u):
        return None
    anchor = points[int(np.argmin(np.hypot(*(points - np.median(points, axis=0)).T)))]
    origin = anchor
    members = np.arange(len(points))
    sites = np.zeros((0, 2), dtype=np.int64)
    for _ in range(3):
        coordinates = np.linalg.solve(basis, (points - origin).T).T
        rounded = np.rint(coordinates)
        error = np.abs(coordinates - rounded).max(axis=1)
        on_lattice = error < SITE_TOLERANCE
        # One point per site: the closest.
        order = np.lexsort((error, rounded[:, 1], rounded[:, 0]))
        first = np.ones(len(order), dtype=bool)
        first[1:] = np.any(np.diff(rounded[order], axis=0) != 0, axis=1)
        unique = np.zeros(len(points), dtype=bool)
        unique[order[first]] = True
        members = np.flatnonzero(on_lattice & unique)
        if members.size < 4:
            return None
        members = members[_largest_block(rounded[members].astype(np.int64))]
        sites = rounded[members].astype(np.int64)
        keep, sites = _coarsest(sites, minimum)
        members = members[keep]
        design = np.column_stack([np.ones(len(members)), sites])
        solution, *_ = np.linalg.lstsq(design, points[members], rcond=None)
        origin, basis = solution[0], solution[1:].T
        if not abs(np.linalg.det(basis)) > 0.1 * min(basis[:, 0] @ basis[:, 0], basis[:, 1] @ basis[:, 1]):
            return None  # the sites lie on a line: no two-dimensional grid
    if members.size < 4:
        return None
    shift = sites.min(axis=0)  # sites from (0, 0), the origin at site (0, 0)
    return _Lattice(origin + basis @ shift, basis, sites - shift, members)


def _occupancy(sites: np.ndarray) -> float:
    """Fraction of the sites' bounding block that they fill."""
    return len(sites) / float(np.prod(np.ptp(sites, axis=0) + 1))


def _coarsest(sites: np.ndarray, minimum: int) -> tuple[np.ndarray, np.ndarray]:
    """Sites of the coarsest well-filled sub-lattice (every 2nd or 3rd site along a vector).

    A sub-lattice replaces the lattice if it keeps ``minimum`` sites and fills its block at least
    :data:`SUBLATTICE_GAIN` times better (a full grid of patches stays whole; patches with small
    regions between them drop the in-between sites). Returns the sites kept (bool) and their
    coordinates on the sub-lattice.
    """
    keep = np.ones(len(sites), dtype=bool)
    sites = sites.copy()
    while True:
        options = []
        filled = _occupancy(sites[keep])
        for axis in (0, 1):
            if np.ptp(sites[keep, axis]) == 0:
                continue
            for step in (2, 3):
                for residue in range(step):
                    subset = keep & (sites[:, axis] % step == residue)
                    if subset.sum() < minimum:
                        continue
                    coarse = sites[subset].copy()
                    coarse[:, axis] = (coarse[:, axis] - residue) // step
                    if _occupancy(coarse) >= SUBLATTICE_GAIN * filled:
                        options.append((int(subset.sum()), step, axis, residue, subset))
        if not options:
            return keep, sites[keep]
        _, step, axis, residue, keep = max(options, key=lambda o: o[:2])
        sites[:, axis] = (sites[:, axis] - residue) // step


def _largest_block(sites: np.ndarray) -> np.ndarray:
    """Indices of the largest group of sites connected through gaps of at most one missing site."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    near = np.abs(sites[:, None] - sites[None]).max(axis=2) <= 2
    _, component = connected_components(sparse.csr_matrix(near), directed=False)
    return np.flatnonzero(component == np.bincount(component).argmax())


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


# -- detection --------------------------------------------------------------------------------
@dataclass(frozen=True)
class ColourFrames:
    """What the orientation test compares: LED frames minus the ambient, under known lights."""

    ambient: int
    """Index (into the frames given) of the ambient frame."""
    leds: tuple[int, ...]
    """Indices of the LED frames."""
    lights: Spectra
    """Each LED frame's illumination (LED spectra · levels), one column per LED frame."""


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
    cfa
        The mosaic's layout, or None for RGB.
    colour
        The frames and lights of the orientation test.
    reflectances
        The chart's patches in chart order (column by column), on the lights' grid.
    rows, columns
        The chart's grid.
    where
        Named in errors (the sequence).
    quanta
        Per image, the linear value of one raw step (``1 / (exposure · gain)``), or None for
        unquantised frames.

    Raises
    ------
    ChartDetectionError
        No chart (or one too small or blurred to show uniform patches), a grid of another size,
        two charts, colours that are not the chart's, or an orientation the colours cannot tell.
    """
    n_patches = rows * columns
    if reflectances.count != n_patches:
        raise ChartDetectionError(
            f"{where}: the chart has {reflectances.count} patches; expected rows × columns = {rows}×{columns}"
        )
    if not colour.leds:
        raise ChartDetectionError(
            f"{where}: no LED frame; chart detection needs LED frames to tell the chart's "
            "orientation (give --patch-px/--border-px)"
        )
    advice = (
        "; expected one chart in view, in focus, with patches of ≥ 4 pixels (8 on a Bayer mosaic) — or give "
        "its layout with --patch-px/--border-px (chart at the top-left)"
    )
    planes = _detection_planes(images, excluded, cfa, quanta)
    regions = uniform_regions(planes.values, planes.excluded, planes.floor)
    candidates = _rectangular_regions(regions)
    minimum = math.ceil(MIN_OCCUPANCY * n_patches)
    lattices = _lattices(candidates, minimum)
    if not lattices:
        raise ChartDetectionError(
            f"{where}: no {rows}×{columns} chart found: fewer than {minimum} uniform, equally "
            f"sized, rectangular regions on a lattice{advice}"
        )
    predicted = reflectances.values.T @ colour.lights.to_unit("photons").values  # (patches, LED frames)
    grids, misfits, extents, weak = [], [], [], math.inf
    for lattice, members in lattices:
        found, best, noisy = _charts_on(
            planes,
            lattice,
            _patch_fraction(candidates, members, lattice.basis),
            colour,
            predicted,
            rows,
            columns,
            minimum,
        )
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
        which = int(np.argmin(misfits))
        extent = "×".join(map(str, extents[which]))
        if math.isfinite(misfits[which]):
            seen = (
                f"a grid of {extent} uniform patches whose colours under the LEDs do not match the chart's in "
                f"any placement (misfit {misfits[which]:.2f} > {COLOUR_MISFIT})"
            )
        elif math.isfinite(weak):
            seen = (
                f"a grid of {extent} uniform patches, but the LED frames minus the ambient are too noisy to tell "
                f"its colours (signal {weak:.1f}× the noise, expected ≥ {MIN_COLOUR_SNR:g}×: dim the ambient or "
                "lengthen the LED exposures)"
            )
        else:
            seen = f"a grid of {extent} uniform patches that does not hold the whole chart inside the frames"
        raise ChartDetectionError(f"{where}: no {rows}×{columns} chart found: {seen}{advice}")
    grid = grids[0]
    if not grid.runner_up_misfit >= AMBIGUITY_RATIO * grid.misfit:
        raise ChartDetectionError(
            f"{where}: the chart's orientation is ambiguous: two placements fit its colours "
            f"(misfit {grid.misfit:.3f} and {grid.runner_up_misfit:.3f}){advice}"
        )
    return grid


def _lattices(candidates: _Candidates, minimum: int) -> list[tuple[_Lattice, np.ndarray]]:
    """Lattices of at least ``minimum`` candidates of one size, with the candidates on each (no overlaps)."""
    lattices: list[tuple[_Lattice, np.ndarray]] = []
    for group in _size_groups(candidates, minimum)[:MAX_SIZE_GROUPS]:
        remaining = group
        while remaining.size >= minimum:
            lattice = _lattice(candidates.centres[remaining], minimum)
            if lattice is None:
                break
            members = remaining[lattice.members]
            if members.size >= minimum and not any(np.intersect1d(members, known).size for _, known in lattices):
                lattices.append((lattice, members))
            remaining = np.delete(remaining, lattice.members)
    return lattices


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


__all__ = [
    "MACBETH_GRID",
    "ChartDetectionError",
    "ChartGrid",
    "ColourFrames",
    "detect_chart",
    "detect_in_sequence",
    "placement_misfit",
    "uniform_regions",
]
