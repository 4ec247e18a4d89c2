"""``msflash run`` (the main job) and ``msflash capture`` on a rig.

``run``: capture ambient + each LED → estimate the ambient from the recorded sequence → solve the
matching and complementary flashes → re-capture with the chosen one (same sequence, role
``flash``) → synthesise both computational images → previews, a spectra plot and a report.

``--sync host|booth|camera`` picks who paces the frames (DESIGN §4; :mod:`acquisition.capture`).

A degenerate estimate (the LED-only images do not determine the ambient: a non-finite condition
number, spectrum or weight — e.g. the ``aravis-fake`` rig's test patterns) does not stop the
capture: the flash the solvers return is still re-captured, so the sequence is complete. No
report is written from it (its numbers are not finite); ``run`` then exits 1 with one
``msflash: error:`` line saying so and where the sequence is.
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
from acquisition.errors import CaptureError
from acquisition.plan import CapturePlan, TriggerSource
from acquisition.rig import Rig, open_rig
from acquisition.sequence_format import SequenceWriter, read_sequence
from led_controller.booth import sigterm_as_exit
from processing.errors import TargetUnreachableWarning

CFA_CHOICES = ("RGGB", "BGGR", "GRBG", "GBRG")
SYNC_MODES: dict[str, TriggerSource] = {"host": "software", "booth": "booth", "camera": "camera"}
"""``--sync`` names and the plan trigger each stands for."""


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


def _capture_led_sequence(rig: Rig, writer: SequenceWriter, exposure_us: float | None, sync: str = "host") -> float:
    suggested = getattr(rig.camera, "suggested_exposure_us", None)
    exposure = float(exposure_us or suggested or 10_000.0)
    if not exposure > 0:
        raise UsageError(f"--exposure-us {exposure_us}: expected a positive exposure")
    plan = CapturePlan.ambient_then_each_led(len(writer.sequence.leds), exposure, trigger=SYNC_MODES[sync])
    run_capture(rig.camera, rig.booth, plan, writer, on_frame=_report_frame)
    return exposure


def _degenerate(estimate) -> str | None:  # noqa: ANN001 - processing.ambient.AmbientEstimate
    """Why the estimate cannot be reported (non-finite numbers), or None."""
    checks = {"condition number": np.asarray(estimate.condition_number, dtype=float),
              "spectrum": np.asarray(estimate.spectrum.values, dtype=float),
              "ambient weights": np.asarray(estimate.ambient_weights, dtype=float),
              "spectrum uncertainty": np.asarray(estimate.spectrum_std, dtype=float)}
    bad = [name for name, values in checks.items() if not np.all(np.isfinite(values))]
    if not bad:
        return None
    return f"not finite: {', '.join(bad)}; condition number {float(estimate.condition_number):.3g}"


def _run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    out = Path(args.out) if args.out else _default_out()
    if (out / "sequence" / "sequence.json").exists():
        raise UsageError(f"--out {out}: already holds a run; expected a new directory")
    out.mkdir(parents=True, exist_ok=True)
    progress(f"opening rig '{args.rig}' (ambient {args.ambient}, scene {args.scene})")
    # SIGTERM unwinds like Ctrl-C, so the LEDs go off and the partial sequence stays readable.
    with sigterm_as_exit(), _open(args) as rig, _writer(rig, out) as writer:
        exposure = _capture_led_sequence(rig, writer, args.exposure_us, args.sync)
        # Estimate from the frames as recorded (the sequence is still open: complete is false).
        sequence = read_sequence(writer.path.parent)
        progress("estimating the ambient spectrum")
        stack = analysis.load_frame_stack(sequence)
        estimate = analysis.estimate_sequence(sequence, args.solver, args.alpha, stack=stack, bin_factor=args.bin)
        for note in estimate.warnings:
            progress(f"warning: {note}")
        degenerate = _degenerate(estimate)
        solutions = {}
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TargetUnreachableWarning)
            for mode in ("matching", "complementary"):
                solutions[mode] = analysis.solve_sequence_flash(sequence, mode, estimate.ambient_weights, args.target)
        for warning in caught:
            progress(f"warning: {warning.message}")
        chosen = solutions[args.mode]
        progress(f"re-capturing with the {args.mode} flash: " + ", ".join(f"{w:.3f}" for w in chosen.flash_weights))
        flash_plan = CapturePlan.single(np.clip(chosen.flash_weights, 0.0, 1.0), exposure, trigger=SYNC_MODES[args.sync])
        run_capture(rig.camera, rig.booth, flash_plan, writer, on_frame=_report_frame)
        writer.finish()
        true_ambient = rig.true_ambient
    if degenerate is not None:
        raise CaptureError(
            f"rig '{args.rig}': the ambient estimate is degenerate ({degenerate}): the LED-only images do not "
            f"determine the ambient (test patterns, or LEDs that do not reach the scene?); no report written. "
            f"The sequence is complete in {out / 'sequence'}"
        )
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
        _capture_led_sequence(rig, writer, args.exposure_us, args.sync)
        writer.finish()
    print(out / "sequence")
    return 0


def _rig_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rig", default="sim",
                        help="rig: sim (default; simulated camera + booth emulator on a pty), aravis-fake (Aravis "
                             "GigE Vision fake on 127.0.0.1 + emulator), replay:DIR (a recorded sequence + emulator)")
    parser.add_argument("--sync", default="host", choices=tuple(SYNC_MODES),
                        help="who paces the frames: host (serial command, then software trigger; default), "
                             "booth (booth sets LEDs then pulses the camera trigger), camera (the camera's "
                             "exposure-active line advances the booth's pattern table)")
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
