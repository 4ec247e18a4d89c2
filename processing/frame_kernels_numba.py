"""The numba kernels behind :mod:`processing.frame_kernels` (imported only through it; needs numba).

Compiled on first use and cached on disk (``cache=True``): each kernel specialisation (frame type, CFA period,
channels, block size) once per installation, then loaded from the cache (the cost: docs/speed.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from msflash.processing.noise_kernels_numba import (  # re-exported: frame_kernels reads every kernel here
    RADIX_BITS,
    _band_median,
    _select,
    _stable_order,
    detail_line,
    floor_levels,
    haar_cells,
    inverse_variances,
)

__all__ = [
    "RADIX_BITS",
    "_band_median",
    "_select",
    "_stable_order",
    "block_pass",
    "block_statistics",
    "detail_line",
    "floor_levels",
    "haar_cells",
    "inverse_variances",
    "moments",
    "weighted_sum",
]


@njit(nogil=True, cache=True)
def block_pass(raw, period_t, plane_channels_t, factor_t, white, stride, sums, differences, saturated, first, stop):
    """Block sums (H/f, C', W/f), probed checkerboard half differences (H'/f, W/f, C') and saturated (H/f, W/f) blocks
    of raw rows (H, W·C), for the block rows ``first ≤ r < stop`` (each block row is written by its own
    call alone: threads may share a frame by block rows); ``period_t``, ``plane_channels_t`` and
    ``factor_t`` carry the CFA period, the channels per frame row group (period · C) and the block side
    as their lengths (compile-time constants). Returns whether any of those blocks saturates.

    Each column of a block row's ``factor`` frame rows is summed in one sweep (the rows' values in
    registers, one store per column), with a running maximum for the whole block row; only a block
    row that reaches ``white`` is searched block by block. The column sums are 32-bit unsigned (numba widens
    signed 32-bit sums to 64-bit lanes); where a pixel column group holds an even number of values (a mosaic's two
    CFA columns), each block adds two channels' column sums at once, packed in one 64-bit word (the same integers).
    """
    period = len(period_t)
    group = len(plane_channels_t)  # values per pixel column group: period · C
    factor = len(factor_t)
    width = sums.shape[2]
    span = factor * group  # values of one block's row in a frame row
    n_columns = width * span
    # The rows' sums and alternating sums as unsigned 32-bit (wrapping, so numba keeps 32-bit lanes); an alternating
    # sum carries ``bias`` (> its largest magnitude, factor · 65536), so that every value is a non-negative integer.
    row_sum = np.zeros(n_columns + n_columns % 2, np.uint32)  # an even length: viewed as 64-bit pairs
    row_alternation = np.zeros(n_columns + n_columns % 2, np.uint32)
    pair_sum = row_sum.view(np.uint64)
    pair_alternation = row_alternation.view(np.uint64)
    bias = np.uint32(factor * 65536)
    low = np.uint64(0xFFFFFFFF)
    shift = np.uint64(32)
    paired = group % 2 == 0
    any_saturated = False
    probing = differences.shape[0] > 0
    for block_row in range(first, stop):
        probed = probing and block_row % stride == 0
        probe_row = block_row // stride
        for p in range(period):
            first = block_row * factor * period + p
            top = raw[first, 0]
            if probed:
                for j in range(n_columns):
                    total = np.uint32(0)
                    alternation = bias
                    for member in range(factor):
                        value = raw[first + member * period, j]
                        total = np.uint32(total + value)
                        if member % 2 == 0:
                            alternation = np.uint32(alternation + value)
                        else:
                            alternation = np.uint32(alternation - value)
                        top = max(top, value)
                    row_sum[j] = total
                    row_alternation[j] = alternation
            else:
                for j in range(n_columns):
                    total = np.uint32(0)
                    for member in range(factor):
                        value = raw[first + member * period, j]
                        total = np.uint32(total + value)
                        top = max(top, value)
                    row_sum[j] = total
            if paired:
                # Two channels' sums in one 64-bit word (little-endian: the even channel low): each half's sum stays
                # below 2³² (factor² · 65536 for factor ≤ 181), so no carry crosses; half the loads and additions.
                half_group, half_span = group // 2, span // 2
                for block in range(width):
                    base = block * half_span
                    for q in range(half_group):
                        packed = np.uint64(0)
                        even = np.uint64(0)
                        odd = np.uint64(0)
                        for member in range(factor):
                            packed += pair_sum[base + member * half_group + q]
                            if probed:  # the checkerboard: even rows minus odd rows, then even columns minus odd
                                if member % 2 == 0:
                                    even += pair_alternation[base + member * half_group + q]
                                else:
                                    odd += pair_alternation[base + member * half_group + q]
                        channel = p * group + 2 * q
                        sums[block_row, channel, block] = packed & low
                        sums[block_row, channel + 1, block] = packed >> shift
                        if probed:  # as many odd members as even: the biases cancel
                            differences[probe_row, block, channel] = np.int64(even & low) - np.int64(odd & low)
                            differences[probe_row, block, channel + 1] = np.int64(even >> shift) - np.int64(
                                odd >> shift
                            )
            else:
                for block in range(width):
                    base = block * span
                    for k in range(group):
                        block_total = np.int64(0)
                        half = np.int64(0)
                        for member in range(factor):
                            block_total += row_sum[base + member * group + k]
                            if probed:  # the checkerboard, as above (the biases cancel)
                                if member % 2 == 0:
                                    half += row_alternation[base + member * group + k]
                                else:
                                    half -= row_alternation[base + member * group + k]
                        channel = p * group + k
                        sums[block_row, channel, block] = block_total
                        if probed:
                            differences[probe_row, block, channel] = half
            if top < white:
                continue
            for block in range(width):
                base = block * span
                hit = False
                for member in range(factor):
                    line = raw[first + member * period]
                    for j in range(base, base + span):
                        if line[j] >= white:
                            hit = True
                if hit:
                    saturated[block_row, block] = True
                    any_saturated = True
    return any_saturated


TILE = 1024
"""Samples per tile of :func:`weighted_sum`: its float64 accumulator (8 KB) stays in L1 with the frames' tiles."""


