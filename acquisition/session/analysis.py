"""From a recorded sequence to processing inputs and back: estimate, flash and synthesise.

``processing`` never sees a file or a sequence (docs/architecture.md §2.1). This module is the thin layer that
reads a :class:`~acquisition.sequence.format.Sequence`, builds the frame stack description, converts
spectra to the processing unit (photons) and converts results back to the sequence's unit.
"""

from __future__ import annotations

from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, replace

import numpy as np

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.image_files import read_image_header
from msflash.acquisition.sequence.memory_budget import check_decode
from msflash.acquisition.sequence.writer import as_recorded
from msflash.acquisition.session.estimate_stream import (
    EstimateStream,
    StackLayout,
    is_mono,
    stack_layout,
    stream_sequence,
)
from msflash.acquisition.session.reference_crops import ReferenceCrops
from msflash.acquisition.session.sequence_spectra import (
    camera_responsivities_photons,
    led_spectra_photons,
    spectrum_in_sequence_unit,
    target_illuminant,
)
from msflash.processing.ambient import AmbientEstimate, AmbientModel, estimate_ambient
from msflash.processing.channel_statistics import plane_channels
from msflash.processing.errors import SpectralDataError
from msflash.processing.flash import FlashBounds, FlashSolution, solve_complementary, solve_matching
from msflash.processing.flicker import FlickerCheck, applied_offsets, check_flicker, with_ambient_gains, with_fit
from msflash.processing.model_error import reference_for, with_model_error
from msflash.processing.statistics import FrameStackSpec, SequenceStatistics
from msflash.processing.synthesis import SynthesisStream, synthesize


@dataclass(frozen=True)
class FrameStack:
    """The ambient frame and the LED frames of a sequence, loaded, with how to linearise them."""

    ambient: np.ndarray
    """Raw ambient frame."""
    led_frames: tuple[np.ndarray, ...]
    """Raw LED frames (ambient + LEDs), in sequence order."""
    spec: FrameStackSpec
    """Black/white levels, exposure·gain scales and LED levels."""
    ambient_index: int
    """Index of the ambient frame in the sequence."""
    led_indices: tuple[int, ...]
    """Indices of the LED frames in the sequence."""


def load_frame_stack(sequence: Sequence, frames: SequenceOf[np.ndarray] | None = None) -> FrameStack:
    """The first ambient frame and every ``led`` frame of a sequence, with how to linearise them: the one
    way from frames to a :class:`FrameStack` for disk, live and replay alike (docs/architecture.md §5).

    ``frames``: the frames already in memory as the camera gave them, indexed like ``sequence.frames``
    (taken as :func:`~acquisition.sequence.writer.as_recorded` returns them); ``None`` reads the files.

    Raises
    ------
    RecordingError
        If there is no ambient frame, no LED frame, or the LED frames do not light every LED
        independently.
    """
    cfa = sequence.camera.cfa
    if frames is None:
        _check_stack_budget(sequence)

    def pixels(index: int) -> np.ndarray:
        return sequence.load_frame(index) if frames is None else as_recorded(frames[index], cfa)

    return frame_stack(sequence_layout(sequence), pixels)


def stream_stack(
    sequence: Sequence,
    stack: FrameStack,
    bin_factor: int = 8,
    tiles: int | None = None,
    full_probe: bool = False,
    references: ReferenceCrops | None = None,
) -> EstimateStream:
    """A stack already in memory fed to the one accumulator, as :func:`stream_sequence` feeds the files
    (``full_probe``: every block row's half difference kept, for the light models' channel statistics;
    ``references``: a reference's crops taken from the frames as they pass)."""
    index = {i: frame for i, frame in zip(stack.led_indices, stack.led_frames, strict=True)}
    index[stack.ambient_index] = stack.ambient
    return stream_sequence(sequence, bin_factor, tiles, index.__getitem__, full_probe, references)


