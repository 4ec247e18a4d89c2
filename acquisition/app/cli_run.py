"""``msflash run`` (the main job) and ``msflash capture`` on a rig.

``run``: capture ambient + each LED → estimate the ambient from the recorded sequence → solve the
matching and complementary flashes → re-capture with the chosen one (same sequence, role
``flash``) → synthesise both computational images → previews, a spectra plot and a report.

``--sync host|booth|camera`` picks who paces the frames (docs/architecture.md §4; :mod:`acquisition.session.capture`).

The flash is captured in the same stream as the LED frames
(:func:`acquisition.session.capture.run_capture_with_flash`): the estimate and the flash are computed
from the frames in memory by a :class:`acquisition.session.flash_session.FlashSession` prepared before
the sequence starts, as soon as the last LED frame arrives, and frames are written by a writer
thread (:class:`acquisition.sequence.async_writer.AsyncSequenceWriter`; all queued frames are written
before an error or Ctrl-C ends the command). A replay rig checks every plan against its
recording up front, so there the flash stays a second capture.

A degenerate estimate (the LED-only images do not determine the ambient: a non-finite condition
number, spectrum or weight — e.g. test patterns, or LEDs that do not reach the scene) does not stop the
capture: the flash the solvers return is still re-captured, so the sequence is complete. No
report is written from it (its numbers are not finite); ``run`` then exits 1 with one
``msflash: error:`` line saying so and where the sequence is.
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from msflash.acquisition.session import analysis
from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.folder_claim import FolderClaim, claim_folder
from msflash.acquisition.session.capture import preview_frames, run_capture, run_capture_with_flash
from msflash.acquisition.app.camera_options import add_camera_options, camera_options_from_args, given_camera_options
from msflash.acquisition.app.cli_common import UsageError, dumps_json, output_directory, progress
from msflash.acquisition.app.options import add_estimation_options
from msflash.acquisition.errors import CaptureError, OutputWriteError
from msflash.acquisition.session.flash_session import FlashSession
from msflash.acquisition.session.exposure import (
    ExposurePlan,
    ExposurePolicy,
    camera_exposure_range,
    camera_noise_model,
    flash_exposure,
    measure_led_snr,
    metering_view,
    plan_exposures,
)
from msflash.acquisition.plan import CapturePlan, TriggerSource
from msflash.acquisition.devices.replay_camera import format_levels, levels_match
from msflash.acquisition.session.rig import Rig, open_rig
from msflash.acquisition.devices.sim_world import SIM_DEFAULT_CAMERA, SIM_SCENES
from msflash.acquisition.sequence.format import (
    SequenceFrame,
    SequenceWriter,
    read_sequence,
)
from msflash.led_controller.booth import sigterm_as_exit
from msflash.processing.datasets import PAPER_LED_SUBSETS
from msflash.processing.errors import TargetUnreachableWarning
from msflash.processing.lights import AMBIENTS
from msflash.processing.user_files import printable

CFA_CHOICES = ("RGGB", "BGGR", "GRBG", "GBRG")
SYNC_MODES: dict[str, TriggerSource] = {"host": "software", "booth": "booth", "camera": "camera"}
"""``--sync`` names and the plan trigger each stands for."""


def _exposure_value(text: str) -> str | float:
    """``--exposure``: ``auto`` or a positive number of microseconds."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}': expected auto or an exposure in microseconds") from None
    if not (value > 0 and np.isfinite(value)):
        raise argparse.ArgumentTypeError(f"'{text}': expected a positive exposure in microseconds")
    return value


def _default_out() -> Path:
    return Path("runs") / datetime.now(UTC).strftime("%Y%m%d-%H%M%S")


def _rig_spec(args: argparse.Namespace) -> str:
    """The rig to open: ``--rig``, or ``hw`` when ``--camera``/``--port`` name real devices."""
    devices = args.camera is not None or args.port is not None
    if args.rig is None:
        return "hw" if devices else "sim"
    if devices and args.rig != "hw":
        raise UsageError(f"--rig {args.rig}: --camera/--port name hardware devices; expected --rig hw (or no --rig)")
    return args.rig


