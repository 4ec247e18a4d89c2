"""Block sums of an ambient + LED frame stack as the rows of the binned statistics' moments (:class:`BlockRows`).

Noise (errors in variables)
---------------------------
The LED-only images are differences of noisy frames, so their Gram matrix carries the noise
variance of every frame and their products with the ambient image lose the ambient frame's
(eq. 5 regresses on noisy regressors: the weights shrink towards zero, most for the LEDs the
camera sees least). Binned statistics with an even block size also measure that noise, from
every block's *half difference* (its samples at even ``row + column`` minus those at odd, a
checkerboard, :func:`processing.block_sums.block_sums_and_differences`): the two halves see the same surfaces and have
independent noise, so with ``x`` a block's row of sums and ``d`` its half difference,
``x xᵀ − d dᵀ = 2 (x₁ x₂ᵀ + x₂ x₁ᵀ)`` is a product of independent halves — moments without the noise
bias, whatever the texture inside a block (an instrumental-variable estimate; no noise model needed).
Texture the halves do not share still enters ``d``: it leaves the moments unbiased where eq. 5 holds
but makes them noisier, and it changes which fit is best where eq. 5 does not. The checkerboard cancels
edges along the rows or the columns and ramps (docs/raw-frames.md: why not even and odd columns). :attr:`SequenceStatistics.noise` holds
``d dᵀ`` mapped like the moments, :meth:`SequenceStatistics.denoised` the corrected statistics.

Inverse-variance weights
------------------------
Unweighted moments count every sample alike, so the brightest samples — a specular highlight
at ten times the white, say — dominate the Gram matrix though their photon noise is the largest.
With ``weighting=True`` (:class:`BlockRows`, :func:`processing.accumulate.accumulate_statistics`) each sample (block ×
channel) enters the moments with weight ``1 / var``, its noise variance predicted from the ambient
frame: ``var = gain · level + read`` (a photon-transfer line fitted to the fine-scale detail of the
ambient frame's 2 × 2 cells, :mod:`processing.noise_level`, then scaled to block sums,
:func:`processing.noise_level.block_noise_line`; not the half differences, which texture fills on a mosaic,
docs/raw-frames.md). The weights depend on the
ambient frame alone, so a capture can apply them to every LED frame as it arrives; the half
differences are weighted alike, so the noise correction still holds. Weighted least squares is the
best linear unbiased estimate of eq. 5 when the residual's noise is that of the ambient frame; the
weights are normalised to mean 1 over all samples, and :attr:`SequenceStatistics.n_samples` stays the
count of valid samples.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from msflash.processing import frame_kernels
from msflash.processing.block_sums import (
    block_row_alternation,
    block_row_sums_and_peak,
    block_sums_into,
    cfa_planes,
    difference_gather,
    frame_may_saturate,
    gathered,
    gathered_by_channel,
    plane_shape,
    saturated_blocks,
)
from msflash.processing.errors import SpectralDataError
from msflash.processing.moment_products import (
    DEFAULT_CHUNK_PIXELS,
    gram_matrices,
    serial_columns,
)
from msflash.processing.noise_level import PixelNoise, ambient_block_weights, detail_noise_line
from msflash.processing.statistics import (
    ChannelMoments,
    FrameStackSpec,
    SequenceStatistics,
    channel_transform,
    frame_name,
    non_finite_error,
    non_finite_frames_error,
    statistics_from_moments,
)

PROBE_BLOCKS = 16384
"""Blocks the noise probe needs at least (:class:`BlockRows`): frames with several times more use
every ``stride``-th block row only, ``stride = min(4, blocks // PROBE_BLOCKS)``. Its moments are then
scaled by valid blocks ÷ probed valid blocks; with ≥ 16 384 probed blocks their sampling error is
below 1.1 % of the noise's share (√(2/n)), while a full probe of a large stack costs markedly more
estimation time (docs/architecture.md §10)."""


CHANNEL_BAND_VALUES = 1 << 17
"""How many values (all images together) :meth:`BlockRows._channel_moments` puts in channel order at a time, at
most (bands are also kept within one BLAS thread's product: :func:`processing.moment_products.serial_columns`)."""


def probe_stride(height: int, width: int) -> int:
    """Every how many block rows the noise probe of ``height × width`` blocks is taken (:data:`PROBE_BLOCKS`)."""
    return max(1, min(4, height * width // PROBE_BLOCKS))


class BlockRows:
    """Block sums of an ambient + LED frame stack as the rows ``[F_1 … F_n, A, 1]`` of the moments.

    The binned statistics (eq. 4–6 on ``factor × factor`` block sums, see :func:`processing.block_sums.bin_frame`) need,
    per frame, its block sums and which blocks saturate; then the second moments of the rows. Every route that
    estimates — :func:`processing.accumulate.accumulate_statistics`, a capture's frames as they arrive, a sequence
    streamed from disk (:mod:`acquisition.session.estimate_stream`), the bench — adds each frame's block sums as it
    comes and takes the moments in one product at the end (:meth:`statistics`): one arithmetic, so one set of numbers
    whatever the route and the thread count. Blocks saturated in any frame (or :meth:`exclude`-d) weigh 0 in that
    product.

    One product at the end, rather than each new row's products with the rows already in as it arrives: the
    per-frame products read every filled row again for each frame (their sum over a stack is about n / 2 full
    products), so the whole estimate costs less, though the last frame's latency carries one full product
    (docs/speed.md).

    Frames may be added from several threads (distinct rows); each frame's pass, the noise line and the moments run on
    the thread that calls them (why not a second thread for a frame's pass, the fit or the probe's moments:
    docs/speed.md).
    """

    def __init__(
        self,
        n_led_frames: int,
        plane_shape: tuple[int, ...],
        factor: int,
        white_level: float,
        black_level: float = 0.0,
        weighting: bool = False,
        compiled: bool | None = None,
        full_probe: bool = False,
    ) -> None:
        height, width = plane_shape[0] // factor, plane_shape[1] // factor
        if height == 0 or width == 0:
            raise SpectralDataError(
                f"frame of shape {plane_shape} is smaller than one {factor}×{factor} block; expected a larger frame"
            )
        self.factor, self.white_level, self.n_led_frames = factor, white_level, n_led_frames
        self.plane_shape = tuple(plane_shape)
        self.block_shape = (height, plane_shape[2], width)
        n_rows = n_led_frames + 2
        # Laid out (block row, channel, block column) per frame: any sample order works for
        # moments, and this one lets every copy run along long rows. Each row is written whole before use.
        self.rows = np.empty((n_rows, height * plane_shape[2] * width))
        self.rows[n_led_frames + 1] = 1.0
        # Even blocks also give every block's half difference: the noise probe (module notes). The
        # ones row has no noise. Laid out as the rows, (block row, channel, block column): the compiled moments read
        # both alike, and the probe's weights are the rows' probed block rows (no transpose). Large frames probe
        # every ``probe_stride``-th block row only (PROBE_BLOCKS).
        self.probe_stride = probe_stride(height, width)
        self.difference_shape = (len(range(0, height, self.probe_stride)), plane_shape[2], width)
        # ``full_probe``: every block row's half difference is kept (what the channel statistics need,
        # :meth:`channel_rows`), and the moments here still take every ``probe_stride``-th (the same numbers).
        self._pass_stride = 1 if full_probe else self.probe_stride
        self._stored_shape = (len(range(0, height, self._pass_stride)), plane_shape[2], width)
        self.differences = np.empty((n_rows, math.prod(self._stored_shape))) if factor % 2 == 0 else None
        if self.differences is not None:
            self.differences[n_led_frames + 1] = 0.0
        self._invalid: list[np.ndarray] = []
        self._saturated: list[np.ndarray] = []  # the frames' saturated blocks only (not those excluded)
        self._filled = [n_led_frames + 1]
        self._floating = False
        # Inverse-variance weights (module notes): per row column, once the ambient frame is in (and its probe:
        # without one there is no noise to fit). ``_ambient_saturated`` are the blocks the ambient frame itself
        # saturates (left out of the fit).
        self.black_level = black_level
        self.weighting = weighting and self.differences is not None
        self.ambient_noise: PixelNoise | None = None
        """The ambient frame's noise per sample (:func:`processing.noise_level.detail_noise_line`), once it is in
        (weighted rows only)."""
        self._ambient_saturated: np.ndarray | None = None
        self._weights: np.ndarray | None = None  # the weights, taken once the ambient row is in
        self.compiled = frame_kernels.statistics_compiled() if compiled is None else compiled
        """Whether :meth:`statistics` takes the moments by the compiled pass (agreeing with the numpy route to
        rounding only): decided when the rows are laid out (:func:`processing.frame_kernels.statistics_compiled`)."""

    def add(self, row: int, plane: np.ndarray) -> None:
        """Block-sum one (H, W, C) plane into ``row`` (LED frame j → j, ambient → n) and note its saturated blocks."""
        if plane.shape != self.plane_shape:
            raise SpectralDataError(f"frame stack: a frame has shape {plane.shape}; expected {self.plane_shape}")
        self._check_row(row)
        if np.issubdtype(plane.dtype, np.floating):
            # NaN/inf refused before the block sums, whose gather products would warn about them first.
            if not np.isfinite(plane.sum()):
                raise non_finite_error([frame_name(row, self.n_led_frames)])
            self._floating = True  # only ever set: safe when worker threads add frames
        if self.differences is None:
            block_sums_into(plane, self.factor, self.rows[row].reshape(self.block_shape))
            may_saturate = frame_may_saturate(plane, self.white_level)
        else:
            # The sums from one pass of row sums, the probe from the probed block rows' alternating sums;
            # each product into its own contiguous array.
            row_sums, may_saturate = block_row_sums_and_peak(plane, self.factor, self.white_level)
            channels = self.plane_shape[2]
            gathered_by_channel(row_sums, self.factor, channels, self.rows[row].reshape(self.block_shape))
            alternation = block_row_alternation(plane, self.factor, self._pass_stride)
            differences = gathered(alternation, self.factor, channels, difference_gather)
            np.copyto(self.differences[row].reshape(self._stored_shape), differences.transpose(0, 2, 1))
        # One max per frame finds the frames that saturate at all; only those build masks.
        self._record(row, saturated_blocks(plane, self.factor, self.white_level) if may_saturate else None)
        if row == self.n_led_frames and self.weighting:
            self._weights = self._fitted_weights(plane, 1)

    def add_frame(self, row: int, frame: np.ndarray, cfa_period: int = 1) -> None:
        """:meth:`add` of the frame's CFA planes (:func:`cfa_planes`), in one compiled pass over the raw
        frame where :mod:`processing.frame_kernels` can take it: each sample read once, no plane copy.

        The block sums and half differences are the same integers either way (exact sums); the
        saturated blocks the same mask.
        """
        if plane_shape(frame.shape, cfa_period) != self.plane_shape:
            self.add(row, cfa_planes(frame, cfa_period))  # refuses the shape
            return
        self._check_row(row)
        differences = None
        if self.differences is not None:  # the kernel writes (block row, block column, channel): a view of our layout
            differences = self.differences[row].reshape(self._stored_shape).transpose(0, 2, 1)
        done, saturated = frame_kernels.block_pass(
            frame,
            self.factor,
            cfa_period,
            self.white_level,
            self._pass_stride,
            self.rows[row].reshape(self.block_shape),
            differences,
        )
        if not done:
            self.add(row, cfa_planes(frame, cfa_period))
            return
        self._record(row, saturated)
        if row == self.n_led_frames and self.weighting:
            # The same cells in the same order as from the planes (add): both routes weigh alike, to the bit.
            self._weights = self._fitted_weights(frame, cfa_period)

    def _check_row(self, row: int) -> None:
        if row in self._filled or not 0 <= row <= self.n_led_frames:
            raise SpectralDataError(
                f"frame stack: row {row} is taken or out of range; expected each of 0…{self.n_led_frames} once"
            )

    def _record(self, row: int, saturated: np.ndarray | None) -> None:
        """After a row's block sums are in: its saturated blocks (the ambient's also for the weights' fit)."""
        if row == self.n_led_frames:
            self._ambient_saturated = saturated
        if saturated is not None:
            self._invalid.append(saturated)
            self._saturated.append(saturated)
        self._filled.append(row)

    def _fitted_weights(self, frame: np.ndarray, cfa_period: int) -> np.ndarray:
        """The ambient frame's noise line (:attr:`ambient_noise`) and the inverse-variance weights of every row column
        it gives, from the ambient row (in) and its frame: they depend on these alone, so the thread that added the
        ambient frame takes them while others still add LED frames (off the serial path of :meth:`statistics`)."""
        self.ambient_noise = detail_noise_line(
            frame, cfa_period, self.black_level, self.white_level, compiled=self.compiled
        )
        return ambient_block_weights(
            self.ambient_noise,
            self.factor,
            self.rows[self.n_led_frames],
            self.block_shape,  # the rows' layout: (block row, channel, block column)
            self.black_level * self.factor * self.factor,
            self._ambient_saturated,
            compiled=self.compiled,
        )

    def _at_probe(self, values: np.ndarray) -> np.ndarray:
        """Per-column ``values`` of the rows at the probed blocks, in the probe's layout."""
        if self.probe_stride == 1:
            return values
        return values.reshape(self.block_shape)[:: self.probe_stride].reshape(-1)

    def channel_rows(self) -> tuple[np.ndarray, np.ndarray | None] | None:
        """The rows as :mod:`processing.channel_statistics` stacks them from the frames — features ``[F_1 … F_n, A] ×
        channels, 1`` by blocks in row-major order, blocks saturated in any frame zeroed in every row — and the probe's
        half differences alike (None without one): the same numbers, so the channel statistics need no second pass
        over the frames. None when the probe is strided (:data:`PROBE_BLOCKS`: the channel statistics probe every
        block) or a frame is missing. Excluded blocks (:meth:`exclude`) stay in: only saturation leaves a block out.

        A copy in the channel statistics' layout (the size of the rows, and of the probe): the moments read it
        column band by column band, and a fold is a band of its columns.
        """
        if len(self._filled) != self.rows.shape[0] or self._pass_stride != 1:
            return None
        height, channels, width = self.block_shape
        features = self.rows.shape[0] - 1

        def stacked(values: np.ndarray, last: float) -> np.ndarray:
            out = np.empty((features * channels + 1, height * width))
            np.copyto(
                out[:-1].reshape(features, channels, height, width),
                values[:features].reshape(features, height, channels, width).transpose(0, 2, 1, 3),
            )
            out[-1] = last
            return out

        raw = stacked(self.rows, 1.0)
        probes = None if self.differences is None else stacked(self.differences, 0.0)
        saturated = self._saturated_anywhere()
        if saturated.any():
            columns = saturated.reshape(-1)
            raw[:, columns] = 0.0  # out of every moment, the count included
            if probes is not None:
                probes[:, columns] = 0.0
        return raw, probes

    def stored_rows(self) -> tuple[np.ndarray, np.ndarray | None, np.ndarray] | None:
        """What :meth:`channel_rows` lays out, as stored and without its copy, for integer frames: the rows and the
        whole probe, each (frames + 1, block row · channel · block column; integers), and the (H/f, W/f) mask of
        blocks saturated in any frame. None where :meth:`channel_rows` is, or for float frames."""
        if len(self._filled) != self.rows.shape[0] or self._pass_stride != 1 or self._floating:
            return None
        return self.rows, self.differences, self._saturated_anywhere()

    def _saturated_anywhere(self) -> np.ndarray:
        """The (H/f, W/f) mask of blocks saturated in any frame (not those :meth:`exclude` left out)."""
        saturated = np.zeros((self.block_shape[0], self.block_shape[2]), dtype=bool)
        for mask in self._saturated:
            saturated |= mask
        return saturated

    def exclude(self, blocks: np.ndarray) -> None:
        """Leave the blocks where the (H/f, W/f) mask ``blocks`` is set out of the moments."""
        self._invalid.append(blocks)

    def _columns(self, blocks: np.ndarray) -> np.ndarray:
        """The row columns of the (H/f, W/f) block mask ``blocks`` (every channel of each block)."""
        return np.broadcast_to(blocks[:, None, :], self.block_shape).reshape(-1)

    def _difference_columns(self, blocks: np.ndarray) -> np.ndarray:
        """The columns of the probe's moments (:meth:`_probe`) of the (H/f, W/f) block mask ``blocks``."""
        return np.broadcast_to(blocks[:: self.probe_stride, None, :], self.difference_shape).reshape(-1)

    def _probe(self) -> np.ndarray | None:
        """The half differences the moments take: every ``probe_stride``-th block row's (a copy of those rows where
        the probe was kept whole, ``full_probe``: the same values in the same layout, so the same moments)."""
        if self.differences is None or self._pass_stride == self.probe_stride:
            return self.differences
        height, channels, width = self._stored_shape
        whole = self.differences.reshape(self.differences.shape[0], height, channels, width)
        return np.ascontiguousarray(whole[:, :: self.probe_stride]).reshape(self.differences.shape[0], -1)

    def _probe_scale(self, excluded_blocks: int, excluded_probed: int) -> float | None:
        """Valid blocks ÷ probed valid blocks (1 without a stride), or None when no probed block is valid."""
        probed = self.difference_shape[0] * self.difference_shape[2] - excluded_probed
        if probed <= 0:
            return None
        return (self.block_shape[0] * self.block_shape[2] - excluded_blocks) / probed

    def statistics(
        self, spec: FrameStackSpec, chunk_pixels: int = DEFAULT_CHUNK_PIXELS, workers: int = 1
    ) -> SequenceStatistics:
        """The statistics of the rows added so far (every row must be in); ``spec`` as for the raw frames.

        ``workers`` threads share the moment product; the moments do not depend on it (the chunks' products are
        added in chunk order, :func:`processing.moment_products.gram_matrices`). The stream leaves it at 1 (a second
        thread is slower there: docs/speed.md).
        """
        rows = self.rows
        if len(self._filled) != rows.shape[0]:
            raise SpectralDataError(
                f"frame stack: {len(self._filled) - 1} of {rows.shape[0] - 1} frames added; expected all of them"
            )
        # Integer sums are always finite; for float frames one sum flags NaN/inf (exact check only then).
        if self._floating and not np.isfinite(rows.sum()) and not np.isfinite(rows).all():
            raise non_finite_frames_error(rows[:-1])
        weights = self._weights if self.weighting else None  # they enter each chunk's product
        black = spec.black_level * self.factor * self.factor  # block sums: the black level counts once per member
        transform = channel_transform(spec, black)
        if self.compiled:
            moments, noise, excluded_columns, scale, channel_moments = self._compiled_moments(weights, transform)
        else:
            moments, noise, excluded_columns, scale, column_factor = self._moments(weights, chunk_pixels, workers)
        if noise is not None:
            noise = None if scale is None else noise * scale
        # The spec's unmixing is reused as is.
        statistics = statistics_from_moments(
            moments,
            spec,
            rows.shape[1],
            black_level=black,
            noise_moments=noise,
            n_samples=rows.shape[1] - excluded_columns,
            weighted=weights is not None,
            transform=transform,
        )
        if not self.compiled:
            channel_moments = self._channel_moments(transform, column_factor, scale if noise is not None else None)
        return replace(statistics, channels=channel_moments)

    def _invalid_blocks(self) -> np.ndarray | None:
        """The (H/f, W/f) blocks left out (saturated in some frame, or excluded), or None when none is."""
        invalid = None
        for mask in self._invalid:
            invalid = mask if invalid is None else invalid | mask
        return invalid if invalid is not None and invalid.any() else None

    def _compiled_moments(
        self, weights: np.ndarray | None, transform: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None, int, float | None, ChannelMoments]:
        """:meth:`_moments` and :meth:`_channel_moments` in one compiled pass over the rows and one over the probe
        (:func:`processing.frame_kernels.block_statistics`): the same quantities, to rounding."""
        invalid = self._invalid_blocks()
        # The columns' factors: 1 where valid, 0 where left out (None: none is, and the kernel skips them).
        factors = None if invalid is None else (~self._columns(invalid)).astype(float)
        if weights is None:
            column_weights = np.ones(self.rows.shape[1]) if factors is None else factors
        else:
            column_weights = weights if factors is None else weights * factors
        moments, fa, ff, aa = frame_kernels.block_statistics(
            self.rows, column_weights, factors, transform, self.block_shape, 1
        )
        if factors is None:  # every block is in (the ones row is 1 everywhere)
            blocks = self.block_shape[0] * self.block_shape[2]
        else:
            blocks = int(np.count_nonzero(factors.reshape(self.block_shape).any(axis=1)))
        excluded = 0 if invalid is None else int(np.count_nonzero(invalid))
        excluded_probed = 0 if invalid is None else int(np.count_nonzero(invalid[:: self.probe_stride]))
        scale = self._probe_scale(excluded, excluded_probed)
        probe = self._probe()
        if probe is None:
            return moments, None, excluded * self.block_shape[1], scale, ChannelMoments(fa, ff, aa, blocks)
        noise, *channel_noise = frame_kernels.block_statistics(
            probe,
            self._at_probe(column_weights),
            None if factors is None else self._at_probe(factors),
            transform,
            self.difference_shape,
            1,
            zero_last=True,  # the ones row has no noise
        )
        if scale is None:
            channels = ChannelMoments(fa, ff, aa, blocks)
        else:
            channels = ChannelMoments(fa, ff, aa, blocks, *(part * scale for part in channel_noise))
        return moments, noise, excluded * self.block_shape[1], scale, channels

    def _moments(
        self, weights: np.ndarray | None, chunk_pixels: int, workers: int
    ) -> tuple[np.ndarray, np.ndarray | None, int, float | None, np.ndarray | None]:
        """The rows' and the probe's moments over the valid blocks (weighted by ``weights``, None: unweighted), the
        columns left out, the probe's scale, and each column's factor (0 where left out; None: none is)."""
        invalid = self._invalid_blocks()
        parts = [_masked_part(self.rows, None if invalid is None else self._columns(invalid), weights)]
        probe = self._probe()
        if probe is not None:
            probe_weights = None if weights is None else self._at_probe(weights)
            left_out = None if invalid is None else self._difference_columns(invalid)
            parts.append(_masked_part(probe, left_out, probe_weights))
        # The rows' and the probe's moments in one map: the probe's single chunk shares the threads.
        moments, *probed = gram_matrices(parts, chunk_pixels * self.block_shape[1], workers)
        if invalid is None:
            return moments, probed[0] if probed else None, 0, self._probe_scale(0, 0), None
        excluded_columns = int(np.count_nonzero(invalid)) * self.block_shape[1]
        scale = self._probe_scale(int(np.count_nonzero(invalid)), int(np.count_nonzero(invalid[:: self.probe_stride])))
        column_factor = (~self._columns(invalid)).astype(float)
        return moments, probed[0] if probed else None, excluded_columns, scale, column_factor

    def _channel_moments(
        self, transform: np.ndarray, column_factor: np.ndarray | None, probe_scale: float | None
    ) -> ChannelMoments:
        """:class:`ChannelMoments` of the rows, masked as :meth:`statistics` takes them (by ``column_factor``), the
        probe's scaled by ``probe_scale`` (None: none).

        Unweighted: a sample's inverse-variance weight differs from channel to channel, and weighing the channels of
        one block unequally would turn its colour away from the LED's (what :mod:`processing.flicker` reads).
        """
        ones = self.rows[-1] if column_factor is None else self.rows[-1] * column_factor
        blocks = int(np.count_nonzero(ones.reshape(self.block_shape).any(axis=1)))
        fa, ff, aa = _channel_products(transform, self.rows, self.block_shape, 1, column_factor)
        probe = self._probe()
        if probe is None or probe_scale is None:
            return ChannelMoments(fa, ff, aa, blocks)
        at_probe = None if column_factor is None else self._at_probe(column_factor)
        noise = _channel_products(transform, probe, self.difference_shape, 1, at_probe)
        return ChannelMoments(fa, ff, aa, blocks, *(part * probe_scale for part in noise))


def _masked_part(
    values: np.ndarray, columns: np.ndarray | None, column_weights: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """``(rows, weights)`` for :func:`processing.moment_products.gram_matrices` with the ``columns`` left out: weighted,
    they weigh 0 (no copy of the rows); unweighted, a copy of the rows with those columns zeroed."""
    if columns is None:
        return values, column_weights
    if column_weights is not None:
        return values, np.where(columns, 0.0, column_weights)
    values = values.copy()
    values[:, columns] = 0.0
    return values, None


def _channel_products(
    transform: np.ndarray,
    values: np.ndarray,
    layout: tuple[int, int, int],
    channel_axis: int,
    column_factor: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(fa, ff, aa)`` of :class:`ChannelMoments` from rows ``values`` whose columns are laid out ``layout`` (block
    rows first, the channels on ``channel_axis``): the rows mapped by ``transform`` (k + 1, n + 2) to the LEDs' and
    the ambient's images, each column scaled by ``column_factor`` (None: 1), summed band by band.

    A band of block rows at a time (the moments are sums over blocks): its images in channel order stay about a
    megabyte (:data:`CHANNEL_BAND_VALUES`) whatever the frame count, so an estimate's peak stays one frame plus the
    statistics. The map comes first, along the rows' own order (one product of the band's contiguous columns): the
    channel-order copy is then of the k + 1 images, not of the n + 2 rows.
    """
    height, inner = layout[0], layout[1] * layout[2]
    k, channels = transform.shape[0] - 1, layout[channel_axis]
    band = max(1, min(CHANNEL_BAND_VALUES // (k + 1), serial_columns(values.shape[0], k + 1)) // max(1, inner))
    # Two buffers for every band (fresh pages for each band's arrays cost more than the products).
    images_buffer = np.empty((k + 1, min(band, height) * inner))
    ordered_buffer = np.empty((k + 1, channels, min(band, height) * inner // channels))
    totals: list[np.ndarray] = []
    for top in range(0, height, band):
        tall = min(top + band, height) - top
        images = np.matmul(
            transform, values[:, top * inner : (top + tall) * inner], out=images_buffer[:, : tall * inner]
        )
        if column_factor is not None:
            images *= column_factor[top * inner : (top + tall) * inner]
        ordered = ordered_buffer[:, :, : tall * inner // channels]  # (k + 1, C, blocks): each LED's, the ambient's
        np.copyto(
            ordered.reshape(k + 1, channels, tall, inner // channels),
            np.moveaxis(images.reshape(k + 1, tall, layout[1], layout[2]), channel_axis + 1, 1),
        )
        leds, ambient = ordered[:k], ordered[k]
        moments = [leds @ ambient.T, leds @ leds.transpose(0, 2, 1), ambient @ ambient.T]
        totals = moments if not totals else [total + part for total, part in zip(totals, moments, strict=True)]
    return totals[0], totals[1], totals[2]
