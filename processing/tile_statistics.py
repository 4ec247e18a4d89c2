"""The tiles of a frame and their sufficient statistics (eq. 4–6 per tile), accumulated one frame at a time.

:class:`TileBlocks` takes each frame's block sums (and half differences, the noise probe) and saturated
blocks as it comes (:class:`acquisition.session.estimate_stream.EstimateStream` feeds it frame by frame);
:class:`TiledStatistics` holds the tiles' moments, their sum, their Gaussian-weighted neighbourhoods and the
noise-corrected ones. :func:`tile_statistics` is the same over frames in memory. Used by
:mod:`processing.local` (estimates) and :mod:`processing.local_selection` (model choice); the module notes
of :mod:`processing.local` say why and how.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from msflash.processing.block_sums import (
    block_sums,
    block_sums_and_differences,
    cfa_planes,
    plane_shape,
    saturated_blocks,
)
from msflash.processing.errors import SpectralDataError
from msflash.processing.moment_products import DEFAULT_WORKERS, thread_pool
from msflash.processing.noise_level import PixelNoise, ambient_block_noise, detail_noise_line
from msflash.processing.statistics import (
    FrameStackSpec,
    NoiseMoments,
    SequenceStatistics,
    channel_transform,
    non_finite_frames_error,
)

DEFAULT_TILES = 8
"""Tiles per side of the frame (8 × 8 = 64 tiles)."""


# -- tile geometry ----------------------------------------------------------------------------
def tile_edges(n_blocks: int, n_tiles: int) -> np.ndarray:
    """Block indices where the tiles of one axis start and end, shape (n_tiles + 1,).

    Examples
    --------
    >>> tile_edges(10, 4).tolist()
    [0, 2, 5, 8, 10]
    """
    if n_tiles < 1 or n_blocks < n_tiles:
        raise SpectralDataError(
            f"tiles: {n_tiles} tiles over {n_blocks} blocks; expected 1 ≤ tiles ≤ blocks "
            "(fewer tiles, or a smaller bin factor)"
        )
    return np.rint(np.linspace(0, n_blocks, n_tiles + 1)).astype(int)


# -- tiled statistics -------------------------------------------------------------------------
@dataclass(frozen=True)
class BlockData:
    """The binned samples of a frame stack, linearised on demand (for :func:`segment_regions`)."""

    raw: np.ndarray = field(repr=False)
    """(n_frames + 2, h, w, C) block sums of the rows [F_1 … F_n, A, 1] (invalid blocks zeroed)."""
    differences: np.ndarray | None = field(repr=False)
    """(n_frames + 2, h, w, C) the blocks' checkerboard half differences (the ones row 0, invalid blocks zeroed):
    the noise probe of :attr:`TiledStatistics.denoised`. None for odd bin factors."""
    valid: np.ndarray = field(repr=False)
    """(h, w) blocks without a saturated member."""
    spec: FrameStackSpec
    """The block-level spec (black level scaled to the block)."""
    pixel: int
    """Block side in pixels (bin factor × CFA period)."""

    @property
    def shape(self) -> tuple[int, int]:
        """Blocks (rows, columns)."""
        return (int(self.valid.shape[0]), int(self.valid.shape[1]))


@dataclass(frozen=True)
class TiledStatistics:
    """:class:`SequenceStatistics` of every tile of a grid, stored as arrays (tile row, tile column, …)."""

    gram: np.ndarray
    """(ty, tx, k, k)."""
    cross: np.ndarray
    """(ty, tx, k)."""
    ambient_energy: np.ndarray
    """(ty, tx)."""
    n_samples: np.ndarray
    """(ty, tx) valid samples (weighted sums after smoothing)."""
    n_total: np.ndarray
    """(ty, tx) samples, valid or not."""
    ambient_sum: np.ndarray
    """(ty, tx)."""
    led_sums: np.ndarray
    """(ty, tx, k)."""
    row_edges: np.ndarray
    """Pixel rows where the tile rows start and end, (ty + 1,); the last is the frame height."""
    column_edges: np.ndarray
    """Pixel columns where the tile columns start and end, (tx + 1,)."""
    blocks: BlockData | None = field(default=None, repr=False, compare=False)
    """The binned samples themselves (for region segmentation); None when built from moments only."""
    denoised: TiledStatistics | None = field(default=None, repr=False, compare=False)
    """The same tiles with the noise's contribution to their moments removed (``Σ (x xᵀ − d dᵀ)``, the half-difference
    probe of :mod:`processing.block_rows`' module notes), or None (odd bin factors). The valid-sample counts and sums
    are the tiles' own. :func:`estimate_local` solves the local model on them; :func:`denoised_global` gives the
    global model's estimate on them."""

    @property
    def shape(self) -> tuple[int, int]:
        """Tiles (rows, columns)."""
        return (int(self.gram.shape[0]), int(self.gram.shape[1]))

    @property
    def n_leds(self) -> int:
        """Number of LEDs k."""
        return int(self.cross.shape[-1])

    @property
    def frame_shape(self) -> tuple[int, int]:
        """(H, W) of the frame the tiles cover."""
        return (int(self.row_edges[-1]), int(self.column_edges[-1]))

    @property
    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates of the tile centres: (rows (ty,), columns (tx,))."""
        return (
            (self.row_edges[:-1] + self.row_edges[1:] - 1) / 2.0,
            (self.column_edges[:-1] + self.column_edges[1:] - 1) / 2.0,
        )

    @property
    def areas(self) -> np.ndarray:
        """Pixel area of every tile, (ty, tx)."""
        return np.outer(np.diff(self.row_edges), np.diff(self.column_edges)).astype(float)

    def tile(self, row: int, column: int) -> SequenceStatistics:
        """The statistics of one tile."""
        return SequenceStatistics(
            gram=self.gram[row, column].copy(),
            cross=self.cross[row, column].copy(),
            ambient_energy=float(self.ambient_energy[row, column]),
            n_samples=int(round(float(self.n_samples[row, column]))),
            n_total=int(round(float(self.n_total[row, column]))),
            ambient_sum=float(self.ambient_sum[row, column]),
            led_sums=self.led_sums[row, column].copy(),
        )

    def total(self) -> SequenceStatistics:
        """The statistics of the whole frame: the sum of the tiles', with the noise the probe measured
        (:attr:`denoised`) as their :attr:`~processing.statistics.SequenceStatistics.noise` — what
        :func:`processing.accumulate.accumulate_statistics` gives for the same blocks (exactly below
        ``4 · PROBE_BLOCKS`` blocks; above, it probes a stride of block rows, the tiles every block)."""
        gram, cross, energy = self.gram.sum(axis=(0, 1)), self.cross.sum(axis=(0, 1)), float(self.ambient_energy.sum())
        clean = self.denoised
        noise = (
            None
            if clean is None
            else NoiseMoments(
                gram - clean.gram.sum(axis=(0, 1)),
                cross - clean.cross.sum(axis=(0, 1)),
                energy - float(clean.ambient_energy.sum()),
            )
        )
        return SequenceStatistics(
            gram=gram,
            cross=cross,
            ambient_energy=energy,
            n_samples=int(round(float(self.n_samples.sum()))),
            n_total=int(round(float(self.n_total.sum()))),
            ambient_sum=float(self.ambient_sum.sum()),
            led_sums=self.led_sums.sum(axis=(0, 1)),
            noise=noise,
        )

    def smoothed(self, sigma: float, leave_out: bool = False) -> TiledStatistics:
        """Gaussian-weighted sums of the neighbours' statistics (width ``sigma`` tiles).

        With ``leave_out`` each tile's own statistics are excluded (its neighbours only), for
        leave-one-tile-out scoring. The kernel is not normalised: least-squares solutions do not
        depend on a common factor, and the dimensionless roughness weight scales with ``tr G``.
        The result has no :attr:`denoised` part (smooth that one itself when it is needed).
        """
        if not sigma > 0:
            raise SpectralDataError(f"smoothing: sigma {sigma}; expected > 0 tiles")
        rows, columns = _kernel(self.shape[0], sigma), _kernel(self.shape[1], sigma)

        def smooth(values: np.ndarray) -> np.ndarray:
            result = np.tensordot(rows, np.tensordot(columns, values, axes=([1], [1])).swapaxes(0, 1), axes=([1], [0]))
            return result - values if leave_out else result

        return TiledStatistics(
            gram=smooth(self.gram),
            cross=smooth(self.cross),
            ambient_energy=smooth(self.ambient_energy),
            n_samples=smooth(self.n_samples),
            n_total=smooth(self.n_total),
            ambient_sum=smooth(self.ambient_sum),
            led_sums=smooth(self.led_sums),
            row_edges=self.row_edges,
            column_edges=self.column_edges,
            blocks=self.blocks,
        )


@lru_cache(maxsize=64)
def _kernel(n: int, sigma: float) -> np.ndarray:
    """(n, n) Gaussian weights ``exp(−(i − j)²/2σ²)`` between tiles of one axis (diagonal 1)."""
    index = np.arange(n, dtype=float)
    kernel = np.exp(-((index[:, None] - index[None, :]) ** 2) / (2.0 * sigma * sigma))
    kernel[kernel < 1e-12] = 0.0
    kernel.flags.writeable = False
    return kernel


def _block_sums(plane: np.ndarray, factor: int, out: np.ndarray) -> None:
    """``factor × factor`` block sums of an (H, W, C) plane into ``out`` (H/f, W/f, C), exactly."""
    height, width, _ = out.shape
    if factor == 1:
        np.copyto(out, plane[:height, :width], casting="unsafe")
        return
    np.copyto(out, block_sums(plane, factor)[:height, :width])


def _block_sums_and_differences(plane: np.ndarray, factor: int, sums: np.ndarray, differences: np.ndarray) -> None:
    """:func:`processing.block_sums.block_sums_and_differences` of an (H, W, C) plane into (H/f, W/f, C) arrays."""
    block_sums_part, difference_part = block_sums_and_differences(plane, factor)
    np.copyto(sums, block_sums_part[: sums.shape[0], : sums.shape[1]])
    np.copyto(differences, difference_part[: differences.shape[0], : differences.shape[1]])


class TileBlocks:
    """Block sums of an ambient + LED frame stack for :class:`TiledStatistics`, added one frame at a time.

    Rows as :class:`processing.block_rows.BlockRows`'s: LED frame j → row j, the ambient frame → row n, a
    ones row last. Each frame's block sums (and half differences, even bin factors) and saturated blocks
    are taken by :meth:`add_frame` and the frame may then be let go; :meth:`statistics` weighs, masks and
    sums the tiles once every frame is in. :func:`tile_statistics` is this over frames in memory.
    """

    def __init__(
        self,
        n_led_frames: int,
        frame_shape: tuple[int, ...],
        black_level: float,
        white_level: float,
        *,
        bin_factor: int = 1,
        cfa_period: int = 1,
        weighting: bool = False,
    ) -> None:
        if bin_factor < 1 or cfa_period not in (1, 2):
            raise SpectralDataError(
                f"tiled statistics: bin_factor {bin_factor}, cfa_period {cfa_period}; expected ≥ 1 and 1 or 2"
            )
        plane = plane_shape(frame_shape, cfa_period)
        height, width, channels = plane[0] // bin_factor, plane[1] // bin_factor, plane[2]
        if height == 0 or width == 0:
            side = bin_factor * cfa_period
            quads = f" ({bin_factor}×{bin_factor} of the mosaic's 2×2 quads)" if cfa_period == 2 else ""
            raise SpectralDataError(
                f"frame of shape {tuple(frame_shape)} is smaller than one {side}×{side}-pixel block{quads}; "
                "expected a larger frame"
            )
        self.frame_shape = tuple(frame_shape)
        self.n_led_frames = n_led_frames
        self.black_level, self.white_level = black_level, white_level
        self.bin_factor, self.cfa_period, self.weighting = bin_factor, cfa_period, weighting
        n_rows = n_led_frames + 2
        self.data = np.empty((n_rows, height, width, channels))
        # Even bin factors also give every block's half difference, the noise probe of ``denoised``.
        self.differences = np.empty_like(self.data) if bin_factor % 2 == 0 else None
        if self.differences is not None:
            self.differences[-1] = 0.0  # the ones row has no noise
        self.data[-1] = 1.0
        self.masks: list[np.ndarray | None] = [None] * (n_rows - 1)
        self.filled: set[int] = set()
        self.pixel_noise: PixelNoise | None = None

    @property
    def block_grid(self) -> tuple[int, int]:
        """Blocks per column and per row of a frame."""
        return self.data.shape[1], self.data.shape[2]

    def add_frame(self, row: int, frame: np.ndarray) -> None:
        """Frame ``row``'s block sums (and half differences) and its saturated blocks (distinct rows may come
        from several threads)."""
        if tuple(frame.shape) != self.frame_shape:
            raise SpectralDataError(
                f"frame stack: a frame has shape {frame.shape} but the first frame {self.frame_shape}; "
                "expected frames of one size"
            )
        if row in self.filled or not 0 <= row <= self.n_led_frames:
            raise SpectralDataError(
                f"frame stack: row {row} is taken or out of range; expected each of 0…{self.n_led_frames} once"
            )
        self.filled.add(row)
        plane = cfa_planes(frame, self.cfa_period)
        # Float frames (EXR) may hold NaN/inf: refused before the block sums, whose gather products would
        # warn about them first. One sum per float frame; integer frames are finite.
        if np.issubdtype(plane.dtype, np.floating) and not np.isfinite(plane.sum()):
            name = "the ambient frame" if row == self.n_led_frames else f"LED frame {row + 1}"
            raise SpectralDataError(f"frame stack: {name} holds non-finite values (NaN or inf); expected finite pixels")
        if self.differences is None:
            _block_sums(plane, self.bin_factor, self.data[row])
        else:
            _block_sums_and_differences(plane, self.bin_factor, self.data[row], self.differences[row])
        if plane.size and plane.max() >= self.white_level:
            self.masks[row] = saturated_blocks(plane, self.bin_factor, self.white_level)
        if row == self.n_led_frames and self.weighting and self.differences is not None:
            self.pixel_noise = detail_noise_line(plane, 1, self.black_level, self.white_level)

    def statistics(
        self, spec: FrameStackSpec, tiles: int | tuple[int, int] = DEFAULT_TILES, workers: int = DEFAULT_WORKERS
    ) -> TiledStatistics:
        """The tiles' statistics of the frames added (every row must be in); ``spec`` as for the raw frames.

        Uses the arrays in place (weighs and masks them): call it once.
        """
        if len(self.filled) != self.n_led_frames + 1:
            raise SpectralDataError(
                f"frame stack: {len(self.filled)} of {self.n_led_frames + 1} frames added; expected all of them"
            )
        rows_tiles, columns_tiles = (tiles, tiles) if isinstance(tiles, int) else tiles
        data, differences, bin_factor = self.data, self.differences, self.bin_factor
        n_rows, height, width = data.shape[0], data.shape[1], data.shape[2]
        saturated = [mask for mask in self.masks if mask is not None]
        if self.weighting and differences is not None:
            ambient_row = self.n_led_frames
            black = spec.black_level * bin_factor * bin_factor
            root = ambient_block_noise(
                self.pixel_noise, bin_factor, data[ambient_row], black, self.masks[ambient_row]
            ).root_weights(data[ambient_row], black)
            data *= root
            differences *= root
        invalid = np.zeros((height, width), dtype=bool)
        for mask in saturated:
            invalid |= mask
        if invalid.any():
            data[:, invalid] = 0.0
            if differences is not None:
                differences[:, invalid] = 0.0
        row_blocks, column_blocks = tile_edges(height, rows_tiles), tile_edges(width, columns_tiles)
        moments = np.empty((rows_tiles, columns_tiles, n_rows, n_rows))
        noise = np.empty_like(moments) if differences is not None else None
        totals = np.empty((rows_tiles, columns_tiles))

        def add_tile_row(i: int) -> None:
            rows = slice(row_blocks[i], row_blocks[i + 1])
            for j in range(columns_tiles):
                columns = slice(column_blocks[j], column_blocks[j + 1])
                samples = data[:, rows, columns].reshape(n_rows, -1)
                moments[i, j] = samples @ samples.T
                totals[i, j] = samples.shape[1]
                if noise is not None and differences is not None:
                    probe = differences[:, rows, columns].reshape(n_rows, -1)
                    noise[i, j] = probe @ probe.T

        list(
            thread_pool(workers).map(add_tile_row, range(rows_tiles))
            if workers > 1
            else map(add_tile_row, range(rows_tiles))
        )
        block_spec = FrameStackSpec(
            black_level=spec.black_level * bin_factor * bin_factor,
            white_level=np.inf,
            ambient_scale=spec.ambient_scale,
            led_scales=spec.led_scales,
            led_levels=spec.led_levels,
        )
        pixel = bin_factor * self.cfa_period
        row_edges = row_blocks * pixel
        column_edges = column_blocks * pixel
        row_edges[-1], column_edges[-1] = self.frame_shape[0], self.frame_shape[1]
        tiled = tiled_from_moments(moments, totals, block_spec, row_edges, column_edges)
        blocks = BlockData(raw=data, differences=differences, valid=~invalid, spec=block_spec, pixel=pixel)
        denoised = None
        if noise is not None:
            denoised = tiled_from_moments(moments - noise, totals, block_spec, row_edges, column_edges)
        return TiledStatistics(
            **{name: getattr(tiled, name) for name in tiled.__dataclass_fields__ if name not in ("blocks", "denoised")},
            blocks=blocks,
            denoised=denoised,
        )


def tile_statistics(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    spec: FrameStackSpec,
    tiles: int | tuple[int, int] = DEFAULT_TILES,
    *,
    bin_factor: int = 1,
    cfa_period: int = 1,
    weighting: bool = False,
) -> TiledStatistics:
    """The statistics of eq. 4–6 of every tile of a ``tiles`` grid, in one pass over the frames (:class:`TileBlocks`).

    Blocks (``bin_factor``, see :func:`processing.block_sums.bin_frame`) are assigned to tiles
    whole; a block is left out when any member saturates in any frame. The tiles' statistics sum
    to those of :func:`processing.accumulate.accumulate_statistics` with the same binning.

    Parameters
    ----------
    ambient, led_frames, spec
        As for :func:`processing.accumulate.accumulate_statistics`.
    tiles
        Tiles per side, or (rows, columns).
    bin_factor, cfa_period
        Block size, and 2 for Bayer mosaics.
    weighting
        Inverse-variance sample weights, the global statistics' (:mod:`processing.statistics`, module
        notes; even bin factors only): the tiles then sum to the weighted global statistics, and
        :attr:`TiledStatistics.blocks` holds the weighted samples.
    """
    if len(led_frames) != spec.led_levels.shape[0]:
        raise SpectralDataError(f"frame stack: {len(led_frames)} LED frames but levels for {spec.led_levels.shape[0]}")
    frames = [*led_frames, ambient]
    for index, frame in enumerate(frames):
        if frame.shape != ambient.shape:
            raise SpectralDataError(
                f"frame stack: frame {index} has shape {frame.shape} but the ambient frame "
                f"{ambient.shape}; expected frames of one size"
            )
    if any(np.issubdtype(frame.dtype, np.floating) and not np.isfinite(frame.sum()) for frame in frames):
        raise non_finite_frames_error([cfa_planes(frame, cfa_period) for frame in frames])
    accumulator = TileBlocks(
        len(led_frames),
        ambient.shape,
        spec.black_level,
        spec.white_level,
        bin_factor=bin_factor,
        cfa_period=cfa_period,
        weighting=weighting,
    )
    # The frames are independent: numpy releases the GIL in the sums (as in the global statistics' pass).
    rows = range(len(frames))
    add = lambda row: accumulator.add_frame(row, frames[row])  # noqa: E731
    list(thread_pool(DEFAULT_WORKERS).map(add, rows) if DEFAULT_WORKERS > 1 else map(add, rows))
    return accumulator.statistics(spec, tiles)


def tiled_from_moments(
    moments: np.ndarray, totals: np.ndarray, spec: FrameStackSpec, row_edges: np.ndarray, column_edges: np.ndarray
) -> TiledStatistics:
    """Tiled statistics from raw moments of the rows [F_1 … F_n, A, 1] (one (R, R) matrix per tile)."""
    projection = channel_transform(spec, float(spec.black_level))
    k = projection.shape[0] - 1
    linear = np.matmul(np.matmul(projection, moments), projection.T)  # (…, k + 1, k + 1)
    sums = moments[..., :, -1] @ projection.T
    return TiledStatistics(
        gram=linear[..., :k, :k].copy(),
        cross=linear[..., :k, k].copy(),
        ambient_energy=linear[..., k, k].copy(),
        n_samples=np.rint(moments[..., -1, -1]),
        n_total=totals.astype(float),
        ambient_sum=sums[..., k].copy(),
        led_sums=sums[..., :k].copy(),
        row_edges=np.asarray(row_edges, dtype=int),
        column_edges=np.asarray(column_edges, dtype=int),
    )
