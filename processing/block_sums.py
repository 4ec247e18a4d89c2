"""Block sums of frame planes: exact ``factor × factor`` sums, the checkerboard half differences (the noise
probe, :mod:`processing.block_rows`), block maxima and saturated blocks, and the CFA planes of a mosaic.

Integer data is summed in float32 (exact for ≤ 16-bit data in blocks ≤ 16×16), float data in float64; the
compiled pass of :mod:`processing.frame_kernels` gives the same integers.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from msflash.processing.errors import SpectralDataError

GATHER_ROWS = 2048
"""Rows per BLAS call in :func:`block_sums`: below OpenBLAS's threading threshold for this thin product."""


ROW_SUM_BAND_BYTES = 1 << 18
"""Raw bytes per band of the block rows' sums (:func:`block_row_sums_and_peak`): a band stays in a core's
cache for its saturation max."""


def bin_frame(frame: np.ndarray, factor: int, cfa_period: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Sum ``factor × factor`` blocks of a frame (per CFA plane for a mosaic); also the block maxima.

    The image formation model is linear, so block sums obey it exactly — whatever the texture
    inside a block — while their noise variance relative to the signal drops by ``factor²``. That
    shrinks the errors-in-variables bias of regressing on noisy LED-only images (the authors'
    code, hblasins/compMultispFlash, downsamples by 4 too). Edges that do not fill a block are dropped.

    Parameters
    ----------
    frame
        (H, W) or (H, W, C) raw values.
    factor
        Block size.
    cfa_period
        2 for a Bayer mosaic: the four CFA planes are binned separately and returned as the
        channels of a (H/2/factor, W/2/factor, 4) array (estimation needs no mosaic layout).

    Returns
    -------
    tuple
        ``(sums, maxima)``: block sums (float32 for integer frames — exact for ≤ 16-bit data and
        blocks ≤ 16×16 — float64 for float frames) and block maxima in the frame's type.

    Examples
    --------
    >>> sums, top = bin_frame(np.arange(16.0).reshape(4, 4), 2)
    >>> sums.tolist(), top.tolist()
    ([[10.0, 18.0], [42.0, 50.0]], [[5.0, 7.0], [13.0, 15.0]])
    """
    if cfa_period == 2:
        frame = cfa_planes(frame, 2)
    # float32 sums are exact for integer data ≤ 16 bits in blocks ≤ 16×16; float frames keep float64.
    sum_type = np.float64 if np.issubdtype(frame.dtype, np.floating) else np.float32
    if factor == 1:
        return frame.astype(sum_type), frame
    height, width = (frame.shape[0] // factor) * factor, (frame.shape[1] // factor) * factor
    if height == 0 or width == 0:
        raise SpectralDataError(
            f"frame of shape {frame.shape} is smaller than one {factor}×{factor} block; expected a larger frame"
        )
    cropped = frame[:height, :width]
    # Strided slices summed one offset at a time: each pass streams through memory, where a
    # reshape-and-sum over two strided axes would crawl.
    row_sums: np.ndarray = cropped[0::factor].astype(sum_type)
    row_max = cropped[0::factor].copy()
    for offset in range(1, factor):
        row_sums += cropped[offset::factor]
        np.maximum(row_max, cropped[offset::factor], out=row_max)
    sums: np.ndarray = row_sums[:, 0::factor].copy()
    maxima = row_max[:, 0::factor].copy()
    for offset in range(1, factor):
        sums += row_sums[:, offset::factor]
        np.maximum(maxima, row_max[:, offset::factor], out=maxima)
    return sums, maxima


def plane_shape(frame_shape: tuple[int, ...], cfa_period: int) -> tuple[int, int, int]:
    """The shape of :func:`cfa_planes` of a frame of ``frame_shape`` (without building them).

    Examples
    --------
    >>> plane_shape((5, 7), 2), plane_shape((5, 7, 3), 1), plane_shape((5, 7), 1)
    ((2, 3, 4), (5, 7, 3), (5, 7, 1))
    """
    if cfa_period == 2:
        return (frame_shape[0] // 2, frame_shape[1] // 2, 4)
    return (frame_shape[0], frame_shape[1], frame_shape[2] if len(frame_shape) == 3 else 1)


def cfa_planes(frame: np.ndarray, cfa_period: int) -> np.ndarray:
    """(H, W, C) view of a frame; a Bayer mosaic becomes its four CFA planes as channels."""
    if cfa_period == 2:
        rows, columns = frame.shape[0] // 2, frame.shape[1] // 2
        return np.stack([frame[p : 2 * rows : 2, q : 2 * columns : 2] for p in (0, 1) for q in (0, 1)], axis=-1)
    return frame if frame.ndim == 3 else frame[:, :, None]


def frame_may_saturate(frame: np.ndarray, white: float) -> bool:
    """Whether any sample of a frame reaches the white level (a fast contiguous max)."""
    if np.issubdtype(frame.dtype, np.integer) and np.iinfo(frame.dtype).max < white:
        return False  # the type cannot reach the white level
    return bool(frame.size) and bool(frame.max() >= white)


def saturated_blocks(plane: np.ndarray, factor: int, white: float) -> np.ndarray:
    """(H/f, W/f) mask of the ``factor × factor`` blocks of an (H, W, C) plane with any sample ≥ ``white``.

    Block maxima first, then one comparison: the maxima over a block's ``factor`` rows run along
    whole contiguous rows, and the maxima over its ``factor · C`` columns work on data already
    ``factor`` times smaller (this runs on the capture's latency path for the last frame). ``fmax``
    ignores NaN as the comparison does.
    """
    height, width, channels = plane.shape[0] // factor, plane.shape[1] // factor, plane.shape[2]
    groups = plane[: height * factor, : width * factor].reshape(height, factor, width * factor * channels)
    peak = np.fmax if np.issubdtype(plane.dtype, np.floating) else np.maximum
    row_maxima = groups[:, 0].copy()
    for member in range(1, factor):
        peak(row_maxima, groups[:, member], out=row_maxima)
    members = row_maxima.reshape(height, width, factor * channels)
    block_maxima = members[:, :, 0].copy()
    for member in range(1, factor * channels):
        peak(block_maxima, members[:, :, member], out=block_maxima)
    return block_maxima >= white


@lru_cache(maxsize=32)
def gather_matrix(factor: int, channels: int, dtype: type) -> np.ndarray:
    """(factor·channels, channels) 0/1 matrix summing the ``factor`` pixels of a row group per channel."""
    gather: np.ndarray = np.zeros((factor * channels, channels), dtype=dtype)
    for member in range(factor):
        gather[member * channels : (member + 1) * channels] = np.eye(channels, dtype=dtype)
    gather.flags.writeable = False
    return gather


def block_sums(plane: np.ndarray, factor: int) -> np.ndarray:
    """Exact ``factor × factor`` block sums of an (H, W, C) plane, shape (H/f, W/f, C); edges dropped.

    Integer data is summed in float32 (exact for ≤ 16 bits in blocks ≤ 16×16), float data in
    float64.

    Examples
    --------
    >>> block_sums(np.arange(16.0).reshape(4, 4, 1), 2)[:, :, 0].tolist()
    [[10.0, 18.0], [42.0, 50.0]]
    """
    return gathered(_block_row_sums(plane, factor), factor, plane.shape[2], gather_matrix)


def _block_row_sums(plane: np.ndarray, factor: int) -> np.ndarray:
    """The sums over each block's rows of an (H, W, C) plane: (H/f, W/f·f·C), edges dropped.

    Integer data is summed in float32 (exact for ≤ 16 bits in blocks ≤ 16×16), float data in float64.
    A reduction over the middle axis streams whole rows (long inner loops).
    """
    height, width, channels = plane.shape[0] // factor, plane.shape[1] // factor, plane.shape[2]
    sum_type = np.float64 if np.issubdtype(plane.dtype, np.floating) else np.float32
    cropped = plane[: height * factor, : width * factor].reshape(height, factor, width * factor * channels)
    return cropped.sum(axis=1, dtype=sum_type)


def block_row_sums_and_peak(plane: np.ndarray, factor: int, white: float) -> tuple[np.ndarray, bool]:
    """:func:`_block_row_sums`, and whether any sample of the blocks reaches ``white`` (as :func:`frame_may_saturate`).

    Taken in bands of block rows of about :data:`ROW_SUM_BAND_BYTES`: each band's max reads it while the
    sums have just brought it into cache, where a separate max of the whole frame reads it from memory again.
    """
    height, width, channels = plane.shape[0] // factor, plane.shape[1] // factor, plane.shape[2]
    sum_type = np.float64 if np.issubdtype(plane.dtype, np.floating) else np.float32
    cropped = plane[: height * factor, : width * factor].reshape(height, factor, width * factor * channels)
    if np.issubdtype(plane.dtype, np.integer) and np.iinfo(plane.dtype).max < white:
        return cropped.sum(axis=1, dtype=sum_type), False  # the type cannot reach the white level
    sums = np.empty((height, cropped.shape[2]), dtype=sum_type)
    band = max(1, ROW_SUM_BAND_BYTES // max(cropped[0].nbytes, 1))
    peak = False
    for start in range(0, height, band):
        part = cropped[start : start + band]
        np.add.reduce(part, axis=1, dtype=sum_type, out=sums[start : start + band])
        peak = peak or bool(part.max() >= white)
    return sums, peak


def gathered(row_sums: np.ndarray, factor: int, channels: int, matrix) -> np.ndarray:
    """Block rows' sums (:func:`_block_row_sums`) gathered per block by ``matrix(factor, channels, dtype)``.

    Each group of ``factor`` pixels is factor·channels contiguous values, so a thin matrix product
    with a gather matrix combines them per channel — far faster than strided slicing, and exact
    (±1/0 weights, integer sums below 2²⁴ in float32). The product runs in slices of GATHER_ROWS
    groups: OpenBLAS splits larger ones across threads, whose wake-up and spinning cost more than
    the product on a busy 2-core machine (docs/architecture.md §10). Returns (H/f, W/f, m) for
    a (factor·channels, m) matrix.
    """
    height, width = row_sums.shape[0], row_sums.shape[1] // (factor * channels)
    groups = row_sums.reshape(height * width, factor * channels)
    gather = matrix(factor, channels, row_sums.dtype.type)
    grouped = np.empty((height * width, gather.shape[1]), dtype=row_sums.dtype)
    for start in range(0, groups.shape[0], GATHER_ROWS):
        np.matmul(groups[start : start + GATHER_ROWS], gather, out=grouped[start : start + GATHER_ROWS])
    return grouped.reshape(height, width, gather.shape[1])


def block_row_alternation(plane: np.ndarray, factor: int, stride: int = 1) -> np.ndarray:
    """Each block's even rows minus its odd rows, per column, of an (H, W, C) plane: (⌈(H/f)/stride⌉, W/f·f·C).

    Block rows ``0, stride, 2·stride…`` only; edges dropped; exact as :func:`_block_row_sums` (integers below
    2²⁴ in float32). Gathered with :func:`difference_gather`, the checkerboard probe of the module notes.
    """
    height, width, channels = plane.shape[0] // factor, plane.shape[1] // factor, plane.shape[2]
    sum_type = np.float64 if np.issubdtype(plane.dtype, np.floating) else np.float32
    cropped = plane[: height * factor, : width * factor].reshape(height, factor, width * factor * channels)[::stride]
    alternation = cropped[:, 0::2].sum(axis=1, dtype=sum_type)
    alternation -= cropped[:, 1::2].sum(axis=1, dtype=sum_type)
    return alternation


@lru_cache(maxsize=16)
def difference_gather(factor: int, channels: int, dtype: type) -> np.ndarray:
    """(factor·channels, channels) ±1 matrix: per channel, a row group's even pixels minus its odd ones."""
    gather: np.ndarray = np.zeros((factor, channels, channels), dtype=dtype)
    for member in range(factor):
        gather[member] = np.eye(channels, dtype=dtype) * (1.0 if member % 2 == 0 else -1.0)
    gather = gather.reshape(factor * channels, channels)
    gather.flags.writeable = False
    return gather


def block_sums_and_differences(plane: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """Block sums of an (H, W, C) plane and their checkerboard half differences, each (H/f, W/f, C).

    A block's half difference is the sum of its samples at even ``row + column`` minus those at odd (both
    counted within the block): the noise probe of the module notes (even ``factor``). Exact: integers below
    2²⁴ in float32 for ≤ 16-bit data and blocks ≤ 16×16.

    Examples
    --------
    A ramp, an edge along the rows or the columns: no half difference (the halves see the same light).

    >>> ramp = np.arange(16.0).reshape(4, 4, 1)
    >>> sums, differences = block_sums_and_differences(ramp, 2)
    >>> sums[:, :, 0].tolist(), differences[:, :, 0].tolist()
    ([[10.0, 18.0], [42.0, 50.0]], [[0.0, 0.0], [0.0, 0.0]])
    >>> edge = np.zeros((4, 4, 1)); edge[:, 1:] = 100.0
    >>> block_sums_and_differences(edge, 4)[1].tolist(), block_sums_and_differences(edge.transpose(1, 0, 2), 4)[1].tolist()
    ([[[0.0]]], [[[0.0]]])
    """
    channels = plane.shape[2]
    sums = gathered(_block_row_sums(plane, factor), factor, channels, gather_matrix)
    return sums, gathered(block_row_alternation(plane, factor), factor, channels, difference_gather)


def block_sums_into(plane: np.ndarray, factor: int, out: np.ndarray) -> None:
    """Write the block sums of an (H, W, C) plane into ``out`` (H/f, C, W/f), float64 (moment-row order)."""
    gathered_by_channel(_block_row_sums(plane, factor), factor, plane.shape[2], out)


def gathered_by_channel(row_sums: np.ndarray, factor: int, channels: int, out: np.ndarray) -> None:
    """Block sums from block rows' sums (:func:`_block_row_sums`) into ``out`` (H/f, C, W/f): moment-row order.

    Per block row, the transposed gather matrix times the transposed row groups gives the channels as
    rows directly — one batched product instead of a product and a transposing copy (exact as
    :func:`gathered`: 0/1 weights, integer sums below 2²⁴ in float32).
    """
    height, width = row_sums.shape[0], row_sums.shape[1] // (factor * channels)
    dtype: type = row_sums.dtype.type
    gather = gather_matrix(factor, channels, dtype)
    groups = row_sums.reshape(height, width, factor * channels).transpose(0, 2, 1)
    if out.dtype == row_sums.dtype:
        np.matmul(gather.T, groups, out=out)
    else:
        np.copyto(out, np.matmul(gather.T, groups))
