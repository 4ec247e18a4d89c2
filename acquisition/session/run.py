"""The capture and run sessions behind ``msflash capture`` and ``msflash run`` (docs/architecture.md §5.1).

``capture``: exposures planned for the rig (:mod:`~acquisition.session.run_exposure`), then
ambient + each LED in one plan. ``run``: the same, with the flash decided from the frames in memory
and re-captured in the same stream (:func:`run_one_stream`), or — on a replay rig, which checks
every plan against its recording up front — as a second capture (:func:`run_two_captures`). Both
run the capture engine (:mod:`~acquisition.session.capture`) with frame handlers: the flash session
(:class:`~acquisition.session.flash_session.FlashSession`, statistics as frames arrive), the run's
flash decision (:class:`StreamFlash`), :class:`ProgressLines` and whatever the caller adds (the
live page). The command line (``app/cli_run.py``) parses options into a :class:`RunOptions`, opens
the rig and reports; everything between is here.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence as Seq
from dataclasses import dataclass, replace
from pathlib import Path
from warnings import WarningMessage

import numpy as np

from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.devices.mains_flicker import MainsFlicker
from msflash.acquisition.devices.replay_camera import format_levels, levels_match
from msflash.acquisition.errors import UsageError
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.acquisition.progress import count, progress
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.format import Sequence, SequenceFrame
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import SequenceWriter, as_recorded
from msflash.acquisition.session import analysis
from msflash.acquisition.session.both_flashes import SequenceFlashes, solve_both
from msflash.acquisition.session.capture import FrameWriter, run_capture, run_capture_with_flash
from msflash.acquisition.session.engine import Cancellation, CaptureResult, FlashChoice, FrameEvent, FrameHandler
from msflash.acquisition.session.estimate_stream import EstimateStream, stream_sequence
from msflash.acquisition.session.exposure import (
    ExposurePlan,
    ExposurePolicy,
    FlashEnergyWarning,
)
from msflash.acquisition.session.flash_session import FlashDecision, FlashSession
from msflash.acquisition.session.metering import flash_exposure, metering_view
from msflash.acquisition.session.rig import Rig
from msflash.acquisition.session.run_exposure import (
    SYNC_MODES,
    LedCapture,
    flash_exposure_for,
    led_capture,
    plan_exposure,
    recording_of,
    report_exposure,
)
from msflash.processing.ambient import AmbientEstimate
from msflash.processing.errors import TargetUnreachableWarning
from msflash.processing.flash import FlashSolution


@dataclass(frozen=True)
class RunOptions:
    """What ``msflash run`` decides with: the flash mode and target, the estimator, the pacing."""

    mode: str = "complementary"
    """The flash re-captured: ``matching`` (eq. 7) or ``complementary`` (eq. 8-9)."""
    target: str = "D65"
    """The complementary target: an illuminant name or a CSV file."""
    solver: str = "tikhonov"
    alpha: float | str = "auto"
    bin_factor: int = analysis.DEFAULT_BIN_FACTOR
    sync: str = "host"
    """``host``, ``booth`` or ``camera`` (docs/architecture.md §4)."""
    from_disk: bool = False
    """Re-read the frames from disk before deciding the flash (a check of the in-memory route)."""


@dataclass(frozen=True)
class RunResult:
    """What a run (:func:`run_one_stream`, :func:`run_two_captures`) leaves for its report."""

    estimate: AmbientEstimate
    """The reported estimate: the statistics accumulated as the frames arrived
    (:class:`~acquisition.session.estimate_stream.EstimateStream`), what ``msflash estimate`` gives for
    the sequence written, to the last digit."""
    solutions: dict[str, FlashSolution]
    """The matching and complementary flashes (:func:`~acquisition.session.both_flashes.solve_both`)."""
    warnings: tuple[WarningMessage, ...]
    """Warnings of the decision and the solves (target unreachable, flash energy), in order."""
    captured: LedCapture
    """The ambient + LED frames as captured, with their measured SNR."""
    flash_exposure_us: float | None
    """The flash frame's exposure as the camera read it back; None when the flash is synthesised only."""
    stack: analysis.FrameStack
    """The recorded frames the report synthesises from (in memory, as the reader would return them)."""
    decided_at: float
    """``time.perf_counter()`` when the flash was decided."""
    flash_frame: np.ndarray | None = None
    """The re-captured flash frame as recorded (in memory), for the report; None when synthesised only."""

    @property
    def decision_ms(self) -> float:
        """From the last LED frame to the flash decision, in milliseconds."""
        return (self.decided_at - self.captured.last_frame_at) * 1e3