def _open(args: argparse.Namespace) -> Rig:
    spec = _rig_spec(args)
    world_options = [option for option, value in (("--sim-camera", args.sim_camera), ("--leds", args.leds),
                                                  ("--flash-power", args.flash_power)) if value is not None]
    if world_options and spec not in ("sim", "aravis-fake"):
        raise UsageError(f"{world_options[0]}: describes the simulated world, but the rig is '{spec}'; expected "
                         "--rig sim or aravis-fake (or no --rig and no --camera/--port)")
    if args.cfa is not None and spec != "sim":
        fixed = " (its frames are BayerRG16, an RGGB mosaic)" if spec == "aravis-fake" else ""
        raise UsageError(f"--cfa: describes the simulated rig's camera, but the rig is '{spec}'{fixed}; expected "
                         "--rig sim (or no --rig and no --camera/--port)")
    hw_only = [option for option, value in (("--responsivity", args.responsivity), ("--calibration", args.calibration),
                                            ("--pixel-format", args.pixel_format)) if value is not None]
    hw_only += given_camera_options(args)
    if hw_only and spec != "hw":
        hint = " (the simulated camera is --sim-camera NAME|FILE.csv)" if spec == "sim" else ""
        raise UsageError(f"{hw_only[0]}: describes a hardware rig's camera or booth, but the rig is '{spec}' and would "
                         f"ignore it{hint}; expected --rig hw (or --camera/--port)")
    if spec == "hw":
        return open_rig("hw", camera=args.camera, port=args.port, interfaces=args.interfaces,
                        calibration=args.calibration, led_spectra=args.led_spectra, responsivity=args.responsivity,
                        log_serial=args.log_serial, sync=args.sync, pixel_format=args.pixel_format,
                        camera_options=camera_options_from_args(args))
    if spec == "sim":
        return open_rig("sim", ambient=args.ambient, scene=args.scene, cfa=args.cfa, seed=args.seed,
                        camera=args.sim_camera, n_leds=args.leds, led_spectra=args.led_spectra,
                        flash_power=args.flash_power, log_serial=args.log_serial)
    if spec == "aravis-fake":
        return open_rig("aravis-fake", ambient=args.ambient, scene=args.scene, seed=args.seed, camera=args.sim_camera,
                        n_leds=args.leds, led_spectra=args.led_spectra, flash_power=args.flash_power,
                        log_serial=args.log_serial)
    return open_rig(spec, log_serial=args.log_serial)


def _writer(rig: Rig, out: Path, exposure: ExposurePlan | None = None) -> SequenceWriter:
    msflash: dict = {"rig": rig.name, "booth": rig.booth.info.firmware}
    if exposure is not None:
        msflash["exposure"] = exposure.to_dict()
    if rig.true_ambient is not None:
        # Ground truth of a simulated rig, on the sequence's grid and in its unit, for later scoring.
        truth = rig.true_ambient.resample(rig.led_spectra.grid).to_unit("energy")
        msflash["true_ambient"] = {"name": truth.names[0], "source": truth.source, "spd": truth.values[:, 0].tolist()}
    return rig.sequence_writer(out / "sequence", extra={"msflash": msflash})


def _report_frame(step, frame, entry) -> None:
    progress(f"captured step {step.index} ({step.label}) → {entry.file}")


def _policy(args: argparse.Namespace) -> ExposurePolicy:
    try:
        return ExposurePolicy(max_saturated_fraction=args.max_saturated / 100.0, criterion=args.exposure_criterion,
                              max_lost_fraction=args.max_lost / 100.0)
    except ValueError as err:
        raise UsageError(f"--max-saturated {args.max_saturated} / --exposure-criterion {args.exposure_criterion} / "
                         f"--max-lost {args.max_lost}: {err}") from err


@dataclass(frozen=True)
class _Recorded:
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


