"""The computational flash image: ``m_a + Σ_k w_k m_f,k`` from the frames already taken.

With the LED-only images ``m_f = pinv(L) · (F − m_a)`` (see :mod:`processing.statistics`), the
synthesised image is a weighted sum of the *raw* frames, ``(1 − Σ_j c_j) m_a + Σ_j c_j F_j``
with ``c = pinv(L)ᵀ w`` — one pass over the frames, in chunks, no LED-only image ever stored.
Works identically on RGB images and raw mosaics (each sample is just a number).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence

import numpy as np

from msflash.processing import frame_kernels
from msflash.processing.errors import SpectralDataError
from msflash.processing.moment_products import DEFAULT_CHUNK_PIXELS, DEFAULT_WORKERS, shared_tasks
from msflash.processing.statistics import FrameStackSpec, non_finite_frames_error


def frame_coefficients(
    spec: FrameStackSpec, flash_weights: np.ndarray, ambient_offsets: np.ndarray | None = None
) -> tuple[float, np.ndarray]:
    """Coefficients of the linearised ambient and LED frames in ``m_a + Σ w_k m_f,k``.

    With ``ambient_offsets`` (``e``, the ambient's share in each LED-only image of a flickering sequence,
    :func:`processing.flicker.applied_offsets`) the LED images are taken as ``m_f,k − e_k m_a``, so the
    ambient's coefficient loses ``w · e`` and the image holds the ambient once, as in the ambient frame.

    Returns
    -------
    tuple
        ``(ambient_coefficient, led_frame_coefficients)`` applied to linearised frames.

    Examples
    --------
    >>> spec = FrameStackSpec(0, 100, 1.0, (1.0, 1.0), np.eye(2))
    >>> a, c = frame_coefficients(spec, np.array([0.5, 0.25]))
    >>> float(a), c.tolist()
    (0.25, [0.5, 0.25])
    """
    weights = np.asarray(flash_weights, dtype=float)
    if weights.shape != (spec.n_leds,):
        raise SpectralDataError(f"synthesis: {weights.size} flash weights; expected {spec.n_leds} (one per LED)")
    if not np.all(np.isfinite(weights)):
        raise SpectralDataError("synthesis: flash weights must be finite numbers")
    share = 0.0
    if ambient_offsets is not None:
        offsets = np.asarray(ambient_offsets, dtype=float)
        if offsets.shape != (spec.n_leds,) or not np.all(np.isfinite(offsets)):
            raise SpectralDataError(
                f"synthesis: ambient offsets of shape {offsets.shape}; expected {spec.n_leds} finite numbers"
            )
        share = float(weights @ offsets)
    with np.errstate(over="ignore", invalid="ignore"):  # huge weights: synthesize refuses what overflows
        coefficients = spec.unmixing.T @ weights
        return float(1.0 - coefficients.sum() - share), coefficients


def synthesize(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    spec: FrameStackSpec,
    flash_weights: np.ndarray,
    *,
    chunk_pixels: int = DEFAULT_CHUNK_PIXELS,
    workers: int = DEFAULT_WORKERS,
    dtype: type = np.float32,
    ambient_offsets: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Synthesise the computational flash image from raw frames.

    Parameters
    ----------
    ambient, led_frames
        Raw frames as captured (any exposures and gains; see ``spec``).
    spec
        Black/white levels, per-frame ``1/(exposure·gain)`` and LED levels.
    flash_weights
        ``w_f``, one weight per LED (in full-drive units).
    chunk_pixels
        Pixels per chunk (each chunk is one cache-resident weighted sum).
    workers
        Threads sharing the chunks (numpy and the compiled pass release the GIL inside each chunk);
        the image does not depend on it.
    dtype
        The image's type, float32 (default) or float64; written directly, in one pass.
    ambient_offsets
        A flickering sequence's ambient share in each LED image (:func:`frame_coefficients`), or None.

    Returns
    -------
    image : ndarray
        The linear image ``m_a + Σ w_k m_f,k`` in units of value per (µs · gain), of ``dtype``, the
        shape of the frames.

    saturated : ndarray
        Boolean (H, W) mask of pixels saturated in some input frame (their values are unreliable).

    Notes
    -----
    Integer frames go through one compiled pass (:func:`processing.frame_kernels.weighted_sum_range`):
    each sample is read once, scaled and summed in float64 in cache-sized tiles, and the image written
    once in ``dtype``. Other frames, or without numba, take chunks through numpy with the same
    arithmetic (float64 sums in frame order, rounded once), so the two routes write the same image.
    """
    ambient_coefficient, coefficients = frame_coefficients(spec, flash_weights, ambient_offsets)
    frames = [ambient, *led_frames]
    for index, frame in enumerate(frames):
        if frame.shape != ambient.shape:
            raise SpectralDataError(
                f"synthesis: frame {index} has shape {frame.shape} but the ambient frame {ambient.shape}"
            )
    # Per-frame factors on raw values, and one constant absorbing every black-level offset.
    factors64 = np.concatenate([[ambient_coefficient * spec.ambient_scale], coefficients * np.asarray(spec.led_scales)])
    _check_range(factors64, frames, spec, flash_weights)
    if np.dtype(dtype) not in (np.float32, np.float64):
        raise SpectralDataError(f"synthesis: image type {np.dtype(dtype).name}; expected float32 or float64")
    output: np.ndarray = np.empty(ambient.shape, dtype=dtype)
    saturated = np.zeros(ambient.shape[:2], dtype=bool)
    channels = ambient.shape[2] if ambient.ndim == 3 else 1
    frame_kernels.wanted(sum(frame.nbytes for frame in frames))  # loads the kernels for large stacks
    compiled = frame_kernels.synthesis_inputs(frames)
    if compiled is not None:
        _synthesize_compiled(
            compiled, factors64, spec.black_level, spec.white_level, channels, output, saturated, workers
        )
    else:
        _synthesize_chunks(frames, factors64, spec, channels, output, saturated, chunk_pixels, workers)
    return output, saturated