def capture_sequence(
    rig: Rig, out: Path, exposure_option: str | float, policy: ExposurePolicy, sync: str = "host"
) -> Path:
    """``msflash capture``: plan the exposures, capture ambient + each LED into ``out/sequence``; its path."""
    exposure = plan_exposure(rig, exposure_option, policy)
    report_exposure(exposure, list(rig.led_spectra.names))
    with sequence_writer(rig, out, exposure) as sync_writer, AsyncSequenceWriter(sync_writer) as writer:
        capture_led_sequence(rig, writer, exposure, sync)
        writer.finish()
    return out / "sequence"


def sequence_writer(rig: Rig, out: Path, exposure: ExposurePlan | None = None) -> SequenceWriter:
    msflash: dict = {"rig": rig.name, "booth": rig.booth.info.firmware}
    if exposure is not None:
        msflash["exposure"] = exposure.to_dict()
    if rig.true_ambient is not None:
        # Ground truth of a simulated rig, on the sequence's grid and in its unit, for later scoring.
        truth = rig.true_ambient.resample(rig.led_spectra.grid).to_unit("energy")
        msflash["true_ambient"] = {"name": truth.names[0], "source": truth.source, "spd": truth.values[:, 0].tolist()}
    flicker = getattr(getattr(rig.camera, "world", rig.camera), "ambient_modulation", None)
    if isinstance(flicker, MainsFlicker):  # a simulated lamp's mains flicker (docs/flicker.md)
        msflash["true_flicker"] = flicker.to_dict()
    return rig.sequence_writer(out / "sequence", extra={"msflash": msflash})


def report_frame(step: CaptureStep, entry: SequenceFrame, total: int | None = None) -> None:
    """One line per frame written; given the plan's ``total`` steps, a bar on a terminal instead."""
    note = f"captured step {step.index} ({step.label}) → {entry.file}"
    if entry.extra.get("retake"):
        note += f" (retake {entry.extra['retake']}, after a lost frame)"
    if total is None:
        progress(note)
    else:
        count("capture", step.index + 1, total, "frame", note)


class ProgressLines:
    """A frame handler reporting each frame written (:func:`report_frame`), as a bar of ``total`` steps on a terminal."""

    def __init__(self, total: int | None = None) -> None:
        self.total = total

    def frame_ready(self, event: FrameEvent) -> None:
        if event.entry is not None:
            report_frame(event.step, event.entry, self.total)

    def sequence_finished(self, result: CaptureResult) -> None:
        """Nothing more to say: the last frame's line was the last."""


class LedFrames:
    """A frame handler keeping the ambient + LED frames in memory and when the last one was handed over."""

    def __init__(self) -> None:
        self.frames: list[RawFrame] = []
        self.flash: RawFrame | None = None
        """The last flash frame handed over, if any."""
        self.last_frame_at = 0.0
        """``time.perf_counter()`` when the last ambient or LED frame was handed over (written)."""

    def frame_ready(self, event: FrameEvent) -> None:
        if event.step.role == "flash":
            self.flash = event.frame
        else:
            self.frames.append(event.frame)
            self.last_frame_at = time.perf_counter()

    def sequence_finished(self, result: CaptureResult) -> None:
        """The frames are kept as they came."""


