"""Sufficient statistics of a flash sequence (eq. 4–6) and how to linearise its frames.

Ambient estimation needs only the k×k Gram matrix of the LED-only images, their k products with the ambient
image, the ambient image's squared norm and the sample count (docs/architecture.md §8): :class:`SequenceStatistics`,
with the noise's share of them (:class:`NoiseMoments`) and their per-channel form (:class:`ChannelMoments`).
They are taken from the raw second moments of the rows ``[F_1 … F_n, A, 1]`` (:func:`statistics_from_moments`),
accumulated by :mod:`processing.accumulate` (all pixels, or block sums: :mod:`processing.block_rows`).

Frames need not light one LED each: any LED frame may drive several LEDs at any levels (a
multiplexed sequence). With ``L`` the (n_led_frames, k) matrix of levels, the per-LED images at
full drive are ``pinv(L) · (frames − ambient)``, applied to the statistics after accumulation.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from msflash.processing.errors import SpectralDataError


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

    @cached_property
    def unmixing_diagonal(self) -> tuple[float, ...] | None:
        """The diagonal of :attr:`unmixing` as floats where it is diagonal (one LED per frame), else None."""
        unmixing = self.unmixing
        diagonal = np.diag(unmixing)
        return tuple(diagonal.tolist()) if np.count_nonzero(unmixing) == np.count_nonzero(diagonal) else None


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
    """The same blocks' moments channel by channel (binned statistics: :class:`processing.block_rows.BlockRows`), or None; kept by
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


def non_finite_frames_error(rows: Sequence[np.ndarray] | np.ndarray, where: str = "frame stack") -> SpectralDataError:
    """The error for frame rows ``[F_1 … F_n, A]`` (the statistics' layout) of which some hold NaN or inf.

    Names the frames (the ambient frame, LED frame k counted from 1 in sequence order) after
    ``where``; searched only once a cheap check has failed.
    """
    bad = [row for row in range(len(rows)) if not np.isfinite(rows[row]).all()]
    return non_finite_error([frame_name(row, len(rows) - 1) for row in bad], where)


def frame_name(row: int, n_led_frames: int) -> str:
    """Row ``row`` of ``[F_1 … F_n, A]`` in words: ``LED frame k`` (from 1) or ``the ambient frame``."""
    return "the ambient frame" if row == n_led_frames else f"LED frame {row + 1}"


def non_finite_error(names: list[str], where: str = "frame stack") -> SpectralDataError:
    return SpectralDataError(
        f"{where}: {', '.join(names) or 'a frame'} holds non-finite values (NaN or inf); expected finite pixels"
    )


def statistics_from_moments(
    moments: np.ndarray,
    spec: FrameStackSpec,
    n_total: int,
    black_level: float | None = None,
    noise_moments: np.ndarray | None = None,
    n_samples: int | None = None,
    weighted: bool = False,
    transform: np.ndarray | None = None,
) -> SequenceStatistics:
    """Statistics from the raw second moments of the rows [F_1 … F_n, A, 1].

    With inverse-variance weights (``weighted``) the rows are ``√wt·x`` and the last one ``√wt``, so the
    same map gives the weighted moments; ``n_samples`` is then the count of valid samples (the
    moments' last entry is their total weight).

    ``black_level`` replaces the spec's (block sums: the black level times the block area).
    ``noise_moments`` are the half differences' moments in the same row layout (the noise probe),
    mapped the same way into :attr:`SequenceStatistics.noise`. ``transform``: :func:`channel_transform` of ``spec`` and
    that black level when the caller has it already.
    """
    if transform is None:
        transform = channel_transform(spec, float(spec.black_level if black_level is None else black_level))
    k = transform.shape[0] - 1
    linear_moments = transform @ moments @ transform.T
    linear_sums = transform @ moments[:, -1]
    noise = None
    if noise_moments is not None:
        linear_noise = transform @ noise_moments @ transform.T
        noise = NoiseMoments(linear_noise[:k, :k], linear_noise[:k, k], float(linear_noise[k, k]))
    return SequenceStatistics(
        gram=linear_moments[:k, :k],
        cross=linear_moments[:k, k],
        ambient_energy=float(linear_moments[k, k]),
        n_samples=int(round(moments[-1, -1])) if n_samples is None else n_samples,
        n_total=n_total,
        ambient_sum=float(linear_sums[k]),
        led_sums=linear_sums[:k],
        noise=noise,
        weighted=weighted,
    )


def channel_transform(spec: FrameStackSpec, black: float) -> np.ndarray:
    """(k + 1, n + 2) map from the raw rows ``[F_1 … F_n, A, 1]`` (of a frame, a block, a channel) to the LED images at
    full drive and the ambient, ``[f_1 … f_k, a]``: ``f_i = Σ_j U_ij (s_j (F_j − b) − s_a (A − b))``, ``a = s_a (A − b)``
    with ``U = pinv(L)`` (:attr:`FrameStackSpec.unmixing`)."""
    diagonal = spec.unmixing_diagonal
    if diagonal is not None and len(diagonal) == len(spec.led_scales):
        return _diagonal_transform(diagonal, tuple(map(float, spec.led_scales)), float(spec.ambient_scale), black)
    unmixing, scales = spec.unmixing, np.asarray(spec.led_scales, dtype=float)
    k, n = unmixing.shape
    transform = np.zeros((k + 1, n + 2))
    transform[:k, :n] = unmixing * scales
    transform[:k, n] = -spec.ambient_scale * unmixing.sum(axis=1)
    transform[:k, n + 1] = unmixing @ ((spec.ambient_scale - scales) * black)
    transform[k, n] = spec.ambient_scale
    transform[k, n + 1] = -spec.ambient_scale * black
    return transform


def _diagonal_transform(
    diagonal: tuple[float, ...], scales: tuple[float, ...], ambient: float, black: float
) -> np.ndarray:
    """:func:`channel_transform` where ``U`` is diagonal (one LED per frame, the usual plan), in Python floats: the
    same products as the array route (a sum or product over a row of ``U`` is its one diagonal term), so the same
    transform to the bit, from one array call instead of a dozen (each costs microseconds right after the frames'
    pass has evicted numpy's code; docs/speed.md, rawspeed30d)."""
    n = len(diagonal)
    rows = []
    for i, (unmix, scale) in enumerate(zip(diagonal, scales, strict=True)):
        row = [0.0] * (n + 2)
        row[i] = unmix * scale
        row[n] = -ambient * unmix
        row[n + 1] = unmix * ((ambient - scale) * black)
        rows.append(row)
    last = [0.0] * (n + 2)
    last[n] = ambient
    last[n + 1] = -ambient * black
    rows.append(last)
    return np.array(rows)
