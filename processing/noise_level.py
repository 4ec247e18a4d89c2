"""The sensor's noise level, read from one raw frame: a photon-transfer line fitted to fine-scale detail.

A linear sensor's sample at level ``ℓ`` above black has the variance ``gain · ℓ + read`` (photon noise
plus read and quantisation noise: the Poisson-Gaussian model). :mod:`processing.block_rows` weighs each
sample by the inverse of that variance, so it needs the line's two parameters — measured from the
pixels, as no sequence records them.

Detail, not texture
-------------------
Each 2 × 2 cell of one plane's samples (a CFA plane of a mosaic, a channel of an RGB frame) has three
Haar details besides its sum ``S``: the diagonal ``HH = x₀₀ − x₀₁ − x₁₀ + x₁₁`` and the row and column
ones ``HL``, ``LH``. For noise alone each has the variance ``gain · S + 4 · read``, and the three are
independent (an orthogonal transform of samples of equal variance). Scene texture enters them too. An
edge along the rows or the columns, a ramp, cancels in ``HH`` (the finest diagonal detail, the band
Donoho's noise estimate reads); a corner or a fine pattern does not, but it shows in ``HL`` and ``LH``
as well. So the line is fitted to ``HH²`` of the cells whose ``HL² + LH²`` is within the 99th
percentile of noise for it (χ² with 2 degrees of freedom), by iteratively reweighted least squares,
starting from the smallest of the three details' medians of squares in bands of level (robust while
textured cells are a minority in every band, or raise only some of the details). The selection uses ``HL`` and ``LH`` only, so it leaves the noise of ``HH`` unbiased; a
cut at the 99.9th percentile of ``HH²`` itself (corrected for) drops what texture remains.

Why not the block sums' half differences (the moments' noise probe, :mod:`processing.block_rows`):
on a mosaic the samples of one CFA plane lie 2 pixels apart, so texture a block's halves do not share
fills the probe, and a line fitted to it puts the weights far off across the levels (docs/raw-frames.md). Poisson-Gaussian fitting from one raw image: Foi et al.,
"Practical Poissonian-Gaussian noise modeling and fitting for single-image raw-data", IEEE TIP 2008.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from msflash.processing import frame_kernels

FIT_CELLS = 4096
"""Cells a line is fitted to at most: whole rows of cells, evenly strided over the frame (why this many:
docs/speed.md, Raw frames)."""
MIN_CELLS = 64
"""Fewer usable cells than this give no line (:func:`detail_noise_line` returns None)."""
LEVEL_BANDS = 16
"""Bands of level (equal counts) of the starting fit's medians."""
SMOOTH_QUANTILE = 9.210340371976184
"""χ²₂ at 0.99: a cell whose ``(HL² + LH²) / var`` exceeds it holds texture."""
DETAIL_CUT = 10.827566170662733
"""χ²₁ at 0.999: a cell whose ``HH² / var`` exceeds it is left out (and the mean corrected for the cut)."""
ROUNDS = 12
"""Rounds of selection and reweighting at most."""
CONVERGED = 1e-3
"""Relative change of both parameters below which the rounds stop."""
CHI2_1_MEDIAN = 0.45493642311957283
"""The median of χ²₁: the median of ``HH²`` is this times its variance (Gaussian noise)."""


def _truncated_mean(cut: float) -> float:
    """``E[X | X ≤ cut]`` for ``X ~ χ²₁``: ``1 − √(2 cut/π) e^(−cut/2) / erf(√(cut/2))``."""
    inside = math.erf(math.sqrt(cut / 2.0))
    return 1.0 - math.sqrt(2.0 * cut / math.pi) * math.exp(-cut / 2.0) / inside


_CUT_MEAN = _truncated_mean(DETAIL_CUT)
_TINY = 1e-100
"""Variances at or below this are no noise (their squares, the fit's weights, would underflow)."""


@dataclass(frozen=True)
class PixelNoise:
    """A sample's noise variance ``gain · ℓ + read`` at level ``ℓ`` above black (raw units)."""

    gain: float
    read: float