def _recorded(rig: Rig) -> _Recorded | None:
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
    return _Recorded(frames[ambient[0]].exposure_us, tuple(frames[i].exposure_us for i in leds),
                     frames[flash[0]].exposure_us if flash else None, frames[ambient[0]].gain,
                     tuple(frames[i].gain for i in leds), frames[flash[0]].gain if flash else 1.0,
                     tuple(frames[flash[0]].led_levels) if flash else None)


def _plan_exposure(rig: Rig, args: argparse.Namespace) -> ExposurePlan:
    """``--exposure``: fixed, the replay's recording, the fake's suggestion, or metered previews (auto)."""
    n_leds = rig.led_spectra.count
    limits = camera_exposure_range(rig.camera)
    policy = _policy(args)
    noise = camera_noise_model(rig.camera)
    method = "photon+read noise" if noise is not None else "difference image"
    nan = (float("nan"),) * n_leds
    if args.exposure != "auto":
        exposure = float(args.exposure)
        if not limits[0] <= exposure <= limits[1]:
            raise UsageError(f"--exposure {exposure:g}: outside the camera's range {limits[0]:g}–{limits[1]:g} µs")
        return ExposurePlan(exposure, (exposure,) * n_leds, nan, method, limits, policy, mode="fixed")
    recorded = _recorded(rig)
    if recorded is not None and len(recorded.led_us) == n_leds:
        return ExposurePlan(recorded.ambient_us, recorded.led_us, nan, method, limits, policy, mode="recorded",
                            ambient_gain=recorded.ambient_gain, led_gains=recorded.led_gains)
    suggested = float(getattr(rig.camera, "suggested_exposure_us", None) or 10_000.0)
    progress(f"auto exposure: metering ambient previews (≤ {policy.max_saturated_fraction:.2%} saturated, "
             f"bright end at {policy.target_fraction:.0%} of full scale)")
    info = rig.camera.info

    def capture(levels, exposure_us: float):
        role = "led" if any(level > 0 for level in levels) else "ambient"
        preview = CapturePlan.single(levels, exposure_us, role=role)
        return metering_view(preview_frames(rig.camera, rig.booth, preview)[0].pixels, mosaic=info.cfa is not None)

    return plan_exposures(capture, n_leds, info.black_level, info.white_level, limits, noise, policy,
                          start_us=suggested, cfa=info.cfa is not None)


def _report_exposure(plan: ExposurePlan, names: list[str]) -> None:
    progress(f"exposure ({plan.mode}): ambient {plan.ambient_exposure_us:.0f} µs; LEDs "
             + ", ".join(f"{n} {e:.0f}" for n, e in zip(names, plan.led_exposures_us)) + " µs")
    if plan.mode == "auto":
        progress(f"planned LED SNR ({plan.snr_method}, median pixel): "
                 + ", ".join(f"{n} {v:.3g}" for n, v in zip(names, plan.predicted_snr)))
    for note in plan.warnings:
        progress(f"warning: {note}")


@dataclass
class _LedCapture:
    """The ambient + LED frames as captured, kept in memory for estimation (no re-read from disk)."""

    plan: ExposurePlan
    frames: list[RawFrame]
    entries: list[SequenceFrame]
    last_frame_at: float
    """``time.perf_counter()`` when the last LED frame was handed over (written)."""
    snr: list[float]
    snr_method: str


def _capture_led_sequence(rig: Rig, writer: SequenceWriter, plan: ExposurePlan, sync: str = "host") -> _LedCapture:
    frames: list[RawFrame] = []
    stamp = {"t": 0.0}

    def keep(step, frame, entry) -> None:
        frames.append(frame)
        stamp["t"] = time.perf_counter()
        _report_frame(step, frame, entry)

    capture_plan = CapturePlan.ambient_then_each_led(len(writer.sequence.leds), plan.ambient_exposure_us,
                                                    gain=plan.ambient_gain, led_exposures_us=plan.led_exposures_us,
                                                    led_gains=plan.led_gains, trigger=SYNC_MODES[sync])
    entries = run_capture(rig.camera, rig.booth, capture_plan, writer, on_frame=keep)
    return _led_capture(rig, writer, plan, frames, entries, stamp["t"])