def _synthesize_chunks(
    frames: list[np.ndarray],
    factors64: np.ndarray,
    spec: FrameStackSpec,
    channels: int,
    output: np.ndarray,
    saturated: np.ndarray,
    chunk_pixels: int,
    workers: int,
) -> None:
    """The numpy route of :func:`synthesize`: chunks of flat samples, the compiled pass's arithmetic."""
    white = spec.white_level
    # Summed in float64 in frame order, then rounded once to the image's type: the compiled kernel's
    # arithmetic step for step, so both routes give the same image bit for bit (a process that has
    # the kernels loaded and one that has not write the same file).
    offset = -spec.black_level * float(factors64.sum())
    # Flat sample views (a copy only for non-contiguous frames): chunks then need no row alignment.
    flat_frames = [np.ascontiguousarray(frame).reshape(-1) for frame in frames]
    flat_output = output.reshape(-1)
    flat_saturated = saturated.reshape(-1)
    # Frames whose type cannot reach the white level never saturate; the others are checked chunk
    # by chunk right after the chunk is read, while it is in cache (a whole-frame max first would be
    # one more pass over every frame in memory, on one thread).
    saturating = [
        not (np.issubdtype(frame.dtype, np.integer) and np.iinfo(frame.dtype).max < white) for frame in flat_frames
    ]
    chunk_samples = max(1, chunk_pixels) * channels
    buffers = threading.local()

    def synthesize_chunk(start: int) -> None:
        stop = min(start + chunk_samples, flat_output.size)
        # Two float64 rows per thread, cache-sized: the running sum and one frame's scaled chunk.
        sums = getattr(buffers, "sums", None)
        if sums is None:
            sums = buffers.sums = np.empty((2, min(chunk_samples, flat_output.size)), dtype=np.float64)
        total, product = sums[0, : stop - start], sums[1, : stop - start]
        bright = None
        for index, frame in enumerate(flat_frames):
            chunk = frame[start:stop]
            # A float frame's inf or NaN stays quiet here: the whole image is checked below and refused.
            with np.errstate(invalid="ignore", over="ignore"):
                if index == 0:
                    np.multiply(chunk, factors64[0], out=total, dtype=np.float64)
                    total += offset
                else:
                    np.multiply(chunk, factors64[index], out=product, dtype=np.float64)
                    total += product
            # A fast reduction on the cached chunk; the comparison mask only where it is needed.
            if saturating[index] and chunk.max() >= white:
                hit = chunk >= white
                bright = hit if bright is None else bright | hit
        np.copyto(flat_output[start:stop], total, casting="same_kind")
        if bright is not None:
            flat_saturated[start // channels : stop // channels] = _any_channel(bright.reshape(-1, channels))

    # Chunks write disjoint slices of the output; each is computed exactly as on one thread.
    _run_tasks(synthesize_chunk, range(0, flat_output.size, chunk_samples), workers)
    # Integer frames are finite and _check_range bounds the sum; float frames (EXR) may hold NaN or
    # inf, which would reach the image: one sum flags them (the exact search runs only then).
    if any(np.issubdtype(frame.dtype, np.floating) for frame in frames) and not np.isfinite(
        output.sum(dtype=np.float64)
    ):
        raise non_finite_frames_error([*frames[1:], frames[0]], "synthesis")  # its layout: LED frames, ambient


COMPILED_TASK_PIXELS = 1 << 16
"""Pixels per task of the compiled synthesis: enough tasks to keep both threads busy to the end."""


def _synthesize_compiled(
    flat_frames: tuple[np.ndarray, ...],
    factors: np.ndarray,
    black_level: float,
    white: float,
    channels: int,
    output: np.ndarray,
    saturated: np.ndarray,
    workers: int,
) -> None:
    """The weighted sum of integer frames in one compiled pass, tasks of whole pixels shared by ``workers``."""
    offset = -black_level * float(factors.sum())
    flat_output, flat_saturated = output.reshape(-1), saturated.reshape(-1)
    step = COMPILED_TASK_PIXELS * channels

    def task(start: int) -> None:
        frame_kernels.weighted_sum_range(
            flat_frames,
            factors,
            offset,
            white,
            channels,
            flat_output,
            flat_saturated,
            start,
            min(start + step, flat_output.size),
        )

    _run_tasks(task, range(0, flat_output.size, step), workers)


def _run_tasks(task: Callable[[int], None], starts: range, workers: int) -> None:
    """``task(start)`` for every start, shared by the calling thread and the pool (:func:`shared_tasks`)."""
    shared_tasks(lambda index: task(starts[index]), len(starts), workers)


_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _check_range(
    factors: np.ndarray, frames: Sequence[np.ndarray], spec: FrameStackSpec, flash_weights: np.ndarray
) -> None:
    """Refuse weights whose image would overflow float32 (to inf, then NaN), bounded from the factors.

    A sample is at most ``Σ |factor_j| · peak + |offset|`` with ``peak`` the largest raw value a frame
    can hold (its integer type's maximum; the white level for float frames): no pass over the pixels.
    """
    peak = max(
        [float(np.iinfo(frame.dtype).max) for frame in frames if np.issubdtype(frame.dtype, np.integer)]
        + [abs(spec.white_level), abs(spec.black_level)]
    )
    with np.errstate(over="ignore", invalid="ignore"):  # an infinite bound is the answer, not a warning
        total = float(np.abs(factors).sum())
    bound = total * peak + abs(spec.black_level) * total
    if not bound < _FLOAT32_MAX:
        largest = float(np.max(np.abs(np.asarray(flash_weights, dtype=float))))
        raise SpectralDataError(
            f"synthesis: flash weights up to {largest:.3g} overflow the float32 image (samples up to {bound:.3g}); "
            f"expected weights that keep it below {_FLOAT32_MAX:.3g}"
        )


def _any_channel(bright: np.ndarray) -> np.ndarray:
    """(pixels,) mask of the rows of a (pixels, channels) mask with any channel set."""
    # ``|`` over strided channel columns: .any(axis=1) over a tiny trailing axis is slow in numpy.
    result = bright[:, 0].copy()
    for channel in range(1, bright.shape[1]):
        result |= bright[:, channel]
    return result


def linearise(
    raw: np.ndarray, black_level: float, white_level: float, exposure_us: float, gain: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """A raw frame in processing units, ``(raw − black) / (exposure_us · gain)``, and its saturation.

    Returns
    -------
    linear : ndarray
        float64, the frame's shape.
    saturated : ndarray
        Boolean (H, W): some channel at or above the white level.

    Examples
    --------
    >>> linear, saturated = linearise(np.array([[64, 1064]]), 64, 1000, 10.0)
    >>> linear.tolist(), saturated.tolist()
    ([[0.0, 100.0]], [[False, True]])
    """
    saturated = raw >= white_level
    saturated = np.any(saturated, axis=2) if saturated.ndim == 3 else saturated
    return (raw.astype(np.float64) - black_level) / (exposure_us * gain), saturated


def to_raw_values(
    image: np.ndarray, exposure_us: float, gain: float, black_level: float, white_level: float, dtype: type = np.uint16
) -> np.ndarray:
    """Encode a linear image as raw values at a given exposure and gain (clipped to the white level)."""
    values = image.astype(np.float64) * (exposure_us * gain) + black_level
    values = np.clip(np.rint(values), 0, white_level)
    return values.astype(dtype)


class SynthesisStream:
    """The computational flash image of :func:`synthesize`, summed one frame at a time.

    Add the ambient frame first, then the LED frames in order (:meth:`add`); each may be let go after.
    The sum runs in float64 in that order and is rounded once to ``dtype`` (:meth:`result`): the
    arithmetic of :func:`synthesize`, step for step, so both give the same image bit for bit. Peak
    memory is the float64 sum (four 16-bit frames' worth) and one frame, whatever the frame count.
    """

    def __init__(
        self,
        spec: FrameStackSpec,
        flash_weights: np.ndarray,
        shape: tuple[int, ...],
        *,
        dtype: type = np.float32,
        ambient_offsets: np.ndarray | None = None,
    ) -> None:
        if np.dtype(dtype) not in (np.float32, np.float64):
            raise SpectralDataError(f"synthesis: image type {np.dtype(dtype).name}; expected float32 or float64")
        ambient_coefficient, coefficients = frame_coefficients(spec, flash_weights, ambient_offsets)
        self.spec, self.flash_weights, self.shape, self.dtype = spec, flash_weights, tuple(shape), dtype
        self.factors = np.concatenate(
            [[ambient_coefficient * spec.ambient_scale], coefficients * np.asarray(spec.led_scales)]
        )
        self.offset = -spec.black_level * float(self.factors.sum())
        self.total = np.empty(self.shape, dtype=np.float64)
        self.saturated = np.zeros(self.shape[:2], dtype=bool)
        self.chunk_samples = DEFAULT_CHUNK_PIXELS * (self.shape[2] if len(self.shape) == 3 else 1)
        self.added = 0
        self.floating = False

    def add(self, frame: np.ndarray) -> None:
        """Add the next frame (the ambient frame first, then each LED frame in the spec's order)."""
        index = self.added
        if index >= self.factors.size:
            raise SpectralDataError(f"synthesis: frame {index} is one more than the {self.factors.size} expected")
        if frame.shape != self.shape:
            raise SpectralDataError(
                f"synthesis: frame {index} has shape {frame.shape} but the ambient frame {self.shape}"
            )
        _check_range(self.factors, [frame], self.spec, self.flash_weights)
        self.floating = self.floating or bool(np.issubdtype(frame.dtype, np.floating))
        self._accumulate(frame, self.factors[index], self.offset if index == 0 else None, overwrite=index == 0)
        if not (np.issubdtype(frame.dtype, np.integer) and np.iinfo(frame.dtype).max < self.spec.white_level):
            bright = frame >= self.spec.white_level
            self.saturated |= np.any(bright, axis=2) if bright.ndim == 3 else bright
        self.added += 1

    def take_out_ambient_share(self, ambient: np.ndarray, ambient_offsets: np.ndarray) -> None:
        """Take a flickering ambient's share out of the sum after the pass, where it was not known before it.

        The LED images taken as ``m_f,k − e_k m_a`` (``ambient_offsets`` = ``e``, :func:`frame_coefficients`)
        lower the ambient's coefficient by ``w · e``: the sum changes by that coefficient's step times the
        linearised ``ambient`` (the frame added first, kept by the caller). Linear in the frames, so the image
        is the one of a stream made with ``ambient_offsets`` to rounding (float64 sums in another order,
        then one rounding to ``dtype``). The saturated pixels do not change.
        """
        if self.added != self.factors.size:
            raise SpectralDataError(f"synthesis: {self.added} of {self.factors.size} frames added; expected all")
        if ambient.shape != self.shape:
            raise SpectralDataError(f"synthesis: ambient frame of shape {ambient.shape}; expected {self.shape}")
        corrected, _ = frame_coefficients(self.spec, self.flash_weights, ambient_offsets)
        factors = self.factors.copy()
        factors[0] = corrected * self.spec.ambient_scale
        _check_range(factors, [ambient], self.spec, self.flash_weights)
        step = float(factors[0] - self.factors[0])
        self._accumulate(ambient, step, -(step * self.spec.black_level), overwrite=False)
        self.factors = factors
        self.offset = -self.spec.black_level * float(factors.sum())

    def _accumulate(self, frame: np.ndarray, factor: float, constant: float | None, *, overwrite: bool) -> None:
        """``total = factor · frame + constant`` (``overwrite``), else ``total += factor · frame + constant``, in
        float64 chunks of :data:`DEFAULT_CHUNK_PIXELS` pixels."""
        flat_total, flat_frame = self.total.reshape(-1), np.ascontiguousarray(frame).reshape(-1)
        product = np.empty(min(self.chunk_samples, flat_total.size), dtype=np.float64)
        for start in range(0, flat_total.size, self.chunk_samples):
            stop = min(start + self.chunk_samples, flat_total.size)
            part = flat_total[start:stop] if overwrite else product[: stop - start]
            with np.errstate(invalid="ignore", over="ignore"):  # non-finite float frames are refused in result()
                np.multiply(flat_frame[start:stop], factor, out=part, dtype=np.float64)
                if constant is not None:
                    part += constant
                if not overwrite:
                    flat_total[start:stop] += part

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """The image (``dtype``) and the saturated pixels, once every frame is in."""
        if self.added != self.factors.size:
            raise SpectralDataError(f"synthesis: {self.added} of {self.factors.size} frames added; expected all")
        if self.floating and not np.isfinite(self.total.sum()):
            raise SpectralDataError("synthesis: a frame holds non-finite values (NaN or inf); expected finite pixels")
        return self.total.astype(self.dtype), self.saturated
