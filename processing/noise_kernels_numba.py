"""The numba kernels of the ambient's noise line and the inverse-variance weights (:mod:`processing.noise_level`), behind
:mod:`processing.frame_kernels` (imported only through :mod:`processing.frame_kernels_numba`, which re-exports them;
needs numba). Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _weighted_line(levels, values, weights, count):
    """:func:`processing.noise_level._weighted_line` of the first ``count`` entries, its sums taken in order."""
    sw = sx = sy = sxx = sxy = 0.0
    for t in range(count):
        w, x, y = weights[t], levels[t], values[t]
        sw += w
        sx += w * x
        sy += w * y
        sxx += w * (x * x)
        sxy += w * (x * y)
    determinant = sw * sxx - sx * sx
    if determinant > 0:
        gain, offset = (sw * sxy - sx * sy) / determinant, (sxx * sy - sx * sxy) / determinant
    else:
        gain, offset = 0.0, -1.0
    if offset < 0:
        gain, offset = (sxy / sxx if sxx > 0 else 0.0), 0.0
    if gain < 0:
        gain, offset = 0.0, (sy / sw if sw > 0 else 0.0)
    return gain, offset


@njit(cache=True)
def _select(values, k, first, second):
    """The ``k``-th smallest of ``values`` (no NaN; left as they are), with ``first`` and ``second`` as scratch of its
    size. Each round splits the range around a median of three into the values below it (to the front of a scratch
    array) and above it (to the back), written without a branch: a data-dependent branch per value (Hoare's
    partition) is mispredicted about every other time, and swapping in place waits on each store (the figures:
    docs/measurements.md). The values equal to the pivot (many ties: squares of integer details) end the search."""
    source, start, size = values, 0, values.size
    target = first
    while size > 1:
        a, b, c = source[start], source[start + size // 2], source[start + size - 1]
        pivot = max(min(a, b), min(max(a, b), c))
        below = above = 0
        for i in range(start, start + size):
            value = source[i]
            target[below] = value
            target[size - 1 - above] = value
            below += value < pivot
            above += value > pivot
        if k < below:
            source, start, size = target, 0, below
        elif k < size - above:
            return pivot
        else:
            source, start, k, size = target, size - above, k - (size - above), above
        target = second if target is first else first
    return source[start]


@njit(cache=True)
def _band_median(values, first, second):
    """``np.median`` of ``values`` (no NaN): the middle value, or the mean of the middle two (:func:`_select`)."""
    half = values.size // 2
    if values.size % 2:
        return _select(values, half, first, second)
    lower = _select(values, half - 1, first, second)
    # The next value up: ``lower`` again where more than ``half`` values are at most it, else the least above it.
    at_most = 0
    above = np.inf
    for value in values:
        at_most += value <= lower
        if value > lower:
            above = min(above, value)
    return (lower + (lower if at_most > half else above)) / 2


RADIX_BITS = 11
"""Bits of the key :func:`_stable_order` sorts by in each pass (2 048 counts, in L1)."""


@njit(cache=True)
def _stable_order(levels):
    """The indices that sort ``levels`` (≥ 0, no NaN; +0.0 for zero), equal levels in index order: what numpy's
    stable argsort gives, by a least-significant-digit radix sort of the values' bits (non-negative doubles sort as
    their bit patterns), over the bits that vary only (whole-number levels below 2¹⁶: 3 passes of 11 bits)."""
    n = levels.size
    keys = levels.view(np.uint64)
    order = np.arange(n)
    other = np.empty(n, np.int64)
    buckets = 1 << RADIX_BITS
    mask = np.uint64(buckets - 1)
    counts = np.empty(buckets + 1, np.int64)
    ones = np.uint64(0)
    zeros = ~np.uint64(0)
    for t in range(n):
        ones |= keys[t]
        zeros &= keys[t]
    varying = ones & ~zeros  # the bits some values have and others not
    shift = 0
    while shift < 64 and (varying >> np.uint64(shift)) & np.uint64(1) == 0:
        shift += 1
    while shift < 64 and varying >> np.uint64(shift) != 0:
        width = np.uint64(shift)
        counts[:] = 0
        for t in range(n):
            counts[np.intp((keys[t] >> width) & mask) + 1] += 1
        for b in range(buckets):
            counts[b + 1] += counts[b]
        for t in range(n):
            index = order[t]
            digit = np.intp((keys[index] >> width) & mask)
            other[counts[digit]] = index
            counts[digit] += 1
        order, other = other, order
        shift += RADIX_BITS
    return order


@njit(nogil=True, cache=True)
def detail_line(
    levels, diagonal, across, down, bands, smooth, cut, cut_mean, rounds, converged, min_cells, median, tiny
):
    """:func:`processing.noise_level.fit_detail_line` in one compiled call: ``(found, gain, offset)`` of the cells'
    line (``found`` False where the numpy fit returns None). The same steps, selections and thresholds; the sums
    taken in order (numpy's are pairwise or BLAS's), so the line agrees with numpy's to rounding."""
    n = levels.size
    level = np.empty(n)
    squares = np.empty(n)
    scaled = np.empty(n)
    texture = np.empty(n)
    total = 0.0
    top = 0.0
    for t in range(n):
        value = max(levels[t], 0.0) + 0.0  # +0.0 for a -0.0 (the radix sort reads the bits)
        level[t] = value
        top = max(top, value)
        squares[t] = diagonal[t] * diagonal[t]
        scaled[t] = squares[t] / cut_mean
        texture[t] = across[t] * across[t] + down[t] * down[t]
        total += squares[t] + texture[t]
    if n < min_cells or not np.isfinite(total):
        return False, 0.0, 0.0
    order = _stable_order(level)  # equal levels in index order, as numpy's stable argsort
    per_band = n // bands
    gain = offset = 0.0
    if per_band >= 8:
        centres = np.empty(bands)
        variances = np.empty(bands)
        band = np.empty(per_band)
        first = np.empty(per_band)
        second = np.empty(per_band)
        for b in range(bands):
            members = order[b * per_band : (b + 1) * per_band]
            centre = 0.0
            for t in range(per_band):
                centre += level[members[t]]
            centres[b] = centre / per_band
            least = np.inf
            for detail in (diagonal, across, down):
                for t in range(per_band):
                    value = detail[members[t]]
                    band[t] = value * value
                least = min(least, _band_median(band, first, second))
            variances[b] = least / median
        largest = variances.max()
        if largest > tiny:
            weights = np.empty(bands)
            for b in range(bands):
                variances[b] = max(variances[b], largest * 1e-12)
                weights[b] = per_band / (variances[b] * variances[b])
            gain, offset = _weighted_line(centres, variances, weights, bands)
    kept_levels = np.empty(n)
    kept_values = np.empty(n)
    kept_weights = np.empty(n)
    for _ in range(rounds):
        peak = gain * top + offset if gain >= 0 and np.isfinite(gain) else -np.inf
        if not (gain >= 0 and np.isfinite(gain)):
            for t in range(n):
                peak = max(peak, level[t] * gain + offset)
        if not peak > tiny:
            return False, 0.0, 0.0
        least = peak * 1e-12
        count = 0
        for t in range(n):
            variance = max(level[t] * gain + offset, least)
            if texture[t] <= smooth * variance and squares[t] <= cut * variance:
                kept_levels[count] = level[t]
                kept_values[count] = scaled[t]
                kept_weights[count] = variance * variance
                count += 1
        if count < min_cells:
            break
        previous_gain, previous_offset = gain, offset
        for t in range(count):  # apart from the selection: a loop without branches divides four lanes at a time
            kept_weights[t] = 1.0 / kept_weights[t]
        gain, offset = _weighted_line(kept_levels, kept_values, kept_weights, count)
        if abs(gain - previous_gain) <= converged * abs(gain) and abs(offset - previous_offset) <= converged * abs(
            offset
        ):
            break
    half = n // 2
    middle = level[order[half]] if n % 2 else (level[order[half - 1]] + level[order[half]]) / 2
    if not gain * middle + offset > 0:
        return False, 0.0, 0.0
    return True, gain, offset