def _check_stack_budget(sequence: Sequence) -> None:
    """Refuse loading every used frame at once past the memory budget, from their headers (nothing decoded)."""
    roles = [entry.role for entry in sequence.frames]
    used = [i for i, role in enumerate(roles) if role == "led"]
    if "ambient" in roles:
        used.insert(0, roles.index("ambient"))
    total = 0
    for index in used:
        header = read_image_header(sequence.frame_path(index))
        total += header.width * header.height * header.channels * header.dtype.itemsize
    check_decode(f"{sequence.path}", total, f"its {len(used)} ambient and LED frames at once")


def sequence_layout(sequence: Sequence) -> StackLayout:
    """:func:`~acquisition.session.estimate_stream.stack_layout` of a sequence's own frame entries."""
    entries = sequence.frames
    roles, levels = [e.role for e in entries], [e.led_levels for e in entries]
    return stack_layout(sequence, roles, levels, [e.exposure_us * e.gain for e in entries])


def frame_stack(layout: StackLayout, pixels: Callable[[int], np.ndarray]) -> FrameStack:
    """A :class:`FrameStack` of the first ambient frame and every LED frame of ``layout`` (``pixels(index)``),
    linearised by black and white levels and 1 / (exposure · gain)."""
    return FrameStack(
        pixels(layout.ambient_index),
        tuple(pixels(i) for i in layout.led_indices),
        layout.spec,
        layout.ambient_index,
        layout.led_indices,
    )


DEFAULT_BIN_FACTOR = 8
"""Block size summed before estimation: the model is linear so block sums obey it exactly, and the
noise of the LED-only images (which biases the weights) drops by its square (the authors' code
downsamples by 4). Frames that keep fewer
than :data:`BLOCKS_PER_SIDE` blocks on their short side use smaller ones (:func:`block_factor`).
Why 8, and what 4 × 4 blocks changed on large frames: docs/block-size.md."""

BLOCKS_PER_SIDE = 32
"""A frame's short side (of its CFA planes) keeps at least this many blocks, or the blocks are halved,
down to 4 × 4 (docs/block-size.md)."""