def _led_capture(rig: Rig, writer, plan: ExposurePlan, frames: list[RawFrame], entries: list[SequenceFrame],
                 last_frame_at: float) -> _LedCapture:
    """The LED frames with their measured SNR (reported)."""
    info = rig.camera.info
    pixels = [metering_view(f.pixels, mosaic=info.cfa is not None) for f in frames]
    snr, method = measure_led_snr(pixels[0], frames[0].exposure_us, pixels[1:],
                                  [f.exposure_us for f in frames[1:]], info.black_level, info.white_level,
                                  camera_noise_model(rig.camera), cfa=info.cfa is not None,
                                  gain=frames[0].gain)
    names = [led.name for led in writer.sequence.leds]
    progress(f"LED SNR ({method}, median pixel): " + ", ".join(f"{n} {v:.3g}" for n, v in zip(names, snr)))
    return _LedCapture(plan, frames, entries, last_frame_at, snr, method)


def _degenerate(estimate) -> str | None:
    """Why the estimate cannot be reported (non-finite numbers), or None."""
    checks = {"condition number": np.asarray(estimate.condition_number, dtype=float),
              "spectrum": np.asarray(estimate.spectrum.values, dtype=float),
              "ambient weights": np.asarray(estimate.ambient_weights, dtype=float),
              "spectrum uncertainty": np.asarray(estimate.spectrum_std, dtype=float)}
    bad = [name for name, values in checks.items() if not np.all(np.isfinite(values))]
    if not bad:
        return None
    return f"not finite: {', '.join(bad)}; condition number {float(estimate.condition_number):.3g}"


def _claimed(out: Path, what: str) -> FolderClaim:
    """``out`` claimed for this process (:mod:`acquisition.sequence.folder_claim`; a ``with`` block releases it), a
    folder that cannot hold the lock file being a bad output path (exit 2)."""
    try:
        return claim_folder(out, what)
    except OSError as err:
        raise UsageError(f"--out {out}: cannot write there ({err.strerror or err}); expected a writable "
                         "directory") from err


