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
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from msflash.acquisition.app.cli_common import UsageError, claimed_output, progress
from msflash.acquisition.app.options import TARGET_HELP, add_estimation_options, target_value
from msflash.acquisition.app.rig_choice import add_rig_options, open_from_args, rig_spec
from msflash.acquisition.devices.sim_world import SIM_DEFAULT_CAMERA, led_files_shown
from msflash.acquisition.errors import CaptureError
from msflash.acquisition.progress import count
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.exposure import (
    ExposurePlan,
    ExposurePolicy,
)
from msflash.acquisition.session.rig import Rig
from msflash.acquisition.session.run import (
    RunOptions,
    RunResult,
    capture_sequence,
    check_colour_camera,
    degenerate,
    plan_exposure,
    report_exposure,
    run_one_stream,
    run_two_captures,
    sequence_writer,
)
from msflash.acquisition.signals import sigterm_as_exit
from msflash.processing.spectra import Spectra
from msflash.processing.user_files import printable


def _default_out() -> Path:
    return Path("runs") / datetime.now(UTC).strftime("%Y%m%d-%H%M%S")


def _run_options(args: argparse.Namespace) -> RunOptions:
    return RunOptions(
        mode=args.mode,
        target=args.target,
        solver=args.solver,
        alpha=args.alpha,
        bin_factor=args.bin,
        sync=args.sync,
        from_disk=args.from_disk,
    )


def _policy(args: argparse.Namespace) -> ExposurePolicy:
    try:
        return ExposurePolicy(
            max_saturated_fraction=args.max_saturated / 100.0,
            criterion=args.exposure_criterion,
            max_lost_fraction=args.max_lost / 100.0,
            anti_flicker=args.anti_flicker,
        )
    except ValueError as err:
        raise UsageError(
            f"--max-saturated {args.max_saturated} / --exposure-criterion {args.exposure_criterion} / "
            f"--max-lost {args.max_lost}: {err}"
        ) from err


