"""``msflash run`` (the main job) and ``msflash capture`` on a rig.

``run``: capture ambient + each LED → estimate the ambient from the recorded sequence → solve the
matching and complementary flashes → re-capture with the chosen one (same sequence, role
``flash``) → synthesise both computational images → previews, a spectra plot and a report.
"""

from __future__ import annotations

import argparse
import time
import warnings
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from acquisition import analysis, report
from acquisition.capture import run_capture
from acquisition.cli_common import UsageError, dumps_json, progress
from acquisition.cli_process import add_estimation_options
from acquisition.plan import CapturePlan
from acquisition.rig import Rig, open_rig
from acquisition.sequence_format import SequenceWriter, read_sequence
from led_controller.booth import sigterm_as_exit
from processing.errors import TargetUnreachableWarning

CFA_CHOICES = ("RGGB", "BGGR", "GRBG", "GBRG")


def _default_out() -> Path:
    return Path("runs") / datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")


def _open(args: argparse.Namespace) -> Rig:
    return open_rig(args.rig, ambient=args.ambient, scene=args.scene, cfa=args.cfa, seed=args.seed,
                    log_serial=args.log_serial)


def _writer(rig: Rig, out: Path) -> SequenceWriter:
    wavelengths, camera, leds = rig.sequence_header()
    return SequenceWriter(out / "sequence", wavelengths_nm=wavelengths, spectral_unit="energy", camera=camera,
                          leds=leds, extra={"msflash": {"rig": rig.name, "booth": rig.booth.info.firmware}})


def _report_frame(step, frame, entry) -> None:  # noqa: ANN001 - capture callback
    progress(f"captured step {step.index} ({step.label}) → {entry.file}")


def _capture_led_sequence(rig: Rig, writer: SequenceWriter, exposure_us: float | None) -> float:
    exposure = float(exposure_us or rig.camera.suggested_exposure_us or 10_000.0)
    if not exposure > 0:
        raise UsageError(f"--exposure-us {exposure_us}: expected a positive exposure")
    plan = CapturePlan.ambient_then_each_led(len(writer.sequence.leds), exposure)
    run_capture(rig.camera, rig.booth, plan, writer, on_frame=_report_frame)
    return exposure


def _run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    out = Path(args.out) if args.out else _default_out()
    if (out / "sequence" / "sequence.json").exists():
        raise UsageError(f"--out {out}: already holds a run; expected a new directory")
    out.mkdir(parents=True, exist_ok=True)
    progress(f"opening rig '{args.rig}' (ambient {args.ambient}, scene {args.scene})")
    # SIGTERM unwinds like Ctrl-C, so the LEDs go off and the partial sequence stays readable.
    with sigterm_as_exit(), _open(args) as rig, _writer(rig, out) as writer:
        exposure = _capture_led_sequence(rig, writer, args.exposure_us)
        # Estimate from the frames as recorded (the sequence is still open: complete is false).
        sequence = read_sequence(writer.path.parent)
        progress("estimating the ambient spectrum")
        stack = analysis.load_frame_stack(sequence)
        estimate = analysis.estimate_sequence(sequence, args.method, args.alpha, stack=stack, bin_factor=args.bin)
        for note in estimate.warnings:
            progress(f"warning: {note}")
        solutions = {}
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TargetUnreachableWarning)
            for mode in ("matching", "complementary"):
                solutions[mode] = analysis.solve_sequence_flash(sequence, mode, estimate.ambient_weights, args.target)
        for warning in caught:
            progress(f"warning: {warning.message}")
        chosen = solutions[args.mode]
        progress(f"re-capturing with the {args.mode} flash: " + ", ".join(f"{w:.3f}" for w in chosen.flash_weights))
        run_capture(rig.camera, rig.booth, CapturePlan.single(chosen.flash_weights, exposure), writer,
                    on_frame=_report_frame)
        writer.finish()
        true_ambient = rig.true_ambient
    sequence = read_sequence(out / "sequence")
    progress("synthesising the computational images, previews and report")
    summary = report.write_run_report(out, sequence, estimate, solutions, args.mode, true_ambient, stack, args.target)
    summary["elapsed_s"] = round(time.perf_counter() - started, 3)
    (out / "run.json").write_text(dumps_json(summary) + "\n")
    progress(f"done in {summary['elapsed_s']:.1f} s: {out}")
    print(out)
    return 0


def _capture(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if (out / "sequence" / "sequence.json").exists():
        raise UsageError(f"--out {out}: already holds a sequence; expected a new directory")
    out.mkdir(parents=True, exist_ok=True)
    with sigterm_as_exit(), _open(args) as rig, _writer(rig, out) as writer:
        _capture_led_sequence(rig, writer, args.exposure_us)
        writer.finish()
    print(out / "sequence")
    return 0


def _rig_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rig", default="sim", help="rig: sim (default; simulated camera + booth emulator on a pty)")
    parser.add_argument("--ambient", default="tungsten",
                        help="sim ambient: tungsten, fluorescent, daylight, underwater, green, orange")
    parser.add_argument("--scene", default="chart110", choices=("chart110", "macbeth"), help="sim scene")
    parser.add_argument("--cfa", default=None, choices=CFA_CHOICES, help="sim: raw Bayer mosaic frames with this layout")
    parser.add_argument("--seed", type=int, default=0, help="sim noise seed")
    parser.add_argument("--exposure-us", type=float, default=None, help="exposure (default: the rig's suggestion)")
    parser.add_argument("--log-serial", default=None, help="write the booth serial transcript to this file")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``run`` and ``capture``."""
    run = subparsers.add_parser("run", help="the main job: capture, estimate, flash, re-capture, synthesise, report")
    _rig_options(run)
    run.add_argument("--out", default=None, help="output directory (default runs/<UTC time>)")
    run.add_argument("--mode", default="complementary", choices=("complementary", "matching"),
                     help="flash to re-capture with (both are synthesised)")
    run.add_argument("--target", default="D65", help="complementary target illuminant (name or CSV file)")
    add_estimation_options(run)
    run.set_defaults(handler=_run)

    capture = subparsers.add_parser("capture", help="capture an ambient + each-LED sequence on a rig")
    _rig_options(capture)
    capture.add_argument("--out", required=True, help="output directory (the sequence goes to OUT/sequence)")
    capture.set_defaults(handler=_capture)