def _run(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else _default_out()
    output_directory(out)  # a file in the way or no write access: one line before any device is opened
    # One owner per run folder, claimed before it is checked (two runs started together must not
    # both find it empty); held until the report is written.
    with _claimed(out, "msflash run"):
        if (out / "sequence" / "sequence.json").exists():
            raise UsageError(f"--out {out}: already holds a run; expected a new directory")
        return _run_claimed(args, out)


def _run_claimed(args: argparse.Namespace, out: Path) -> int:
    started = time.perf_counter()
    spec = _rig_spec(args)
    # printable: a file name given to an option may hold any bytes, the line stays one line.
    progress(printable(f"opening rig '{spec}'" + (f" (ambient {args.ambient}, scene {args.scene}, camera "
                                                  f"{args.sim_camera or SIM_DEFAULT_CAMERA}, LEDs "
                                                  f"{args.led_spectra or f'paper {args.leds or 7}'})"
                                                  if spec in ("sim", "aravis-fake") else "")))
    # SIGTERM unwinds like Ctrl-C, so the LEDs go off and the partial sequence stays readable.
    with sigterm_as_exit(), _open(args) as rig:
        if rig.camera_responsivities is None:
            raise UsageError(f"rig '{spec}': the flash solvers need the camera's responsivities; expected "
                             "--responsivity FILE.csv (wavelength_nm, R, G, B) or a calibration with a camera section")
        exposure = _plan_exposure(rig, args)
        _report_exposure(exposure, list(rig.led_spectra.names))
        with _writer(rig, out, exposure) as sync_writer, AsyncSequenceWriter(sync_writer) as writer:
            if rig.name.startswith("replay:"):
                estimate, solutions, caught, captured, flash_us, stack, decided = _run_two_captures(
                    rig, writer, exposure, args)
            else:
                estimate, solutions, caught, captured, flash_us, stack, decided = _run_one_stream(
                    rig, writer, exposure, args)
            chosen = solutions[args.mode]
            degenerate = _degenerate(estimate)
            writer.finish()
            true_ambient = rig.true_ambient
    decision_ms = (decided - captured.last_frame_at) * 1e3
    progress(f"estimated the ambient and solved the flash in {decision_ms:.1f} ms after the last LED frame")
    for note in estimate.warnings:
        progress(f"warning: {note}")
    for warning in caught:
        progress(f"warning: {warning.message}")
    progress((f"re-captured with the {args.mode} flash at {flash_us:.0f} µs: " if flash_us is not None
              else f"the {args.mode} flash (synthesised only): ") + ", ".join(f"{w:.3f}" for w in chosen.flash_weights))
    if degenerate is not None:
        raise CaptureError(
            f"rig '{spec}': the ambient estimate is degenerate ({degenerate}): the LED-only images do not "
            f"determine the ambient (test patterns, or LEDs that do not reach the scene?); no report written. "
            f"The sequence is complete in {out / 'sequence'}"
        )
    from msflash.acquisition.app import report  # colour and matplotlib: only a run that reports needs them

    sequence = read_sequence(out / "sequence")
    progress("synthesising the computational images, previews and report")
    summary = report.write_run_report(out, sequence, estimate, solutions, args.mode, true_ambient, stack, args.target)
    if "spectrum_rmse_vs_truth" in summary:
        progress(f"spectrum RMSE against the true ambient {summary['spectrum_rmse_vs_truth']:.4f}; the best "
                 f"non-negative LED fit of it {summary['spectrum_rmse_led_bound']:.4f} (what the LEDs allow)")
    summary["exposure"] = {**exposure.to_dict(), "flash_exposure_us": flash_us, "led_snr": captured.snr,
                           "led_snr_method": captured.snr_method}
    summary["decision_ms"] = round(decision_ms, 3)
    summary["elapsed_s"] = round(time.perf_counter() - started, 3)
    try:
        (out / "run.json").write_text(dumps_json(summary) + "\n")
    except OSError as err:
        raise OutputWriteError(f"{out / 'run.json'}: could not be written ({err}); expected a writable disk with room "
                               f"for it. The sequence is complete in {out / 'sequence'} and the report beside it") from err
    progress(f"done in {summary['elapsed_s']:.1f} s: {out}")
    print(out)
    return 0


def _solve_both(solve, weights: np.ndarray, first: str) -> tuple[dict, list]:
    """Both flashes (``first`` solved first), with the TargetUnreachable warnings recorded."""
    solutions = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        for mode in (first, *(m for m in ("matching", "complementary") if m != first)):
            solutions[mode] = solve(mode, weights)
    return solutions, list(caught)


def _run_one_stream(rig: Rig, writer: AsyncSequenceWriter, exposure: ExposurePlan, args: argparse.Namespace):
    """Ambient + LEDs + flash in one stream, the flash decided from the frames in memory."""
    auto = exposure.mode == "auto"  # then the session predicts the flash exposure from the frames as they arrive
    session = FlashSession.prepare(writer.sequence, args.target, args.solver, args.alpha, args.bin,
                                   exposure_limits_us=exposure.exposure_range_us if auto else None,
                                   exposure_policy=exposure.policy)
    n_leds = len(writer.sequence.leds)
    frames: list[RawFrame] = []
    stamp = {"t": 0.0, "decided": 0.0}
    result: dict = {}

    def keep(step, frame, entry) -> None:
        if step.role != "flash":
            session.add(frame, step.role, step.led_levels)
            frames.append(frame)
            stamp["t"] = time.perf_counter()
        _report_frame(step, frame, entry)

    def decide(_frames):
        # As the capture bench: FlashSession.decide, the estimate's reliability signals left for
        # after the flash trigger (``decision.estimate`` is read once the capture is over).
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TargetUnreachableWarning)
            if args.from_disk:
                sequence = read_sequence(writer.flush().directory)
                stack = analysis.load_frame_stack(sequence)
                estimate = analysis.estimate_sequence(sequence, args.solver, args.alpha, stack=stack,
                                                      bin_factor=args.bin)
                chosen = session.solve(args.mode, estimate.ambient_weights)
                levels = np.clip(chosen.flash_weights, 0.0, 1.0)
                result.update(estimate=lambda: estimate, chosen=chosen, stack=stack)
            else:
                decision = session.decide(args.mode)
                levels = decision.levels
                result.update(estimate=lambda: decision.estimate, chosen=decision.solution)
        flash_us = _flash_exposure(rig, exposure, levels, session.flash_exposure)
        result.update(caught=list(caught), flash_us=flash_us)
        stamp["decided"] = time.perf_counter()
        return levels, flash_us

    plan = CapturePlan.ambient_then_each_led(n_leds, exposure.ambient_exposure_us,
                                             led_exposures_us=exposure.led_exposures_us, trigger=SYNC_MODES[args.sync])
    entries = run_capture_with_flash(rig.camera, rig.booth, plan, writer, decide, on_frame=keep)
    if "stack" not in result:
        # The report's frames as the sequence records them (a mono camera's as three identical
        # channels), as for two captures; the session's own stack holds a mono frame's one plane.
        result["stack"] = analysis.load_frame_stack(writer.flush(), [frame.pixels for frame in frames])
    estimate = result["estimate"]()
    other = "matching" if args.mode == "complementary" else "complementary"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        solutions = {args.mode: result["chosen"], other: session.solve(other, estimate.ambient_weights)}
    captured = _led_capture(rig, writer, exposure, frames, list(entries[:-1]), stamp["t"])
    flash_entry = entries[-1]
    return (estimate, solutions, result["caught"] + list(caught),
            captured, flash_entry.exposure_us, result["stack"], stamp["decided"])


