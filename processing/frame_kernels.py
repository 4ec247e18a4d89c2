"""Compiled one-pass kernels over raw integer frames: block sums with their noise probe, and weighted sums.

The binned statistics (:class:`processing.block_rows.BlockRows`) and synthesis
(:func:`processing.synthesis.synthesize`) are passes over the raw frames. In numpy each step is a
pass of its own (convert, sum rows, gather blocks, take differences, find the maxima), several
times the cost of reading the frames once. These kernels read each raw sample once, in rows that
stay in cache, and write only their results: per frame, its ``factor × factor`` block sums, its
blocks' half differences (the noise probe of :mod:`processing.block_rows`) and its saturated
blocks; for synthesis, the weighted sum of the frames (eq. 7–9's image) and its saturated pixels.

Integer frames only (≤ 16 bits: the block sums are exact in 32-bit integers for blocks up to
181 × 181, the weighted sums are taken in float64); float frames keep the numpy route, as does
everything when numba is missing (it is an optional dependency, ``pip install msflash[fast]``) or
``MSFLASH_KERNELS=numpy`` is set, and small one-off work in a process that has not loaded the
kernels (:func:`wanted`: numba's start-up would cost more than it saves). The passes over the frames
give the same numbers to the bit on both routes (exact integer sums; tests/processing/test_frame_kernels.py),
so which one a process takes changes its speed only. The moments of the block rows
(:func:`block_statistics`) and the fit of the ambient's noise line (:func:`detail_line`, on the Haar cells of
:func:`haar_cells`, which are numpy's to the bit) agree with numpy's to rounding only (about 1e-14 relative): their
route is decided once per stack, by whether the process has the kernels loaded before the stack's rows are laid
out (:func:`statistics_compiled`), so that the live and the disk stream of one sequence in the same kind
of process report the same digits.

The block size, the CFA period and the channel count are passed as tuples of that length so that
numba compiles (and caches on disk) one specialised kernel per combination: with them constant, its
inner loops unroll (the gain: docs/measurements.md).
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from functools import lru_cache
from typing import Any

import numpy as np

KERNELS_VARIABLE = "MSFLASH_KERNELS"
"""Environment variable: ``numpy`` turns the compiled kernels off, ``numba`` uses them on any work;
unset (or ``auto``), :func:`wanted` decides."""

COMPILE_BYTES = 256 << 20
"""Frame bytes from which one call's work loads the kernels (:func:`wanted`): importing numba and
loading the cached kernels is a one-off cost per process that the kernels win back only on stacks
about this large (the figures: docs/measurements.md). A process that has loaded them (:func:`prepare`: the bench) uses
them on any work. A capture session does not load them itself: numba's import can hold the
interpreter for seconds on a busy machine, and a camera's stream would lose frames to it."""


def _mode() -> str:
    return os.environ.get(KERNELS_VARIABLE, "").strip().lower()


@lru_cache(maxsize=1)
def _compiled() -> Any:
    """The compiled kernels (a namespace), imported on first call, or None without numba or with
    ``MSFLASH_KERNELS=numpy``."""
    if _mode() == "numpy":
        return None
    try:
        from msflash.processing import frame_kernels_numba
    except ImportError:
        return None
    _warm(frame_kernels_numba)
    return frame_kernels_numba


def _warm(kernels: Any) -> None:
    """Run :func:`block_statistics`', :func:`detail_line`'s and :func:`haar_cells`' specialisations once, as the
    kernels load: a stream that decided on them (:func:`statistics_compiled`) then never compiles one while a camera
    streams (loaded from the disk cache, or compiled now, once per installation)."""
    one = np.ones(1)
    kernels.block_statistics(
        np.ones((1, 1)),
        one,
        one,
        True,
        np.ones((1, 1)),
        1,
        1,
        1,
        False,
        1,
        np.zeros((1, 1)),
        *(np.zeros((0, 1, 1)),) * 2,
        np.zeros((1, 1)),
    )
    cells = np.arange(80.0)
    kernels.detail_line(cells, cells, cells, cells, 16, 9.0, 10.0, 0.9, 1, 1e-3, 64, 0.45, 1e-100)
    kernels.floor_levels(cells, np.zeros((1, 1), dtype=bool), True, 1, 80, 0.0)
    kernels.inverse_variances(cells, 0.0, 1.0, 1.0, 1.0, np.empty(80))
    for sample in (np.uint8, np.uint16):
        kernels.haar_cells(np.zeros((4, 4), sample), 1, 1, 2, 1, 2, 0.0, 1.0)  # 2 × 2 cells of one channel


_paused = 0
_paused_lock = threading.Lock()