def _run(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else _default_out()
    # One owner per run folder, claimed before it is checked (two runs started together must not
    # both find it empty); held until the report is written. A file in the way or no write access:
    # one line before any device is opened.
    with claimed_output(out, "msflash run"):
        if (out / "sequence" / "sequence.json").exists():
            raise UsageError(f"--out {out}: already holds a run; expected a new directory")
        return _run_claimed(args, out)


RUN_STEPS = 4
"""The steps of ``run`` its progress bar counts: open the rig, plan the exposures, capture, report."""


def _run_claimed(args: argparse.Namespace, out: Path) -> int:
    started = time.perf_counter()
    spec = rig_spec(args)
    count("run", 0, RUN_STEPS, "step")
    progress(_opening(args, spec))
    # SIGTERM unwinds like Ctrl-C, so the LEDs go off and the partial sequence stays readable.
    with sigterm_as_exit(), open_from_args(args) as rig:
        count("run", 1, RUN_STEPS, "step")
        _check_rig_runs(args, rig, spec)
        exposure = plan_exposure(rig, args.exposure, _policy(args))
        report_exposure(exposure, list(rig.led_spectra.names))
        count("run", 2, RUN_STEPS, "step")
        with sequence_writer(rig, out, exposure) as sync_writer, AsyncSequenceWriter(sync_writer) as writer:
            run = run_two_captures if rig.name.startswith("replay:") else run_one_stream
            result = run(rig, writer, exposure, _run_options(args))
            why_degenerate = degenerate(result.estimate)
            writer.finish()
            true_ambient = rig.true_ambient
    count("run", 3, RUN_STEPS, "step")
    _say_decision(args, result)
    if why_degenerate is not None:
        raise CaptureError(
            f"rig '{spec}': the ambient estimate is degenerate ({why_degenerate}): the LED-only images do not "
            f"determine the ambient (test patterns, or LEDs that do not reach the scene?); no report written. "
            f"The sequence is complete in {out / 'sequence'}"
        )
    summary = _report(args, out, exposure, result, true_ambient, started)
    count("run", RUN_STEPS, RUN_STEPS, "step")
    progress(f"done in {summary['elapsed_s']:.1f} s: {out}")
    print(out)
    return 0


def _opening(args: argparse.Namespace, spec: str) -> str:
    """``opening rig 'SPEC'`` and, for a simulated world, what it is (printable: a file name may hold any bytes)."""
    world = (
        f" (ambient {args.ambient}, scene {args.scene}, camera {args.sim_camera or SIM_DEFAULT_CAMERA}, LEDs "
        f"{led_files_shown(args.led_spectra) if args.led_spectra else f'paper {args.leds or 7}'})"
    )
    return printable(f"opening rig '{spec}'" + (world if spec in ("sim", "aravis-fake") else ""))


def _check_rig_runs(args: argparse.Namespace, rig: Rig, spec: str) -> None:
    """Refuse a rig the run cannot use: no responsivities for the flash, a mono camera (a flash mix matches or
    complements colours: one channel has none), or a DNG export of RGB frames."""
    if rig.camera_responsivities is None:
        raise UsageError(
            f"rig '{spec}': the flash solvers need the camera's responsivities; expected "
            "--responsivity FILE.csv (wavelength_nm, R, G, B) or a calibration with a camera section"
        )
    check_colour_camera(rig, spec)
    if args.export and "dng" in args.export and rig.camera.info.cfa is None:
        raise UsageError(
            f"--export {','.join(args.export)}: rig '{spec}' gives RGB (debayered) frames, and a DNG holds a raw "
            "mosaic; expected a raw (CFA) camera for dng (the sim rig's default: not --cfa none), or ome-tiff/exr for RGB"
        )


def _say_decision(args: argparse.Namespace, result: RunResult) -> None:
    """The decision's time, the warnings, and the flash re-captured (or synthesised only)."""
    progress(f"estimated the ambient and solved the flash in {result.decision_ms:.1f} ms after the last LED frame")
    flicker = result.estimate.flicker.summary() if result.estimate.flicker is not None else None
    if flicker is not None:
        progress(flicker)
    for note in result.estimate.warnings:
        progress(f"warning: {note}")
    for warning in result.warnings:
        progress(f"warning: {warning.message}")
    flash_us = result.flash_exposure_us
    progress(
        (
            f"re-captured with the {args.mode} flash at {flash_us:.0f} µs: "
            if flash_us is not None
            else f"the {args.mode} flash (synthesised only): "
        )
        + ", ".join(f"{w:.3f}" for w in result.solutions[args.mode].flash_weights)
    )


def _report(
    args: argparse.Namespace,
    out: Path,
    exposure: ExposurePlan,
    result: RunResult,
    true_ambient: Spectra | None,
    started: float,
) -> dict[str, Any]:
    """The run's report, exports and ``run.json`` (its summary, returned)."""
    from msflash.acquisition.app import report, run_html  # colour and matplotlib: only a run that reports needs them

    sequence = read_sequence(out / "sequence")
    sequence.check_digests()  # the files are what was written (a failing disk): bytes only, no frame decoded
    progress("synthesising the computational images, previews and report")
    estimate, solutions = result.estimate, result.solutions
    summary = report.write_run_report(
        out, sequence, estimate, solutions, args.mode, true_ambient, result.stack, args.target, result.flash_frame
    )
    if "spectrum_rmse_vs_truth" in summary:
        progress(
            f"spectrum RMSE against the true ambient {summary['spectrum_rmse_vs_truth']:.4f}; the best "
            f"non-negative LED fit of it {summary['spectrum_rmse_led_bound']:.4f} (what the LEDs allow)"
        )
    if args.export:
        from msflash.acquisition.export.sequence_export import export_sequence

        exported = export_sequence(
            sequence, args.export, out / "export", estimate=estimate, solutions=solutions, target=args.target
        )
        for note in exported.notes:
            progress(f"note: {note}")
        summary["export"] = {
            "formats": list(args.export),
            "files": [str(path) for path in exported.files],
            "notes": list(exported.notes),
        }
    summary["exposure"] = run_html.exposure_summary(exposure, result.flash_exposure_us, result.captured)
    summary["decision_ms"] = round(result.decision_ms, 3)
    summary["elapsed_s"] = round(time.perf_counter() - started, 3)
    run_html.write_run_summary(out, summary, sequence)
    return summary


def _capture(args: argparse.Namespace) -> int:
    out = Path(args.out)
    with claimed_output(out, "msflash capture"):
        if (out / "sequence" / "sequence.json").exists():
            raise UsageError(f"--out {out}: already holds a sequence; expected a new directory")
        return _capture_claimed(args, out)


def _capture_claimed(args: argparse.Namespace, out: Path) -> int:
    count("opening the rig", 0, 1, "step")  # seconds on the sim rig (its world is built): the bar shows them pass
    with sigterm_as_exit(), open_from_args(args) as rig:
        count("opening the rig", 1, 1, "step")
        path = capture_sequence(rig, out, args.exposure, _policy(args), args.sync)
    print(path)
    return 0


def _export_formats(text: str) -> tuple[str, ...]:
    from msflash.acquisition.export.formats import parse_formats

    try:
        return parse_formats(text, "--export")
    except UsageError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``run`` and ``capture``."""
    run = subparsers.add_parser("run", help="the main job: capture, estimate, flash, re-capture, synthesise, report")
    add_rig_options(run)
    run.add_argument("--out", default=None, help="output directory (default runs/<UTC time>)")
    run.add_argument(
        "--mode",
        default="complementary",
        choices=("complementary", "matching"),
        help="flash to re-capture with (both are synthesised)",
    )
    run.add_argument("--target", default="D65", type=target_value, help=TARGET_HELP)
    add_estimation_options(run)
    run.add_argument(
        "--export",
        default=None,
        type=_export_formats,
        help="also export into OUT/export: dng, ome-tiff, csv, exr, comma-separated (as msflash export --to)",
    )
    run.add_argument(
        "--from-disk",
        action="store_true",
        help="estimate from the frames re-read from disk instead of those in memory (slower; a check)",
    )
    run.set_defaults(handler=_run)

    capture = subparsers.add_parser("capture", help="capture an ambient + each-LED sequence on a rig")
    add_rig_options(capture)
    capture.add_argument("--out", required=True, help="output directory (the sequence goes to OUT/sequence)")
    capture.set_defaults(handler=_capture)