def _run_two_captures(rig: Rig, writer: AsyncSequenceWriter, exposure: ExposurePlan, args: argparse.Namespace):
    """LED sequence, then the flash as a second capture (replay rigs: plans are checked up front)."""
    captured = _capture_led_sequence(rig, writer, exposure, args.sync)
    sequence = writer.flush()
    if args.from_disk:
        sequence = read_sequence(writer.path.parent)
        stack = analysis.load_frame_stack(sequence)
    else:
        stack = analysis.load_frame_stack(sequence, [frame.pixels for frame in captured.frames])
    estimate = analysis.estimate_sequence(sequence, args.solver, args.alpha, stack=stack, bin_factor=args.bin)
    solutions, caught = _solve_both(
        lambda mode, weights: analysis.solve_sequence_flash(sequence, mode, weights, args.target),
        estimate.ambient_weights, args.mode)
    levels = np.clip(solutions[args.mode].flash_weights, 0.0, 1.0)
    recorded = _recorded(rig)
    if exposure.mode == "recorded" and recorded is not None and recorded.flash_us is None:
        progress("the recording has no flash frame (a sequence from 'msflash capture'): the flash is synthesised "
                 "from the frames, not re-captured")
        return estimate, solutions, caught, captured, None, stack, time.perf_counter()
    if exposure.mode == "recorded" and recorded is not None and recorded.flash_levels is not None and \
            not levels_match(recorded.flash_levels, levels):
        # A recording made by another msflash version or with other options (--mode, --solver, --target…):
        # its flash frame is not this flash, and replay cannot capture another one.
        progress(f"the recording's flash frame has LED levels {format_levels(recorded.flash_levels)}, this run's "
                 f"{args.mode} flash asks for {format_levels(levels)} (recorded with other options or another "
                 "msflash version): the flash is synthesised from the frames, not replayed")
        return estimate, solutions, caught, captured, None, stack, time.perf_counter()
    frames = captured.frames
    info = rig.camera.info  # read once: on a real camera each read is several feature round trips
    pixels = [metering_view(f.pixels, mosaic=info.cfa is not None) for f in frames]
    flash_us = _flash_exposure(rig, exposure, levels, lambda weights: flash_exposure(
        pixels[0], frames[0].exposure_us, pixels[1:], [f.exposure_us for f in frames[1:]],
        weights, info.black_level, info.white_level, exposure.exposure_range_us, exposure.policy))
    flash_gain = recorded.flash_gain if exposure.mode == "recorded" and recorded is not None else 1.0
    flash_plan = CapturePlan.single(levels, flash_us, gain=flash_gain, trigger=SYNC_MODES[args.sync])
    decided = time.perf_counter()
    run_capture(rig.camera, rig.booth, flash_plan, writer, on_frame=_report_frame)
    return estimate, solutions, caught, captured, flash_us, stack, decided