@contextmanager
def paused() -> Iterator[None]:
    """No compiled kernel in this process while the block runs (every thread takes the numpy route).

    For a capture that streams: a kernel specialisation not compiled yet in this process (a fresh
    install has no on-disk cache) compiles on first use, holding the interpreter for a second or
    more, and the booth's watchdog switched the LEDs off during the flash frame of a camera-synced
    run while that happened. The numpy route gives the same block sums and all-pixel moments to the bit
    (exact integers). The block rows' moments keep the route :func:`statistics_compiled` chose for the stack
    (its one kernel specialisation is compiled as the kernels load, :func:`_warm`, so it never compiles here).
    """
    global _paused
    with _paused_lock:
        _paused += 1
    try:
        yield
    finally:
        with _paused_lock:
            _paused -= 1


def _loaded(*, pausable: bool = True) -> Any:
    """The kernels if they are in use in this process (loaded before, or forced), else None; also None inside
    :func:`paused` unless ``pausable`` is False."""
    if _mode() == "numpy" or (_paused and pausable):
        return None
    if _mode() == "numba" or "msflash.processing.frame_kernels_numba" in sys.modules:
        return _compiled()
    return None


def prepare() -> bool:
    """Load the kernels now (numba's import and the cached kernels), for a process that will run many
    passes (the bench); whether they are available. Not while a camera streams (:data:`COMPILE_BYTES`)."""
    return _compiled() is not None


def wanted(frame_bytes: int) -> bool:
    """Whether the passes over ``frame_bytes`` of frames use the kernels: loaded already, forced, or work
    of at least :data:`COMPILE_BYTES` (which loads them)."""
    if _loaded() is not None:
        return True
    return frame_bytes >= COMPILE_BYTES and _mode() != "numpy" and _compiled() is not None


def statistics_compiled() -> bool:
    """Whether block rows laid out now take their moments by the compiled :func:`block_statistics`: the kernels are
    loaded in this process already, or forced (``MSFLASH_KERNELS=numba``) — whatever :func:`paused` says, and never
    by loading them. Decided once per stack, when its rows are laid out and before anything loads the kernels for it,
    so that a capture's live stream and ``msflash estimate`` of its sequence in the same kind of process take the
    same route (the two routes agree to rounding only; :class:`processing.block_rows.BlockRows`). A process that
    loads the kernels partway — the live view does for its first mix preview — takes the compiled route for the
    stacks laid out after: its later fires agree with a one-off ``msflash estimate`` to rounding, not to the digit."""
    return _loaded(pausable=False) is not None


def enabled() -> bool:
    """Whether the compiled kernels are in use in this process."""
    return _loaded() is not None


def _rows_view(frame: np.ndarray) -> np.ndarray | None:
    """The frame as (H, W·C) integer rows without a copy, or None when the kernels cannot take it."""
    if frame.dtype not in (np.uint8, np.uint16) or frame.ndim not in (2, 3) or frame.size == 0:
        return None
    if frame.strides[-1] != frame.itemsize or (frame.ndim == 3 and frame.strides[1] != frame.itemsize * frame.shape[2]):
        return None
    return frame.reshape(frame.shape[0], -1)


def block_pass(
    frame: np.ndarray,
    factor: int,
    cfa_period: int,
    white: float,
    probe_stride: int,
    sums: np.ndarray,
    differences: np.ndarray | None,
) -> tuple[bool, np.ndarray | None]:
    """Block sums, half differences and saturated blocks of one raw frame, in one compiled pass.

    Parameters
    ----------
    frame
        (H, W) or (H, W, C) raw integer values; a Bayer mosaic with ``cfa_period`` 2 (then C = 1).
    factor, cfa_period, white, probe_stride
        Block side, CFA period, white level, and every how many block rows the probe is taken.
    sums
        Output, (H/f, C', W/f) float64 (C' = cfa_period² · C): block sums in moment-row order.
    differences
        Output, (⌈(H/f)/probe_stride⌉, W/f, C') float64, any strides (a transposed view of (…, C', W/f) storage
        writes the sums' order): each probed block's checkerboard half difference
        (:func:`processing.block_sums.block_sums_and_differences`); or None.

    Returns
    -------
    tuple
        ``(done, saturated)``: False when the kernels cannot take this frame (the caller takes the
        numpy route); else the (H/f, W/f) mask of blocks with a sample at or above ``white``, or None
        when there is none.
    """
    kernels = _loaded()
    rows = _rows_view(frame) if kernels is not None else None
    if rows is None:
        return False, None
    channels = frame.shape[2] if frame.ndim == 3 else 1
    height = sums.shape[0]
    saturated = np.zeros((height, sums.shape[2]), dtype=bool)
    probe = differences if differences is not None else np.empty((0, sums.shape[2], sums.shape[1]))
    shape = ((0,) * cfa_period, (0,) * (cfa_period * channels), (0,) * factor)

    hit = kernels.block_pass(rows, *shape, float(white), int(probe_stride), sums, probe, saturated, 0, height)
    return True, saturated if hit else None


