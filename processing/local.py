"""Spatially varying ambient light: tiled statistics, local estimates and model selection (issue 9).

The paper assumes one ambient over the whole scene and names patch-based local estimation as
future work (Blasinski & Farrell 2017, among the limits the authors name). Here the frame is cut
into a grid of tiles and the sufficient statistics of eq. 4–6
(:class:`~processing.statistics.SequenceStatistics`) are accumulated per tile in one pass.
Statistics of disjoint samples add, so

- the global statistics are the sum of the tiles' (:meth:`TiledStatistics.total`),
- a Gaussian-weighted sum of neighbouring tiles' statistics is a *local weighted least squares*
  (:meth:`TiledStatistics.smoothed`): each tile borrows surfaces from its neighbours, in
  proportion to ``exp(−d²/2σ²)`` with ``d`` the distance in tiles,
- and every tile is then solved in microseconds (:func:`estimate_local`).

Model selection (:func:`select_model`)
-------------------------------------
Candidates are the global model and local models with smoothing widths :data:`SMOOTHING_GRID`
(the smallest is "local", the larger ones "local-smoothed"). Each is scored by **leave-one-tile-out
prediction**: tile ``t``'s ambient image is predicted from LED weights fitted *without* tile ``t``
— on all other tiles for the global model, on the Gaussian-weighted neighbours for a local one —
and the held-out squared errors are summed over the tiles (from the statistics alone:
``‖a_t − F_t w‖² = E_t − 2 c_tᵀ w + wᵀ G_t w``). Holding out whole tiles, not pixels, matters:
when the ambient is uniform but outside the LEDs' span, a local fit adapts to the local surfaces
and would win a pixel-wise split (neighbouring pixels share surfaces), but it does not generalise
to the next tile's surfaces, while a truly varying ambient is shared by neighbours. A local model
is chosen only when it cuts the held-out error by more than :data:`SELECTION_MARGIN` — the
safeguard that keeps uniform scenes global (calibrated on simulated uniform scenes:
docs/local-estimation.md) — *and* the cut is more than :data:`MIN_EXPLAINED_GAIN` of the ambient
image's energy. The ratio alone fails at high signal-to-noise ratios: when the global model's
held-out error is nothing but a tiny misfit (an ambient slightly outside the LEDs' span, blocks
dropped for saturation), a local fit can cut that tiny error by half on a uniform scene. Two
ambients leave a misfit that is a sizeable part of the image.

Noise correction
----------------
The LED-only images are differences of noisy frames, so the moments of eq. 5 carry the noise
variance (errors in variables). :func:`tile_statistics` also measures it per block from the
difference of two interleaved column halves (:attr:`TiledStatistics.denoised`), and the local model
is solved on the corrected statistics, as the global estimate is (:mod:`processing.statistics` measures
the same probe for the whole frame; docs/architecture.md §8: the noise is measured from the data,
without a noise model).

Public objects
--------------
- :class:`TiledStatistics`, :func:`tile_statistics`, :func:`tile_edges`, :func:`denoised_global`
- :class:`ModelSelection`, :func:`select_model`
- :class:`LocalEstimate`, :func:`estimate_local`, :data:`LOCAL_METHODS`
- :func:`coefficient_maps`, :func:`synthesize_local`: the spatially varying computational image.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from msflash.processing.ambient import AMBIENT_METHODS, AmbientEstimate, AmbientModel, gcv_alpha
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.noise_level import PixelNoise, detail_noise_line
from msflash.processing.spectra import Spectra, require_unit
from msflash.processing.statistics import (
    DEFAULT_WORKERS,
    FrameStackSpec,
    NoiseMoments,
    SequenceStatistics,
    ambient_block_noise,
    block_sums,
    block_sums_and_differences,
    cfa_planes,
    non_finite_frames_error,
    plane_shape,
    saturated_blocks,
    thread_pool,
)
from msflash.processing.synthesis import frame_coefficients

LOCAL_METHODS = ("auto", "global", "local")
"""``auto`` selects the model from the data; ``global`` is the paper's; ``local`` forces tiles."""
DEFAULT_TILES = 8
"""Tiles per side of the frame (8 × 8 = 64 tiles)."""
SMOOTHING_GRID = (0.5, 1.0, 2.0)
"""Gaussian widths (in tiles) of the local candidates: 0.5 is "local" (a tile and a little of its
four neighbours), 1 and 2 "local-smoothed"."""
SELECTION_MARGIN = 0.10
"""A local model must cut the leave-one-tile-out prediction error by more than this fraction of the
global model's; otherwise the global model is kept (calibrated on uniform scenes, see the docs)."""
MIN_EXPLAINED_GAIN = 1e-3
"""A local model must also cut the held-out squared error by more than this fraction of the ambient
image's energy ``Σ_t ‖a_t‖²`` (a global model that predicts the ambient image within √0.001 ≈ 3 %
RMS stays). It lies between the largest cut simulated uniform scenes gave and the smallest of the
gradients, whose two ambients can look alike to the camera (docs/local-estimation.md, how it works)."""
REGION_RADIUS = 2
"""Half-width in blocks of the box over which block residuals are pooled before labelling (5 × 5 blocks)."""
REGION_ITERATIONS = 20
"""At most this many alternations of labelling blocks and re-pooling the regions' statistics (they stop
when no label changes; a few suffice on most scenes)."""
MAX_REGION_CELLS = 6000
"""Blocks are grouped into cells of g × g blocks so that the labels have at most about this many cells
(cost: a 240 × 320 frame at 4× binning keeps its 4 800 blocks; a 1024 × 1280 frame gets 16-pixel cells)."""
MIN_TILE_SAMPLES_PER_LED = 4
"""A tile with fewer valid samples than this many per LED borrows its estimate from the smoothed fit."""


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
    """(n_frames + 2, h, w, C) the blocks' even-column sums minus their odd-column sums (the ones row 0,
    invalid blocks zeroed): the noise probe of :attr:`TiledStatistics.denoised`. None for odd bin factors."""
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
class Cells:
    """The valid cells of ``g × g`` blocks, reduced once to their statistics for :func:`segment_regions`.

    Every cell's products of its ambient and LED images (eq. 4–5), so that any region's or tile's
    statistics, and any weights' residual per cell, are sums and products over the cells.
    """

    valid: np.ndarray = field(repr=False)
    """(h, w) the cell grid's valid cells (the N rows are its True entries in row-major order)."""
    size: int
    """Cell side in pixels."""
    channels: int
    """Samples per cell (colour channels)."""
    gram: np.ndarray = field(repr=False)
    """(N, k·k) ``F_bᵀ F_b`` of every cell, flattened."""
    cross: np.ndarray = field(repr=False)
    """(N, k) ``F_bᵀ a_b``."""
    energy: np.ndarray = field(repr=False)
    """(N,) ``a_bᵀ a_b``."""
    sums: np.ndarray = field(repr=False)
    """(N, 1 + k) sums over the channels of ``a_b`` and of every LED image."""
    spec: FrameStackSpec | None = field(default=None, repr=False)
    """The block-level spec that maps raw moments to statistics (for :meth:`denoised_statistics`)."""
    differences: np.ndarray | None = field(default=None, repr=False)
    """(R, N, C) every cell's half difference (the noise probe of :attr:`TiledStatistics.denoised`) in
    the rows ``[F_1 … F_n, A, 1]``; None when the blocks carry none."""

    @classmethod
    def of(cls, blocks: BlockData, group: int | None = None) -> Cells:
        """The cells of ``group × group`` blocks (None: at most about :data:`MAX_REGION_CELLS` cells).

        Sums of blocks obey the same linear model, so grouping only coarsens the labels. A cell is
        kept when all its blocks are valid. Each cell's statistics come from the raw moments of its
        samples by the map of :func:`tile_statistics`: a cell is a tiny tile.
        """
        if group is None:
            group = max(1, int(np.ceil(np.sqrt(blocks.valid.size / MAX_REGION_CELLS))))
        rows, columns = blocks.shape[0] // group, blocks.shape[1] // group
        valid = blocks.valid[: rows * group, : columns * group]
        if group > 1:
            valid = np.all(valid.reshape(rows, group, columns, group), axis=(1, 3))

        def cell_samples(values: np.ndarray) -> np.ndarray:
            values = values[:, : rows * group, : columns * group]
            if group > 1:  # the rows' sums on the image threads (numpy releases the GIL)
                values = np.stack(list(thread_pool(DEFAULT_WORKERS).map(lambda row: block_sums(row, group), values)))
            return values[:, valid]  # (R, N, C)

        samples = cell_samples(blocks.raw)
        # The raw rows of every sample mapped to [f_1 … f_k, a] first (one product), then each cell's
        # products summed over its channels: the same statistics as the tiles' map of raw moments.
        # Channels before cells, so that the sums over the channels add whole rows of cells.
        linear = np.tensordot(_projection(blocks.spec), samples.transpose(0, 2, 1), axes=1)  # (k + 1, C, N)
        leds, ambient = linear[:-1], linear[-1]
        k = leds.shape[0]
        gram = (leds[:, None] * leds[None]).sum(axis=2).reshape(k * k, -1).T
        differences = None if blocks.differences is None else cell_samples(blocks.differences)
        return cls(
            valid=valid,
            size=blocks.pixel * group,
            channels=int(samples.shape[2]),
            gram=np.ascontiguousarray(gram),
            cross=np.ascontiguousarray((leds * ambient).sum(axis=1).T),
            energy=(ambient * ambient).sum(axis=0),
            sums=np.column_stack([ambient.sum(axis=0), leds.sum(axis=1).T]),
            spec=blocks.spec,
            differences=differences,
        )

    def errors(self, weights: np.ndarray) -> np.ndarray:
        """``‖a_b − F_b w‖²`` of every cell for each row of ``weights`` (R, k): (R, N)."""
        quadratic = np.einsum("ri,rj->rij", weights, weights).reshape(weights.shape[0], -1)
        return np.clip(self.energy[None] - 2.0 * weights @ self.cross.T + quadratic @ self.gram.T, 0.0, None)

    def statistics(self, member: np.ndarray) -> SequenceStatistics:
        """Pooled statistics of the cells where ``member`` (N,) is set."""
        k = self.cross.shape[1]
        select = np.asarray(member, dtype=float)
        n = int(select.sum()) * self.channels
        return SequenceStatistics(
            gram=(select @ self.gram).reshape(k, k),
            cross=select @ self.cross,
            ambient_energy=float(select @ self.energy),
            n_samples=n,
            n_total=n,
            ambient_sum=float(select @ self.sums[:, 0]),
            led_sums=select @ self.sums[:, 1:],
        )

    def denoised_statistics(self, member: np.ndarray) -> SequenceStatistics | None:
        """:meth:`statistics` with the noise's contribution removed (:attr:`TiledStatistics.denoised`), or None.

        The member cells' raw noise moments ``Σ d dᵀ`` are summed first and mapped once (the map is linear).
        """
        if self.differences is None or self.spec is None:
            return None
        observed = self.statistics(member)
        probe = self.differences[:, np.asarray(member, dtype=bool)].reshape(self.differences.shape[0], -1)
        pooled = (probe @ probe.T)[None, None]
        noise = _tiled_from_moments(pooled, np.ones((1, 1)), self.spec, np.zeros(2, dtype=int), np.zeros(2, dtype=int))
        return replace(
            observed,
            gram=observed.gram - noise.gram[0, 0],
            cross=observed.cross - noise.cross[0, 0],
            ambient_energy=observed.ambient_energy - float(noise.ambient_energy[0, 0]),
        )


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
    """The same tiles with the noise's contribution to their moments removed, or None (odd bin factors).

    The LED-only images are differences of noisy frames, so ``GᵀG``-type moments are biased by the
    noise variance (eq. 5 regresses on noisy regressors: errors in variables). Each block's columns
    are split into two interleaved halves with independent noise; with ``x = x₁ + x₂`` the block's
    row of sums and ``d = x₁ − x₂``, ``E[d dᵀ]`` holds the noise covariance of ``x`` (plus the
    halves' texture difference), and ``Σ (x xᵀ − d dᵀ) = 2 Σ (x₁ x₂ᵀ + x₂ x₁ᵀ)`` is a cross-product
    of independent halves: the estimating equations of eq. 5 on these moments have no noise bias (an
    instrumental-variable estimate; no noise model needed). The valid-sample counts and sums are the
    tiles' own. :func:`estimate_local` solves the local model on them; :func:`denoised_global`
    gives the global model's estimate on them."""

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
        :func:`processing.statistics.accumulate_statistics` gives for the same blocks (exactly below
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
    """:func:`processing.statistics.block_sums_and_differences` of an (H, W, C) plane into (H/f, W/f, C) arrays."""
    block_sums_part, difference_part = block_sums_and_differences(plane, factor)
    np.copyto(sums, block_sums_part[: sums.shape[0], : sums.shape[1]])
    np.copyto(differences, difference_part[: differences.shape[0], : differences.shape[1]])


class TileBlocks:
    """Block sums of an ambient + LED frame stack for :class:`TiledStatistics`, added one frame at a time.

    Rows as :class:`processing.statistics.BlockRows`'s: LED frame j → row j, the ambient frame → row n, a
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
        tiled = _tiled_from_moments(moments, totals, block_spec, row_edges, column_edges)
        blocks = BlockData(raw=data, differences=differences, valid=~invalid, spec=block_spec, pixel=pixel)
        denoised = None
        if noise is not None:
            denoised = _tiled_from_moments(moments - noise, totals, block_spec, row_edges, column_edges)
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
    workers: int = DEFAULT_WORKERS,
    weighting: bool = False,
) -> TiledStatistics:
    """The statistics of eq. 4–6 of every tile of a ``tiles`` grid, in one pass over the frames (:class:`TileBlocks`).

    Blocks (``bin_factor``, see :func:`processing.statistics.bin_frame`) are assigned to tiles
    whole; a block is left out when any member saturates in any frame. The tiles' statistics sum
    to those of :func:`processing.statistics.accumulate_statistics` with the same binning.

    Parameters
    ----------
    ambient, led_frames, spec
        As for :func:`processing.statistics.accumulate_statistics`.
    tiles
        Tiles per side, or (rows, columns).
    bin_factor, cfa_period
        Block size, and 2 for Bayer mosaics.
    workers
        Threads sharing the frames' block sums and the tiles' moments (1: the calling thread). The
        statistics do not depend on it.
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
    list(thread_pool(workers).map(add, rows) if workers > 1 else map(add, rows))
    return accumulator.statistics(spec, tiles, workers)


def _projection(spec: FrameStackSpec) -> np.ndarray:
    """(k + 1, R) linear map of the raw rows [F_1 … F_n, A, 1] to [f_1 … f_k, a] (LED images at full drive, ambient)."""
    n_led_frames = len(spec.led_scales)
    scales = np.asarray(spec.led_scales, dtype=float)
    black = float(spec.black_level)
    # d_j = s_j (F_j − b) − s_a (A − b), a = s_a (A − b): a linear map of the raw rows.
    transform = np.zeros((n_led_frames + 1, n_led_frames + 2))
    transform[:n_led_frames, :n_led_frames] = np.diag(scales)
    transform[:n_led_frames, n_led_frames] = -spec.ambient_scale
    transform[:n_led_frames, n_led_frames + 1] = (spec.ambient_scale - scales) * black
    transform[n_led_frames, n_led_frames] = spec.ambient_scale
    transform[n_led_frames, n_led_frames + 1] = -spec.ambient_scale * black
    # Unmixed LED images at full drive (pinv of the levels) and the ambient: one (k + 1, R) map.
    return np.vstack([spec.unmixing @ transform[:n_led_frames], transform[n_led_frames:]])


def _tiled_from_moments(
    moments: np.ndarray, totals: np.ndarray, spec: FrameStackSpec, row_edges: np.ndarray, column_edges: np.ndarray
) -> TiledStatistics:
    """Tiled statistics from raw moments of the rows [F_1 … F_n, A, 1] (one (R, R) matrix per tile)."""
    projection = _projection(spec)
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


# -- model selection --------------------------------------------------------------------------
@dataclass(frozen=True)
class ModelSelection:
    """The outcome of leave-one-tile-out model selection."""

    model: str
    """``global`` or ``local``."""
    smoothing: float | None
    """Gaussian width in tiles of the chosen local model (None for global)."""
    scores: dict[str, float]
    """Held-out prediction error of every candidate relative to the global model's (global = 1)."""
    best_local: float
    """The smoothing width of the best local candidate (used when ``local`` is forced)."""
    margin: float
    """The margin a local model had to beat."""
    explained_gain: float = 0.0
    """The best local model's held-out error cut as a fraction of the ambient image's energy."""
    min_explained_gain: float = MIN_EXPLAINED_GAIN
    """The fraction it had to exceed."""


def _batched_ridge(gram: np.ndarray, cross: np.ndarray, penalty: np.ndarray, alpha: float) -> np.ndarray:
    """Tikhonov weights ``(G + λ LᵀL)⁻¹ c`` of every tile, λ = α tr(G)/tr(LᵀL) (unconstrained, batched)."""
    k = gram.shape[-1]
    trace = np.trace(gram, axis1=-2, axis2=-1)
    weight = alpha * trace / max(float(np.trace(penalty)), 1e-300)
    system = (
        gram + weight[..., None, None] * penalty + (1e-12 * np.maximum(trace, 1e-300) / k)[..., None, None] * np.eye(k)
    )
    return np.linalg.solve(system, cross[..., None])[..., 0]


def _held_out_error(tiles: TiledStatistics, weights: np.ndarray) -> np.ndarray:
    """``‖a_t − F_t w_t‖²`` of every tile for per-tile weights (ty, tx, k)."""
    quadratic = np.einsum("tsi,tsij,tsj->ts", weights, tiles.gram, weights)
    return np.clip(tiles.ambient_energy - 2.0 * np.einsum("tsi,tsi->ts", tiles.cross, weights) + quadratic, 0.0, None)


def select_model(
    tiles: TiledStatistics,
    led_spectra: Spectra,
    alpha: float | None = None,
    smoothing_grid: Sequence[float] = SMOOTHING_GRID,
    margin: float = SELECTION_MARGIN,
    min_explained_gain: float = MIN_EXPLAINED_GAIN,
) -> ModelSelection:
    """Choose between the global and local models by leave-one-tile-out prediction error.

    Parameters
    ----------
    tiles
        Tiled statistics.
    led_spectra
        The LED spectra (photons): the fits are Tikhonov-regularised with their roughness.
    alpha
        Dimensionless roughness weight of the scoring fits; None chooses it by GCV on the global
        statistics.
    smoothing_grid
        Widths (tiles) of the local candidates.
    margin
        Relative improvement over the global model a local one must exceed.
    min_explained_gain
        Improvement, as a fraction of the ambient image's energy, a local one must also exceed.
    """
    roughness = np.diff(led_spectra.values, axis=0)
    penalty = roughness.T @ roughness
    total = tiles.total()
    if alpha is None:
        alpha = gcv_alpha(total, roughness)
    # Global model without tile t: all statistics minus tile t's.
    global_gram = total.gram[None, None] - tiles.gram
    global_cross = total.cross[None, None] - tiles.cross
    global_error = float(_held_out_error(tiles, _batched_ridge(global_gram, global_cross, penalty, alpha)).sum())
    scores = {"global": 1.0}
    reference = max(global_error, 1e-300)
    best_sigma, best_score = float(smoothing_grid[0]), np.inf
    for sigma in smoothing_grid:
        neighbours = tiles.smoothed(float(sigma), leave_out=True)
        usable = neighbours.n_samples > tiles.n_leds
        weights = _batched_ridge(neighbours.gram, neighbours.cross, penalty, alpha)
        error = _held_out_error(tiles, weights)
        # A tile whose neighbourhood is empty (tiny grids) is predicted by the global model.
        if not usable.all():
            fallback = _held_out_error(tiles, _batched_ridge(global_gram, global_cross, penalty, alpha))
            error = np.where(usable, error, fallback)
        score = float(error.sum()) / reference
        scores[f"local(sigma={sigma:g})"] = score
        if score < best_score:
            best_sigma, best_score = float(sigma), score
    explained_gain = (1.0 - best_score) * global_error / max(float(tiles.ambient_energy.sum()), 1e-300)
    chosen = "local" if best_score < 1.0 - margin and explained_gain > min_explained_gain else "global"
    return ModelSelection(
        model=chosen,
        smoothing=best_sigma if chosen == "local" else None,
        scores=scores,
        best_local=best_sigma,
        margin=margin,
        explained_gain=float(explained_gain),
        min_explained_gain=min_explained_gain,
    )


# -- two illuminant regions ---------------------------------------------------------------------
@dataclass(frozen=True)
class RegionSegmentation:
    """Two ambient regions: block labels and one estimate per region pooled over all its blocks."""

    labels: np.ndarray
    """(h, w) bool block labels: True = region 1."""
    weights: np.ndarray
    """(2, k) ambient weights of regions 0 and 1 (the chosen solver on each region's pooled statistics)."""
    residual: float
    """In-sample ``Σ_b ‖a_b − F_b w_label(b)‖²`` over the valid blocks."""
    affine_residual: float
    """In-sample residual of the smooth alternative: weights affine in the position, ``w(x) = w₀ + u wᵤ + v wᵥ``."""
    pixel: int
    """Block side in pixels."""

    @property
    def chosen(self) -> bool:
        """Whether two regions explain the ambient image better than a smooth (affine) field."""
        return bool(self.labels.any() and not self.labels.all() and self.residual < self.affine_residual)

    def label_map(self, shape: tuple[int, int]) -> np.ndarray:
        """(H, W) per-pixel region labels (blocks repeated, the uncovered margin takes the nearest block)."""
        rows = np.minimum(np.arange(shape[0]) // self.pixel, self.labels.shape[0] - 1)
        columns = np.minimum(np.arange(shape[1]) // self.pixel, self.labels.shape[1] - 1)
        return self.labels[rows[:, None], columns[None, :]]


def _box(values: np.ndarray, radius: int) -> np.ndarray:
    """Sums over (2r + 1)² windows of an (h, w) map, truncated at the border (cumulative sums)."""

    def along(x: np.ndarray, axis: int) -> np.ndarray:
        n = x.shape[axis]
        padded = np.concatenate([np.zeros_like(np.take(x, [0], axis=axis)), np.cumsum(x, axis=axis)], axis=axis)
        upper = np.minimum(np.arange(n) + radius + 1, n)
        lower = np.maximum(np.arange(n) - radius, 0)
        return np.take(padded, upper, axis=axis) - np.take(padded, lower, axis=axis)

    return along(along(values, 0), 1)


def _interior(region: np.ndarray) -> np.ndarray:
    """(h, w) cells of a boolean map whose 3 × 3 neighbourhood (truncated at the frame's border) is all in it.

    Examples
    --------
    >>> _interior(np.array([[1, 1, 1, 0], [1, 1, 1, 0], [1, 1, 1, 0]], dtype=bool)).astype(int).tolist()
    [[1, 1, 0, 0], [1, 1, 0, 0], [1, 1, 0, 0]]
    """
    inside = region.astype(float)
    return region & (_box(inside, 1) == _box(np.ones_like(inside), 1))


def _affine_residual(tiles: TiledStatistics, penalty: np.ndarray, alpha: float) -> float:
    """In-sample residual of weights affine in the tile-centre position (Tikhonov, from the tile statistics)."""
    rows, columns = tiles.centres
    height, width = tiles.frame_shape
    u = np.broadcast_to((columns / width - 0.5)[None, :], tiles.shape)
    v = np.broadcast_to((rows / height - 0.5)[:, None], tiles.shape)
    basis = np.stack([np.ones(tiles.shape), u, v], axis=-1)  # (ty, tx, 3)
    k = tiles.n_leds
    gram = np.einsum("tsb,tsc,tsij->bicj", basis, basis, tiles.gram, optimize=True).reshape(3 * k, 3 * k)
    cross = np.einsum("tsb,tsi->bi", basis, tiles.cross).reshape(3 * k)
    theta = _batched_ridge(gram, cross, np.kron(np.eye(3), penalty), alpha)
    return float(max(tiles.ambient_energy.sum() - 2.0 * cross @ theta + theta @ gram @ theta, 0.0))


def segment_regions(
    tiles: TiledStatistics,
    led_spectra: Spectra,
    alpha: float,
    solver: str = "tikhonov",
    solver_alpha: float | str = "auto",
    radius: int = REGION_RADIUS,
    iterations: int = REGION_ITERATIONS,
    cells: Cells | None = None,
    noise_correction: bool = True,
) -> RegionSegmentation | None:
    """Split the frame into two ambient regions and estimate each from all of its blocks.

    1. Tile estimates (ridge on the σ = 0.5 smoothed statistics) seed two clusters: the two tiles
       whose normalised spectra differ most, every tile to the nearer; each cluster's tiles are
       pooled into a first estimate.
    2. Every block is labelled with the region whose weights predict its ambient image better,
       the residual differences summed over a (2r + 1)² box of cells first (a vote: the label
       follows the data, not the tile grid; a bright neighbour can pull a boundary by ≤ r cells). Each region's statistics are then
       pooled from its blocks and re-solved; repeated until no label changes (at most ``iterations`` times).
    3. The chosen solver runs on each region's pooled statistics: a region sees as many surfaces
       as it covers, not a tile's worth. With ``noise_correction`` (and cells that carry a noise
       probe) these are the denoised statistics (:attr:`TiledStatistics.denoised`); labelling uses
       the statistics as observed.

    ``cells`` are the tiles' :class:`Cells` when already built. Returns None when the tiles hold no
    block data (statistics built from moments only).
    """
    blocks = tiles.blocks
    if blocks is None or not blocks.valid.any():
        return None
    cells = Cells.of(blocks) if cells is None else cells
    if not cells.valid.any():
        return None
    led_values = led_spectra.values
    roughness = np.diff(led_values, axis=0)
    penalty = roughness.T @ roughness
    smoothed = tiles.smoothed(0.5)
    tile_weights = _batched_ridge(smoothed.gram, smoothed.cross, penalty, alpha).reshape(-1, tiles.n_leds)
    spectra = tile_weights @ led_values.T
    spectra /= np.maximum(np.linalg.norm(spectra, axis=1, keepdims=True), 1e-300)
    distances = ((spectra[:, None] - spectra[None]) ** 2).sum(axis=-1)
    first, second = np.unravel_index(int(distances.argmax()), distances.shape)
    in_second = distances[second] < distances[first]
    gram = tiles.gram.reshape(-1, tiles.n_leds, tiles.n_leds)
    cross = tiles.cross.reshape(-1, tiles.n_leds)
    weights = np.stack(
        [
            _batched_ridge(gram[~in_second].sum(axis=0), cross[~in_second].sum(axis=0), penalty, alpha),
            _batched_ridge(gram[in_second].sum(axis=0), cross[in_second].sum(axis=0), penalty, alpha),
        ]
    )
    valid = cells.valid
    difference = np.zeros(valid.shape)
    labels = np.zeros(valid.shape, dtype=bool)
    for iteration in range(iterations):
        errors = cells.errors(weights)
        # Residual differences summed over a (2r + 1)² box of cells: a vote weighted by the cells'
        # brightness (normalised votes were tried: noisy dark cells then flip labels, worse on the study).
        difference[valid] = errors[1] - errors[0]
        previous, labels = labels, _box(difference, radius) < 0.0
        member = labels[valid]
        if member.all() or not member.any() or (iteration > 0 and np.array_equal(labels, previous)):
            break
        pooled = [cells.statistics(mask) for mask in (~member, member)]
        weights = np.stack([_batched_ridge(p.gram, p.cross, penalty, alpha) for p in pooled])
    member = labels[valid]
    final = weights.copy()
    if member.any() and not member.all():
        model = AmbientModel(led_spectra)
        for index, region in enumerate((~labels, labels)):
            # The cells next to the label edge may straddle the true boundary (light of both sides) or
            # be mislabelled: each region is solved on its interior (cells whose 3 × 3 neighbourhood
            # shares the label), or on all its cells when it has no interior.
            interior = _interior(region)[valid]
            mask = interior if interior.any() else region[valid]
            try:
                final[index] = model.weights(
                    cells.statistics(mask),
                    solver,
                    solver_alpha,
                    denoised=cells.denoised_statistics(mask) if noise_correction else None,
                )[0]
            except SolverError:
                pass
    errors = cells.errors(final)
    residual = float(np.where(member, errors[1], errors[0]).sum())
    return RegionSegmentation(
        labels=labels,
        weights=final,
        residual=residual,
        affine_residual=_affine_residual(tiles, penalty, alpha),
        pixel=cells.size,
    )


# -- local estimates --------------------------------------------------------------------------
@dataclass(frozen=True)
class LocalEstimate:
    """The ambient of a scene: global, or one estimate per tile."""

    model: str
    """``global`` or ``local`` (what was used)."""
    method: str
    """What was asked: ``auto``, ``global`` or ``local``."""
    smoothing: float | None
    """Gaussian width in tiles of the local fit (None for global)."""
    global_estimate: AmbientEstimate
    """The single (global) estimate, eq. 4–6 on the whole frame's denoised statistics (always computed: the one
    the caller gave, else solved on the sum of the tiles)."""
    tile_weights: np.ndarray
    """Ambient weights of every tile, (ty, tx, k); all equal to the global weights for the global model."""
    tile_residuals: np.ndarray
    """Relative residual ``‖a_t − F_t w_t‖ / ‖a_t‖`` of every tile under its own weights, (ty, tx)."""
    tile_samples: np.ndarray
    """Valid samples of every tile (own, before smoothing), (ty, tx)."""
    tiles: TiledStatistics
    """The tiled statistics (and geometry)."""
    selection: ModelSelection | None
    """The model selection (None when the method was forced and selection skipped)."""
    led_values: np.ndarray = field(repr=False)
    """The LED spectra (photons, n_wavelengths × k) the weights refer to."""
    warnings: tuple[str, ...] = ()
    """Human-readable warnings."""
    structure: str | None = None
    """For the local model: ``regions`` (two illuminant regions, :func:`segment_regions`) or ``tiles``."""
    regions: RegionSegmentation | None = None
    """The two-region segmentation when ``structure == "regions"``."""

    @property
    def tile_spectra(self) -> np.ndarray:
        """``I w_t`` of every tile, (ty, tx, n_wavelengths), photons."""
        return np.einsum("lk,tsk->tsl", self.led_values, self.tile_weights)

    @property
    def mean_weights(self) -> np.ndarray:
        """Area-weighted mean of the tiles' weights, (k,) — the global weights for the global model."""
        if self.model == "global":
            return self.global_estimate.ambient_weights
        areas = self.tiles.areas
        return np.einsum("ts,tsk->k", areas, self.tile_weights) / areas.sum()

    @property
    def mean_spectrum(self) -> np.ndarray:
        """``I`` times :attr:`mean_weights`, photons (n_wavelengths,)."""
        return self.led_values @ self.mean_weights

    def weights_map(self, shape: tuple[int, int] | None = None) -> np.ndarray:
        """Per-pixel ambient weights (H, W, k): each pixel's region's, or bilinear between tile centres."""
        shape = shape if shape is not None else self.tiles.frame_shape
        if self.regions is not None:
            labels = self.regions.label_map(shape)
            return np.where(labels[..., None], self.regions.weights[1], self.regions.weights[0])
        return upsample_tiles(self.tile_weights, self.tiles, shape)


def estimate_local(
    tiles: TiledStatistics,
    led_spectra: Spectra,
    method: str = "auto",
    solver: str = "tikhonov",
    alpha: float | str = "auto",
    smoothing: float | None = None,
    margin: float = SELECTION_MARGIN,
    regions_allowed: bool = True,
    noise_correction: bool = True,
    global_estimate: AmbientEstimate | None = None,
) -> LocalEstimate:
    """Estimate the ambient globally or per tile, choosing the model from the data for ``auto``.

    Parameters
    ----------
    tiles
        Tiled statistics (:func:`tile_statistics`).
    led_spectra
        The k LED spectra at full drive, photons.
    method
        ``auto`` (:func:`select_model`), ``global`` (the paper) or ``local``.
    solver, alpha
        The estimator of :func:`processing.ambient.estimate_ambient` and its roughness weight. For
        ``alpha="auto"`` with ``tikhonov``, the discrepancy principle chooses it per tile
        (:func:`processing.ambient.discrepancy_alpha`; the model selection's scoring fits use GCV).
    smoothing
        Gaussian width in tiles of the local fit; None takes the best of the selection. Giving it
        forces the tile model.
    margin
        See :func:`select_model`.
    regions_allowed
        When the local model is used (and ``smoothing`` is None), try the two-region model
        (:func:`segment_regions`) and keep it when two regions explain the ambient image better
        than a smooth affine field; otherwise (or when False) solve per tile.
    noise_correction
        Solve the local model (tiles and regions) on the denoised statistics
        (:attr:`TiledStatistics.denoised`: the noise bias of the LED-only images' moments removed)
        when the tiles have them (even bin factors). The global estimate is solved on them too (as
        :func:`processing.ambient.estimate_ambient` does on any statistics that carry their noise), so it is
        the whole-frame estimate of ``msflash estimate --method global``; model selection and region
        labels use the statistics as observed. False: everything on the statistics as observed.
    global_estimate
        The whole-frame estimate (eq. 4–6) when the caller has it: a sequence's, from the whole frame's
        statistics (:func:`processing.statistics.accumulate_statistics`), so that the global numbers are
        those of every other route from the frames to an estimate. It is then used as it is (its α scores
        the selection), not solved again on the sum of the tiles — which is the same up to the summation
        order, except on large frames (:data:`processing.statistics.PROBE_BLOCKS`), where the whole-frame
        pass probes the noise on a stride of block rows and the tiles on every block (a different noise
        correction, hence a different GCV α). None: solved on :meth:`TiledStatistics.total`.
    """
    if method not in LOCAL_METHODS:
        raise ValueError(f"local method '{method}' is unknown; expected one of {', '.join(LOCAL_METHODS)}")
    if solver not in AMBIENT_METHODS:
        raise ValueError(f"ambient method '{solver}' is unknown; expected one of {', '.join(AMBIENT_METHODS)}")
    require_unit(led_spectra, "photons")
    total = tiles.total() if noise_correction else replace(tiles.total(), noise=None)
    clean = tiles.denoised if noise_correction else None
    ambient_model = AmbientModel(led_spectra)
    # The global model is the one `msflash estimate --method global` and `msflash run` compute from the
    # whole frame: solved on the denoised statistics when the blocks carry the noise probe.
    if global_estimate is None:
        global_estimate = ambient_model.estimate(total, solver, alpha)
    led_values = led_spectra.values
    shape = tiles.shape
    selection = None
    # The scoring fits' roughness weight: the global estimate's (GCV on the statistics as observed,
    # or the given α) — already computed there.
    scoring_alpha = None
    if solver == "tikhonov":
        scoring_alpha = global_estimate.alpha if global_estimate.alpha > 0 else None
    if method == "auto" or (method == "local" and smoothing is None):
        selection = select_model(tiles, led_spectra, scoring_alpha, margin=margin)
    model = selection.model if method == "auto" and selection is not None else method
    weights = np.broadcast_to(global_estimate.ambient_weights, shape + (tiles.n_leds,)).copy()
    used_sigma, structure, regions = None, None, None
    warnings: list[str] = []
    if model == "local":
        if smoothing is not None:
            used_sigma = float(smoothing)
        else:
            assert selection is not None  # chosen above whenever no smoothing is given
            used_sigma = float(selection.best_local)
        if smoothing is None and regions_allowed:
            labelling_alpha = (
                scoring_alpha if scoring_alpha is not None else gcv_alpha(total, ambient_model.terms.roughness)
            )
            regions = segment_regions(
                tiles, led_spectra, labelling_alpha, solver, alpha, noise_correction=noise_correction
            )
            if regions is not None and not regions.chosen:
                regions = None
        if regions is not None:
            structure = "regions"
            weights = _region_tile_weights(regions, tiles)
        else:
            structure = "tiles"
            weights, warnings = _solve_tiles(
                tiles.smoothed(used_sigma),
                None if clean is None else clean.smoothed(used_sigma),
                tiles,
                ambient_model,
                solver,
                alpha,
                global_estimate,
            )
    residual = np.sqrt(_held_out_error(tiles, weights) / np.maximum(tiles.ambient_energy, 1e-300))
    return LocalEstimate(
        model=model,
        method=method,
        smoothing=used_sigma,
        global_estimate=global_estimate,
        tile_weights=weights,
        tile_residuals=residual,
        tile_samples=tiles.n_samples.copy(),
        tiles=tiles,
        selection=selection,
        led_values=led_values,
        warnings=tuple(warnings),
        structure=structure,
        regions=regions,
    )


def _region_tile_weights(regions: RegionSegmentation, tiles: TiledStatistics) -> np.ndarray:
    """Every tile's weights for a two-region estimate: the regions' mixed by their shares of the tile's cells."""
    cells_rows, cells_columns = regions.labels.shape
    centre_rows = (np.arange(cells_rows) + 0.5) * regions.pixel
    centre_columns = (np.arange(cells_columns) + 0.5) * regions.pixel
    tile_rows = np.clip(np.searchsorted(tiles.row_edges, centre_rows, side="right") - 1, 0, tiles.shape[0] - 1)
    tile_columns = np.clip(np.searchsorted(tiles.column_edges, centre_columns, side="right") - 1, 0, tiles.shape[1] - 1)
    index = (tile_rows[:, None] * tiles.shape[1] + tile_columns[None, :]).ravel()
    count = np.bincount(index, minlength=tiles.shape[0] * tiles.shape[1]).astype(float)
    ones = np.bincount(index, weights=regions.labels.ravel().astype(float), minlength=count.size)
    # A tile without a cell centre (tiny tiles) takes its nearest cell's label.
    rows = np.minimum(tiles.centres[0].astype(int) // regions.pixel, cells_rows - 1)
    columns = np.minimum(tiles.centres[1].astype(int) // regions.pixel, cells_columns - 1)
    nearest = regions.labels[rows[:, None], columns[None, :]]
    share = np.where(count > 0, ones / np.maximum(count, 1.0), nearest.ravel().astype(float)).reshape(tiles.shape)
    return (1.0 - share)[..., None] * regions.weights[0] + share[..., None] * regions.weights[1]


def denoised_global(
    tiles: TiledStatistics, led_spectra: Spectra, solver: str = "tikhonov", alpha: float | str = "auto"
) -> np.ndarray:
    """``w_a`` of the global model solved on the denoised statistics (:attr:`TiledStatistics.denoised`).

    The same estimator as the local model's, over the whole frame — the reference that isolates
    what locality adds; the global estimate of :func:`estimate_local` (with ``noise_correction``) is
    this one. Falls back to the observed statistics as :func:`estimate_local` does.
    """
    clean = tiles.denoised
    return AmbientModel(led_spectra).weights(
        tiles.total(), solver, alpha, denoised=None if clean is None else clean.total()
    )[0]


def _solve_tiles(
    smoothed: TiledStatistics,
    denoised: TiledStatistics | None,
    own: TiledStatistics,
    model: AmbientModel,
    solver: str,
    alpha: float | str,
    global_estimate: AmbientEstimate,
) -> tuple[np.ndarray, list[str]]:
    """The chosen solver on every tile's smoothed (denoised when given) statistics; empty tiles take the global weights."""
    weights = np.empty(smoothed.shape + (smoothed.n_leds,))
    fallback = 0
    for i in range(smoothed.shape[0]):
        for j in range(smoothed.shape[1]):
            statistics = smoothed.tile(i, j)
            if statistics.n_samples < MIN_TILE_SAMPLES_PER_LED * statistics.n_leds or not np.all(
                np.diag(statistics.gram) > 0
            ):
                weights[i, j] = global_estimate.ambient_weights
                fallback += 1
                continue
            try:
                weights[i, j] = model.weights(
                    statistics, solver, alpha, denoised=None if denoised is None else denoised.tile(i, j)
                )[0]
            except SolverError:
                weights[i, j] = global_estimate.ambient_weights
                fallback += 1
    warnings = []
    if fallback:
        warnings.append(
            f"{fallback} of {own.shape[0] * own.shape[1]} tiles had too few valid samples and took the global estimate"
        )
    return weights, warnings


# -- the spatially varying computational image ------------------------------------------------
def _interpolation_matrix(centres: np.ndarray, size: int) -> np.ndarray:
    """(size, n) linear interpolation between tile centres, constant beyond the outer ones."""
    n = centres.size
    if n == 1:
        return np.ones((size, 1))
    position = np.clip(np.interp(np.arange(size, dtype=float), centres, np.arange(n, dtype=float)), 0, n - 1)
    lower = np.minimum(np.floor(position).astype(int), n - 2)
    fraction = position - lower
    matrix = np.zeros((size, n))
    matrix[np.arange(size), lower] = 1.0 - fraction
    matrix[np.arange(size), lower + 1] = fraction
    return matrix


def upsample_tiles(values: np.ndarray, tiles: TiledStatistics, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Per-pixel maps (H, W, …) of per-tile values (ty, tx, …), bilinear between tile centres."""
    height, width = shape if shape is not None else tiles.frame_shape
    scale_rows, scale_columns = height / tiles.frame_shape[0], width / tiles.frame_shape[1]
    centre_rows, centre_columns = tiles.centres
    rows = _interpolation_matrix(centre_rows * scale_rows, height)
    columns = _interpolation_matrix(centre_columns * scale_columns, width)
    return np.einsum("hi,ij...,wj->hw...", rows, values, columns, optimize=True)


def coefficient_maps(
    spec: FrameStackSpec, tile_flash_weights: np.ndarray, tiles: TiledStatistics, shape: tuple[int, int]
) -> np.ndarray:
    """Per-pixel coefficients of the linearised frames [ambient, LED frames…], (H, W, 1 + n_frames).

    Each tile's flash weights give frame coefficients (:func:`processing.synthesis.frame_coefficients`);
    they are linear in the weights, so interpolating coefficients = interpolating weights.
    """
    per_tile: np.ndarray = np.empty(tile_flash_weights.shape[:2] + (1 + len(spec.led_scales),))
    for i in range(per_tile.shape[0]):
        for j in range(per_tile.shape[1]):
            ambient_coefficient, coefficients = frame_coefficients(spec, tile_flash_weights[i, j])
            per_tile[i, j, 0], per_tile[i, j, 1:] = ambient_coefficient, coefficients
    return upsample_tiles(per_tile, tiles, shape)


def synthesize_local(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    spec: FrameStackSpec,
    tile_flash_weights: np.ndarray,
    tiles: TiledStatistics,
) -> tuple[np.ndarray, np.ndarray]:
    """The spatially varying computational flash image ``m_a + Σ_k w_k(x) m_f,k``.

    Per-tile flash weights (e.g. complementary to each tile's ambient) are blended bilinearly
    between tile centres into per-pixel coefficient maps, and the image is the per-pixel weighted
    sum of the raw frames (a Bayer mosaic stays a mosaic: every sample has its own coefficients).
    With equal weights in every tile it equals :func:`processing.synthesis.synthesize`.

    Returns
    -------
    image, saturated
        float32 linear image (value per µs·gain), the frames' shape; (H, W) mask of pixels
        saturated in some input frame.
    """
    frames = [ambient, *led_frames]
    for index, frame in enumerate(frames):
        if frame.shape != ambient.shape:
            raise SpectralDataError(
                f"synthesis: frame {index} has shape {frame.shape} but the ambient frame {ambient.shape}"
            )
    if tile_flash_weights.shape != tiles.shape + (spec.n_leds,):
        raise SpectralDataError(
            f"synthesis: tile flash weights of shape {tile_flash_weights.shape}; expected "
            f"{tiles.shape + (spec.n_leds,)}"
        )
    shape = ambient.shape[:2]
    maps = coefficient_maps(spec, tile_flash_weights, tiles, shape)
    scales = np.concatenate([[spec.ambient_scale], np.asarray(spec.led_scales, dtype=float)])
    factors = (maps * scales).astype(np.float32)
    offset = (-spec.black_level * factors.astype(float).sum(axis=-1)).astype(np.float32)
    output = np.empty(ambient.shape, dtype=np.float32)
    saturated = np.zeros(shape, dtype=bool)
    expand = (lambda m: m[:, :, None]) if ambient.ndim == 3 else (lambda m: m)
    output[...] = expand(offset)
    for index, frame in enumerate(frames):
        output += expand(factors[:, :, index]) * frame.astype(np.float32)
        hit = frame >= spec.white_level
        saturated |= hit.any(axis=2) if hit.ndim == 3 else hit
    return output, saturated
