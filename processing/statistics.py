"""Sufficient statistics of a flash sequence, accumulated in one pass over the pixels.

Ambient estimation (eq. 4–6) needs only the k×k Gram matrix of the LED-only images, their
k products with the ambient image, the ambient image's squared norm and the sample count
(docs/architecture.md §8). They are accumulated chunk by chunk straight from the raw frames: each chunk is
linearised (``(value − black_level) / (exposure_us · gain)``), saturated pixels are masked, the
LED frames are differenced against the ambient frame and the products are added up. No full-size
float copy of the stack ever exists.

Frames need not light one LED each: any LED frame may drive several LEDs at any levels (a
multiplexed sequence). With ``L`` the (n_led_frames, k) matrix of levels, the per-LED images at
full drive are ``pinv(L) · (frames − ambient)``, applied to the statistics after accumulation.

Noise (errors in variables)
---------------------------
The LED-only images are differences of noisy frames, so their Gram matrix carries the noise
variance of every frame and their products with the ambient image lose the ambient frame's
(eq. 5 regresses on noisy regressors: the weights shrink towards zero, most for the LEDs the
camera sees least). Binned statistics with an even block size also measure that noise, from
every block's *half difference* (its samples at even ``row + column`` minus those at odd, a
checkerboard, :func:`block_sums_and_differences`): the two halves see the same surfaces and have
independent noise, so with ``x`` a block's row of sums and ``d`` its half difference,
``x xᵀ − d dᵀ = 2 (x₁ x₂ᵀ + x₂ x₁ᵀ)`` is a product of independent halves — moments without the noise
bias, whatever the texture inside a block (an instrumental-variable estimate; no noise model needed).
Texture the halves do not share still enters ``d``: it leaves the moments unbiased where eq. 5 holds
but makes them noisier, and it changes which fit is best where eq. 5 does not. The checkerboard cancels
edges along the rows or the columns and ramps; the even and odd *columns* it replaced did not cancel
edges along the columns, which on a mosaic (one CFA plane's samples 2 pixels apart) put scene texture
in 85 % of the simulated chart's probes (docs/raw-frames.md). :attr:`SequenceStatistics.noise` holds
``d dᵀ`` mapped like the moments, :meth:`SequenceStatistics.denoised` the corrected statistics.

Inverse-variance weights
------------------------
Unweighted moments count every sample alike, so the brightest samples — a specular highlight
at ten times the white, say — dominate the Gram matrix though their photon noise is the largest.
With ``weighting=True`` (:class:`BlockRows`, :func:`accumulate_statistics`) each sample (block ×
channel) enters the moments with weight ``1 / var``, its noise variance predicted from the ambient
frame: ``var = gain · level + read`` (a photon-transfer line fitted to the fine-scale detail of the
ambient frame's 2 × 2 cells, :mod:`processing.noise_level`, then scaled to block sums,
:func:`block_noise_line`). It used to be fitted to the half differences against the block sums: on a
mosaic, texture filled them and the weights came out up to 20× off either way. The weights depend on the
ambient frame alone, so a capture can apply them to every LED frame as it arrives; the half
differences are weighted alike, so the noise correction still holds. Weighted least squares is the
best linear unbiased estimate of eq. 5 when the residual's noise is that of the ambient frame; the
weights are normalised to mean 1 over all samples, and :attr:`SequenceStatistics.n_samples` stays the
count of valid samples.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from functools import cached_property, lru_cache

import numpy as np

from msflash.processing import frame_kernels
from msflash.processing.errors import SpectralDataError
from msflash.processing.noise_level import PixelNoise, detail_noise_line

DEFAULT_CHUNK_PIXELS = 1 << 15
"""Pixels per chunk: small enough to stay in cache for k ≈ 8 frames, large enough to amortise numpy calls."""

DEFAULT_WORKERS = 2 if (os.cpu_count() or 1) >= 2 else 1
"""Threads for the image passes (block sums, moments, synthesis): the app runs on 2 cores."""

GATHER_ROWS = 2048
"""Rows per BLAS call in :func:`block_sums`: below OpenBLAS's threading threshold for this thin product."""
PROBE_BLOCKS = 16384
"""Blocks the noise probe needs at least (:class:`BlockRows`): frames with several times more use
every ``stride``-th block row only, ``stride = min(4, blocks // PROBE_BLOCKS)``. Its moments are then
scaled by valid blocks ÷ probed valid blocks; with ≥ 16 384 probed blocks their sampling error is
below 1.1 % of the noise's share (√(2/n)), while a full probe of a large stack costs markedly more
estimation time (docs/architecture.md §10)."""
PRODUCT_COLUMNS = 4096
"""Columns per slice of the incremental moments' matrix–vector products (:func:`_row_products`):
one thread each (OpenBLAS threads a product only above about 10⁵ elements)."""
ROW_SUM_BAND_BYTES = 1 << 18
"""Raw bytes per band of the block rows' sums (:func:`_block_row_sums_and_peak`): a band stays in a core's
cache for its saturation max."""


@dataclass(frozen=True)
class FrameStackSpec:
    """How to linearise the frames of one sequence."""

    black_level: float
    """Raw value of no light."""
    white_level: float
    """Raw value at or above which a pixel is saturated."""
    ambient_scale: float
    """``1 / (exposure_us · gain)`` of the ambient frame."""
    led_scales: tuple[float, ...]
    """``1 / (exposure_us · gain)`` of each LED frame."""
    led_levels: np.ndarray
    """Drive levels, shape (n_led_frames, k): frame j lights LED i at ``led_levels[j, i]``."""

    def __post_init__(self) -> None:
        levels = np.array(self.led_levels, dtype=float, copy=True)
        if levels.ndim != 2 or levels.shape[0] != len(self.led_scales):
            raise SpectralDataError(
                f"frame stack: led_levels has shape {levels.shape}; expected ({len(self.led_scales)}, n_leds)"
            )
        if not self.white_level > self.black_level:
            raise SpectralDataError(
                f"frame stack: white_level {self.white_level} is not above black_level {self.black_level}"
            )
        if not _is_invertible_diagonal(levels) and np.linalg.matrix_rank(levels) < levels.shape[1]:
            raise SpectralDataError(
                "frame stack: the LED levels of the frames do not separate every LED "
                f"(rank {np.linalg.matrix_rank(levels)} < {levels.shape[1]} LEDs); expected each LED "
                "lit in some frame independently of the others"
            )
        levels.flags.writeable = False
        object.__setattr__(self, "led_levels", levels)

    @property
    def n_leds(self) -> int:
        """Number of LEDs k."""
        return self.led_levels.shape[1]

    @cached_property
    def unmixing(self) -> np.ndarray:
        """pinv(L), shape (k, n_led_frames): LED-only images at full drive from frame differences (computed once)."""
        levels = self.led_levels
        # One LED per frame (the usual plan): pinv of a diagonal is exactly its reciprocal — what
        # the SVD gives too, without its cost on the capture's latency path.
        unmixing = np.diag(1.0 / np.diag(levels)) if _is_invertible_diagonal(levels) else np.linalg.pinv(levels)
        unmixing.flags.writeable = False
        return unmixing


def _is_invertible_diagonal(levels: np.ndarray) -> bool:
    """Whether the levels are square, diagonal and without a zero on the diagonal."""
    if levels.shape[0] != levels.shape[1]:
        return False
    diagonal = np.diag(levels)
    return bool(np.count_nonzero(levels) == np.count_nonzero(diagonal) == levels.shape[0]) and bool(
        np.isfinite(diagonal).all()
    )


