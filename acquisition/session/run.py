"""The capture and run sessions behind ``msflash capture`` and ``msflash run`` (docs/architecture.md §5.1).

``capture``: exposures planned for the rig, then ambient + each LED in one plan. ``run``: the same,
with the flash decided from the frames in memory and re-captured in the same stream
(:func:`run_one_stream`), or — on a replay rig, which checks every plan against its recording up
front — as a second capture (:func:`run_two_captures`). The command line (``app/cli_run.py``)
parses options into a :class:`RunOptions`, opens the rig and reports; everything between is here.
"""

from __future__ import annotations

import logging
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.devices.replay_camera import format_levels, levels_match
from msflash.acquisition.errors import UsageError
from msflash.acquisition.plan import CapturePlan, StepRole, TriggerSource
from msflash.acquisition.progress import count, progress
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.format import Sequence, SequenceFrame, SequenceWriter, read_sequence
from msflash.acquisition.session import analysis
from msflash.acquisition.session.capture import FrameWriter, preview_frames, run_capture, run_capture_with_flash
from msflash.acquisition.session.exposure import (
    ExposurePlan,
    ExposurePolicy,
    FlashEnergyWarning,
    camera_exposure_range,
    camera_noise_model,
    flash_exposure,
    format_led_snr,
    led_snr_warnings,
    measure_led_snr,
    metering_view,
    plan_exposures,
    whole_pwm_periods,
)
from msflash.acquisition.session.flash_session import FlashSession
from msflash.acquisition.session.rig import Rig
from msflash.processing.ambient import AmbientEstimate
from msflash.processing.errors import TargetUnreachableWarning

log = logging.getLogger(__name__)

SYNC_MODES: dict[str, TriggerSource] = {"host": "software", "booth": "booth", "camera": "camera"}
"""``--sync`` names and the plan trigger each stands for."""


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
    if hasattr(flicker, "to_dict"):  # a simulated lamp's mains flicker (docs/flicker.md)
        msflash["true_flicker"] = flicker.to_dict()
    return rig.sequence_writer(out / "sequence", extra={"msflash": msflash})


def report_frame(step, frame, entry, total: int | None = None) -> None:
    """One line per frame written; given the plan's ``total`` steps, a bar on a terminal instead."""
    note = f"captured step {step.index} ({step.label}) → {entry.file}"
    if entry.extra.get("retake"):
        note += f" (retake {entry.extra['retake']}, after a lost frame)"
    if total is None:
        progress(note)
    else:
        count("capture", step.index + 1, total, "frame", note)


@dataclass(frozen=True)
class Recorded:
    """A replay rig's recorded exposures and gains: replay must ask for exactly those."""

    ambient_us: float
    led_us: tuple[float, ...]
    flash_us: float | None
    """None when the recording has no flash frame (a sequence from ``msflash capture``)."""
    ambient_gain: float
    led_gains: tuple[float, ...]
    flash_gain: float
    flash_levels: tuple[float, ...] | None = None
    """The recorded flash frame's LED levels (None without one)."""


def recording_of(rig: Rig) -> Recorded | None:
    """What a replay rig's recording holds (None for other rigs)."""
    sequence = getattr(rig.camera, "sequence", None)
    if sequence is None or not rig.name.startswith("replay:"):
        return None
    ambient = sequence.indices("ambient")
    leds = sequence.indices("led")
    flash = sequence.indices("flash")
    if not ambient:
        return None
    frames = sequence.frames
    return Recorded(
        frames[ambient[0]].exposure_us,
        tuple(frames[i].exposure_us for i in leds),
        frames[flash[0]].exposure_us if flash else None,
        frames[ambient[0]].gain,
        tuple(frames[i].gain for i in leds),
        frames[flash[0]].gain if flash else 1.0,
        tuple(frames[flash[0]].led_levels) if flash else None,
    )