def capture_led_sequence(
    rig: Rig,
    writer: FrameWriter,
    plan: ExposurePlan,
    sync: str = "host",
    handlers: Seq[FrameHandler] = (),
    cancel: Cancellation | None = None,
) -> LedCapture:
    """Ambient + each LED at the planned exposures and gains, written by ``writer``; the frames with their SNR."""
    capture_plan = CapturePlan.ambient_then_each_led(
        len(writer.sequence.leds),
        plan.ambient_exposure_us,
        gain=plan.ambient_gain,
        led_exposures_us=plan.led_exposures_us,
        led_gains=plan.led_gains,
        trigger=SYNC_MODES[sync],
    )
    kept = LedFrames()
    entries = run_capture(
        rig.camera,
        rig.booth,
        capture_plan,
        writer,
        (kept, ProgressLines(len(capture_plan.steps)), *handlers),
        cancel=cancel,
    )
    names = [led.name for led in writer.sequence.leds]
    return led_capture(rig, names, plan, kept.frames, entries, kept.last_frame_at)


def check_colour_camera(rig: Rig, spec: str) -> None:
    """Refuse a run (``msflash run``, a sequence fired from the live view) on a mono camera: the flash matches or
    complements the ambient's colour, which one channel does not see (docs/decisions/mono-camera.md).

    Raises
    ------
    UsageError
        The rig's camera sends one value a pixel (:attr:`Rig.mono`), named with its pixel format.
    """
    if rig.mono:
        info = rig.camera.info
        raise UsageError(
            f"rig '{spec}': camera {info.model} sends {info.pixel_format}, one value a pixel: the flash matches or "
            "complements the ambient's colour, which one channel does not see; expected a colour camera (a Bayer or "
            "RGB pixel format); `msflash capture` and `msflash estimate` take a mono camera's sequence"
        )


def degenerate(estimate) -> str | None:
    """Why the estimate cannot be reported (non-finite numbers), or None."""
    checks = {
        "condition number": np.asarray(estimate.condition_number, dtype=float),
        "spectrum": np.asarray(estimate.spectrum.values, dtype=float),
        "ambient weights": np.asarray(estimate.ambient_weights, dtype=float),
        "spectrum uncertainty": np.asarray(estimate.spectrum_std, dtype=float),
    }
    bad = [name for name, values in checks.items() if not np.all(np.isfinite(values))]
    if not bad:
        return None
    return f"not finite: {', '.join(bad)}; condition number {float(estimate.condition_number):.3g}"


class StreamFlash(LedFrames):
    """The one-stream run's flash decision (a :class:`~acquisition.session.engine.FlashDecider`).

    A frame handler too: it keeps the ambient + LED frames (:class:`LedFrames`) while the
    :class:`FlashSession`, another handler, takes their statistics. :meth:`decide_flash` solves the
    ``options.mode`` flash from those statistics (or, with ``options.from_disk``, from the frames
    re-read from disk), predicts its exposure, and keeps what the run reports: the solution, the
    warnings raised (the estimate's reliability signals are left until read), the time decided.
    """

    def __init__(self, rig: Rig, writer: AsyncSequenceWriter, exposure: ExposurePlan, options: RunOptions) -> None:
        super().__init__()
        self.rig, self.writer, self.exposure, self.options = rig, writer, exposure, options
        auto = exposure.mode == "auto"  # then the session predicts the flash exposure from the frames as they arrive
        self.session = FlashSession.prepare(
            writer.sequence,
            options.target,
            options.solver,
            options.alpha,
            options.bin_factor,
            exposure_limits_us=exposure.exposure_range_us if auto else None,
            exposure_policy=exposure.policy,
        )
        self.chosen: FlashSolution | None = None
        self.decision: FlashDecision | None = None
        """The in-memory decision (its estimate is the one reported), unless ``from_disk``."""
        self.reread: EstimateStream | None = None
        """The frames re-read from disk and fed to a stream of their own (``from_disk``), else None."""
        self.warnings: tuple[WarningMessage, ...] = ()
        self.decided_at = 0.0

    def decide_flash(self) -> FlashChoice:
        """The flash levels and exposure from the frames taken (between the last LED frame and the flash)."""
        options = self.options
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TargetUnreachableWarning)
            if options.from_disk:
                sequence = read_sequence(self.writer.flush().directory)
                self.reread = stream_sequence(sequence, options.bin_factor)
                estimate = self.reread.estimate(options.solver, options.alpha)
                self.chosen = self.session.solve(options.mode, estimate.ambient_weights)
                levels = np.clip(self.chosen.flash_weights, 0.0, 1.0)
            else:
                # As the capture bench: the estimate's reliability signals are left for after the trigger.
                self.decision = self.session.decide(options.mode)
                levels, self.chosen = self.decision.levels, self.decision.solution
        with warnings.catch_warnings(record=True) as flash_caught:
            warnings.simplefilter("always", FlashEnergyWarning)
            flash_us = flash_exposure_for(self.rig, self.exposure, levels, self.session.flash_exposure, options.sync)
        self.warnings = (*caught, *flash_caught)
        self.decided_at = time.perf_counter()
        return FlashChoice(tuple(float(v) for v in levels), float(flash_us))