@dataclass(frozen=True)
class NoiseMoments:
    """The noise's share of a :class:`SequenceStatistics`' moments, measured by the half-difference probe."""

    gram: np.ndarray
    """Noise part of :attr:`SequenceStatistics.gram`, shape (k, k)."""
    cross: np.ndarray
    """Noise part of :attr:`SequenceStatistics.cross`, shape (k,) (the ambient frame's noise, negated)."""
    ambient_energy: float
    """Noise part of :attr:`SequenceStatistics.ambient_energy`."""

    def __add__(self, other: NoiseMoments) -> NoiseMoments:
        """The noise of the union of two disjoint sets of samples."""
        return NoiseMoments(
            self.gram + other.gram, self.cross + other.cross, self.ambient_energy + other.ambient_energy
        )


CHANNEL_BAND_VALUES = 1 << 17
"""How many values (all rows together) :meth:`BlockRows._channel_moments` puts in channel order at a time."""


@dataclass(frozen=True)
class ChannelMoments:
    """Per-channel second moments of each LED-only block image with the ambient's (what a per-frame ambient gain
    is read from, :mod:`processing.flicker`), over the same blocks, weights and noise probe as the statistics.

    With ``f_i,b ∈ R^C`` block b's LED-only response to LED i at full drive (channel by channel: RGB, or a
    mosaic's CFA planes in CFA order) and ``a_b ∈ R^C`` its ambient response: ``fa[i] = Σ_b f_i,b a_bᵀ``,
    ``ff[i] = Σ_b f_i,b f_i,bᵀ``, ``aa = Σ_b a_b a_bᵀ``. The ``noise_*`` are the half-difference probe's share
    of each (None when it was not measured).
    """

    fa: np.ndarray
    """(k, C, C)."""
    ff: np.ndarray
    """(k, C, C)."""
    aa: np.ndarray
    """(C, C)."""
    n_blocks: int
    """Valid blocks summed."""
    noise_fa: np.ndarray | None = None
    noise_ff: np.ndarray | None = None
    noise_aa: np.ndarray | None = None

    @property
    def n_channels(self) -> int:
        """C."""
        return int(self.aa.shape[0])

    def denoised(self) -> ChannelMoments:
        """The moments less the noise's share (as they are when the noise was not measured)."""
        if self.noise_fa is None or self.noise_ff is None or self.noise_aa is None:
            return self
        return ChannelMoments(self.fa - self.noise_fa, self.ff - self.noise_ff, self.aa - self.noise_aa, self.n_blocks)

    def __add__(self, other: ChannelMoments) -> ChannelMoments:
        """The moments of the union of two disjoint sets of blocks."""

        def both(mine: np.ndarray | None, theirs: np.ndarray | None) -> np.ndarray | None:
            return None if mine is None or theirs is None else mine + theirs

        return ChannelMoments(
            self.fa + other.fa,
            self.ff + other.ff,
            self.aa + other.aa,
            self.n_blocks + other.n_blocks,
            both(self.noise_fa, other.noise_fa),
            both(self.noise_ff, other.noise_ff),
            both(self.noise_aa, other.noise_aa),
        )


@dataclass(frozen=True)
class SequenceStatistics:
    """Sufficient statistics for ambient estimation (eq. 4–6) over the unsaturated samples.

    With ``a`` the linear ambient image and ``f_i`` the LED-only image of LED i at full drive,
    both flattened over the valid samples: ``gram[i, j] = f_i · f_j``, ``cross[i] = f_i · a``,
    ``ambient_energy = a · a``.
    """

    gram: np.ndarray
    """LED-only Gram matrix, shape (k, k)."""
    cross: np.ndarray
    """Products of the LED-only images with the ambient image, shape (k,)."""
    ambient_energy: float
    """Squared norm of the ambient image."""
    n_samples: int
    """Number of valid (unsaturated) samples summed."""
    n_total: int
    """Number of samples in a frame (valid or not)."""
    ambient_sum: float
    """Sum of the ambient image (mean level = ambient_sum / n_samples)."""
    led_sums: np.ndarray
    """Sum of each LED-only image, shape (k,)."""
    noise: NoiseMoments | None = None
    """The noise's share of ``gram``, ``cross`` and ``ambient_energy`` (binned statistics with an even
    block size; see the module notes), or None when it was not measured."""
    weighted: bool = False
    """Whether the samples carry inverse-variance weights (module notes): the moments and sums are then
    weighted ones, normalised to mean weight 1 over all samples."""
    channels: ChannelMoments | None = None
    """The same blocks' moments channel by channel (binned statistics: :class:`BlockRows`), or None; kept by
    :meth:`denoised` and ``+``, dropped by the other derivations."""

    @property
    def n_leds(self) -> int:
        """Number of LEDs k."""
        return self.cross.size

    @property
    def saturated_fraction(self) -> float:
        """Fraction of samples excluded because some frame saturated there."""
        return 1.0 - self.n_samples / self.n_total if self.n_total else 0.0

    def denoised(self) -> SequenceStatistics | None:
        """The statistics with the noise's share of the moments removed (no noise bias in eq. 5), or None
        when the noise was not measured. Sums and counts are unchanged; the result has no :attr:`noise`.

        Examples
        --------
        >>> noisy = SequenceStatistics(np.eye(2) * 3, np.ones(2), 4.0, 10, 10, 5.0, np.ones(2),
        ...                            NoiseMoments(np.eye(2), -np.ones(2), 1.0))
        >>> clean = noisy.denoised()
        >>> clean.gram.diagonal().tolist(), clean.cross.tolist(), clean.ambient_energy, clean.noise
        ([2.0, 2.0], [2.0, 2.0], 3.0, None)
        """
        noise = self.noise
        if noise is None:
            return None
        return SequenceStatistics(
            gram=self.gram - noise.gram,
            cross=self.cross - noise.cross,
            ambient_energy=self.ambient_energy - noise.ambient_energy,
            n_samples=self.n_samples,
            n_total=self.n_total,
            ambient_sum=self.ambient_sum,
            led_sums=self.led_sums,
            weighted=self.weighted,
            channels=self.channels,
        )

    def residual_energy(self, weights: np.ndarray) -> float:
        """``‖a − Σ wᵢ fᵢ‖²`` for ambient weights ``w``, from the statistics alone (clipped at 0: denoised
        statistics can put it below, by the noise's sampling error)."""
        return float(max(self.ambient_energy + self.fit_energy(weights), 0.0))

    def fit_energy(self, weights: np.ndarray) -> float:
        """``wᵀ G w − 2 cᵀ w``: the part of :meth:`residual_energy` that depends on the weights, unclipped.

        Differences of residuals between two weight vectors are differences of this: the ambient's own
        energy (and the noise correction of it) cancels, so they hold even where the residual of
        denoised statistics reads 0.

        Examples
        --------
        >>> stats = SequenceStatistics(np.eye(2), np.array([1.0, 0.5]), 0.5, 10, 10, 5.0, np.ones(2))
        >>> stats.fit_energy(np.array([1.0, 0.5])), stats.residual_energy(np.array([1.0, 0.5]))
        (-1.25, 0.0)
        """
        w = np.asarray(weights, dtype=float)
        return float(w @ self.gram @ w - 2.0 * self.cross @ w)

    def replicated(self, copies: int) -> SequenceStatistics:
        """The statistics of ``copies`` identical copies of these samples: every sum times ``copies``.

        A mono frame recorded as three identical channels (format v1 stores RGB or mosaics) has
        the statistics of its one plane, replicated 3 times: taking them from the plane reads a
        third of the data for the same result.

        Examples
        --------
        >>> one = SequenceStatistics(np.eye(2), np.ones(2), 4.0, 10, 12, 5.0, np.ones(2))
        >>> three = one.replicated(3)
        >>> float(three.gram[0, 0]), three.ambient_energy, three.n_samples, three.saturated_fraction == one.saturated_fraction
        (3.0, 12.0, 30, True)
        """
        if copies < 1:
            raise SpectralDataError(f"replicated statistics: {copies} copies; expected at least 1")
        return SequenceStatistics(
            gram=self.gram * copies,
            cross=self.cross * copies,
            ambient_energy=self.ambient_energy * copies,
            n_samples=self.n_samples * copies,
            n_total=self.n_total * copies,
            ambient_sum=self.ambient_sum * copies,
            led_sums=self.led_sums * copies,
            noise=None
            if self.noise is None
            else NoiseMoments(self.noise.gram * copies, self.noise.cross * copies, self.noise.ambient_energy * copies),
            weighted=self.weighted,
        )

    def select_leds(self, which: Sequence[int]) -> SequenceStatistics:
        """Statistics restricted to a subset of the LEDs (for leave-one-out and LED-count studies)."""
        idx = np.asarray(which, dtype=int)
        return SequenceStatistics(
            gram=self.gram[np.ix_(idx, idx)],
            cross=self.cross[idx],
            ambient_energy=self.ambient_energy,
            n_samples=self.n_samples,
            n_total=self.n_total,
            ambient_sum=self.ambient_sum,
            led_sums=self.led_sums[idx],
            noise=None
            if self.noise is None
            else NoiseMoments(self.noise.gram[np.ix_(idx, idx)], self.noise.cross[idx], self.noise.ambient_energy),
            weighted=self.weighted,
        )

    def permuted(self, order: Sequence[int]) -> SequenceStatistics:
        """The same statistics with the LEDs in another order."""
        return self.select_leds(order)

    def __add__(self, other: SequenceStatistics) -> SequenceStatistics:
        """Statistics of the union of two disjoint sets of samples (for tiles, chunks, workers)."""
        return SequenceStatistics(
            gram=self.gram + other.gram,
            cross=self.cross + other.cross,
            ambient_energy=self.ambient_energy + other.ambient_energy,
            n_samples=self.n_samples + other.n_samples,
            n_total=self.n_total + other.n_total,
            ambient_sum=self.ambient_sum + other.ambient_sum,
            led_sums=self.led_sums + other.led_sums,
            noise=None if self.noise is None or other.noise is None else self.noise + other.noise,
            weighted=self.weighted and other.weighted,
            channels=None if self.channels is None or other.channels is None else self.channels + other.channels,
        )