def block_statistics(
    values: np.ndarray,
    weights: np.ndarray,
    factors: np.ndarray | None,
    transform: np.ndarray,
    layout: tuple[int, int, int],
    channel_axis: int,
    zero_last: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The weighted second moments of the rows ``values`` (R, N) and their images' channel moments, in one compiled
    pass over them (used where :func:`statistics_compiled` said so, :func:`paused` or not).

    ``weights`` (N,) weigh each column in ``Σ w x xᵀ``; ``transform`` (K + 1, R) maps the rows to the K LED images and
    the ambient's, each column scaled by ``factors`` (N,; None: all 1), whose products per channel give
    ``(gram, fa, ff, aa)``: ``gram`` (R, R) symmetric, ``fa`` and ``ff`` (K, C, C), ``aa`` (C, C) as :class:`processing.statistics.ChannelMoments`
    holds them. The columns are laid out ``layout`` (block rows first; the channels on ``channel_axis`` 1 or 2).
    ``zero_last``: the last row is zero (a probe's ones row), its Gram entries 0 without products.
    """
    kernels = _compiled()
    height = layout[0]
    channels, width = (layout[1], layout[2]) if channel_axis == 1 else (layout[2], layout[1])
    rows, images = values.shape[0], transform.shape[0]
    gram = np.zeros((rows, rows))
    fa, ff = np.zeros((images - 1, channels, channels)), np.zeros((images - 1, channels, channels))
    aa = np.zeros((channels, channels))
    kernels.block_statistics(
        np.ascontiguousarray(values, dtype=np.float64),
        np.ascontiguousarray(weights, dtype=np.float64),
        np.ascontiguousarray(weights if factors is None else factors, dtype=np.float64),  # unread when None
        factors is not None,
        np.ascontiguousarray(transform, dtype=np.float64),
        height,
        channels,
        width,
        channel_axis == 2,
        rows - 1 if zero_last else rows,
        gram,
        fa,
        ff,
        aa,
    )
    return gram, fa, ff, aa


def detail_line(
    levels: np.ndarray, diagonal: np.ndarray, across: np.ndarray, down: np.ndarray, constants: tuple[float, ...]
) -> tuple[bool, float, float]:
    """:func:`processing.noise_level.fit_detail_line`'s ``(found, gain, offset)`` in one compiled call (used where
    :func:`statistics_compiled` said so); ``constants`` are that module's ``(LEVEL_BANDS, SMOOTH_QUANTILE,
    DETAIL_CUT, cut mean, ROUNDS, CONVERGED, MIN_CELLS, CHI2_1_MEDIAN, tiny)``. The same selections and thresholds
    as numpy's fit, its sums in order: the line agrees with numpy's to rounding (tests/processing/test_noise_level.py).
    """
    bands, smooth, cut, cut_mean, rounds, converged, min_cells, median, tiny = constants
    found, gain, offset = _compiled().detail_line(
        *(np.ascontiguousarray(cells, dtype=np.float64).reshape(-1) for cells in (levels, diagonal, across, down)),
        int(bands),
        float(smooth),
        float(cut),
        float(cut_mean),
        int(rounds),
        float(converged),
        int(min_cells),
        float(median),
        float(tiny),
    )
    return bool(found), float(gain), float(offset)


def haar_cells(
    frame: np.ndarray, cfa_period: int, cell_rows: int, stride: int, cell_columns: int, black: float, white: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`processing.noise_level.haar_details` of an (H, W) or (H, W, C) integer frame's cells (every ``stride``-th of the
    first ``cell_rows`` rows of cells, the first ``cell_columns`` columns) in one compiled pass (used where
    :func:`statistics_compiled` said so): the same arrays to the bit; None where the kernel cannot take the frame.
    C-contiguous 8- or 16-bit rows only: the specialisations :func:`_warm` compiles as the kernels load (a frame of
    padded rows would compile another while a camera streams, which :func:`paused` exists to prevent)."""
    rows = _rows_view(frame)
    if rows is None or not rows.flags.c_contiguous:
        return None
    levels, diagonal, across, down = _compiled().haar_cells(
        rows,
        frame.shape[2] if frame.ndim == 3 else 1,
        cfa_period,
        cell_rows,
        stride,
        cell_columns,
        float(black),
        float(white),
    )
    return levels, diagonal, across, down