def _flash_exposure(rig: Rig, plan: ExposurePlan, levels: np.ndarray, predict: Callable[[np.ndarray], float]) -> float:
    """The flash frame's exposure: fixed, recorded (replay), or ``predict(levels)`` from the frames in memory."""
    if plan.mode != "auto":
        recorded = _recorded(rig)
        if plan.mode == "recorded" and recorded is not None and recorded.flash_us is not None:
            return recorded.flash_us
        return plan.ambient_exposure_us
    return predict(levels)


def _capture(args: argparse.Namespace) -> int:
    out = Path(args.out)
    output_directory(out)
    with _claimed(out, "msflash capture"):
        if (out / "sequence" / "sequence.json").exists():
            raise UsageError(f"--out {out}: already holds a sequence; expected a new directory")
        return _capture_claimed(args, out)


def _capture_claimed(args: argparse.Namespace, out: Path) -> int:
    with sigterm_as_exit(), _open(args) as rig:
        exposure = _plan_exposure(rig, args)
        _report_exposure(exposure, list(rig.led_spectra.names))
        with _writer(rig, out, exposure) as sync_writer, AsyncSequenceWriter(sync_writer) as writer:
            _capture_led_sequence(rig, writer, exposure, args.sync)
            writer.finish()
    print(out / "sequence")
    return 0


