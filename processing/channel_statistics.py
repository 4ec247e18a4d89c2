"""Channel-resolved block statistics of a flash sequence, for models that need more than eq. 5's sums.

:mod:`processing.statistics` sums every product over the camera channels: eq. 5 predicts each
channel of the ambient image by the *same* weighted sum of the LED-only images, so the channels
need not be told apart. A model that reads a surface from its colour — a reflectance recovered
from its k LED responses in C channels, then lit by a light outside the LEDs' span
(:mod:`processing.light_prior`) — needs, per block ``b``, the vector of all its LED-only responses
``f_b ∈ R^{C·k}`` (index ``c·k + i``: channel c, LED i) and its ambient response ``a_b ∈ R^C``, and
their second moments

    S_ff = Σ_b f_b f_bᵀ  (Ck × Ck),   S_fa = Σ_b f_b a_bᵀ  (Ck × C),   S_aa = Σ_b a_b a_bᵀ  (C × C)

over the unsaturated blocks. They are kept per *fold* — contiguous bands of block rows — so that
a model can be trained on all folds but one and judged on the pixels of the one left out
(:func:`processing.prior_choice.choose_model`); the totals are the sums over folds.

Frames are linearised as :mod:`processing.statistics` does (``(value − black) / (exposure · gain)``,
LED-only images unmixed by ``pinv(levels)``), binned in ``factor × factor`` blocks per CFA plane
(C = 4 planes for a Bayer mosaic, two of them green), and blocks with any saturated member in any
frame are dropped. With an even block size every block's half difference (even minus odd columns)
measures the noise (errors in variables; see :mod:`processing.statistics`): its moments, mapped
like the signal's, are :attr:`ChannelStatistics.noise`, which the models subtract.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from msflash.processing import family_kernels, frame_kernels
from msflash.processing.block_rows import BlockRows
from msflash.processing.block_sums import (
    block_sums,
    block_sums_and_differences,
    cfa_planes,
    plane_shape,
    saturated_blocks,
)
from msflash.processing.errors import SpectralDataError
from msflash.processing.moment_products import serial_columns
from msflash.processing.statistics import FrameStackSpec, NoiseMoments, SequenceStatistics

DEFAULT_FOLDS = 5
"""Bands of block rows kept apart for held-out prediction (:func:`processing.prior_choice.choose_model`)."""


@dataclass(frozen=True)
class Moments:
    """Second moments of (f, a) over a set of blocks, per fold: arrays with a leading fold axis."""

    ff: np.ndarray
    """``Σ f fᵀ``, shape (n_folds, C·k, C·k)."""
    fa: np.ndarray
    """``Σ f aᵀ``, shape (n_folds, C·k, C)."""
    aa: np.ndarray
    """``Σ a aᵀ``, shape (n_folds, C, C)."""

    def __sub__(self, other: Moments) -> Moments:
        return Moments(self.ff - other.ff, self.fa - other.fa, self.aa - other.aa)

    def total(self) -> Moments:
        """The moments of all folds together (a leading axis of length 1)."""
        return Moments(self.ff.sum(0, keepdims=True), self.fa.sum(0, keepdims=True), self.aa.sum(0, keepdims=True))

    def without(self, fold: int) -> Moments:
        """Every fold but ``fold``, summed (length-1 leading axis)."""
        keep = [j for j in range(self.ff.shape[0]) if j != fold]
        return Moments(
            self.ff[keep].sum(0, keepdims=True),
            self.fa[keep].sum(0, keepdims=True),
            self.aa[keep].sum(0, keepdims=True),
        )

    def fold(self, fold: int) -> Moments:
        """One fold alone (length-1 leading axis)."""
        return Moments(self.ff[fold : fold + 1], self.fa[fold : fold + 1], self.aa[fold : fold + 1])


@dataclass(frozen=True)
class ChannelStatistics:
    """Channel-resolved second moments of a sequence's LED-only and ambient block images (module notes)."""

    moments: Moments
    """Moments as observed, per fold."""
    noise: Moments | None
    """The noise's share of :attr:`moments` (half-difference probe), or None when not measured."""
    counts: np.ndarray
    """Valid blocks per fold, shape (n_folds,)."""
    led_sums: np.ndarray
    """``Σ f`` per fold, shape (n_folds, C·k)."""
    ambient_sums: np.ndarray
    """``Σ a`` per fold, shape (n_folds, C)."""
    n_blocks_total: int
    """Blocks in a frame, valid or not."""
    n_leds: int
    """k."""
    channels: tuple[str, ...]
    """What each of the C channels is: ``"R"``, ``"G"``, ``"B"`` (a Bayer mosaic's planes in CFA order)."""

    @property
    def n_channels(self) -> int:
        """C."""
        return len(self.channels)

    @property
    def n_folds(self) -> int:
        """Number of folds."""
        return int(self.counts.size)

    @property
    def n_blocks(self) -> int:
        """Valid blocks in all folds."""
        return int(self.counts.sum())

    def replicated(self, channels: tuple[str, ...]) -> ChannelStatistics:
        """One plane's statistics as ``len(channels)`` identical channels: a mono camera's frames, which format v1
        records as three alike channels, read as their one plane (every moment repeated in each pair of channels, f
        laid out ``c·k + i``; what the frames as recorded give, to rounding).

        Examples
        --------
        >>> one = Moments(np.ones((1, 2, 2)), np.ones((1, 2, 1)), np.ones((1, 1, 1)))
        >>> mono = ChannelStatistics(one, None, np.array([4]), np.ones((1, 2)), np.ones((1, 1)), 4, 2, ("Y",))
        >>> three = mono.replicated(("R", "G", "B"))
        >>> three.moments.ff.shape, three.moments.fa.shape, three.led_sums.shape, three.n_blocks
        ((1, 6, 6), (1, 6, 3), (1, 6), 4)
        """
        if self.n_channels != 1:
            raise SpectralDataError(f"replicated channel statistics: {self.n_channels} channels; expected one plane")
        copies = np.ones((len(channels), len(channels)))

        def spread(moments: Moments) -> Moments:
            return Moments(np.kron(copies, moments.ff), np.kron(copies, moments.fa), np.kron(copies, moments.aa))

        return ChannelStatistics(
            moments=spread(self.moments),
            noise=None if self.noise is None else spread(self.noise),
            counts=self.counts,
            led_sums=np.tile(self.led_sums, (1, len(channels))),
            ambient_sums=np.tile(self.ambient_sums, (1, len(channels))),
            n_blocks_total=self.n_blocks_total,
            n_leds=self.n_leds,
            channels=channels,
        )

    def led_statistics(self, folds: Sequence[int] | None = None) -> SequenceStatistics:
        """The channel-summed statistics of eq. 4–6 (:class:`~processing.statistics.SequenceStatistics`) of some folds.

        ``gram[i, j] = Σ_c S_ff[(c,i),(c,j)]``, ``cross[i] = Σ_c S_fa[(c,i), c]``, ``ambient_energy = tr S_aa``:
        what the LED-span estimator sees, with the noise moments mapped the same way.
        """
        chosen = list(range(self.n_folds)) if folds is None else list(folds)
        k, channels = self.n_leds, self.n_channels

        def summed(moments: Moments) -> tuple[np.ndarray, np.ndarray, float]:
            ff = moments.ff[chosen].sum(0).reshape(channels, k, channels, k)
            fa = moments.fa[chosen].sum(0).reshape(channels, k, channels)
            gram = np.einsum("cicj->ij", ff)
            cross = np.einsum("cic->i", fa)
            return gram, cross, float(np.trace(moments.aa[chosen].sum(0)))

        gram, cross, energy = summed(self.moments)
        noise = None
        if self.noise is not None:
            noise = NoiseMoments(*summed(self.noise))
        n = int(self.counts[chosen].sum())
        return SequenceStatistics(
            gram=gram,
            cross=cross,
            ambient_energy=energy,
            n_samples=n * channels,
            n_total=self.n_blocks_total * channels,
            ambient_sum=float(self.ambient_sums[chosen].sum()),
            led_sums=self.led_sums[chosen].sum(0).reshape(channels, k).sum(0),
            noise=noise,
        )


