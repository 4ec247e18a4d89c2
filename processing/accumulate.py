"""Sufficient statistics of a flash sequence (:mod:`processing.statistics`), accumulated in one pass over the pixels.

They are accumulated straight from the raw frames (docs/architecture.md §8): the raw second moments of the rows
``[F_1 … F_n, A, 1]`` over the valid samples (all pixels, or block sums: :mod:`processing.block_rows`), then mapped
to the linearised, differenced and unmixed images. No full-size float copy of the stack ever exists.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from msflash.processing import frame_kernels
from msflash.processing.block_rows import BlockRows
from msflash.processing.block_sums import bin_frame, plane_shape
from msflash.processing.errors import SpectralDataError
from msflash.processing.moment_products import DEFAULT_CHUNK_PIXELS, DEFAULT_WORKERS, thread_pool
from msflash.processing.statistics import (
    FrameStackSpec,
    SequenceStatistics,
    non_finite_frames_error,
    statistics_from_moments,
)


def _as_samples(frame: np.ndarray, where: str) -> np.ndarray:
    """View a frame as (n_pixels, n_channels) without copying."""
    if frame.ndim == 2:
        return frame.reshape(-1, 1)
    if frame.ndim == 3:
        return frame.reshape(-1, frame.shape[2])
    raise SpectralDataError(f"{where}: frame has shape {frame.shape}; expected (H, W) or (H, W, C)")


def accumulate_statistics(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    spec: FrameStackSpec,
    *,
    sample_mask: np.ndarray | None = None,
    chunk_pixels: int = DEFAULT_CHUNK_PIXELS,
    bin_factor: int = 1,
    cfa_period: int = 1,
    workers: int = DEFAULT_WORKERS,
    weighting: bool = False,
) -> SequenceStatistics:
    """Accumulate the sufficient statistics of eq. 4–6 in one pass over raw frames.

    Parameters
    ----------
    ambient
        The ambient frame m_a, raw values, shape (H, W) (mono or raw mosaic) or (H, W, C).
    led_frames
        The frames m_a + m_f,j, raw values, each the shape of ``ambient``.
    spec
        Black/white levels, per-frame exposure·gain scales and LED levels.
    sample_mask
        Optional boolean (H, W) mask of the pixels to use (a region, a subsample).
    chunk_pixels
        Pixels processed per chunk.
    bin_factor
        Sum ``bin_factor × bin_factor`` blocks first (see :func:`bin_frame`); 1 uses every pixel.
    cfa_period
        2 when the frames are Bayer mosaics (blocks then gather same-colour samples).
    workers
        Threads sharing the frames of the binned pass, or the pixels of the compiled all-pixel pass
        (numpy and the compiled kernels release the GIL while they sum); 1 runs on the calling
        thread. The statistics do not depend on it (beyond rounding).
    weighting
        Inverse-variance sample weights (module notes); binned statistics with an even block size only
        (elsewhere there is no noise probe to fit them to, and the samples stay unweighted).

    Returns
    -------
    SequenceStatistics
        Statistics of the LED-only images at full drive.

    Raises
    ------
    SpectralDataError
        If frames differ in shape or contain non-finite values.

    Notes
    -----
    A pixel is excluded when any channel of it, in any frame, is at or above the white level
    (docs/architecture.md §6). Moments are accumulated in float64 (all pixels of ≤ 16-bit integer
    frames: exactly, in integers). Integer frames are read once, by the compiled kernels of
    :mod:`processing.frame_kernels` (binned: per frame; all pixels: every frame's tile together), when
    numba is installed; numpy takes the same steps otherwise. The block sums and the all-pixel moments are
    exact integers on both routes; the moments of the block sums are taken by the compiled
    :func:`processing.frame_kernels.block_statistics` where the kernels were loaded before the call
    (:func:`processing.frame_kernels.statistics_compiled`), by numpy otherwise: the two agree to rounding.
    """
    if bin_factor < 1 or cfa_period not in (1, 2):
        raise SpectralDataError(
            f"statistics: bin_factor {bin_factor}, cfa_period {cfa_period}; expected ≥ 1 and 1 or 2"
        )
    _check_stack(ambient, led_frames, spec, sample_mask)
    block_moments_compiled = frame_kernels.statistics_compiled()  # as a stream decides: before this call loads them
    frame_kernels.wanted(ambient.nbytes * (len(led_frames) + 1))  # loads the kernels for large stacks
    if bin_factor > 1:
        return _accumulate_binned(
            ambient,
            led_frames,
            spec,
            sample_mask,
            chunk_pixels,
            bin_factor,
            cfa_period,
            workers,
            weighting,
            block_moments_compiled,
        )
    n_samples = ambient.size
    if sample_mask is None:
        # Integer frames: one compiled pass, each sample converted once in a cache-sized tile.
        pool = thread_pool(workers) if workers > 1 else None
        compiled = frame_kernels.raw_moments([*led_frames, ambient], spec.white_level, workers, pool)
        if compiled is not None:
            return statistics_from_moments(compiled, spec, n_samples)
    moments = _pixel_moments(ambient, led_frames, spec.white_level, sample_mask, chunk_pixels)
    return statistics_from_moments(moments, spec, n_samples)


def _check_stack(
    ambient: np.ndarray, led_frames: Sequence[np.ndarray], spec: FrameStackSpec, sample_mask: np.ndarray | None
) -> None:
    """Refuse LED frames without levels, frames of another shape than the ambient's or not (H, W[, C]), a mask of
    another size."""
    if len(led_frames) != spec.led_levels.shape[0]:
        raise SpectralDataError(f"frame stack: {len(led_frames)} LED frames but levels for {spec.led_levels.shape[0]}")
    for index, frame in enumerate([ambient, *led_frames]):
        if frame.shape != ambient.shape:
            raise SpectralDataError(
                f"frame stack: frame {index} has shape {frame.shape} but the ambient frame {ambient.shape}; "
                "expected frames of one size"
            )
    if sample_mask is not None and sample_mask.shape != ambient.shape[:2]:
        raise SpectralDataError(f"sample mask has shape {sample_mask.shape}; expected {ambient.shape[:2]}")
    _as_samples(ambient, "frame 0")


def _pixel_moments(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    white: float,
    sample_mask: np.ndarray | None,
    chunk_pixels: int,
) -> np.ndarray:
    """Raw second moments of the rows ``[F_1 … F_n, A, 1]`` over every valid sample, in numpy, chunk by chunk.

    Every statistic of the linearised differences is a linear transform of these
    (:func:`processing.statistics.statistics_from_moments`), so the per-chunk work is one conversion and one
    Gram product: no per-frame subtract, scale or difference passes. float64 keeps the cancellation in
    ``(s_j F_j − s_a A)`` harmless. Integer frames of ≤ 16 bits: each chunk's products are integers summing
    below 2⁵² (exact in float64 whatever the order of BLAS's sums), added up exactly in int64 — the compiled
    route's totals to the bit (:data:`processing.frame_kernels.EXACT_SAMPLES`).
    """
    frames = [ambient, *led_frames]
    samples = [_as_samples(f, f"frame {i}") for i, f in enumerate(frames)]
    n_pixels, n_channels = samples[0].shape
    mask_flat = None if sample_mask is None else sample_mask.reshape(-1)
    n_led_frames = len(led_frames)
    n_rows = n_led_frames + 2
    exact = all(np.issubdtype(frame.dtype, np.integer) and frame.dtype.itemsize <= 2 for frame in frames)
    if exact:
        chunk_pixels = max(1, min(chunk_pixels, frame_kernels.EXACT_SAMPLES // n_channels))
    moments = np.zeros((n_rows, n_rows), dtype=np.int64 if exact else np.float64)
    block = np.empty((n_rows, min(chunk_pixels, n_pixels), n_channels))
    for start in range(0, n_pixels, chunk_pixels):
        stop = min(start + chunk_pixels, n_pixels)
        view = block[:, : stop - start]
        for j in range(n_led_frames):
            view[j] = samples[j + 1][start:stop]
        view[n_led_frames] = samples[0][start:stop]
        view[n_led_frames + 1] = 1.0
        brightest = np.maximum.reduce(view[: n_rows - 1], axis=0)
        if not np.isfinite(brightest).all():
            raise non_finite_frames_error(view[: n_rows - 1])
        saturated = brightest[:, 0] >= white
        for channel in range(1, n_channels):
            saturated |= brightest[:, channel] >= white
        if mask_flat is not None:
            saturated |= ~mask_flat[start:stop]
        if saturated.any():
            view[:, saturated] = 0.0
        flat = view.reshape(n_rows, -1)
        moments += (flat @ flat.T).astype(moments.dtype, copy=False)
    return moments.astype(np.float64, copy=False)


def _accumulate_binned(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    spec: FrameStackSpec,
    sample_mask: np.ndarray | None,
    chunk_pixels: int,
    factor: int,
    cfa_period: int,
    workers: int,
    weighting: bool = False,
    compiled: bool | None = None,
) -> SequenceStatistics:
    """Statistics of block sums: a block is valid when no member is saturated (or masked out); the moments by the
    compiled pass or numpy as ``compiled`` says (:class:`processing.block_rows.BlockRows`)."""
    frames = [ambient, *led_frames]
    n_led_frames = len(led_frames)
    rows = BlockRows(
        n_led_frames,
        plane_shape(ambient.shape, cfa_period),
        factor,
        spec.white_level,
        black_level=spec.black_level,
        weighting=weighting,
        compiled=compiled,
    )
    # Rows [F_1 … F_n, A, 1]: the ambient frame is row n. Each frame is one independent pass
    # (block sums, saturation), so ``workers`` threads share the frames: the compiled pass and
    # numpy both release the GIL inside it.
    jobs = list(zip([n_led_frames, *range(n_led_frames)], frames))
    if workers > 1 and len(jobs) > 1:
        list(thread_pool(workers).map(lambda job: rows.add_frame(job[0], job[1], cfa_period), jobs))
    else:
        for row, frame in jobs:
            rows.add_frame(row, frame, cfa_period)
    if sample_mask is not None:
        mask_sums, _ = bin_frame(sample_mask.astype(np.uint8), factor, cfa_period)
        full = mask_sums == factor * factor
        rows.exclude(~(full.all(axis=2) if full.ndim == 3 else full))
    return rows.statistics(spec, chunk_pixels, workers)