def _fitted(estimate: AmbientEstimate, recorded: Sequence) -> AmbientEstimate:
    """The estimate with the mains fitted to its flicker gains at the frames' timestamps: the live stream's header
    has no frames yet, the sequence written has (docs/flicker.md)."""
    if estimate.flicker is None:
        return estimate
    return replace(estimate, flicker=analysis.with_mains_fit(estimate.flicker, recorded))


def run_one_stream(
    rig: Rig,
    writer: AsyncSequenceWriter,
    exposure: ExposurePlan,
    options: RunOptions,
    handlers: Seq[FrameHandler] = (),
    cancel: Cancellation | None = None,
) -> RunResult:
    """Ambient + LEDs + flash in one stream, the flash decided from the frames in memory.

    Each frame goes to the flash session, the decision, the progress line and then ``handlers`` as it
    lands (the flash frame too), after it is queued for writing: ``msflash live`` shows the
    sequence's progress with one. ``cancel`` stops the capture between frames.
    """
    n_leds = len(writer.sequence.leds)
    flash = StreamFlash(rig, writer, exposure, options)
    plan = CapturePlan.ambient_then_each_led(
        n_leds,
        exposure.ambient_exposure_us,
        led_exposures_us=exposure.led_exposures_us,
        trigger=SYNC_MODES[options.sync],
    )
    handled: tuple[FrameHandler, ...] = (
        flash.session,
        flash,
        ProgressLines(n_leds + 2),
        *handlers,
    )  # ambient, the LEDs, the flash
    entries = run_capture_with_flash(rig.camera, rig.booth, plan, writer, flash, handled, cancel=cancel)
    assert flash.chosen is not None
    # The report's frames as the sequence records them (a mono camera's as three identical channels),
    # from memory; the reported estimate is the statistics accumulated as they arrived (no second pass).
    recorded = writer.flush()
    stack = analysis.load_frame_stack(recorded, [frame.pixels for frame in flash.frames])
    # The flicker check and the ambient weights are the decision's, not solved again.
    if flash.reread is not None:
        estimate = flash.reread.estimate(options.solver, options.alpha)
    else:
        assert flash.decision is not None
        estimate = _fitted(flash.decision.estimate, recorded)
    both = solve_both(flash.session, estimate.ambient_weights, options.mode, solved={options.mode: flash.chosen})
    names = [led.name for led in writer.sequence.leds]
    captured = led_capture(rig, names, exposure, flash.frames, list(entries[:-1]), flash.last_frame_at)
    return RunResult(
        estimate,
        both.solutions,
        (*flash.warnings, *both.warnings),
        captured,
        entries[-1].exposure_us,
        stack,
        flash.decided_at,
        None if flash.flash is None else as_recorded(flash.flash.pixels, recorded.camera.cfa),
    )