@njit(nogil=True, cache=True)
def weighted_sum(frames, factors, offset, white, channels, output, saturated, start, stop):
    """``output[i] = offset + Σ_j factors[j] · frames[j][i]`` for ``start ≤ i < stop``, summed in the type
    of ``factors`` (float64) in frame order and cast to the output's, and ``saturated[i // channels]``
    where some frame reaches ``white``.

    Four frames are added per sweep of a tile (``((t + w₀a) + w₁b) + w₂c) + w₃d``, the same order and
    roundings as one frame at a time, so the numpy route gives the same bits): the accumulator is loaded
    and stored a quarter as often, which was the kernel's bound. The saturation test is a running
    maximum per tile; only a tile that reaches ``white`` is searched sample by sample.
    """
    tile = max(TILE - TILE % channels, channels)
    total = np.empty(tile, factors.dtype)
    n_frames = len(frames)
    for low in range(start, stop, tile):
        high = min(low + tile, stop)
        n = high - low
        for t in range(n):
            total[t] = offset
        top = frames[0][low]
        j = 0
        while j + 3 < n_frames:
            a, b, c, d = frames[j][low:high], frames[j + 1][low:high], frames[j + 2][low:high], frames[j + 3][low:high]
            wa, wb, wc, wd = factors[j], factors[j + 1], factors[j + 2], factors[j + 3]
            for t in range(n):
                va, vb, vc, vd = a[t], b[t], c[t], d[t]
                total[t] = (((total[t] + wa * va) + wb * vb) + wc * vc) + wd * vd
                top = max(top, max(max(va, vb), max(vc, vd)))
            j += 4
        while j < n_frames:
            a = frames[j][low:high]
            wa = factors[j]
            for t in range(n):
                va = a[t]
                total[t] += wa * va
                top = max(top, va)
            j += 1
        out = output[low:high]
        for t in range(n):
            out[t] = total[t]
        if top >= white:
            for j in range(n_frames):
                frame = frames[j][low:high]
                for t in range(n):
                    if frame[t] >= white:
                        saturated[(low + t) // channels] = True


MOMENT_TILE = 192
"""Samples per tile of :func:`moments`: every row's float64 tile together stays in L1 (9 × 192 × 8 B)."""
MOMENT_BLOCK = 3
"""Rows per side of the blocks of :func:`moments`' products: 3 × 3 running sums and 6 rows fit the registers."""


@njit(nogil=True, cache=True, fastmath=True)
def moments(frames, channels, white, start, stop, out):
    """Raw second moments of the rows ``[frames…, 1]`` over the flat samples ``start ≤ t < stop`` (whole
    pixels), leaving out every sample of a pixel that some frame saturates (a sample at or above ``white``):
    ``out[i, j] += Σ_t x_i x_j`` for ``i, j ≤ n`` with ``n = len(frames)`` and ``x_n = 1`` (so
    ``out[n, i]`` is the sum of row i and ``out[n, n]`` the count). ``out`` is (r, r) with r the rows
    rounded up to :data:`MOMENT_BLOCK`; only its lower triangle (``j ≤ i``) is meaningful.

    Each tile of samples is converted to float64 once, in cache; the products are taken in 3 × 3 blocks
    of rows, so each loaded value serves three products. A saturated pixel's samples are zeroed in every row, the row of ones included.
    """
    n = len(frames)
    rows = out.shape[0]
    tile = max(MOMENT_TILE - MOMENT_TILE % channels, channels)
    values = np.zeros((rows, tile))
    for low in range(start, stop, tile):
        high = min(low + tile, stop)
        width = high - low
        top = frames[0][low]
        for i in range(n):
            source = frames[i][low:high]
            target = values[i]
            for t in range(width):
                value = source[t]
                target[t] = value
                top = max(top, value)
        ones = values[n]
        for t in range(width):
            ones[t] = 1.0
        if width < tile:  # the last tile: its unused columns add nothing
            for i in range(rows):
                for t in range(width, tile):
                    values[i, t] = 0.0
        if top >= white:
            for pixel in range(width // channels):
                hit = False
                for i in range(n):
                    for c in range(channels):
                        if frames[i][low + pixel * channels + c] >= white:
                            hit = True
                if hit:
                    for i in range(n + 1):
                        for c in range(channels):
                            values[i, pixel * channels + c] = 0.0
        for first in range(0, rows, 3):
            a0, a1, a2 = values[first], values[first + 1], values[first + 2]
            for second in range(0, first + 3, 3):
                b0, b1, b2 = values[second], values[second + 1], values[second + 2]
                s00 = s01 = s02 = s10 = s11 = s12 = s20 = s21 = s22 = 0.0
                for t in range(tile):
                    x0, x1, x2, y0, y1, y2 = a0[t], a1[t], a2[t], b0[t], b1[t], b2[t]
                    s00 += x0 * y0
                    s01 += x0 * y1
                    s02 += x0 * y2
                    s10 += x1 * y0
                    s11 += x1 * y1
                    s12 += x1 * y2
                    s20 += x2 * y0
                    s21 += x2 * y1
                    s22 += x2 * y2
                out[first, second] += s00
                out[first, second + 1] += s01
                out[first, second + 2] += s02
                out[first + 1, second] += s10
                out[first + 1, second + 1] += s11
                out[first + 1, second + 2] += s12
                out[first + 2, second] += s20
                out[first + 2, second + 1] += s21
                out[first + 2, second + 2] += s22


@njit(nogil=True, cache=True, fastmath=True)
def block_statistics(
    values, weights, factors, masked, transform, height, channels, width, channels_inner, gram_rows, gram, fa, ff, aa
):
    """The moments of block rows in one pass over them, block row by block row (each block row's values in cache):
    ``gram[i, j] += Σ_t w_t x_it x_jt`` (``j ≤ i < gram_rows``; the rows from ``gram_rows`` on
    are zero, as the probe's ones row) over the columns ``t`` of ``values`` (R, N), weighted by ``weights`` (N,); and
    the channel moments of the images ``y = transform · x`` (K + 1, R) scaled by ``factors`` (N,; all ones unless
    ``masked``): per image ``i < K`` and channels ``c, d``, ``fa[i, c, d] += Σ y_ic y_Kd`` and ``ff[i, c, d] += Σ y_ic
    y_id`` over the blocks, and ``aa[c, d] += Σ y_Kc y_Kd`` (``gram``, ``ff`` and ``aa`` summed for ``d ≤ c`` only, then
    their upper triangles set from the lower: symmetric).

    The N columns are ``height`` block rows of ``channels × width`` values, laid out (channel, block column) or, with
    ``channels_inner``, (block column, channel). Sums are reassociated (fastmath): the numpy route
    (:class:`processing.block_rows.BlockRows`) agrees to rounding, not to the bit. The map skips the transform's zeros
    (an LED image is two rows' difference, the ambient's one row less its black: 2 of R rows each), and in the
    (channel, block column) layout the images are mapped in place of their channel-order copy; both only leave out
    additions of zero (the dense map's numbers to the bit on the bench's worlds; docs/speed.md, rawblock30).
    """
    rows = values.shape[0]
    images = transform.shape[0]
    k = images - 1
    inner = channels * width
    weighted = np.empty((rows, inner))
    image = np.empty((images, channels, width))
    mapped = np.empty((images, inner)) if channels_inner else image.reshape((images, inner))
    for h in range(height):
        base = h * inner
        for i in range(gram_rows):
            source = values[i, base : base + inner]
            target = weighted[i]
            for t in range(inner):
                target[t] = weights[base + t] * source[t]
        for i in range(gram_rows):
            left = weighted[i]
            # Four products with one weighted row in one sweep (its values loaded once, four independent sums):
            # the gain: docs/speed.md, rawest30.
            fours = (i + 1) // 4 * 4
            for j in range(0, fours, 4):
                right0 = values[j, base : base + inner]
                right1 = values[j + 1, base : base + inner]
                right2 = values[j + 2, base : base + inner]
                right3 = values[j + 3, base : base + inner]
                total0 = total1 = total2 = total3 = 0.0
                for t in range(inner):
                    x = left[t]
                    total0 += x * right0[t]
                    total1 += x * right1[t]
                    total2 += x * right2[t]
                    total3 += x * right3[t]
                gram[i, j] += total0
                gram[i, j + 1] += total1
                gram[i, j + 2] += total2
                gram[i, j + 3] += total3
            for j in range(fours, i + 1):
                right = values[j, base : base + inner]
                total = 0.0
                for t in range(inner):
                    total += left[t] * right[t]
                gram[i, j] += total
        for i in range(images):
            target = mapped[i]
            for t in range(inner):
                target[t] = 0.0
            for j in range(rows):
                scale = transform[i, j]
                if scale == 0.0:
                    continue
                source = values[j, base : base + inner]
                for t in range(inner):
                    target[t] += scale * source[t]
            if masked:
                for t in range(inner):
                    target[t] *= factors[base + t]
            if channels_inner:
                for b in range(width):
                    for c in range(channels):
                        image[i, c, b] = target[b * channels + c]
        _image_moments(image, k, channels, width, fa, ff, aa)
    for i in range(rows):  # the upper triangles from the lower
        for j in range(i):
            gram[j, i] = gram[i, j]
    for c in range(channels):
        for d in range(c):
            aa[d, c] = aa[c, d]
            for i in range(k):
                ff[i, d, c] = ff[i, c, d]


@njit(nogil=True, cache=True, fastmath=True)
def _image_moments(image, k, channels, width, fa, ff, aa):
    """One block row's channel moments of the mapped images ``image`` (K + 1, C, W), LEDs first: ``fa[i, c, d] += Σ_b
    y_icb y_Kdb``, ``ff[i, c, d] += Σ_b y_icb y_idb`` and ``aa[c, d] += Σ_b y_Kcb y_Kdb`` (``ff`` and ``aa`` for
    ``d ≤ c`` only). Four channels (a mosaic's CFA planes) take each LED's 16 + 10 sums in two sweeps over the block
    columns (:func:`_led_sums4`); a sum a loop, as for other channel counts, spent more on each short loop's set-up and
    final reduction than on its 80 products (docs/speed.md, rawspeed30d)."""
    ambient = image[k]
    for i in range(k):
        led = image[i]
        if channels == 4:
            _led_sums4(led, ambient, width, fa[i], ff[i])
            continue
        for c in range(channels):
            first = led[c]
            for d in range(c + 1):
                other = ambient[d]
                second = led[d]
                cross = 0.0
                own = 0.0
                for b in range(width):
                    cross += first[b] * other[b]
                    own += first[b] * second[b]
                fa[i, c, d] += cross
                ff[i, c, d] += own
            for d in range(c + 1, channels):
                other = ambient[d]
                cross = 0.0
                for b in range(width):
                    cross += first[b] * other[b]
                fa[i, c, d] += cross
    for c in range(channels):
        first = ambient[c]
        for d in range(c + 1):
            other = ambient[d]
            total = 0.0
            for b in range(width):
                total += first[b] * other[b]
            aa[c, d] += total


@njit(nogil=True, cache=True, fastmath=True)
def _led_sums4(led, ambient, width, fa, ff):
    """:func:`_image_moments` of one LED image ``led`` (4, W) with the ambient's (4, W): ``fa`` (4, 4) in one sweep
    (16 sums), the lower triangle of ``ff`` in another (10); each sum's products in block-column order, as before."""
    l0, l1, l2, l3 = led[0], led[1], led[2], led[3]
    a0, a1, a2, a3 = ambient[0], ambient[1], ambient[2], ambient[3]
    x00 = x01 = x02 = x03 = x10 = x11 = x12 = x13 = 0.0
    x20 = x21 = x22 = x23 = x30 = x31 = x32 = x33 = 0.0
    for b in range(width):
        p0, p1, p2, p3 = l0[b], l1[b], l2[b], l3[b]
        q0, q1, q2, q3 = a0[b], a1[b], a2[b], a3[b]
        x00 += p0 * q0
        x01 += p0 * q1
        x02 += p0 * q2
        x03 += p0 * q3
        x10 += p1 * q0
        x11 += p1 * q1
        x12 += p1 * q2
        x13 += p1 * q3
        x20 += p2 * q0
        x21 += p2 * q1
        x22 += p2 * q2
        x23 += p2 * q3
        x30 += p3 * q0
        x31 += p3 * q1
        x32 += p3 * q2
        x33 += p3 * q3
    fa[0, 0] += x00
    fa[0, 1] += x01
    fa[0, 2] += x02
    fa[0, 3] += x03
    fa[1, 0] += x10
    fa[1, 1] += x11
    fa[1, 2] += x12
    fa[1, 3] += x13
    fa[2, 0] += x20
    fa[2, 1] += x21
    fa[2, 2] += x22
    fa[2, 3] += x23
    fa[3, 0] += x30
    fa[3, 1] += x31
    fa[3, 2] += x32
    fa[3, 3] += x33
    y00 = y10 = y11 = y20 = y21 = y22 = y30 = y31 = y32 = y33 = 0.0
    for b in range(width):
        p0, p1, p2, p3 = l0[b], l1[b], l2[b], l3[b]
        y00 += p0 * p0
        y10 += p1 * p0
        y11 += p1 * p1
        y20 += p2 * p0
        y21 += p2 * p1
        y22 += p2 * p2
        y30 += p3 * p0
        y31 += p3 * p1
        y32 += p3 * p2
        y33 += p3 * p3
    ff[0, 0] += y00
    ff[1, 0] += y10
    ff[1, 1] += y11
    ff[2, 0] += y20
    ff[2, 1] += y21
    ff[2, 2] += y22
    ff[3, 0] += y30
    ff[3, 1] += y31
    ff[3, 2] += y32
    ff[3, 3] += y33