def block_factor(shape: tuple[int, ...], cfa: str | None, bin_factor: int = DEFAULT_BIN_FACTOR) -> int:
    """The block side the statistics sum for a frame of ``shape`` (docs/block-size.md).

    ``bin_factor`` made even (an odd block has no half-difference noise probe: its estimate is solved
    on the moments as observed, biased towards zero weights); halved, not below 4, while the frame's
    short side (of its CFA planes) keeps fewer than :data:`BLOCKS_PER_SIDE` blocks; then halved until it
    keeps at least 8, so that tiny frames still give enough samples; at least 1. ``1`` (every pixel,
    no noise probe) is kept when asked for.

    Examples
    --------
    >>> block_factor((1024, 1280, 3), None), block_factor((128, 160, 3), None), block_factor((128, 160), "RGGB")
    (8, 4, 4)
    >>> block_factor((1024, 1280, 3), None, 5), block_factor((1024, 1280, 3), None, 1)
    (4, 1)
    >>> [block_factor((106, 112), "RGGB", factor) for factor in (6, 10, 12, 1000)]
    [4, 4, 4, 4]
    """
    period = 2 if cfa is not None else 1
    side = min(shape[:2]) // period

    def even(factor: int) -> int:  # an odd block has no noise probe: 1000 halved to 125, or 6 to 3, lost it
        return factor - 1 if factor > 1 and factor % 2 else factor

    bin_factor = even(bin_factor)
    while bin_factor > 4 and side // bin_factor < BLOCKS_PER_SIDE:
        bin_factor = max(4, even(bin_factor // 2))
    while bin_factor > 1 and side // bin_factor < 8:
        bin_factor = even(bin_factor // 2)
    return max(bin_factor, 1)


def estimate_sequence(
    sequence: Sequence,
    method: str = "tikhonov",
    alpha: float | str = "auto",
    bin_factor: int = DEFAULT_BIN_FACTOR,
    stream: EstimateStream | None = None,
) -> AmbientEstimate:
    """Estimate the ambient illuminant of a sequence (eq. 4–6): its frames fed from disk, one at a time, to
    the one accumulator (:func:`~acquisition.session.estimate_stream.stream_sequence`), or ``stream`` when
    the frames were already fed (a capture's)."""
    stream = stream or stream_sequence(sequence, bin_factor)
    return stream.estimate(method, alpha)


def estimate_from_statistics(
    sequence: Sequence,
    statistics: SequenceStatistics,
    method: str = "tikhonov",
    alpha: float | str = "auto",
    model: AmbientModel | None = None,
) -> AmbientEstimate:
    """The ambient estimate of a sequence's statistics (eq. 4–6) with the LED model's band: the one place
    every route (from disk, live, replay) estimates. ``model``: one prepared for the sequence's LEDs (a
    live session prepares it before the first frame), else made here."""
    statistics, check = flicker_corrected(sequence, statistics)
    if model is None:
        estimate = estimate_ambient(statistics, led_spectra_photons(sequence), method, alpha)
    else:
        estimate = model.estimate(statistics, method, alpha)
    return reported(estimate, sequence, check)


def reported(estimate: AmbientEstimate, sequence: Sequence, check: FlickerCheck) -> AmbientEstimate:
    """The estimate as reported: the LED model's band (:func:`with_model_band`) and the flicker ``check`` its
    statistics were corrected by."""
    return replace(with_model_band(estimate, sequence), flicker=check)


def flicker_corrected(sequence: Sequence, statistics: SequenceStatistics) -> tuple[SequenceStatistics, FlickerCheck]:
    """The statistics with each LED frame's ambient gain taken out where flicker is detected, and the check
    (:func:`flicker_check`): what every estimate of a sequence, and a live flash decision, is made from."""
    check = flicker_check(sequence, statistics)
    if check.corrected and check.applied_offsets is not None:
        statistics = with_ambient_gains(statistics, check.applied_offsets)
    return statistics, check


def flicker_check(sequence: Sequence, statistics: SequenceStatistics) -> FlickerCheck:
    """Each LED frame's ambient gain read from the statistics' colours, and whether to correct for it
    (:func:`processing.flicker.check_flicker`); the mains fitted to the gains where frames carry timestamps."""
    responsivities = sequence.camera_responsivities()
    channels_of = plane_channels(sequence.camera.cfa) if statistics.channels is not None else None
    stack = [i for i, e in enumerate(sequence.frames) if e.role == "led"]
    levels = np.array([sequence.frames[i].led_levels for i in stack], dtype=float)
    if not stack or levels.shape[1] != statistics.n_leds:  # a header written so far (a live capture): one LED a frame
        levels = np.eye(statistics.n_leds)
    check = check_flicker(
        statistics,
        led_spectra_photons(sequence),
        None if responsivities is None else responsivities.to_unit("photons"),
        channels_of,
        levels,
    )
    return with_mains_fit(check, sequence)


def synthesize_checked(
    sequence: Sequence, flash_weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray, StackLayout, FlickerCheck | None]:
    """The computational flash image of a sequence on disk and the flicker check it was corrected by (None
    without camera responsivities), each frame read once (``msflash synthesize``, :func:`msflash.synthesize_flash`).

    Each frame feeds both the check's statistics and the synthesis sum; where the check corrects, the ambient's
    extra share is taken out of the sum after the pass (the correction is linear,
    :func:`processing.flicker.applied_offsets`). The image is :func:`synthesize_sequence`'s with the same check,
    bit for bit where nothing is corrected, to one float32 step where it is. Peak memory and speed:
    docs/measurements-acquisition.md.
    """
    layout = sequence_layout(sequence)
    checked = sequence.camera_responsivities() is not None
    order = (layout.ambient_index, *layout.led_indices)
    waiting: dict[int, np.ndarray] = {}  # frames read, not yet summed (LED frames before the ambient)
    summed: SynthesisStream | None = None
    ambient: np.ndarray | None = None

    def read(index: int) -> np.ndarray:
        nonlocal summed, ambient
        frame = sequence.load_frame(index)
        waiting[index] = frame
        while summed is None or summed.added < len(order):
            position = 0 if summed is None else summed.added
            if order[position] not in waiting:
                break
            next_frame = waiting.pop(order[position])
            if summed is None:
                summed = SynthesisStream(layout.spec, flash_weights, next_frame.shape)
                ambient = next_frame if checked else None
            try:
                summed.add(next_frame)
            except SpectralDataError as err:
                raise RecordingError(f"{sequence.path}: frames[{order[position]}]: {err}") from err
        return frame

    flicker = None
    if checked:
        flicker = flicker_check(sequence, stream_sequence(sequence, DEFAULT_BIN_FACTOR, pixels=read).statistics())
    else:
        for index in order:
            read(index)
    assert summed is not None
    offsets = applied_offsets(flicker)
    try:
        if offsets is not None:
            assert ambient is not None
            summed.take_out_ambient_share(ambient, offsets)
        ambient = None  # the raw ambient frame let go before the float32 image is made
        image, saturated = summed.result()
    except SpectralDataError as err:
        raise RecordingError(f"{sequence.path}: {err}") from err
    return image, saturated, layout, flicker


def with_mains_fit(check: FlickerCheck, sequence: Sequence) -> FlickerCheck:
    """``check`` with the mains fitted to its frame gains at the frames' timestamps, where ``sequence`` records them
    (a capture's estimate is made from a header without frames: the run fits again on the sequence it wrote)."""
    stack = [i for i, e in enumerate(sequence.frames) if e.role == "led"]
    ambient = next((i for i, e in enumerate(sequence.frames) if e.role == "ambient"), None)
    order = [] if ambient is None else [ambient, *stack]
    stamps = [sequence.frames[i].extra.get("timestamp_ns") for i in order]
    if order and all(isinstance(v, int | float) and not isinstance(v, bool) for v in stamps):
        check = with_fit(
            check,
            np.array(stamps, dtype=float) * 1e-9,
            np.array([sequence.frames[i].exposure_us for i in order]) * 1e-6,
        )
    return check


def with_model_band(estimate: AmbientEstimate, sequence: Sequence) -> AmbientEstimate:
    """The estimate with the LED model's error in its band and miss risk in its warnings
    (:mod:`processing.model_error`); as it is when the sequence carries no camera responsivities."""
    if sequence.camera_responsivities() is None:
        return estimate
    return with_model_error(
        estimate, reference_for(led_spectra_photons(sequence), camera_responsivities_photons(sequence))
    )


def estimate_payload(sequence: Sequence, estimate: AmbientEstimate) -> dict:
    """The ``msflash estimate --json`` object (docs/architecture.md §7)."""
    spectrum = spectrum_in_sequence_unit(sequence, estimate.spectrum)

    def in_unit(values: np.ndarray) -> np.ndarray:
        return spectrum_in_sequence_unit(sequence, estimate.spectrum.replace(values=np.asarray(values)[:, None]))

    std = in_unit(estimate.spectrum_std)
    return {
        "sequence": str(sequence.directory),
        "wavelengths_nm": sequence.wavelengths_nm,
        "spectral_unit": sequence.spectral_unit,
        "spectrum": spectrum,
        "spectrum_std": std,
        "spectrum_std_noise": in_unit(estimate.noise_std if estimate.noise_std is not None else estimate.spectrum_std),
        "band": estimate.band_meaning,
        "miss_risk": estimate.miss_risk,
        "expected_ratio_to_led_bound": estimate.expected_ratio,
        "model_misfit": estimate.model_misfit,
        "ambient_weights": estimate.ambient_weights,
        "led_names": [led.name for led in sequence.leds],
        "method": "global",
        "solver": estimate.method,
        "alpha": estimate.alpha,
        "relative_residual": estimate.relative_residual,
        "residual_rms": estimate.residual_rms,
        "condition_number": estimate.condition_number,
        "n_samples": estimate.n_samples,
        "saturated_fraction": estimate.saturated_fraction,
        "warnings": list(estimate.warnings),
        "noise_correction": estimate.noise_correction,
        "sample_weights": "inverse noise variance" if estimate.weighted else "uniform",
        "flicker": None if estimate.flicker is None else estimate.flicker.to_dict(),
        "complete": sequence.complete,
    }


def solve_sequence_flash(
    sequence: Sequence, mode: str, ambient_weights: np.ndarray, target: str = "D65", bounds: FlashBounds = "physical"
) -> FlashSolution:
    """The matching or complementary flash for a sequence's estimated ambient weights.

    Raises
    ------
    RecordingError
        An unknown mode, or a mono camera's sequence (its three channels one: no colour to match or complement).
    """
    if is_mono(sequence):
        raise RecordingError(
            f"{sequence.path}: camera {sequence.camera.model} is mono ({sequence.camera.extra['channels']}): the flash "
            "matches or complements the ambient's colour, which one channel does not see; expected a colour camera's "
            "sequence (`msflash estimate` gives a mono sequence's ambient)"
        )
    leds = led_spectra_photons(sequence)
    camera = camera_responsivities_photons(sequence)
    if mode == "matching":
        return solve_matching(ambient_weights, leds, camera, bounds=bounds)
    if mode == "complementary":
        return solve_complementary(ambient_weights, leds, camera, target_illuminant(target, sequence), bounds=bounds)
    raise RecordingError(f"flash mode '{mode}' is unknown; expected matching or complementary")


def flash_payload(sequence: Sequence, solution: FlashSolution, target: str | None) -> dict:
    """The ``msflash flash --json`` object (docs/architecture.md §7)."""
    payload = {
        "sequence": str(sequence.directory),
        "mode": solution.mode,
        "led_names": [led.name for led in sequence.leds],
        "ambient_weights": solution.ambient_weights,
        "flash_weights": solution.flash_weights,
        "bounds": solution.bounds,
        "relative_error": solution.relative_error,
        "target_reached": solution.target_reached,
        "warnings": list(solution.warnings),
    }
    if solution.mode == "complementary":
        payload["scale"] = solution.scale
        payload["target"] = target
    return payload


def synthesize_sequence(
    sequence: Sequence, flash_weights: np.ndarray, stack: FrameStack | None = None, flicker: FlickerCheck | None = None
) -> tuple[np.ndarray, np.ndarray, StackLayout]:
    """The computational flash image ``m_a + Σ w_k m_f,k`` of a sequence (linear, per µs·gain), its saturated
    pixels and the frames it used.

    Without ``stack`` the frames are read from disk one at a time into a
    :class:`~processing.synthesis.SynthesisStream` (the ambient frame first, then the LED frames in order):
    peak memory the float64 sum and one frame, and the image of :func:`processing.synthesis.synthesize`
    on the stack, bit for bit. With an estimate's ``flicker`` check that corrected the LED images, the
    ambient's extra share in them is taken out of the image too (:func:`processing.flicker.applied_offsets`).
    """
    offsets = applied_offsets(flicker)
    if stack is not None:
        image, saturated = synthesize(
            stack.ambient, stack.led_frames, stack.spec, flash_weights, ambient_offsets=offsets
        )
        return image, saturated, StackLayout(stack.spec, stack.ambient_index, stack.led_indices)
    layout = sequence_layout(sequence)
    summed: SynthesisStream | None = None
    for index in (layout.ambient_index, *layout.led_indices):
        frame = sequence.load_frame(index)
        if summed is None:
            summed = SynthesisStream(layout.spec, flash_weights, frame.shape, ambient_offsets=offsets)
        try:
            summed.add(frame)
        except SpectralDataError as err:
            raise RecordingError(f"{sequence.path}: frames[{index}]: {err}") from err
        del frame
    assert summed is not None
    image, saturated = summed.result()
    return image, saturated, layout