def run_two_captures(
    rig: Rig,
    writer: AsyncSequenceWriter,
    exposure: ExposurePlan,
    options: RunOptions,
    handlers: Seq[FrameHandler] = (),
    cancel: Cancellation | None = None,
) -> RunResult:
    """LED sequence, then the flash as a second capture (replay rigs: plans are checked up front).

    Both captures go through the capture engine's runner (:func:`run_capture`), each frame to
    ``handlers`` after the progress line."""
    statistics = EstimateStream(writer.sequence, len(writer.sequence.leds), options.bin_factor, live=True)
    captured = capture_led_sequence(rig, writer, exposure, options.sync, (statistics, *handlers), cancel)
    sequence = writer.flush()
    if options.from_disk:
        sequence = read_sequence(writer.path.parent)
        statistics = stream_sequence(sequence, options.bin_factor)
    stack = analysis.load_frame_stack(sequence, [frame.pixels for frame in captured.frames])
    estimate = _fitted(statistics.estimate(options.solver, options.alpha), sequence)
    both = solve_both(SequenceFlashes(sequence, options.target), estimate.ambient_weights, options.mode)
    solutions, caught = both.solutions, both.warnings
    levels = np.clip(solutions[options.mode].flash_weights, 0.0, 1.0)
    recorded = recording_of(rig)
    if exposure.mode == "recorded" and recorded is not None and recorded.flash_us is None:
        progress(
            "the recording has no flash frame (a sequence from 'msflash capture'): the flash is synthesised "
            "from the frames, not re-captured"
        )
        return RunResult(estimate, solutions, caught, captured, None, stack, time.perf_counter())
    if (
        exposure.mode == "recorded"
        and recorded is not None
        and recorded.flash_levels is not None
        and not levels_match(recorded.flash_levels, levels)
    ):
        # A recording made by another msflash version or with other options (--mode, --solver, --target…):
        # its flash frame is not this flash, and replay cannot capture another one.
        progress(
            f"the recording's flash frame has LED levels {format_levels(recorded.flash_levels)}, this run's "
            f"{options.mode} flash asks for {format_levels(levels)} (recorded with other options or another "
            "msflash version): the flash is synthesised from the frames, not replayed"
        )
        return RunResult(estimate, solutions, caught, captured, None, stack, time.perf_counter())
    frames = captured.frames
    info = rig.camera.info  # read once: on a real camera each read is several feature round trips
    pixels = [metering_view(f.pixels, mosaic=info.cfa is not None) for f in frames]
    with warnings.catch_warnings(record=True) as flash_caught:
        warnings.simplefilter("always", FlashEnergyWarning)
        flash_us = flash_exposure_for(
            rig,
            exposure,
            levels,
            lambda weights: flash_exposure(
                pixels[0],
                frames[0].exposure_us,
                pixels[1:],
                [f.exposure_us for f in frames[1:]],
                weights,
                info.black_level,
                info.white_level,
                exposure.exposure_range_us,
                exposure.policy,
            ),
            options.sync,
        )
    caught = (*caught, *flash_caught)
    flash_gain = recorded.flash_gain if exposure.mode == "recorded" and recorded is not None else 1.0
    flash_plan = CapturePlan.single(levels, flash_us, gain=flash_gain, trigger=SYNC_MODES[options.sync])
    decided = time.perf_counter()
    flash_kept = LedFrames()
    run_capture(rig.camera, rig.booth, flash_plan, writer, (flash_kept, ProgressLines(), *handlers), cancel=cancel)
    flash_frame = None if flash_kept.flash is None else as_recorded(flash_kept.flash.pixels, sequence.camera.cfa)
    return RunResult(estimate, solutions, caught, captured, flash_us, stack, decided, flash_frame)
