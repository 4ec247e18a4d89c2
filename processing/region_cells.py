"""Cells of ``g × g`` blocks reduced once to their statistics, for the two-region labels of
:func:`processing.local_selection.segment_regions`: a cell is a tiny tile (:mod:`processing.tile_statistics`), its
raw moments mapped like the tiles', so that any region's statistics and any weights' residual per cell are sums and
products over the cells.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from msflash.processing.block_sums import block_sums
from msflash.processing.moment_products import DEFAULT_WORKERS, thread_pool
from msflash.processing.statistics import FrameStackSpec, SequenceStatistics, channel_transform
from msflash.processing.tile_statistics import BlockData, tiled_from_moments

MAX_REGION_CELLS = 6000
"""Blocks are grouped into cells of g × g blocks so that the labels have at most about this many cells
(cost: a 240 × 320 frame at 4× binning keeps its 4 800 blocks; a 1024 × 1280 frame gets 16-pixel cells)."""


@dataclass(frozen=True)
class Cells:
    """The valid cells of ``g × g`` blocks, reduced once to their statistics for :func:`processing.local_selection.segment_regions`.

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
    """(R, N, C) every cell's half difference (the noise probe of :attr:`processing.tile_statistics.TiledStatistics.denoised`) in
    the rows ``[F_1 … F_n, A, 1]``; None when the blocks carry none."""

    @classmethod
    def of(cls, blocks: BlockData, group: int | None = None) -> Cells:
        """The cells of ``group × group`` blocks (None: at most about :data:`MAX_REGION_CELLS` cells).

        Sums of blocks obey the same linear model, so grouping only coarsens the labels. A cell is
        kept when all its blocks are valid. Each cell's statistics come from the raw moments of its
        samples by the map of :func:`processing.tile_statistics.tile_statistics`: a cell is a tiny tile.
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
        linear = np.tensordot(
            channel_transform(blocks.spec, float(blocks.spec.black_level)), samples.transpose(0, 2, 1), axes=1
        )  # (k + 1, C, N)
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
        """:meth:`statistics` with the noise's contribution removed (:attr:`processing.tile_statistics.TiledStatistics.denoised`), or None.

        The member cells' raw noise moments ``Σ d dᵀ`` are summed first and mapped once (the map is linear).
        """
        if self.differences is None or self.spec is None:
            return None
        observed = self.statistics(member)
        probe = self.differences[:, np.asarray(member, dtype=bool)].reshape(self.differences.shape[0], -1)
        pooled = (probe @ probe.T)[None, None]
        noise = tiled_from_moments(pooled, np.ones((1, 1)), self.spec, np.zeros(2, dtype=int), np.zeros(2, dtype=int))
        return replace(
            observed,
            gram=observed.gram - noise.gram[0, 0],
            cross=observed.cross - noise.cross[0, 0],
            ambient_energy=observed.ambient_energy - float(noise.ambient_energy[0, 0]),
        )