def floor_level(
    ambient: np.ndarray, left_out: np.ndarray | None, layout: tuple[int, int, int], black: float, position: int
) -> float:
    """The ``position``-th smallest of ``ambient − black`` (block sums (N,) laid out ``layout`` = (block rows,
    channels, block columns)) over the blocks not ``left_out`` ((block rows, block columns) or None): the levels
    gathered in one compiled pass, the value by ``np.partition`` (:func:`processing.noise_level.ambient_block_weights`;
    faster here than a compiled quickselect: docs/speed.md)."""
    masked = left_out is not None
    mask = np.ascontiguousarray(left_out, dtype=bool) if left_out is not None else _NO_BLOCKS
    levels = _compiled().floor_levels(ambient, mask, masked, layout[1], layout[2], float(black))
    return float(np.partition(levels, position)[position])


_NO_BLOCKS = np.zeros((1, 1), dtype=bool)


def inverse_variances(ambient: np.ndarray, black: float, gain: float, read: float, floor: float) -> np.ndarray:
    """``1 / max(max(ambient − black, 0) · gain + read, floor)`` of float64 block sums in one compiled pass: the
    steps of :meth:`processing.noise_level.NoiseLine.weights` before its normalisation, to the bit."""
    out = np.empty(ambient.shape)
    _compiled().inverse_variances(ambient, float(black), float(gain), float(read), float(floor), out)
    return out


def synthesis_inputs(frames: list[np.ndarray]) -> tuple[np.ndarray, ...] | None:
    """The frames as flat integer views of one type for :func:`weighted_sum_range`, or None when the
    kernels cannot take them (numba missing, float or mixed types, non-contiguous frames)."""
    if _loaded() is None or len({frame.dtype for frame in frames}) != 1:
        return None
    flat = []
    for frame in frames:
        rows = _rows_view(frame)
        if rows is None or not frame.flags.c_contiguous:
            return None
        flat.append(frame.reshape(-1))
    return tuple(flat)


def weighted_sum_range(
    flat_frames: tuple[np.ndarray, ...],
    factors: np.ndarray,
    offset: float,
    white: float,
    channels: int,
    output: np.ndarray,
    saturated: np.ndarray,
    start: int,
    stop: int,
) -> None:
    """``output[i] = offset + Σ_j factors[j] · frame_j[i]`` for flat samples ``start ≤ i < stop`` (whole
    pixels), and ``saturated[p]`` for their pixels: a sample of some frame at or above ``white``."""
    kernels = _loaded()
    # Summed in float64 whatever the image's type: a float32 sum was measured no faster (the pass is
    # bound by reading the frames), and it rounds.
    kernels.weighted_sum(
        flat_frames, factors.astype(np.float64), float(offset), float(white), channels, output, saturated, start, stop
    )


MOMENT_TASK_PIXELS = 1 << 16
"""Pixels per task of :func:`raw_moments` (several per worker, so both finish together)."""
EXACT_SAMPLES = 1 << 20
"""Samples whose second moments sum exactly in float64, in any order: each product of two ≤ 16-bit values
is below 2³², so 2²⁰ of them stay below 2⁵². A task or chunk of at most this many samples has exact
integer moments, which are then added up in int64: the compiled and numpy routes give the same totals
to the bit (an entry holds up to 2³¹ samples before int64 could overflow)."""


def raw_moments(frames: list[np.ndarray], white: float, workers: int, pool: Any = None) -> np.ndarray | None:
    """The raw second moments of the rows ``[frames…, 1]`` over every sample of pixels no frame saturates,
    (n+1, n+1) float64, in one compiled pass over integer frames; None when the kernels cannot take them.

    ``pool`` (an executor) shares tasks of whole pixels among ``workers`` threads. Each task's moments are
    exact integers (:data:`EXACT_SAMPLES`), added in int64: the result depends neither on the number of
    workers nor on the route (the numpy route of :func:`processing.accumulate.accumulate_statistics`
    gives the same bits).
    """
    flat = synthesis_inputs(frames)
    if flat is None:
        return None
    kernels = _loaded()
    channels = frames[0].shape[2] if frames[0].ndim == 3 else 1
    size = flat[0].size
    step = max(1, min(MOMENT_TASK_PIXELS, EXACT_SAMPLES // channels)) * channels
    n = len(frames)

    rows = -(-(n + 1) // kernels.MOMENT_BLOCK) * kernels.MOMENT_BLOCK

    def task(start: int) -> np.ndarray:
        block = np.zeros((rows, rows))
        kernels.moments(flat, channels, float(white), start, min(start + step, size), block)
        return block

    starts = range(0, size, step)
    parts = pool.map(task, starts) if pool is not None and workers > 1 and len(starts) > 1 else map(task, starts)
    exact = np.zeros((rows, rows), dtype=np.int64)
    for part in parts:
        exact += part.astype(np.int64)  # each task's moments are exact integers (EXACT_SAMPLES)
    lower = np.tril(exact[: n + 1, : n + 1].astype(np.float64))
    return lower + np.tril(lower, -1).T