def plane_channels(cfa: str | None, n_channels: int = 3) -> tuple[str, ...]:
    """The channel of each plane: ``("R", "G", "B")`` for RGB frames, the CFA letters (e.g. ``RGGB``) for a mosaic.

    Examples
    --------
    >>> plane_channels("BGGR"), plane_channels(None)
    (('B', 'G', 'G', 'R'), ('R', 'G', 'B'))
    """
    if cfa is None:
        if n_channels != 3:
            raise SpectralDataError(f"channel statistics: {n_channels} channels without a CFA; expected RGB frames")
        return ("R", "G", "B")
    letters = tuple(cfa.upper())
    if len(letters) != 4 or any(letter not in "RGB" for letter in letters):
        raise SpectralDataError(f"channel statistics: CFA '{cfa}'; expected four letters of R, G, B such as RGGB")
    return letters


def accumulate_channel_statistics(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    spec: FrameStackSpec,
    *,
    cfa: str | None = None,
    bin_factor: int = 4,
    n_folds: int = DEFAULT_FOLDS,
) -> ChannelStatistics:
    """Channel-resolved block moments of a raw frame stack (module notes).

    Parameters
    ----------
    ambient
        Raw ambient frame, (H, W, 3) RGB or (H, W) Bayer mosaic (``cfa`` set).
    led_frames
        Raw frames ambient + LEDs, each like ``ambient``; frame j lights the LEDs at ``spec.led_levels[j]``.
    spec
        Black/white levels, exposure·gain scales, LED levels (as for :mod:`processing.statistics`).
    cfa
        The mosaic's 2×2 pattern (``"RGGB"``…), or None for RGB frames.
    bin_factor
        Block size per plane (4, like ``msflash estimate``); even sizes measure the noise too.
    n_folds
        Bands of block rows kept apart (at least 2).

    Returns
    -------
    ChannelStatistics
        With f laid out ``c·k + i`` and the LEDs at full drive: ``f = pinv(L) · (s_j (F_j − b) − s_a (A − b))``.

    Raises
    ------
    SpectralDataError
        Frames of different shapes, the wrong number of LED frames, non-finite values, too few blocks.
    """
    frames, period = _checked_frames(ambient, led_frames, spec, cfa, bin_factor, n_folds)
    shape = plane_shape(frames[0].shape, period)
    channels = plane_channels(cfa, shape[2])
    blocks = _BlockLayout(shape[0] // bin_factor, shape[1] // bin_factor, shape[2])
    if blocks.height < n_folds or blocks.width < 1:
        raise SpectralDataError(
            f"channel statistics: {blocks.height}×{blocks.width} blocks of {bin_factor}×{bin_factor}; expected at "
            f"least {n_folds} rows of blocks (a larger frame or smaller blocks)"
        )
    raw, probes = _stacked_block_rows(frames, period, bin_factor, spec.white_level, blocks)
    return _statistics_of_products(
        *_fold_products(raw, probes, n_folds, blocks), spec, bin_factor, n_folds, blocks, channels
    )


def channel_statistics_of_block_rows(
    rows: BlockRows, spec: FrameStackSpec, *, cfa: str | None = None, n_folds: int = DEFAULT_FOLDS
) -> ChannelStatistics | None:
    """:func:`accumulate_channel_statistics` of the frames already block-summed into ``rows`` (every frame in), with
    their block size: the same numbers to the bit for integer frames (the block sums are the same exact integers, in
    the same order, :meth:`processing.block_rows.BlockRows.channel_rows`), without a second pass over the frames.

    One plane without a CFA is a mono camera's: its statistics are :meth:`ChannelStatistics.replicated` to the three
    alike channels its sequence records (the frames' own pass on them gives the same, to rounding). None where the
    rows cannot give them — a strided probe (large frames; ``BlockRows(full_probe=True)`` keeps it whole), a missing
    frame, fewer block rows than folds, planes that are not ``cfa``'s.
    """
    height, n_planes, width = rows.block_shape
    if n_folds < 2 or height < n_folds or len(spec.led_levels) != rows.n_led_frames:
        return None
    mono = cfa is None and n_planes == 1
    try:
        channels = ("Y",) if mono else plane_channels(cfa, n_planes)
    except SpectralDataError:
        return None
    if len(channels) != n_planes:
        return None
    blocks = _BlockLayout(height, width, n_planes)
    products = _compiled_fold_products(rows, n_folds, blocks)
    if products is None:
        stacked = rows.channel_rows()
        if stacked is None:
            return None
        products = _fold_products(*stacked, n_folds, blocks)
    statistics = _statistics_of_products(*products, spec, rows.factor, n_folds, blocks, channels)
    return statistics.replicated(plane_channels(None)) if mono else statistics


def _compiled_fold_products(
    rows: BlockRows, n_folds: int, blocks: _BlockLayout
) -> tuple[np.ndarray, np.ndarray | None] | None:
    """Each fold's Gram matrix of the rows and of the probe, as :func:`_fold_products` takes them from
    :meth:`~processing.block_rows.BlockRows.channel_rows`, by the compiled kernel from the rows as stored
    (:func:`processing.family_kernels_numba.fold_grams`: no transposing copy, 4 × 4 tiles): the same numbers to the
    bit, since it answers only where every sum is exact (block sums of integer frames). None where the compiled fits
    are not in use (:func:`processing.family_kernels.kernels`), the rows cannot give them or a sum would not be
    exact: then the copy and the BLAS products. Not tried where the white level allows block sums whose squares
    over a fold could exceed the bound (16-bit frames at 1280×1024: the kernel would only find them inexact)."""
    compiled = family_kernels.kernels()
    largest = rows.factor * rows.factor * float(rows.white_level)
    blocks_a_fold = -(-blocks.height // n_folds) * blocks.width
    if compiled is None or blocks_a_fold * largest * largest > compiled.EXACT_SUMS:
        return None
    stored = rows.stored_rows()
    if stored is None:
        return None
    values, differences, saturated = stored
    features = rows.n_led_frames + 1
    bounds = ((np.arange(n_folds + 1) * blocks.height + n_folds - 1) // n_folds).astype(np.int64)

    def grams(array: np.ndarray, last: float) -> np.ndarray | None:
        taken, exact = compiled.fold_grams(array, features, blocks.channels, blocks.width, last, saturated, bounds)
        return taken if exact else None

    products = grams(values, 1.0)
    noise = None if differences is None else grams(differences, 0.0)
    if products is None or (differences is not None and noise is None):
        return None
    return products, noise


def _checked_frames(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    spec: FrameStackSpec,
    cfa: str | None,
    bin_factor: int,
    n_folds: int,
) -> tuple[list[np.ndarray], int]:
    """The frames ``[A, F_1 … F_n]`` and the CFA period, or the error naming what does not fit."""
    frames = [np.asarray(ambient), *[np.asarray(f) for f in led_frames]]
    if len(led_frames) != spec.led_levels.shape[0]:
        raise SpectralDataError(
            f"channel statistics: {len(led_frames)} LED frames but levels for "
            f"{spec.led_levels.shape[0]}; expected one row of levels per LED frame"
        )
    if bin_factor < 1 or n_folds < 2:
        raise SpectralDataError(f"channel statistics: bin_factor {bin_factor}, n_folds {n_folds}; expected ≥ 1 and ≥ 2")
    for index, frame in enumerate(frames):
        if frame.shape != frames[0].shape:
            raise SpectralDataError(
                f"channel statistics: frame {index} has shape {frame.shape} but the ambient frame "
                f"{frames[0].shape}; expected frames of one size"
            )
        if np.issubdtype(frame.dtype, np.floating) and not np.isfinite(frame.sum()):
            raise SpectralDataError(
                f"channel statistics: frame {index} holds non-finite values; expected finite pixels"
            )
    if cfa is not None and frames[0].ndim != 2:
        raise SpectralDataError(
            f"channel statistics: CFA '{cfa}' but frames of shape {frames[0].shape}; expected (H, W)"
        )
    return frames, 2 if cfa is not None else 1


@dataclass(frozen=True)
class _BlockLayout:
    """Blocks per frame: ``height`` rows of ``width`` blocks, each ``channels`` values (the CFA planes)."""

    height: int
    width: int
    channels: int


def _stacked_block_rows(
    frames: list[np.ndarray], period: int, factor: int, white: float, blocks: _BlockLayout
) -> tuple[np.ndarray, np.ndarray | None]:
    """Raw block sums of every frame stacked, ``[F_1 … F_n, A] × channels``, then a row of ones; the probe's
    half differences alike (even ``factor``), or None. Blocks saturated in any frame are zeroed in every row.

    Every moment of the linearised, differenced and unmixed responses is a linear map of these rows' moments
    (as in :mod:`processing.statistics`), so the pixels see no arithmetic beyond the block sums. Features ×
    blocks, row-major: each frame's channels are written as whole rows and a fold is a band of columns.
    """
    channels, n_blocks = blocks.channels, blocks.height * blocks.width
    raw = np.empty((len(frames) * channels + 1, n_blocks))
    raw[-1] = 1.0
    probes = np.empty_like(raw) if factor % 2 == 0 else None
    if probes is not None:
        probes[-1] = 0.0
    invalid = np.zeros((blocks.height, blocks.width), dtype=bool)
    # The compiled one-pass kernel where this process has it loaded (the same integers as the numpy route).
    fast = frame_kernels.wanted(sum(frame.nbytes for frame in frames))
    for column, index in enumerate([*range(1, len(frames)), 0]):  # LED frames first, the ambient frame last
        band = slice(column * channels, (column + 1) * channels)
        rows = raw[band].reshape(channels, blocks.height, blocks.width)
        probe_rows = None if probes is None else probes[band].reshape(channels, blocks.height, blocks.width)
        done, saturated = (
            _compiled_block_sums(frames[index], period, factor, white, rows, probe_rows) if fast else (False, None)
        )
        if not done:
            saturated = _numpy_block_sums(cfa_planes(frames[index], period), factor, white, rows, probe_rows)
        if saturated is not None:
            invalid |= saturated
    if invalid.any():
        raw[:, invalid.reshape(-1)] = 0.0  # out of every moment, the count included
        if probes is not None:
            probes[:, invalid.reshape(-1)] = 0.0
    return raw, probes


def _compiled_block_sums(
    frame: np.ndarray, period: int, factor: int, white: float, rows: np.ndarray, probe_rows: np.ndarray | None
) -> tuple[bool, np.ndarray | None]:
    """One raw frame's block sums into ``rows`` (C, h, w) and half differences into ``probe_rows``, in one compiled
    pass (:func:`processing.frame_kernels.block_pass`, no CFA-plane copy), written in place through transposed
    views (no temporary, no transposing copy): ``(done, saturated)`` as that returns."""
    differences = None if probe_rows is None else probe_rows.transpose(1, 2, 0)
    return frame_kernels.block_pass(frame, factor, period, white, 1, rows.transpose(1, 0, 2), differences)


def _numpy_block_sums(
    plane: np.ndarray, factor: int, white: float, rows: np.ndarray, probe_rows: np.ndarray | None
) -> np.ndarray | None:
    """:func:`_compiled_block_sums` of an (H, W, C) plane in numpy (the same integers)."""
    if probe_rows is not None:
        block, half = block_sums_and_differences(plane, factor)
        probe_rows[...] = half.transpose(2, 0, 1)
    else:
        block = block_sums(plane, factor)
    rows[...] = block.transpose(2, 0, 1)
    if np.issubdtype(plane.dtype, np.floating) or np.iinfo(plane.dtype).max >= white:
        if plane.max() >= white:
            return saturated_blocks(plane, factor, white)
    return None


def _fold_products(
    raw: np.ndarray, probes: np.ndarray | None, n_folds: int, blocks: _BlockLayout
) -> tuple[np.ndarray, np.ndarray | None]:
    """Each fold's Gram matrix of stacked block rows (:func:`_stacked_block_rows`) and of their probe."""
    # Folds are bands of block rows: contiguous slices of the row-major blocks.
    bounds = ((np.arange(n_folds + 1) * blocks.height + n_folds - 1) // n_folds) * blocks.width

    def products_of(rows: np.ndarray) -> np.ndarray:
        return np.stack([_gram(rows[:, bounds[j] : bounds[j + 1]]) for j in range(n_folds)])

    return products_of(raw), None if probes is None else products_of(probes)


def _statistics_of_products(
    products: np.ndarray,
    noise_products: np.ndarray | None,
    spec: FrameStackSpec,
    factor: int,
    n_folds: int,
    blocks: _BlockLayout,
    channels: tuple[str, ...],
) -> ChannelStatistics:
    """:class:`ChannelStatistics` of each fold's Gram matrix of the stacked block rows and of their probe
    (:func:`_fold_products`)."""
    transform = _response_transform(spec, blocks.channels, spec.black_level * factor * factor)
    width_f = spec.n_leds * blocks.channels

    def moments_of(products: np.ndarray) -> Moments:
        mapped = transform @ products @ transform.T
        return Moments(mapped[:, :width_f, :width_f], mapped[:, :width_f, width_f:], mapped[:, width_f:, width_f:])

    moments = moments_of(products)
    sums = products[:, :, -1] @ transform.T  # (folds, Ck + C): Σ f, Σ a
    return ChannelStatistics(
        moments=moments,
        noise=None if noise_products is None else moments_of(noise_products),
        counts=np.rint(products[:, -1, -1]).astype(int),
        led_sums=sums[:, :width_f],
        ambient_sums=sums[:, width_f:],
        n_blocks_total=blocks.height * blocks.width,
        n_leds=spec.n_leds,
        channels=channels,
    )


def _response_transform(spec: FrameStackSpec, channels: int, black: float) -> np.ndarray:
    """(C·k + C, n·C + C + 1) map from raw block sums ``[F_1 … F_n, A] × C, 1`` to ``[f (c·k + i), a (c)]``.

    ``d_j = s_j (F_j − b) − s_a (A − b)``, ``f_i = Σ_j U_ij d_j`` (U = pinv(levels)), ``a = s_a (A − b)``.
    """
    unmixing, scales = spec.unmixing, np.asarray(spec.led_scales, dtype=float)
    k, n = unmixing.shape
    transform = np.zeros((channels * k + channels, n * channels + channels + 1))
    for c in range(channels):
        rows = slice(c * k, (c + 1) * k)
        transform[rows, [j * channels + c for j in range(n)]] = unmixing * scales
        transform[rows, n * channels + c] = -spec.ambient_scale * unmixing.sum(axis=1)
        transform[rows, -1] = unmixing @ ((spec.ambient_scale - scales) * black)
        transform[channels * k + c, n * channels + c] = spec.ambient_scale
        transform[channels * k + c, -1] = -spec.ambient_scale * black
    return transform


def _gram(values: np.ndarray) -> np.ndarray:
    """``values valuesᵀ`` of (features, blocks) values, summed over slices of blocks small enough for one BLAS
    thread (:func:`processing.moment_products.serial_columns`: 240 blocks for the 33 rows of 8 raw frames)."""
    product = np.zeros((values.shape[0], values.shape[0]))
    columns = serial_columns(values.shape[0], values.shape[0])
    for start in range(0, values.shape[1], columns):
        part = values[:, start : start + columns]
        product += part @ part.T
    return product