def plan_exposure(rig: Rig, exposure_option: str | float, policy: ExposurePolicy) -> ExposurePlan:
    """``--exposure``: fixed, the replay's recording, the fake's suggestion, or metered previews (auto)."""
    n_leds = rig.led_spectra.count
    limits = camera_exposure_range(rig.camera)
    noise = camera_noise_model(rig.camera)
    method = "photon+read noise" if noise is not None else "difference image"
    nan = (float("nan"),) * n_leds
    if exposure_option != "auto":
        exposure = float(exposure_option)
        if not limits[0] <= exposure <= limits[1]:
            raise UsageError(f"--exposure {exposure:g}: outside the camera's range {limits[0]:g}–{limits[1]:g} µs")
        return ExposurePlan(exposure, (exposure,) * n_leds, nan, method, limits, policy, mode="fixed")
    recorded = recording_of(rig)
    if recorded is not None and len(recorded.led_us) == n_leds:
        return ExposurePlan(
            recorded.ambient_us,
            recorded.led_us,
            nan,
            method,
            limits,
            policy,
            mode="recorded",
            ambient_gain=recorded.ambient_gain,
            led_gains=recorded.led_gains,
        )
    suggested = float(getattr(rig.camera, "suggested_exposure_us", None) or 10_000.0)
    progress(
        f"auto exposure: metering ambient previews (≤ {policy.max_saturated_fraction:.2%} saturated, "
        f"bright end at {policy.target_fraction:.0%} of full scale)"
    )
    info = rig.camera.info

    def capture(levels, exposure_us: float):
        role: StepRole = "led" if any(level > 0 for level in levels) else "ambient"
        preview = CapturePlan.single(levels, exposure_us, role=role)
        return metering_view(preview_frames(rig.camera, rig.booth, preview)[0].pixels, mosaic=info.cfa is not None)

    return plan_exposures(
        capture,
        n_leds,
        info.black_level,
        info.white_level,
        limits,
        noise,
        policy,
        start_us=suggested,
        cfa=info.cfa is not None,
        led_names=list(rig.led_spectra.names),
    )


def report_exposure(plan: ExposurePlan, names: list[str]) -> None:
    progress(
        f"exposure ({plan.mode}): ambient {plan.ambient_exposure_us:.0f} µs; LEDs "
        + ", ".join(f"{n} {e:.0f}" for n, e in zip(names, plan.led_exposures_us))
        + " µs"
    )
    if plan.mode == "auto":
        progress(f"planned LED SNR ({plan.snr_method}, median pixel): " + format_led_snr(names, plan.predicted_snr))
    for note in plan.warnings:
        progress(f"warning: {note}")


@dataclass
class LedCapture:
    """The ambient + LED frames as captured, kept in memory for estimation (no re-read from disk)."""

    plan: ExposurePlan
    frames: list[RawFrame]
    entries: list[SequenceFrame]
    last_frame_at: float
    """``time.perf_counter()`` when the last LED frame was handed over (written)."""
    snr: list[float]
    snr_method: str
    snr_warnings: tuple[str, ...] = ()
    """One per LED whose measured SNR is no measurement (no LED signal; :func:`led_snr_warnings`)."""


def capture_led_sequence(rig: Rig, writer: FrameWriter, plan: ExposurePlan, sync: str = "host") -> LedCapture:
    frames: list[RawFrame] = []
    stamp = {"t": 0.0}

    def keep(step, frame, entry) -> None:
        frames.append(frame)
        stamp["t"] = time.perf_counter()
        report_frame(step, frame, entry, len(capture_plan.steps))

    capture_plan = CapturePlan.ambient_then_each_led(
        len(writer.sequence.leds),
        plan.ambient_exposure_us,
        gain=plan.ambient_gain,
        led_exposures_us=plan.led_exposures_us,
        led_gains=plan.led_gains,
        trigger=SYNC_MODES[sync],
    )
    entries = run_capture(rig.camera, rig.booth, capture_plan, writer, on_frame=keep)
    return led_capture(rig, writer, plan, frames, entries, stamp["t"])


def led_capture(
    rig: Rig, writer, plan: ExposurePlan, frames: list[RawFrame], entries: list[SequenceFrame], last_frame_at: float
) -> LedCapture:
    """The LED frames with their measured SNR (reported)."""
    info = rig.camera.info
    pixels = [metering_view(f.pixels, mosaic=info.cfa is not None) for f in frames]
    snr, method = measure_led_snr(
        pixels[0],
        frames[0].exposure_us,
        pixels[1:],
        [f.exposure_us for f in frames[1:]],
        info.black_level,
        info.white_level,
        camera_noise_model(rig.camera),
        cfa=info.cfa is not None,
        gain=frames[0].gain,
    )
    names = [led.name for led in writer.sequence.leds]
    progress(f"LED SNR ({method}, median pixel): " + format_led_snr(names, snr))
    warned = tuple(led_snr_warnings(names, snr, "measured SNR"))
    for note in warned:
        progress(f"warning: {note}")
    return LedCapture(plan, frames, entries, last_frame_at, snr, method, warned)


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