def _as_samples(frame: np.ndarray, where: str) -> np.ndarray:
    """View a frame as (n_pixels, n_channels) without copying."""
    if frame.ndim == 2:
        return frame.reshape(-1, 1)
    if frame.ndim == 3:
        return frame.reshape(-1, frame.shape[2])
    raise SpectralDataError(f"{where}: frame has shape {frame.shape}; expected (H, W) or (H, W, C)")


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


def non_finite_frames_error(rows: Sequence[np.ndarray] | np.ndarray, where: str = "frame stack") -> SpectralDataError:
    """The error for frame rows ``[F_1 … F_n, A]`` (the statistics' layout) of which some hold NaN or inf.

    Names the frames (the ambient frame, LED frame k counted from 1 in sequence order) after
    ``where``; searched only once a cheap check has failed.
    """
    bad = [row for row in range(len(rows)) if not np.isfinite(rows[row]).all()]
    return _non_finite_error([_frame_name(row, len(rows) - 1) for row in bad], where)


def _frame_name(row: int, n_led_frames: int) -> str:
    """Row ``row`` of ``[F_1 … F_n, A]`` in words: ``LED frame k`` (from 1) or ``the ambient frame``."""
    return "the ambient frame" if row == n_led_frames else f"LED frame {row + 1}"


