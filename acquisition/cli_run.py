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
    return Path("runs") / datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")


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
    if spec == "hw":
        return open_rig("hw", camera=args.camera, port=args.port, interfaces=args.interfaces,
                        calibration=args.calibration, led_spectra=args.led_spectra, responsivity=args.responsivity,
                        log_serial=args.log_serial, sync=args.sync, pixel_format=args.pixel_format)
    return open_rig(spec, ambient=args.ambient, scene=args.scene, cfa=args.cfa, seed=args.seed,
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
    spec = _rig_spec(args)
    progress(f"opening rig '{spec}'" + (f" (ambient {args.ambient}, scene {args.scene})" if spec == "sim" else ""))
    # SIGTERM unwinds like Ctrl-C, so the LEDs go off and the partial sequence stays readable.
    with sigterm_as_exit(), _open(args) as rig, _writer(rig, out) as writer:
        exposure = _capture_led_sequence(rig, writer, (None if args.exposure == 'auto' else args.exposure), args.sync)
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
            f"rig '{spec}': the ambient estimate is degenerate ({degenerate}): the LED-only images do not "
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
        _capture_led_sequence(rig, writer, (None if args.exposure == 'auto' else args.exposure), args.sync)
        writer.finish()
    print(out / "sequence")
    return 0


def _rig_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rig", default=None,
                        help="rig: sim (default; simulated camera + booth emulator on a pty), aravis-fake (Aravis "
                             "GigE Vision fake on 127.0.0.1 + emulator), replay:DIR (a recorded sequence + emulator), "
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
    hardware.add_argument("--led-spectra", default=None, metavar="FILE.csv",
                          help="LED spectra: first column wavelength_nm, one column per booth channel (energy)")
    hardware.add_argument("--responsivity", default=None, metavar="FILE.csv",
                          help="camera responsivities: wavelength_nm, R, G, B (energy); needed by the flash solvers")
    hardware.add_argument("--pixel-format", default=None,
                          help="camera PixelFormat to set (default: keep the camera's)")
    parser.add_argument("--sync", default="host", choices=tuple(SYNC_MODES),
                        help="who paces the frames: host (serial command, then software trigger; default), "
                             "booth (booth sets LEDs then pulses the camera trigger), camera (the camera's "
                             "exposure-active line advances the booth's pattern table)")
    parser.add_argument("--ambient", default="tungsten",
                        help="sim ambient: tungsten, fluorescent, daylight, underwater, green, orange")
    parser.add_argument("--scene", default="chart110", choices=("chart110", "macbeth"), help="sim scene")
    parser.add_argument("--cfa", default=None, choices=CFA_CHOICES, help="sim: raw Bayer mosaic frames with this layout")
    parser.add_argument("--seed", type=int, default=0, help="sim noise seed")
    parser.add_argument("--exposure", "--exposure-us", dest="exposure", type=_exposure_value, default="auto",
                        metavar="auto|MICROSECONDS",
                        help="auto (default: meter an ambient preview, then choose each LED frame's exposure for "
                             "SNR below saturation) or one exposure in microseconds for every frame")
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
