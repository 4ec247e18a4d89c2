"""Chart detection, steps 1–2: the frames as detection planes, their uniform regions, and the patch candidates.

Public objects
--------------
- :func:`uniform_regions`: the components of statistically equal neighbours (step 1 of
  :mod:`calibration.chart_detection`'s method: a χ² test against a noise model measured on the frames).
- The detection planes (frames stacked as channels, Bayer quads as four planes, binned) and the
  candidates (filled rectangles of a common size) for :mod:`calibration.chart_lattice`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from msflash.calibration.chart_grid import ChartDetectionError
from msflash.processing.block_sums import cfa_planes
from msflash.processing.sensor import CFA_PATTERNS

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