@njit(nogil=True, cache=True)
def haar_cells(rows, channels, period, cell_rows, stride, cell_columns, black, white):
    """:func:`processing.noise_level.haar_details` of raw integer rows (H, W·C): ``(S, HH, HL, LH)`` of the 2 × 2 cells
    of every ``stride``-th of the first ``cell_rows`` rows of cells and of the first ``cell_columns`` cell columns, in
    (cell row, cell column, phase row, phase column, channel) order, cells with a sample at or above ``white`` left
    out. The same float64 operations in the same order on exact integers: the same arrays to the bit."""
    per_row = cell_columns * period * period * channels
    slabs = len(range(0, cell_rows, stride))
    levels = np.empty(slabs * per_row)
    diagonal = np.empty(slabs * per_row)
    across = np.empty(slabs * per_row)
    down = np.empty(slabs * per_row)
    black4 = 4.0 * black
    count = 0
    for cell_row in range(0, cell_rows, stride):
        top = cell_row * 2 * period
        for cell_column in range(cell_columns):
            left = cell_column * 2 * period
            for p in range(period):
                upper, lower = rows[top + p], rows[top + period + p]
                for q in range(period):
                    first, second = (left + q) * channels, (left + period + q) * channels
                    for c in range(channels):
                        x00, x01 = float(upper[first + c]), float(upper[second + c])
                        x10, x11 = float(lower[first + c]), float(lower[second + c])
                        if max(max(x00, x01), max(x10, x11)) >= white:
                            continue
                        top_sum, bottom_sum = x00 + x01, x10 + x11
                        top_difference, bottom_difference = x00 - x01, x10 - x11
                        total = top_sum + bottom_sum
                        total -= black4
                        levels[count] = total
                        diagonal[count] = top_difference - bottom_difference
                        across[count] = top_difference + bottom_difference
                        down[count] = top_sum - bottom_sum
                        count += 1
    return levels[:count], diagonal[:count], across[:count], down[:count]


@njit(nogil=True, cache=True)
def floor_levels(values, left_out, masked, channels, width, black):
    """``values − black`` over the blocks not ``left_out``: ``values`` (N,) one row of block sums laid out (block row,
    channel, block column), ``left_out`` (block rows, ``width``) the blocks to leave out where ``masked``. The levels
    whose quantile :func:`processing.noise_level.block_noise_line` takes (in another order: a quantile is one value)."""
    levels = np.empty(values.size)
    if not masked:
        for t in range(values.size):
            levels[t] = values[t] - black
        return levels
    count = 0
    for block_row in range(values.size // (channels * width)):
        for channel in range(channels):
            base = (block_row * channels + channel) * width
            for column in range(width):
                if not left_out[block_row, column]:
                    levels[count] = values[base + column] - black
                    count += 1
    return levels[:count]


@njit(nogil=True, cache=True)
def inverse_variances(values, black, gain, read, floor, out):
    """``1 / max(max(values − black, 0) · gain + read, floor)`` into ``out``: the steps of
    :meth:`processing.noise_level.NoiseLine.weights` before its normalisation, one IEEE operation each in the same
    order (no fastmath: no fused multiply-add), so the same numbers to the bit."""
    for t in range(values.size):
        variance = values[t] - black
        variance = max(variance, 0.0)
        variance = variance * gain
        variance = variance + read
        variance = max(variance, floor)
        out[t] = 1.0 / variance