def _non_finite_error(names: list[str], where: str = "frame stack") -> SpectralDataError:
    return SpectralDataError(
        f"{where}: {', '.join(names) or 'a frame'} holds non-finite values (NaN or inf); expected finite pixels"
    )


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
    numba is installed; numpy takes the same steps otherwise, and both routes give the same statistics
    to the bit (the block sums and the all-pixel moments are exact integers; the weighted moments of
    the block sums are taken by numpy on either route).
    """
    if bin_factor < 1 or cfa_period not in (1, 2):
        raise SpectralDataError(
            f"statistics: bin_factor {bin_factor}, cfa_period {cfa_period}; expected ≥ 1 and 1 or 2"
        )
    frame_kernels.wanted(ambient.nbytes * (len(led_frames) + 1))  # loads the kernels for large stacks
    if bin_factor > 1:
        return _accumulate_binned(
            ambient, led_frames, spec, sample_mask, chunk_pixels, bin_factor, cfa_period, workers, weighting
        )
    frames = [ambient, *led_frames]
    if len(led_frames) != spec.led_levels.shape[0]:
        raise SpectralDataError(f"frame stack: {len(led_frames)} LED frames but levels for {spec.led_levels.shape[0]}")
    shape = ambient.shape
    for index, frame in enumerate(frames):
        if frame.shape != shape:
            raise SpectralDataError(
                f"frame stack: frame {index} has shape {frame.shape} but the ambient frame {shape}; "
                "expected frames of one size"
            )
    samples = [_as_samples(f, f"frame {i}") for i, f in enumerate(frames)]
    n_pixels, n_channels = samples[0].shape
    mask_flat = None
    if sample_mask is not None:
        if sample_mask.shape != shape[:2]:
            raise SpectralDataError(f"sample mask has shape {sample_mask.shape}; expected {shape[:2]}")
        mask_flat = sample_mask.reshape(-1)
    n_led_frames = len(led_frames)
    n_rows = n_led_frames + 2
    white = spec.white_level
    if mask_flat is None:
        # Integer frames: one compiled pass, each sample converted once in a cache-sized tile.
        pool = thread_pool(workers) if workers > 1 else None
        compiled = frame_kernels.raw_moments([*led_frames, ambient], white, workers, pool)
        if compiled is not None:
            return statistics_from_moments(compiled, spec, n_pixels * n_channels)
    # Raw second moments of the rows [F_1 … F_n, A, 1] over the valid samples. Every statistic of
    # the linearised differences is a linear transform of these (below), so the per-chunk work is
    # one conversion and one Gram product: no per-frame subtract, scale or difference passes.
    # float64 keeps the cancellation in (s_j F_j − s_a A) harmless.
    # Integer frames of ≤ 16 bits: each chunk's products are integers summing below 2⁵² (exact in
    # float64 whatever the order of BLAS's sums), added up exactly in int64 — the compiled route's
    # totals to the bit (frame_kernels.EXACT_SAMPLES).
    exact = all(np.issubdtype(frame.dtype, np.integer) and frame.dtype.itemsize <= 2 for frame in frames)
    if exact:
        chunk_pixels = max(1, min(chunk_pixels, frame_kernels.EXACT_SAMPLES // n_channels))
    moments = np.zeros((n_rows, n_rows), dtype=np.int64 if exact else np.float64)
    block = np.empty((n_rows, min(chunk_pixels, n_pixels), n_channels))
    for start in range(0, n_pixels, chunk_pixels):
        stop = min(start + chunk_pixels, n_pixels)
        rows = stop - start
        view = block[:, :rows]
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
    return statistics_from_moments(moments.astype(np.float64, copy=False), spec, n_pixels * n_channels)


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
) -> SequenceStatistics:
    """Statistics of block sums: a block is valid when no member is saturated (or masked out)."""
    frames = [ambient, *led_frames]
    if len(led_frames) != spec.led_levels.shape[0]:
        raise SpectralDataError(f"frame stack: {len(led_frames)} LED frames but levels for {spec.led_levels.shape[0]}")
    for index, frame in enumerate(frames):
        if frame.shape != ambient.shape:
            raise SpectralDataError(
                f"frame stack: frame {index} has shape {frame.shape} but the ambient frame {ambient.shape}; "
                "expected frames of one size"
            )
    if sample_mask is not None and sample_mask.shape != ambient.shape[:2]:
        raise SpectralDataError(f"sample mask has shape {sample_mask.shape}; expected {ambient.shape[:2]}")
    n_led_frames = len(led_frames)
    rows = BlockRows(
        n_led_frames,
        plane_shape(ambient.shape, cfa_period),
        factor,
        spec.white_level,
        black_level=spec.black_level,
        weighting=weighting,
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


@lru_cache(maxsize=4)
def thread_pool(workers: int) -> ThreadPoolExecutor:
    """A process-wide pool of ``workers`` threads for the image passes (created on first use, then reused)."""
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix="msflash-image")


class BlockRows:
    """Block sums of an ambient + LED frame stack as the rows ``[F_1 … F_n, A, 1]`` of the moments.

    The binned statistics (eq. 4–6 on ``factor × factor`` block sums, see :func:`bin_frame`) need,
    per frame, its block sums and which blocks saturate; then the second moments of the rows. The
    binned pass of :func:`accumulate_statistics` adds every frame and takes the moments in one
    product. A capture adds each frame as it arrives (``incremental=True``): the new row's
    products with the rows already in are taken then, so once the last frame is in only its own
    block sums and one matrix–vector product remain — no full moment product on the latency path.
    Blocks saturated in any frame (or :meth:`exclude`-d) are left out of the moments; in
    incremental mode as soon as they are known (their columns zeroed in every row, their products
    taken out of the moments), so :meth:`statistics` has no mask left to apply.

    Frames may be added from several threads (distinct rows), but not in incremental mode.
    """

    def __init__(
        self,
        n_led_frames: int,
        plane_shape: tuple[int, ...],
        factor: int,
        white_level: float,
        incremental: bool = False,
        black_level: float = 0.0,
        weighting: bool = False,
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
        # moments, and this one lets every copy run along long rows.
        # Incremental moments take every row's product with the new one: rows not filled yet must
        # be zeros then; otherwise each row is written whole before use (no zeroing pass).
        shape = (n_rows, height * plane_shape[2] * width)
        self.rows = np.zeros(shape) if incremental else np.empty(shape)
        self.rows[n_led_frames + 1] = 1.0
        # Even blocks also give every block's half difference: the noise probe (module notes). The
        # ones row has no noise; rows not filled yet are zeros in incremental mode, as above. Laid
        # out (block row, block column, channel): the block sums' own order, copied without a transpose.
        # Large frames probe every ``probe_stride``-th block row only (PROBE_BLOCKS).
        self.probe_stride = probe_stride(height, width)
        self.difference_shape = (len(range(0, height, self.probe_stride)), width, plane_shape[2])
        probe_shape = (n_rows, math.prod(self.difference_shape))
        self.differences = (
            (np.zeros(probe_shape) if incremental else np.empty(probe_shape)) if factor % 2 == 0 else None
        )
        if self.differences is not None:
            self.differences[n_led_frames + 1] = 0.0
        self._noise: np.ndarray | None = None  # incremental mode: the probe's moments so far
        self._invalid: list[np.ndarray] = []
        self._filled = [n_led_frames + 1]
        self._floating = False
        # Inverse-variance weights (module notes): their square roots per row column, once the ambient
        # frame is in (and its probe: without one there is no noise to fit). ``_ambient_saturated`` are
        # the blocks the ambient frame itself saturates (left out of the fit).
        self.black_level = black_level
        self.weighting = weighting and self.differences is not None
        self.ambient_noise: PixelNoise | None = None
        """The ambient frame's noise per sample (:func:`processing.noise_level.detail_noise_line`), once it is in
        (weighted rows only)."""
        self.root_weights: np.ndarray | None = None
        self._ambient_saturated: np.ndarray | None = None
        self._moments: np.ndarray | None = None
        self._batch_weights: np.ndarray | None = None  # batch mode: the weights, taken once the ambient row is in
        self._excluded: np.ndarray | None = None  # incremental mode: columns already left out
        self._excluded_differences: np.ndarray | None = None  # the same blocks' columns of the differences
        if incremental:
            self._moments = np.zeros((n_rows, n_rows))
            self._moments[-1, -1] = self.rows.shape[1]
            if self.differences is not None:
                self._noise = np.zeros((n_rows, n_rows))

    def add(self, row: int, plane: np.ndarray) -> None:
        """Block-sum one (H, W, C) plane into ``row`` (LED frame j → j, ambient → n) and note its saturated blocks."""
        if plane.shape != self.plane_shape:
            raise SpectralDataError(f"frame stack: a frame has shape {plane.shape}; expected {self.plane_shape}")
        self._check_row(row)
        if np.issubdtype(plane.dtype, np.floating):
            # NaN/inf refused before the block sums, whose gather products would warn about them first.
            if not np.isfinite(plane.sum()):
                raise _non_finite_error([_frame_name(row, self.n_led_frames)])
            self._floating = True  # only ever set: safe when worker threads add frames
        if self.differences is None:
            _block_sums_into(plane, self.factor, self.rows[row].reshape(self.block_shape))
            may_saturate = _may_saturate(plane, self.white_level)
        else:
            # The sums from one pass of row sums, the probe from the probed block rows' alternating sums;
            # each product into its own contiguous array.
            row_sums, may_saturate = _block_row_sums_and_peak(plane, self.factor, self.white_level)
            channels = self.plane_shape[2]
            _gathered_by_channel(row_sums, self.factor, channels, self.rows[row].reshape(self.block_shape))
            alternation = _block_row_alternation(plane, self.factor, self.probe_stride)
            differences = _gathered(alternation, self.factor, channels, _difference_gather)
            np.copyto(self.differences[row].reshape(self.difference_shape), differences)
        if row == self.n_led_frames and self.weighting:
            self.ambient_noise = detail_noise_line(plane, 1, self.black_level, self.white_level)
        # One max per frame finds the frames that saturate at all; only those build masks.
        self._record(row, saturated_blocks(plane, self.factor, self.white_level) if may_saturate else None)

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
        differences = None if self.differences is None else self.differences[row].reshape(self.difference_shape)
        done, saturated = frame_kernels.block_pass(
            frame,
            self.factor,
            cfa_period,
            self.white_level,
            self.probe_stride,
            self.rows[row].reshape(self.block_shape),
            differences,
        )
        if not done:
            self.add(row, cfa_planes(frame, cfa_period))
            return
        if row == self.n_led_frames and self.weighting:
            # The same cells in the same order as from the planes (add): both routes weigh alike, to the bit.
            self.ambient_noise = detail_noise_line(frame, cfa_period, self.black_level, self.white_level)
        self._record(row, saturated)

    def _check_row(self, row: int) -> None:
        if row in self._filled or not 0 <= row <= self.n_led_frames:
            raise SpectralDataError(
                f"frame stack: row {row} is taken or out of range; expected each of 0…{self.n_led_frames} once"
            )

    def _record(self, row: int, saturated: np.ndarray | None) -> None:
        """After a row's block sums are in: its saturated blocks, the weights, the incremental moments."""
        if row == self.n_led_frames:
            self._ambient_saturated = saturated
            if self._moments is None and self.weighting:
                # Batch mode: the weights depend on the ambient row alone, so the thread that added it
                # takes them while others still add LED frames (off the serial path of statistics()).
                self._batch_weights = self._sample_weights()
        if self._moments is not None and self.weighting:
            if row == self.n_led_frames:
                self._weigh_filled()  # the ambient frame sets the weights: weigh it and any row in before it
            elif self.root_weights is not None:
                self._weigh_row(row)
        if self._moments is None:
            if saturated is not None:
                self._invalid.append(saturated)
        else:
            if saturated is not None:
                self._drop(saturated)  # the new row is not in the moments yet: its columns are only zeroed
            if self._excluded is not None:
                self.rows[row, self._excluded] = 0.0
                if self.differences is not None:
                    self.differences[row, self._excluded_differences] = 0.0
            # One matrix–vector product with every row (rows not filled yet are zeros; their
            # products are set when they arrive): cheaper than gathering the filled rows first.
            filled = [*self._filled, row]
            for rows, moments in ((self.rows, self._moments), (self.differences, self._noise)):
                if rows is not None and moments is not None:
                    products = _row_products(rows, row)
                    moments[row, filled] = products[filled]
                    moments[filled, row] = products[filled]
        self._filled.append(row)

    def _sample_weights(self) -> np.ndarray:
        """The inverse-variance weights of every row column, from the ambient row and the noise line of its frame."""
        ambient = self.n_led_frames
        # rows layout (block row, channel, block column)
        black = self.black_level * self.factor * self.factor
        line = ambient_block_noise(
            self.ambient_noise,
            self.factor,
            self.rows[ambient].reshape(self.block_shape).transpose(0, 2, 1),
            black,
            self._ambient_saturated,
        )
        return line.weights(self.rows[ambient], black)

    def _weigh_row(self, row: int) -> None:
        """Scale one row (and its probe) by the root weights (incremental mode, weights known)."""
        assert self.root_weights is not None
        self.rows[row] *= self.root_weights
        if self.differences is not None:
            self.differences[row] *= self._at_probe(self.root_weights)

    def _at_probe(self, values: np.ndarray) -> np.ndarray:
        """Per-column ``values`` of the rows at the probed blocks, in the probe's layout."""
        return values.reshape(self.block_shape)[:: self.probe_stride].transpose(0, 2, 1).reshape(-1)

    def _weigh_filled(self) -> None:
        """Incremental mode, the ambient row just in: weigh every filled row and retake their moments."""
        assert self._moments is not None
        self.root_weights = np.sqrt(self._sample_weights())
        filled = [row for row in self._filled if row != self.n_led_frames + 1]
        for row in [*filled, self.n_led_frames]:
            self._weigh_row(row)
        ones = self.n_led_frames + 1
        self.rows[ones] = self.root_weights
        if self._excluded is not None:
            self.rows[ones, self._excluded] = 0.0
        every = self._filled  # the ambient row's own products are taken by add() right after
        chunk = DEFAULT_CHUNK_PIXELS * self.block_shape[1]
        # The ambient first (the usual order) leaves the ones row alone: a (1, K) gram is BLAS's threaded
        # dot, whose wake-ups on a busy machine cost 10-20 ms; its product in slices (_row_products) does not.
        gram = (lambda rows: _row_products(rows, 0)[:, None]) if len(every) == 1 else (lambda rows: _gram(rows, chunk))
        self._moments[np.ix_(every, every)] = gram(self.rows[every])
        if self._noise is not None and self.differences is not None:
            self._noise[np.ix_(every, every)] = gram(self.differences[every])

    def exclude(self, blocks: np.ndarray) -> None:
        """Leave the blocks where the (H/f, W/f) mask ``blocks`` is set out of the moments."""
        if self._moments is None:
            self._invalid.append(blocks)
        else:
            self._drop(blocks)

    def _columns(self, blocks: np.ndarray) -> np.ndarray:
        """The row columns of the (H/f, W/f) block mask ``blocks`` (every channel of each block)."""
        return np.broadcast_to(blocks[:, None, :], self.block_shape).reshape(-1)

    def _difference_columns(self, blocks: np.ndarray) -> np.ndarray:
        """The columns of :attr:`differences` of the (H/f, W/f) block mask ``blocks``."""
        return np.broadcast_to(blocks[:: self.probe_stride, :, None], self.difference_shape).reshape(-1)

    def _probe_scale(self, excluded_blocks: int, excluded_probed: int) -> float | None:
        """Valid blocks ÷ probed valid blocks (1 without a stride), or None when no probed block is valid."""
        probed = self.difference_shape[0] * self.difference_shape[1] - excluded_probed
        if probed <= 0:
            return None
        return (self.block_shape[0] * self.block_shape[2] - excluded_blocks) / probed

    def _drop(self, blocks: np.ndarray) -> None:
        """Incremental mode: zero the columns of the (H/f, W/f) mask ``blocks`` in every row and take
        the products of the filled rows over the newly left-out columns back out of the moments.

        Once a quarter of the columns or more is out, the moments of the filled rows are taken
        anew instead (subtracting most of a sum loses precision), as :meth:`statistics` does.
        """
        assert self._moments is not None
        columns = self._columns(blocks)
        new = columns if self._excluded is None else columns & ~self._excluded
        fresh = np.flatnonzero(new)
        if not fresh.size:
            return
        self._excluded = new if self._excluded is None else self._excluded | new
        filled = np.asarray(self._filled, dtype=np.intp)
        few = np.count_nonzero(self._excluded) * 4 < columns.size
        parts = [(self.rows, self._moments, fresh)]
        if self.differences is not None and self._noise is not None:
            columns = self._difference_columns(blocks)
            new = columns if self._excluded_differences is None else columns & ~self._excluded_differences
            self._excluded_differences = new if self._excluded_differences is None else self._excluded_differences | new
            parts.append((self.differences, self._noise, np.flatnonzero(new)))
        for rows, moments, fresh in parts:
            if few:
                dropped = rows[np.ix_(filled, fresh)]
                rows[:, fresh] = 0.0
                moments[np.ix_(filled, filled)] -= dropped @ dropped.T
            else:
                rows[:, fresh] = 0.0
                moments[np.ix_(filled, filled)] = _gram(rows[filled], DEFAULT_CHUNK_PIXELS * self.block_shape[1])

    def statistics(
        self, spec: FrameStackSpec, chunk_pixels: int = DEFAULT_CHUNK_PIXELS, workers: int = 1
    ) -> SequenceStatistics:
        """The statistics of the rows added so far (every row must be in); ``spec`` as for the raw frames.

        ``workers`` threads share the moment product (when it is not already accumulated).
        """
        rows = self.rows
        if len(self._filled) != rows.shape[0]:
            raise SpectralDataError(
                f"frame stack: {len(self._filled) - 1} of {rows.shape[0] - 1} frames added; expected all of them"
            )
        # Integer sums are always finite; for float frames one sum flags NaN/inf (exact check only then).
        if self._floating and not np.isfinite(rows.sum()) and not np.isfinite(rows).all():
            raise non_finite_frames_error(rows[:-1])
        channels = self.block_shape[1]
        weights = probe_weights = None
        if self.weighting and self._moments is None:
            # Batch mode: the weights enter each chunk's product (incremental mode weighs rows as frames come).
            weights = self._sample_weights() if self._batch_weights is None else self._batch_weights
            probe_weights = self._at_probe(weights)
        column_factor: np.ndarray | None = None  # batch mode: √weight per column, 0 where left out
        if self._moments is not None:
            moments = self._moments  # incremental: saturated blocks were left out as they came (_drop)
            noise = self._noise
            excluded_columns = 0 if self._excluded is None else int(np.count_nonzero(self._excluded))
            scale = self._probe_scale(
                0 if self._excluded is None else int(np.count_nonzero(self._excluded)) // channels,
                0
                if self._excluded_differences is None
                else int(np.count_nonzero(self._excluded_differences)) // channels,
            )
        else:
            invalid = None
            for mask in self._invalid:
                invalid = mask if invalid is None else invalid | mask
            chunk = chunk_pixels * self.block_shape[1]
            invalid = invalid if invalid is not None and invalid.any() else None

            def masked_part(
                values: np.ndarray, columns: np.ndarray | None, column_weights: np.ndarray | None
            ) -> tuple[np.ndarray, np.ndarray | None]:
                if columns is not None:
                    if column_weights is not None:  # weighted: left-out columns weigh 0, no copy of the rows
                        column_weights = np.where(columns, 0.0, column_weights)
                    else:
                        values = values.copy()
                        values[:, columns] = 0.0
                return values, column_weights

            parts = [masked_part(rows, self._columns(invalid) if invalid is not None else None, weights)]
            if self.differences is not None:
                parts.append(
                    masked_part(
                        self.differences,
                        self._difference_columns(invalid) if invalid is not None else None,
                        probe_weights,
                    )
                )
            column_factor = np.ones(rows.shape[1]) if invalid is None else (~self._columns(invalid)).astype(float)
            # The rows' and the probe's moments in one map: the probe's single chunk shares the threads.
            moments, *probed = _grams(parts, chunk, workers)
            noise = probed[0] if probed else None
            excluded_columns = int(np.count_nonzero(invalid)) * channels if invalid is not None else 0
            scale = self._probe_scale(
                int(np.count_nonzero(invalid)) if invalid is not None else 0,
                int(np.count_nonzero(invalid[:: self.probe_stride])) if invalid is not None else 0,
            )
        if noise is not None:
            noise = None if scale is None else noise * scale
        # Block sums: the black level counts once per member; the spec's unmixing is reused as is.
        factor = self.factor
        statistics = statistics_from_moments(
            moments,
            spec,
            rows.shape[1],
            black_level=spec.black_level * factor * factor,
            noise_moments=noise,
            n_samples=rows.shape[1] - excluded_columns,
            weighted=self.root_weights is not None or weights is not None,
        )
        channel_moments = self._channel_moments(spec, column_factor, scale if noise is not None else None)
        return replace(statistics, channels=channel_moments)

    def _channel_moments(
        self, spec: FrameStackSpec, column_factor: np.ndarray | None, probe_scale: float | None
    ) -> ChannelMoments:
        """:class:`ChannelMoments` of the rows, masked as :meth:`statistics` takes them (batch mode: by ``column_factor``;
        incremental rows already are), the probe's scaled by ``probe_scale`` (None: none).

        Unweighted: a sample's inverse-variance weight differs from channel to channel, and weighing the channels of
        one block unequally would turn its colour away from the LED's (what :mod:`processing.flicker` reads).
        """
        n_rows, (height, channels, width) = self.rows.shape[0], self.block_shape
        if column_factor is None and self.root_weights is not None:  # incremental rows were weighed: undo it
            column_factor = np.divide(
                1.0, self.root_weights, out=np.zeros_like(self.root_weights), where=self.root_weights > 0
            )
        transform = _channel_transform(spec, spec.black_level * self.factor * self.factor)
        k = spec.n_leds

        def mapped(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            images = np.tensordot(transform, rows, axes=(1, 0))  # (k + 1, C, blocks): each LED's, then the ambient's
            leds, ambient = images[:k], images[k]
            return leds @ ambient.T, leds @ leds.transpose(0, 2, 1), ambient @ ambient.T

        def summed(parts: Iterator[np.ndarray]) -> tuple[np.ndarray, ...]:
            total: list[np.ndarray] | None = None
            for part in parts:
                moments = mapped(part)
                total = list(moments) if total is None else [a + b for a, b in zip(total, moments, strict=True)]
            assert total is not None
            return tuple(total)

        # A band of block rows at a time (the moments are sums over blocks): the rows' copy in channel order stays
        # about a megabyte whatever the frame count, so an estimate's peak stays one frame plus the statistics.
        band = max(1, CHANNEL_BAND_VALUES // max(1, n_rows * channels * width))
        row_values = height * channels * width

        def rows_by_channel() -> Iterator[np.ndarray]:
            for top in range(0, height, band):
                cut = slice(top * channels * width, min(top + band, height) * channels * width)
                values = self.rows[:, cut] if column_factor is None else self.rows[:, cut] * column_factor[cut]
                tall = values.shape[1] // (channels * width)
                yield values.reshape(n_rows, tall, channels, width).transpose(0, 2, 1, 3).reshape(n_rows, channels, -1)

        assert self.rows.shape[1] == row_values
        last_row = self.rows[n_rows - 1] if column_factor is None else self.rows[n_rows - 1] * column_factor
        last = last_row.reshape(height, channels, width)
        blocks = int(np.count_nonzero(last.any(axis=1))) if n_rows else 0
        fa, ff, aa = summed(rows_by_channel())
        noise: tuple[np.ndarray | None, ...] = (None, None, None)
        if self.differences is not None and probe_scale is not None:
            probed = self.difference_shape
            at_probe = None if column_factor is None else self._at_probe(column_factor)
            probe_band = max(1, CHANNEL_BAND_VALUES // max(1, n_rows * channels * probed[1]))

            def probe_by_channel() -> Iterator[np.ndarray]:
                assert self.differences is not None
                for top in range(0, probed[0], probe_band):
                    cut = slice(top * probed[1] * channels, min(top + probe_band, probed[0]) * probed[1] * channels)
                    values = self.differences[:, cut] if at_probe is None else self.differences[:, cut] * at_probe[cut]
                    tall = values.shape[1] // (probed[1] * channels)
                    yield (
                        values.reshape(n_rows, tall, probed[1], channels)
                        .transpose(0, 3, 1, 2)
                        .reshape(n_rows, channels, -1)
                    )

            noise = tuple(part * probe_scale for part in summed(probe_by_channel()))
        return ChannelMoments(fa, ff, aa, blocks, *noise)


def statistics_from_moments(
    moments: np.ndarray,
    spec: FrameStackSpec,
    n_total: int,
    black_level: float | None = None,
    noise_moments: np.ndarray | None = None,
    n_samples: int | None = None,
    weighted: bool = False,
) -> SequenceStatistics:
    """Statistics from the raw second moments of the rows [F_1 … F_n, A, 1].

    With inverse-variance weights (``weighted``) the rows are ``√wt·x`` and the last one ``√wt``, so the
    same map gives the weighted moments; ``n_samples`` is then the count of valid samples (the
    moments' last entry is their total weight).

    ``black_level`` replaces the spec's (block sums: the black level times the block area).
    ``noise_moments`` are the half differences' moments in the same row layout (the noise probe),
    mapped the same way into :attr:`SequenceStatistics.noise`.
    """
    n_led_frames = moments.shape[0] - 2
    n_rows = n_led_frames + 2
    # Linear map from the raw rows to [d_1 … d_n, a]: d_j = s_j (F_j − b) − s_a (A − b), a = s_a (A − b).
    transform = np.zeros((n_led_frames + 1, n_rows))
    scales = np.asarray(spec.led_scales, dtype=float)
    black = float(spec.black_level if black_level is None else black_level)
    transform[:n_led_frames, :n_led_frames] = np.diag(scales)
    transform[:n_led_frames, n_led_frames] = -spec.ambient_scale
    transform[:n_led_frames, n_led_frames + 1] = (spec.ambient_scale - scales) * black
    transform[n_led_frames, n_led_frames] = spec.ambient_scale
    transform[n_led_frames, n_led_frames + 1] = -spec.ambient_scale * black
    linear_moments = transform @ moments @ transform.T
    linear_sums = transform @ moments[:, -1]
    unmixing = spec.unmixing
    noise = None
    if noise_moments is not None:
        linear_noise = transform @ noise_moments @ transform.T
        noise = NoiseMoments(
            gram=unmixing @ linear_noise[:n_led_frames, :n_led_frames] @ unmixing.T,
            cross=unmixing @ linear_noise[:n_led_frames, n_led_frames],
            ambient_energy=float(linear_noise[n_led_frames, n_led_frames]),
        )
    return SequenceStatistics(
        gram=unmixing @ linear_moments[:n_led_frames, :n_led_frames] @ unmixing.T,
        cross=unmixing @ linear_moments[:n_led_frames, n_led_frames],
        ambient_energy=float(linear_moments[n_led_frames, n_led_frames]),
        n_samples=int(round(moments[-1, -1])) if n_samples is None else n_samples,
        n_total=n_total,
        ambient_sum=float(linear_sums[n_led_frames]),
        led_sums=unmixing @ linear_sums[:n_led_frames],
        noise=noise,
        weighted=weighted,
    )


def _channel_transform(spec: FrameStackSpec, black: float) -> np.ndarray:
    """(k + 1, n + 2) map from one channel's raw rows ``[F_1 … F_n, A, 1]`` to ``[f_1 … f_k, a]``:
    ``f_i = Σ_j U_ij (s_j (F_j − b) − s_a (A − b))``, ``a = s_a (A − b)`` (the same for every channel)."""
    unmixing, scales = spec.unmixing, np.asarray(spec.led_scales, dtype=float)
    k, n = unmixing.shape
    transform = np.zeros((k + 1, n + 2))
    transform[:k, :n] = unmixing * scales
    transform[:k, n] = -spec.ambient_scale * unmixing.sum(axis=1)
    transform[:k, n + 1] = unmixing @ ((spec.ambient_scale - scales) * black)
    transform[k, n] = spec.ambient_scale
    transform[k, n + 1] = -spec.ambient_scale * black
    return transform


def probe_stride(height: int, width: int) -> int:
    """Every how many block rows the noise probe of ``height × width`` blocks is taken (:data:`PROBE_BLOCKS`)."""
    return max(1, min(4, height * width // PROBE_BLOCKS))


@dataclass(frozen=True)
class NoiseLine:
    """A photon-transfer line: the noise variance of a sample at raw level ``x`` (black removed) is
    ``max(gain · x + read, floor)`` (:func:`block_noise_line`)."""

    gain: float
    read: float
    floor: float

    def weights(self, levels: np.ndarray, black: float = 0.0) -> np.ndarray:
        """``1/var`` of samples at raw ``levels`` (less ``black``), normalised to average 1, in the layout of
        ``levels``."""
        variance = np.subtract(levels, black, dtype=float)
        np.maximum(variance, 0.0, out=variance)
        variance *= self.gain
        variance += self.read
        np.maximum(variance, self.floor, out=variance)
        np.reciprocal(variance, out=variance)
        variance *= 1.0 / float(variance.mean())
        return variance

    def root_weights(self, levels: np.ndarray, black: float = 0.0) -> np.ndarray:
        """``√`` of :meth:`weights`: the factor each sample's row entry is scaled by."""
        weights = self.weights(levels, black)
        return np.sqrt(weights, out=weights)


UNIFORM_NOISE = NoiseLine(0.0, 1.0, 1.0)
"""Noise alike everywhere: uniform weights."""

FLOOR_QUANTILE = 0.05
"""The weights' variance floor is the line's variance at this quantile of the samples' levels: a read
noise near zero would give black samples unbounded weight."""


def block_noise_line(pixel: PixelNoise | None, factor: int, levels: np.ndarray) -> NoiseLine:
    """The noise line of ``factor × factor`` block sums whose samples have the noise ``pixel`` (per sample,
    :func:`processing.noise_level.detail_noise_line`): ``gain · B + factor² · read`` at block sum ``B`` above
    black, floored at its value at the :data:`FLOOR_QUANTILE` of ``levels`` (block sums above black).
    :data:`UNIFORM_NOISE` without a line, levels or a positive floor.

    Examples
    --------
    >>> line = block_noise_line(PixelNoise(gain=2.0, read=16.0), 4, np.arange(100.0, 2100.0))
    >>> line.gain, line.read, line.floor
    (2.0, 256.0, 656.0)
    """
    flat = np.asarray(levels, dtype=float).reshape(-1)
    if pixel is None or not flat.size:
        return UNIFORM_NOISE
    gain, read = pixel.gain, pixel.read * factor * factor
    position = int(FLOOR_QUANTILE * flat.size)
    floor = gain * max(float(np.partition(flat, position)[position]), 0.0) + read
    return NoiseLine(gain, read, floor) if floor > 0 and math.isfinite(floor) else UNIFORM_NOISE


def ambient_block_noise(
    pixel: PixelNoise | None, factor: int, ambient: np.ndarray, black: float, saturated: np.ndarray | None
) -> NoiseLine:
    """:func:`block_noise_line` for (h, w, C) ambient block sums (raw, black ``black`` per block), its floor
    taken over the blocks the ambient frame does not saturate (``saturated``, (h, w)). Used alike by
    :class:`BlockRows` and the tiled statistics of :mod:`processing.local`, so that both weigh the samples alike.
    """
    levels = ambient if saturated is None else ambient[~saturated]
    return block_noise_line(pixel, factor, np.subtract(levels, black, dtype=float))


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


def _may_saturate(frame: np.ndarray, white: float) -> bool:
    """Whether any sample of a frame reaches the white level (a fast contiguous max)."""
    if np.issubdtype(frame.dtype, np.integer) and np.iinfo(frame.dtype).max < white:
        return False  # the type cannot reach the white level
    return bool(frame.size) and bool(frame.max() >= white)


def saturated_blocks(plane: np.ndarray, factor: int, white: float) -> np.ndarray:
    """(H/f, W/f) mask of the ``factor × factor`` blocks of an (H, W, C) plane with any sample ≥ ``white``.

    Block maxima first, then one comparison: the maxima over a block's ``factor`` rows run along
    whole contiguous rows, and the maxima over its ``factor · C`` columns work on data already
    ``factor`` times smaller — about 3× faster than comparing every sample and reducing the
    boolean mask (this runs on the capture's latency path for the last frame). ``fmax`` ignores
    NaN as the comparison does.
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
    return _gathered(_block_row_sums(plane, factor), factor, plane.shape[2], gather_matrix)


def _block_row_sums(plane: np.ndarray, factor: int) -> np.ndarray:
    """The sums over each block's rows of an (H, W, C) plane: (H/f, W/f·f·C), edges dropped.

    Integer data is summed in float32 (exact for ≤ 16 bits in blocks ≤ 16×16), float data in float64.
    A reduction over the middle axis streams whole rows (long inner loops).
    """
    height, width, channels = plane.shape[0] // factor, plane.shape[1] // factor, plane.shape[2]
    sum_type = np.float64 if np.issubdtype(plane.dtype, np.floating) else np.float32
    cropped = plane[: height * factor, : width * factor].reshape(height, factor, width * factor * channels)
    return cropped.sum(axis=1, dtype=sum_type)


def _block_row_sums_and_peak(plane: np.ndarray, factor: int, white: float) -> tuple[np.ndarray, bool]:
    """:func:`_block_row_sums`, and whether any sample of the blocks reaches ``white`` (as :func:`_may_saturate`).

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


def _gathered(row_sums: np.ndarray, factor: int, channels: int, matrix) -> np.ndarray:
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


def _block_row_alternation(plane: np.ndarray, factor: int, stride: int = 1) -> np.ndarray:
    """Each block's even rows minus its odd rows, per column, of an (H, W, C) plane: (⌈(H/f)/stride⌉, W/f·f·C).

    Block rows ``0, stride, 2·stride…`` only; edges dropped; exact as :func:`_block_row_sums` (integers below
    2²⁴ in float32). Gathered with :func:`_difference_gather`, the checkerboard probe of the module notes.
    """
    height, width, channels = plane.shape[0] // factor, plane.shape[1] // factor, plane.shape[2]
    sum_type = np.float64 if np.issubdtype(plane.dtype, np.floating) else np.float32
    cropped = plane[: height * factor, : width * factor].reshape(height, factor, width * factor * channels)[::stride]
    alternation = cropped[:, 0::2].sum(axis=1, dtype=sum_type)
    alternation -= cropped[:, 1::2].sum(axis=1, dtype=sum_type)
    return alternation


@lru_cache(maxsize=16)
def _difference_gather(factor: int, channels: int, dtype: type) -> np.ndarray:
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
    sums = _gathered(_block_row_sums(plane, factor), factor, channels, gather_matrix)
    return sums, _gathered(_block_row_alternation(plane, factor), factor, channels, _difference_gather)


def _row_products(rows: np.ndarray, row: int) -> np.ndarray:
    """``rows @ rows[row]``, summed over slices of :data:`PRODUCT_COLUMNS` columns.

    OpenBLAS splits one large matrix–vector product across its threads; on a busy 2-core machine
    (the capture's stream and writer threads) their wake-up costs many times the product itself
    (docs/architecture.md §10). Slices stay below its threading threshold.
    """
    products = np.zeros(rows.shape[0])
    vector = rows[row]
    for start in range(0, rows.shape[1], PRODUCT_COLUMNS):
        products += rows[:, start : start + PRODUCT_COLUMNS] @ vector[start : start + PRODUCT_COLUMNS]
    return products


def _block_sums_into(plane: np.ndarray, factor: int, out: np.ndarray) -> None:
    """Write the block sums of an (H, W, C) plane into ``out`` (H/f, C, W/f), float64 (moment-row order)."""
    _gathered_by_channel(_block_row_sums(plane, factor), factor, plane.shape[2], out)


def _gathered_by_channel(row_sums: np.ndarray, factor: int, channels: int, out: np.ndarray) -> None:
    """Block sums from block rows' sums (:func:`_block_row_sums`) into ``out`` (H/f, C, W/f): moment-row order.

    Per block row, the transposed gather matrix times the transposed row groups gives the channels as
    rows directly — one batched product instead of a product and a transposing copy (exact as
    :func:`_gathered`: 0/1 weights, integer sums below 2²⁴ in float32).
    """
    height, width = row_sums.shape[0], row_sums.shape[1] // (factor * channels)
    dtype: type = row_sums.dtype.type
    gather = gather_matrix(factor, channels, dtype)
    groups = row_sums.reshape(height, width, factor * channels).transpose(0, 2, 1)
    if out.dtype == row_sums.dtype:
        np.matmul(gather.T, groups, out=out)
    else:
        np.copyto(out, np.matmul(gather.T, groups))


def _gram(rows: np.ndarray, chunk: int, workers: int = 1, weights: np.ndarray | None = None) -> np.ndarray:
    """``rows @ rows.T`` (with ``weights``, ``rows @ diag(weights) @ rows.T``) in float64 (:func:`_grams`)."""
    return _grams([(rows, weights)], chunk, workers)[0]


def _grams(parts: Sequence[tuple[np.ndarray, np.ndarray | None]], chunk: int, workers: int = 1) -> list[np.ndarray]:
    """:func:`_gram` of several ``(rows, weights)`` at once, accumulated over column chunks; ``workers``
    threads share the chunks of all of them (one map: a part with a single chunk does not run alone after
    the others). Each chunk is weighted while it is in cache.

    The chunks' products are added in chunk order whatever the number of workers, so the result
    does not depend on it.
    """
    chunk = max(chunk, 1)

    def product(task: tuple[int, int]) -> np.ndarray:
        rows, weights = parts[task[0]]
        start = task[1]
        block = rows[:, start : start + chunk]
        if weights is None:
            return block @ block.T
        # Weighted in slices of PRODUCT_COLUMNS, so that each weighted copy is still in cache for its
        # product: ``(x·√w)(x·√w)ᵀ``, one symmetric product (BLAS syrk: half the multiplications).
        result = np.zeros((rows.shape[0], rows.shape[0]))
        column_weights = weights[start : start + chunk]
        for offset in range(0, block.shape[1], PRODUCT_COLUMNS):
            part = block[:, offset : offset + PRODUCT_COLUMNS] * np.sqrt(
                column_weights[offset : offset + PRODUCT_COLUMNS]
            )
            result += part @ part.T
        return result

    tasks = [(index, start) for index, (rows, _) in enumerate(parts) for start in range(0, rows.shape[1], chunk)]
    products = thread_pool(workers).map(product, tasks) if workers > 1 and len(tasks) > 1 else map(product, tasks)
    moments = [np.zeros((rows.shape[0], rows.shape[0])) for rows, _ in parts]
    for (index, _), part in zip(tasks, products):
        moments[index] += part
    return moments