def haar_details(
    frame: np.ndarray,
    cfa_period: int,
    black: float,
    white: float,
    max_cells: int = FIT_CELLS,
    compiled: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(S, HH, HL, LH)`` of 2 × 2 cells of a raw frame's planes, flattened; cells with a sample at or
    above ``white`` are left out, ``S`` is the cell's sum less ``4 · black``.

    ``compiled``: integer frames in one compiled pass over the chosen rows
    (:func:`processing.frame_kernels.haar_cells`; the kernels must be loaded): the same arrays to the bit.

    ``frame`` is (H, W) (mono, or a Bayer mosaic with ``cfa_period`` 2) or (H, W, C). Whole rows of cells
    are taken, evenly strided so that at most about ``max_cells`` cells are read: a 1280 × 1024 frame
    gives a tenth of its rows. Integer frames are converted in those rows only.

    Examples
    --------
    >>> frame = np.array([[10, 20, 13, 20], [10, 20, 10, 20]], dtype=np.uint16)  # an edge, and a corner
    >>> levels, hh, hl, lh = haar_details(frame, 1, 0.0, 4095.0)
    >>> levels.tolist(), hh.tolist(), hl.tolist(), lh.tolist()
    ([60.0, 63.0], [0.0, 3.0], [-20.0, -17.0], [0.0, 3.0])
    """
    rows_per_cell = 2 * cfa_period
    raw = frame
    if frame.ndim == 2:
        frame = frame[:, :, None]
    n_cell_rows = frame.shape[0] // rows_per_cell
    columns = (frame.shape[1] // rows_per_cell) * rows_per_cell
    if n_cell_rows == 0 or columns == 0:
        empty = np.zeros(0)
        return empty, empty, empty, empty
    per_row = (columns // rows_per_cell) * cfa_period * cfa_period * frame.shape[2]
    stride = max(1, math.ceil(n_cell_rows * per_row / max(max_cells, 1)))
    if compiled:
        compiled_cells = frame_kernels.haar_cells(
            raw, cfa_period, n_cell_rows, stride, columns // rows_per_cell, black, white
        )
        if compiled_cells is not None:
            return compiled_cells
    # (cell rows, 2·period, W, C): the chosen rows of cells.
    slabs = frame[: n_cell_rows * rows_per_cell, :columns].reshape(n_cell_rows, rows_per_cell, columns, -1)[::stride]
    channels, cell_columns = slabs.shape[-1], columns // rows_per_cell
    # Split rows and columns into (cell member, CFA phase): sample (p, q) of cell member (i, j) is at
    # row i·period + p, column j·period + q of the slab.
    cells = slabs.reshape(slabs.shape[0], 2, cfa_period, cell_columns, 2, cfa_period, channels)
    # Converted once into (member row, member column, cell row, phase row, phase column, channel, cell column):
    # each member a contiguous array with the long axis last, so the details below are plain array passes.
    members = np.empty((2, 2, slabs.shape[0], cfa_period, cfa_period, channels, cell_columns))
    np.copyto(members, cells.transpose(1, 4, 0, 2, 5, 6, 3))
    x00, x01, x10, x11 = members[0, 0], members[0, 1], members[1, 0], members[1, 1]
    top_sum, bottom_sum, top_difference, bottom_difference = x00 + x01, x10 + x11, x00 - x01, x10 - x11
    total = top_sum + bottom_sum
    total -= 4.0 * black
    details = (top_difference - bottom_difference, top_difference + bottom_difference, top_sum - bottom_sum)
    usable = np.maximum(np.maximum(x00, x01), np.maximum(x10, x11)) < white
    # Returned in (cell row, cell column, phase row, phase column, channel) order: the order the CFA planes' own
    # cells take (:func:`processing.block_sums.cfa_planes`), so a frame and its planes give the same arrays.
    order = _cell_order(x00.shape)
    usable = usable.reshape(-1).take(order)
    if not usable.all():
        order = order.compress(usable)
    return total.reshape(-1).take(order), *(detail.reshape(-1).take(order) for detail in details)


@lru_cache(maxsize=16)
def _cell_order(shape: tuple[int, ...]) -> np.ndarray:
    """The flat indices that take (cell row, phase row, phase column, channel, cell column) arrays of ``shape`` to
    (cell row, cell column, phase row, phase column, channel) order (cached, read-only)."""
    order = np.arange(math.prod(shape)).reshape(shape).transpose(0, 4, 1, 2, 3).reshape(-1)
    order.flags.writeable = False
    return order


def _weighted_line(levels: np.ndarray, values: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    """Weighted least squares of ``values ≈ gain · levels + offset``; a negative offset refitted as 0 (a line
    through the origin), a negative gain as a constant."""
    sw, sx, sy = float(weights.sum()), float(weights @ levels), float(weights @ values)
    sxx, sxy = float(weights @ (levels * levels)), float(weights @ (levels * values))
    determinant = sw * sxx - sx * sx
    gain, offset = (
        ((sw * sxy - sx * sy) / determinant, (sxx * sy - sx * sxy) / determinant) if determinant > 0 else (0.0, -1.0)
    )
    if offset < 0:
        gain, offset = (sxy / sxx if sxx > 0 else 0.0), 0.0
    if gain < 0:
        gain, offset = 0.0, sy / sw if sw > 0 else 0.0
    return gain, offset


def _level_order(levels: np.ndarray, top: float) -> np.ndarray:
    """The indices that sort ``levels`` (≥ 0, largest ``top``), equal levels in index order: a stable argsort.

    Whole-number levels (the sums of integer samples less an integer black) up to 65535 (a 12-bit mosaic's
    cells) are sorted as 16-bit integers, which numpy's stable sort takes by radix; larger whole numbers as the
    distinct keys ``level · n + index``, which a plain argsort puts in the same order (the keys are exact while
    ``top · n + n < 2⁵³``); both faster than the stable sort (docs/speed.md). Other levels take the stable sort
    itself.
    """
    n = levels.size
    if top * n + n < 2.0**53 and np.array_equal(levels, np.trunc(levels)):
        if top <= 65535:
            return np.argsort(levels.astype(np.uint16), kind="stable")
        return np.argsort(levels * n + np.arange(n, dtype=np.float64))
    return np.argsort(levels, kind="stable")


def _sorted_median(ordered: np.ndarray) -> float:
    """``np.median`` of the values of ``ordered`` (sorted ascending, no NaN): the middle one or the mean of the
    middle two."""
    half = ordered.size // 2
    return float(ordered[half]) if ordered.size % 2 else float((ordered[half - 1] + ordered[half]) / 2)


def _banded_medians(levels: np.ndarray, order: np.ndarray, squares: np.ndarray) -> tuple[float, float]:
    """The starting line: per band of level (:data:`LEVEL_BANDS` of equal counts, the highest levels left over
    when the count does not divide), the smallest of the three details' medians of squares over the χ²₁
    median — an edge along the rows or the columns and a fine pattern each raise some of the three only —
    fitted with weights count / variance².

    ``order`` sorts ``levels`` (:func:`_level_order`); ``squares`` is (3, n): ``HH²``, ``HL²``, ``LH²``. The
    medians are ``np.median``'s (the mean of the two middle values of a band of even count), taken in one
    partition of the three details' bands together.
    """
    per_band = levels.size // LEVEL_BANDS
    if per_band < 8:
        return 0.0, 0.0
    order = order[: per_band * LEVEL_BANDS]
    centres = levels.take(order).reshape(LEVEL_BANDS, per_band).mean(axis=1)
    half = per_band // 2
    bands = squares.take(order, axis=1).reshape(3, LEVEL_BANDS, per_band)
    if per_band % 2:
        medians = np.partition(bands, half, axis=2)[:, :, half]
    else:
        # The two middle values: the lower one by a partition, the upper the least of what lies above it (one
        # selection, where numpy's partition at two ranks does the work of several).
        bands = np.partition(bands, half - 1, axis=2)
        medians = (bands[:, :, half - 1] + np.minimum.reduce(bands[:, :, half:], axis=2)) / 2
    variances = np.minimum.reduce(medians) / CHI2_1_MEDIAN
    if not float(np.max(variances)) > _TINY:
        return 0.0, 0.0  # no noise to see (identical samples): no line
    variances = np.maximum(variances, float(np.max(variances)) * 1e-12)
    return _weighted_line(centres, variances, per_band / (variances * variances))


def fit_detail_line(
    levels: np.ndarray, diagonal: np.ndarray, across: np.ndarray, down: np.ndarray, compiled: bool = False
) -> PixelNoise | None:
    """The noise line of cells with sums ``levels`` (above black) and Haar details ``HH``, ``HL``, ``LH``
    (module notes); None with fewer than :data:`MIN_CELLS` cells or no positive variance.

    ``compiled``: the same fit in one compiled call (:func:`processing.frame_kernels.detail_line`; the kernels must
    be loaded), for block rows that take the compiled route (:func:`processing.frame_kernels.statistics_compiled`):
    it agrees with this numpy fit to rounding (its sums are taken in another order), and costs far less than its
    few dozen numpy calls (docs/speed.md).

    Examples
    --------
    Photon and read noise (gain 2, read 16 a sample) on cells of which a third hold a strong corner:

    >>> rng = np.random.default_rng(0)
    >>> level = rng.uniform(100, 4000, (30000, 1)) * np.ones((1, 4))
    >>> level[::3, 0] *= 3.0  # the corners
    >>> x = level + rng.normal(0.0, np.sqrt(2.0 * level + 16.0))
    >>> cells = (x.sum(axis=1), x[:, 0] - x[:, 1] - x[:, 2] + x[:, 3], x[:, 0] - x[:, 1] + x[:, 2] - x[:, 3],
    ...          x[:, 0] + x[:, 1] - x[:, 2] - x[:, 3])
    >>> line = fit_detail_line(*cells)
    >>> bool(1.9 < line.gain < 2.1)
    True
    """
    if compiled:
        constants = (LEVEL_BANDS, SMOOTH_QUANTILE, DETAIL_CUT, _CUT_MEAN, ROUNDS, CONVERGED, MIN_CELLS)
        found, gain, offset = frame_kernels.detail_line(
            levels, diagonal, across, down, (*constants, CHI2_1_MEDIAN, _TINY)
        )
        return PixelNoise(gain=gain, read=offset / 4.0) if found else None
    levels = np.maximum(np.asarray(levels, dtype=float), 0.0)
    squares = np.empty((3, levels.size))
    np.square(np.asarray(diagonal, dtype=float), out=squares[0])
    np.square(np.asarray(across, dtype=float), out=squares[1])
    np.square(np.asarray(down, dtype=float), out=squares[2])
    texture = squares[1] + squares[2]
    if levels.size < MIN_CELLS or not np.isfinite(squares[0].sum() + texture.sum()):
        return None
    top = float(np.max(levels))
    order = _level_order(levels, top)
    gain, offset = _banded_medians(levels, order, squares)
    diagonal_squares = squares[0]
    scaled_squares = diagonal_squares / _CUT_MEAN
    for _ in range(ROUNDS):
        variance = levels * gain
        variance += offset
        # max(gain · ℓ + offset) is gain · max ℓ + offset: both roundings are monotone for gain ≥ 0.
        peak = gain * top + offset if gain >= 0 and math.isfinite(gain) else float(np.max(variance))
        if not peak > _TINY:
            return None
        np.maximum(variance, peak * 1e-12, out=variance)
        keep = texture <= SMOOTH_QUANTILE * variance
        keep &= diagonal_squares <= DETAIL_CUT * variance
        kept = np.flatnonzero(keep)
        if kept.size < MIN_CELLS:
            break
        kept_variance = variance.take(kept)
        previous = (gain, offset)
        gain, offset = _weighted_line(
            levels.take(kept), scaled_squares.take(kept), np.reciprocal(kept_variance * kept_variance)
        )
        if abs(gain - previous[0]) <= CONVERGED * abs(gain) and abs(offset - previous[1]) <= CONVERGED * abs(offset):
            break
    if not gain * _sorted_median(levels.take(order)) + offset > 0:
        return None
    # HH's variance is that of the cell's sum: gain · S + 4 · read.
    return PixelNoise(gain=float(gain), read=float(offset) / 4.0)


def detail_noise_line(
    frame: np.ndarray, cfa_period: int, black: float, white: float, compiled: bool = False
) -> PixelNoise | None:
    """:func:`fit_detail_line` of :func:`haar_details` of one raw frame: its sensor's noise line, or None
    (``compiled`` as there)."""
    return fit_detail_line(*haar_details(frame, cfa_period, black, white, compiled=compiled), compiled=compiled)


@dataclass(frozen=True)
class NoiseLine:
    """A photon-transfer line: the noise variance of a sample at raw level ``x`` (black removed) is
    ``max(gain · x + read, floor)`` (:func:`block_noise_line`)."""

    gain: float
    read: float
    floor: float

    def weights(self, levels: np.ndarray, black: float = 0.0, compiled: bool = False) -> np.ndarray:
        """``1/var`` of samples at raw ``levels`` (less ``black``), normalised to average 1, in the layout of
        ``levels``. ``compiled`` (float64 levels, the kernels loaded): the steps before the normalisation in one
        compiled pass (:func:`processing.frame_kernels.inverse_variances`), the same numbers to the bit."""
        if compiled:
            variance = frame_kernels.inverse_variances(levels, black, self.gain, self.read, self.floor)
        else:
            variance = np.subtract(levels, black, dtype=float)
            np.maximum(variance, 0.0, out=variance)
            variance *= self.gain
            variance += self.read
            np.maximum(variance, self.floor, out=variance)
            np.reciprocal(variance, out=variance)
        variance *= 1.0 / float(variance.mean())
        return variance

    def root_weights(self, levels: np.ndarray, black: float = 0.0) -> np.ndarray:
        """``√`` of :meth:`weights`: the factor each sample's row entry is scaled by."""
        weights = self.weights(levels, black)
        return np.sqrt(weights, out=weights)


UNIFORM_NOISE = NoiseLine(0.0, 1.0, 1.0)
"""Noise alike everywhere: uniform weights."""


FLOOR_QUANTILE = 0.05
"""The weights' variance floor is the line's variance at this quantile of the samples' levels: a read
noise near zero would give black samples unbounded weight."""


def block_noise_line(pixel: PixelNoise | None, factor: int, levels: np.ndarray) -> NoiseLine:
    """The noise line of ``factor × factor`` block sums whose samples have the noise ``pixel`` (per sample,
    :func:`processing.noise_level.detail_noise_line`): ``gain · B + factor² · read`` at block sum ``B`` above
    black, floored at its value at the :data:`FLOOR_QUANTILE` of ``levels`` (block sums above black).
    :data:`UNIFORM_NOISE` without a line, levels or a positive floor.

    Examples
    --------
    >>> line = block_noise_line(PixelNoise(gain=2.0, read=16.0), 4, np.arange(100.0, 2100.0))
    >>> line.gain, line.read, line.floor
    (2.0, 256.0, 656.0)
    """
    flat = np.asarray(levels, dtype=float).reshape(-1)
    return _floored_line(pixel, factor, flat.size, lambda position: float(np.partition(flat, position)[position]))


def _floored_line(pixel: PixelNoise | None, factor: int, count: int, smallest: Callable[[int], float]) -> NoiseLine:
    """:func:`block_noise_line` of ``count`` levels whose ``position``-th smallest is ``smallest(position)``."""
    if pixel is None or not count:
        return UNIFORM_NOISE
    gain, read = pixel.gain, pixel.read * factor * factor
    floor = gain * max(smallest(int(FLOOR_QUANTILE * count)), 0.0) + read
    return NoiseLine(gain, read, floor) if floor > 0 and math.isfinite(floor) else UNIFORM_NOISE


def ambient_block_noise(
    pixel: PixelNoise | None, factor: int, ambient: np.ndarray, black: float, saturated: np.ndarray | None
) -> NoiseLine:
    """:func:`block_noise_line` for (h, w, C) ambient block sums (raw, black ``black`` per block), its floor
    taken over the blocks the ambient frame does not saturate (``saturated``, (h, w)). Used alike by
    :class:`processing.block_rows.BlockRows` and the tiled statistics of :mod:`processing.local`, so that both weigh the samples alike.
    """
    levels = ambient if saturated is None else ambient[~saturated]
    return block_noise_line(pixel, factor, np.subtract(levels, black, dtype=float))


def ambient_block_weights(
    pixel: PixelNoise | None,
    factor: int,
    ambient: np.ndarray,
    layout: tuple[int, int, int],
    black: float,
    saturated: np.ndarray | None,
    compiled: bool = False,
) -> np.ndarray:
    """The inverse-variance weights (:meth:`NoiseLine.weights`) of the ambient's block sums ``ambient`` (N,), laid
    out ``layout`` = (block rows, channels, block columns), under :func:`ambient_block_noise`'s line: what
    :class:`processing.block_rows.BlockRows` weighs every row by.

    ``compiled`` (the kernels loaded; the block rows' route, :func:`processing.frame_kernels.statistics_compiled`):
    the floor's quantile by a compiled selection and the weights' steps before their normalisation in one compiled
    pass (:func:`processing.frame_kernels.floor_level`, :func:`processing.frame_kernels.inverse_variances`), the
    mean by numpy's: **the same weights to the bit** on both routes (a k-th smallest is one number; the same IEEE
    operations in the same order), in less time (docs/speed.md).
    """
    if not compiled:
        blocks = ambient.reshape(layout).transpose(0, 2, 1)
        return ambient_block_noise(pixel, factor, blocks, black, saturated).weights(ambient, black)
    height, channels, width = layout
    count = ambient.size if saturated is None else int(height * width - np.count_nonzero(saturated)) * channels
    line = _floored_line(
        pixel,
        factor,
        count,
        lambda position: frame_kernels.floor_level(ambient, saturated, layout, black, position),
    )
    return line.weights(ambient, black, compiled=True)