def solve_both(solve, weights: np.ndarray, first: str) -> tuple[dict, list]:
    """Both flashes (``first`` solved first), with the TargetUnreachable warnings recorded."""
    solutions = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        for mode in (first, *(m for m in ("matching", "complementary") if m != first)):
            solutions[mode] = solve(mode, weights)
    return solutions, list(caught)


def run_one_stream(
    rig: Rig,
    writer: AsyncSequenceWriter,
    exposure: ExposurePlan,
    options: RunOptions,
    on_frame: Callable[..., None] | None = None,
):
    """Ambient + LEDs + flash in one stream, the flash decided from the frames in memory.

    ``on_frame(step, frame, entry)`` is called as each frame lands (the flash frame too), after it is
    queued for writing: ``msflash live`` shows the sequence's progress with it.
    """
    auto = exposure.mode == "auto"  # then the session predicts the flash exposure from the frames as they arrive
    session = FlashSession.prepare(
        writer.sequence,
        options.target,
        options.solver,
        options.alpha,
        options.bin_factor,
        exposure_limits_us=exposure.exposure_range_us if auto else None,
        exposure_policy=exposure.policy,
    )
    n_leds = len(writer.sequence.leds)
    frames: list[RawFrame] = []
    stamp = {"t": 0.0, "decided": 0.0}
    result: dict = {}

    def keep(step, frame, entry) -> None:
        if step.role != "flash":
            session.add(frame, step.role, step.led_levels)
            frames.append(frame)
            stamp["t"] = time.perf_counter()
        report_frame(step, frame, entry, n_leds + 2)  # ambient, the LEDs, the flash
        if on_frame is not None:
            on_frame(step, frame, entry)

    def decide(_frames):
        # As the capture bench: FlashSession.decide, the estimate's reliability signals left for
        # after the flash trigger (``decision.estimate`` is read once the capture is over).
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TargetUnreachableWarning)
            if options.from_disk:
                sequence = read_sequence(writer.flush().directory)
                stack = analysis.load_frame_stack(sequence)
                estimate = analysis.estimate_sequence(
                    sequence, options.solver, options.alpha, stack=stack, bin_factor=options.bin_factor
                )
                chosen = session.solve(options.mode, estimate.ambient_weights)
                levels = np.clip(chosen.flash_weights, 0.0, 1.0)
                result.update(chosen=chosen, stack=stack)
            else:
                decision = session.decide(options.mode)
                levels = decision.levels
                result.update(chosen=decision.solution)
        with warnings.catch_warnings(record=True) as flash_caught:
            warnings.simplefilter("always", FlashEnergyWarning)
            flash_us = flash_exposure_for(rig, exposure, levels, session.flash_exposure, options.sync)
        result.update(caught=[*caught, *flash_caught], flash_us=flash_us)
        stamp["decided"] = time.perf_counter()
        return levels, flash_us

    plan = CapturePlan.ambient_then_each_led(
        n_leds,
        exposure.ambient_exposure_us,
        led_exposures_us=exposure.led_exposures_us,
        trigger=SYNC_MODES[options.sync],
    )
    entries = run_capture_with_flash(rig.camera, rig.booth, plan, writer, decide, on_frame=keep)
    if "stack" not in result:
        # The report's frames as the sequence records them (a mono camera's as three identical
        # channels), as for two captures; the session's own stack holds a mono frame's one plane.
        result["stack"] = analysis.load_frame_stack(writer.flush(), [frame.pixels for frame in frames])
    estimate = reported_estimate(writer.flush(), result["stack"], options)
    other = "matching" if options.mode == "complementary" else "complementary"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        solutions = {options.mode: result["chosen"], other: session.solve(other, estimate.ambient_weights)}
    captured = led_capture(rig, writer, exposure, frames, list(entries[:-1]), stamp["t"])
    flash_entry = entries[-1]
    return (
        estimate,
        solutions,
        result["caught"] + list(caught),
        captured,
        flash_entry.exposure_us,
        result["stack"],
        stamp["decided"],
    )