def _flash_power(text: str) -> float:
    """``--flash-power``: a positive number (each LED's signal in units of the ambient's)."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"'{text}': expected a positive number (each LED's signal in units of the "
                                         "ambient's, e.g. 1)")
    return value


def _rig_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rig", default=None,
                        help="rig: sim (default; simulated camera + booth emulator on a pty), aravis-fake (Aravis "
                             "GigE Vision fake on 127.0.0.1 streaming the simulated scene, + emulator), replay:DIR (a recorded sequence + emulator), "
                             "hw (a real camera and booth; implied by --camera/--port)")
    hardware = parser.add_argument_group("hardware rig (--rig hw)")
    hardware.add_argument("--camera", default=None, metavar="ID",
                          help="camera device id, serial number or IP address (default: the single camera found)")
    hardware.add_argument("--port", default=None, metavar="PATH",
                          help="booth serial port, e.g. /dev/ttyACM0 (default: the single booth found)")
    hardware.add_argument("--interfaces", default="usb3",
                          help="Aravis interfaces to search: usb3 (default), gige, fake, comma-separated; gige "
                               "broadcasts discovery on every network interface unless --camera is an IP address")
    hardware.add_argument("--calibration", default=None, metavar="DIR",
                          help="calibration directory with led_spectra.csv (and camera_responsivity.csv)")
    hardware.add_argument("--responsivity", default=None, metavar="FILE.csv",
                          help="camera responsivities: wavelength_nm, R, G, B (energy); needed by the flash solvers")
    hardware.add_argument("--pixel-format", default=None,
                          help="camera PixelFormat to set (default: keep the camera's); packed Mono10p, Mono12p, "
                               "Bayer*10p/12p, Mono12Packed, Bayer*12Packed … are decoded")
    add_camera_options(hardware)
    parser.add_argument("--sync", default="host", choices=tuple(SYNC_MODES),
                        help="who paces the frames: host (serial command, then software trigger; default), "
                             "booth (booth sets LEDs then pulses the camera trigger), camera (the camera's "
                             "exposure-active line advances the booth's pattern table)")
    parser.add_argument("--led-spectra", default=None, metavar="FILE.csv",
                        help="LED spectra: first column wavelength_nm, one column per booth channel at full drive "
                             "(energy); hw: the real booth's channels; sim: the emulated booth gets these channels "
                             "(names and peaks from the columns; the file must cover 400-700 nm)")
    sim = parser.add_argument_group("simulated world (--rig sim; --rig aravis-fake renders it too, except --cfa)")
    sim.add_argument("--sim-camera", default=None, metavar="NAME|FILE.csv",
                     help=f"camera: a shipped camera ({SIM_DEFAULT_CAMERA} by default; ISETCam's, the paper's 34 — an "
                          "unknown name lists them) or responsivities wavelength_nm, R, G, B (energy) covering "
                          "400-700 nm, as --responsivity reads them")
    sim.add_argument("--leds", type=int, default=None, choices=tuple(PAPER_LED_SUBSETS),
                     help="the paper's subset of N LEDs (3: 440, 520, 660 nm … 7: all; default 7); or --led-spectra")
    sim.add_argument("--ambient", default="tungsten", metavar="NAME|FILE.csv",
                     help=f"ambient: {', '.join(AMBIENTS)}, a CIE/colour-science illuminant (A, D50, D65, F2, "
                          "F11, LED-B1, blackbody:3200 …) or a CSV wavelength_nm, value (energy) covering 400-700 nm")
    sim.add_argument("--scene", default="chart110", metavar="NAME|FILE.csv",
                     help=f"scene: {', '.join(SIM_SCENES)} (white: a white reference for calibrate leds --white), or "
                          "reflectances wavelength_nm + one column per surface (0-1, covering 400-700 nm) shown as a "
                          "random mosaic of those surfaces (--seed)")
    sim.add_argument("--flash-power", type=_flash_power, default=None, metavar="P",
                     help="how bright the booth is: every LED at full drive gives at least P times the ambient's "
                          "mean camera signal (the weakest LED exactly P; the LEDs keep their ratios; default 1)")
    sim.add_argument("--cfa", default=None, choices=CFA_CHOICES, help="raw Bayer mosaic frames with this layout")
    sim.add_argument("--seed", type=int, default=0, help="noise seed (and the mosaic scene's layout)")
    parser.add_argument("--exposure", "--exposure-us", dest="exposure", type=_exposure_value, default="auto",
                        metavar="auto|MICROSECONDS",
                        help="auto (default: meter an ambient preview, then choose each LED frame's exposure for "
                             "SNR below saturation) or one exposure in microseconds for every frame")
    parser.add_argument("--log-serial", default=None, help="write the booth serial transcript to this file")
    parser.add_argument("--max-saturated", type=float, default=0.1, metavar="PERCENT",
                        help="auto exposure: at most this percentage of pixels may saturate in a frame (default 0.1)")
    parser.add_argument("--exposure-criterion", choices=("bright_end", "information"), default="bright_end",
                        help="auto exposure: bright_end (default: the brightest pixels just below saturation, so "
                             "every chart patch stays usable) or information (longest exposures whose unsaturated "
                             "blocks carry the most LED-only information; highlights may clip — see README)")
    parser.add_argument("--max-lost", type=float, default=25.0, metavar="PERCENT",
                        help="information criterion: at most this percentage of the estimator's blocks may be lost "
                             "to saturation over all frames (default 25)")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``run`` and ``capture``."""
    run = subparsers.add_parser("run", help="the main job: capture, estimate, flash, re-capture, synthesise, report")
    _rig_options(run)
    run.add_argument("--out", default=None, help="output directory (default runs/<UTC time>)")
    run.add_argument("--mode", default="complementary", choices=("complementary", "matching"),
                     help="flash to re-capture with (both are synthesised)")
    run.add_argument("--target", default="D65", help="complementary target illuminant (name or CSV file)")
    add_estimation_options(run)
    run.add_argument("--from-disk", action="store_true",
                     help="estimate from the frames re-read from disk instead of those in memory (slower; a check)")
    run.set_defaults(handler=_run)

    capture = subparsers.add_parser("capture", help="capture an ambient + each-LED sequence on a rig")
    _rig_options(capture)
    capture.add_argument("--out", required=True, help="output directory (the sequence goes to OUT/sequence)")
    capture.set_defaults(handler=_capture)