def reported_estimate(sequence: Sequence, stack: analysis.FrameStack, options: RunOptions) -> AmbientEstimate:
    """The estimate a run reports: the sequence's, by :func:`analysis.estimate_sequence` on its frames.

    The one route every command takes (``msflash estimate SEQ`` gives the same numbers, bit for bit).
    The one-stream run decided its flash earlier, from the block sums :class:`FlashSession` took as the
    frames arrived: the same statistics summed in another order, whose weights agree with these to
    rounding (about 1e-11 relative); the flash it re-captured is that decision's.
    """
    return analysis.estimate_sequence(
        sequence, options.solver, options.alpha, stack=stack, bin_factor=options.bin_factor
    )


def run_two_captures(rig: Rig, writer: AsyncSequenceWriter, exposure: ExposurePlan, options: RunOptions):
    """LED sequence, then the flash as a second capture (replay rigs: plans are checked up front)."""
    captured = capture_led_sequence(rig, writer, exposure, options.sync)
    sequence = writer.flush()
    if options.from_disk:
        sequence = read_sequence(writer.path.parent)
        stack = analysis.load_frame_stack(sequence)
    else:
        stack = analysis.load_frame_stack(sequence, [frame.pixels for frame in captured.frames])
    estimate = analysis.estimate_sequence(
        sequence, options.solver, options.alpha, stack=stack, bin_factor=options.bin_factor
    )
    solutions, caught = solve_both(
        lambda mode, weights: analysis.solve_sequence_flash(sequence, mode, weights, options.target),
        estimate.ambient_weights,
        options.mode,
    )
    levels = np.clip(solutions[options.mode].flash_weights, 0.0, 1.0)
    recorded = recording_of(rig)
    if exposure.mode == "recorded" and recorded is not None and recorded.flash_us is None:
        progress(
            "the recording has no flash frame (a sequence from 'msflash capture'): the flash is synthesised "
            "from the frames, not re-captured"
        )
        return estimate, solutions, caught, captured, None, stack, time.perf_counter()
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
        return estimate, solutions, caught, captured, None, stack, time.perf_counter()
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
    caught = [*caught, *flash_caught]
    flash_gain = recorded.flash_gain if exposure.mode == "recorded" and recorded is not None else 1.0
    flash_plan = CapturePlan.single(levels, flash_us, gain=flash_gain, trigger=SYNC_MODES[options.sync])
    decided = time.perf_counter()
    run_capture(rig.camera, rig.booth, flash_plan, writer, on_frame=report_frame)
    return estimate, solutions, caught, captured, flash_us, stack, decided


def flash_exposure_for(
    rig: Rig, plan: ExposurePlan, levels: np.ndarray, predict: Callable[[np.ndarray], float], sync: str = "host"
) -> float:
    """The flash frame's exposure: fixed, recorded (replay), or ``predict(levels)`` from the frames in memory.

    A predicted exposure for a booth that dims by PWM here (host paced, or a booth without pulse
    dimming) is made whole PWM periods, or a :class:`FlashEnergyWarning` gives the energy error
    (:func:`~acquisition.session.exposure.whole_pwm_periods`).
    """
    if plan.mode != "auto":
        recorded = recording_of(rig)
        if plan.mode == "recorded" and recorded is not None and recorded.flash_us is not None:
            return recorded.flash_us
        return plan.ambient_exposure_us
    exposure_us = predict(levels)
    info = getattr(rig.booth, "info", None)
    pwm_hz = getattr(info, "pwm_hz", None)
    if pwm_hz is None or (sync in ("booth", "camera") and getattr(info, "pulse_dimming", False)):
        return exposure_us
    chosen, note = whole_pwm_periods(
        exposure_us, [float(v) for v in levels], pwm_hz, plan.exposure_range_us, plan.policy
    )
    if note is not None:
        warnings.warn(note, FlashEnergyWarning, stacklevel=2)
    elif chosen != exposure_us:
        log.info(
            "flash exposure %.0f µs → %.0f µs: whole periods of the booth's %g Hz PWM", exposure_us, chosen, pwm_hz
        )
    return chosen
