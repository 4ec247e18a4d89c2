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
import math
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from msflash.acquisition.app.camera_options import (
    FAKE_RIG_OPTIONS,
    add_camera_options,
    camera_options_from_args,
    given_camera_options,
)
from msflash.acquisition.app.cli_common import UsageError, add_booth_boot_option, claimed_output, progress
from msflash.acquisition.app.options import (
    SIM_CFA_CHOICES,
    SIM_CFA_HELP,
    add_estimation_options,
    add_fake_camera_option,
    sim_cfa,
    simulated_world,
)
from msflash.acquisition.devices.aravis.fake_models import DEFAULT_FAKE_MODEL
from msflash.acquisition.devices.mains_flicker import FLICKER_WAVEFORMS, drawn_flicker, parse_flicker
from msflash.acquisition.devices.sim_world import SIM_DEFAULT_CAMERA, SIM_SCENES
from msflash.acquisition.devices.simulated_camera import SimulatedCamera
from msflash.acquisition.errors import CaptureError
from msflash.acquisition.progress import count
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.format import (
    read_sequence,
)
from msflash.acquisition.session.exposure import (
    ExposurePolicy,
)
from msflash.acquisition.session.external_booth import check_booth_port
from msflash.acquisition.session.rig import Rig, open_rig
from msflash.acquisition.session.run import (
    SYNC_MODES,
    RunOptions,
    capture_sequence,
    degenerate,
    plan_exposure,
    report_exposure,
    run_one_stream,
    run_two_captures,
    sequence_writer,
)
from msflash.acquisition.signals import sigterm_as_exit
from msflash.led_controller.adapters import BOOTH_PROTOCOLS
from msflash.led_controller.booth_interface import unsupported_sync
from msflash.processing.datasets import PAPER_LED_SUBSETS
from msflash.processing.lights import AMBIENTS
from msflash.processing.user_files import printable


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
    world_options = [
        option
        for option, value in (
            ("--sim-camera", args.sim_camera),
            ("--leds", args.leds),
            ("--flash-power", args.flash_power),
        )
        if value is not None
    ]
    if world_options and spec not in ("sim", "aravis-fake"):
        raise UsageError(
            f"{world_options[0]}: describes the simulated world, but the rig is '{spec}'; expected "
            "--rig sim or aravis-fake (or no --rig and no --camera/--port)"
        )
    if args.cfa is not None and spec != "sim":
        fixed = " (its frames are BayerRG16, an RGGB mosaic)" if spec == "aravis-fake" else ""
        raise UsageError(
            f"--cfa: describes the simulated rig's camera, but the rig is '{spec}'{fixed}; expected "
            "--rig sim (or no --rig and no --camera/--port)"
        )
    hw_only = [
        option
        for option, value in (
            ("--responsivity", args.responsivity),
            ("--calibration", args.calibration),
            ("--pixel-format", args.pixel_format),
        )
        if value is not None
    ]
    camera_options = given_camera_options(args)
    hw_only += [name for name in camera_options if spec != "aravis-fake" or name not in FAKE_RIG_OPTIONS]
    if args.fake_camera is not None and spec != "aravis-fake":
        raise UsageError(
            f"--fake-camera {args.fake_camera}: picks the aravis-fake rig's camera model, but the rig is '{spec}'; "
            "expected --rig aravis-fake"
        )
    if hw_only and spec != "hw":
        hint = " (the simulated camera is --sim-camera NAME|FILE.csv)" if spec == "sim" else ""
        raise UsageError(
            f"{hw_only[0]}: describes a hardware rig's camera or booth, but the rig is '{spec}' and would "
            f"ignore it{hint}; expected --rig hw (or --camera/--port)"
        )
    if args.booth_port is not None:
        check_booth_port(spec, args.sync)
    for option, given in (("--booth-firmware", args.booth_firmware), ("--line-time-us", args.line_time_us != 0.0)):
        if given and spec != "sim":
            raise UsageError(f"{option}: configures the simulated rig, but the rig is '{spec}'; expected --rig sim")
    if args.ambient_flicker is not None and spec not in ("sim", "aravis-fake"):
        raise UsageError(
            f"--ambient-flicker: describes the simulated world's lamp, but the rig is '{spec}'; expected --rig sim or "
            "aravis-fake"
        )
    if args.booth_protocol != "msflash" and args.port is None and args.booth_port is None:
        raise UsageError(
            f"--booth-protocol {args.booth_protocol}: says what the booth at --port or --booth-port "
            "speaks, but neither is given (discovery and the emulators speak msflash); expected --port "
            "PATH or --booth-port PATH"
        )
    rig = _open_spec(args, spec)
    why = unsupported_sync(rig.booth, args.sync)
    if why is not None:  # a host-paced-only adapter asked for booth or camera master
        rig.close()
        raise UsageError(why)
    return rig


def _open_spec(args: argparse.Namespace, spec: str) -> Rig:
    if spec == "hw":
        return open_rig(
            "hw",
            camera=args.camera,
            port=args.port,
            interfaces=args.interfaces,
            calibration=args.calibration,
            led_spectra=args.led_spectra,
            responsivity=args.responsivity,
            log_serial=args.log_serial,
            sync=args.sync,
            pixel_format=args.pixel_format,
            camera_options=camera_options_from_args(args),
            booth_protocol=args.booth_protocol,
            booth_boot_s=args.booth_boot_s,
        )
    # The simulated world: the sim rig renders it with its own camera, aravis-fake through Aravis.
    world = simulated_world(args)
    if spec == "sim":
        return _with_flicker(
            open_rig(
                "sim",
                cfa=sim_cfa(args.cfa),
                booth_port=args.booth_port,
                booth_protocol=args.booth_protocol,
                booth_boot_s=args.booth_boot_s,
                booth_firmware=args.booth_firmware,
                line_time_us=args.line_time_us,
                **world,
            ),
            args,
        )
    if spec == "aravis-fake":
        return _with_flicker(
            open_rig(
                "aravis-fake",
                camera_options=camera_options_from_args(args),
                fake_camera=args.fake_camera or DEFAULT_FAKE_MODEL,
                **world,
            ),
            args,
        )
    return open_rig(spec, log_serial=args.log_serial)


def _ambient_flicker(text: str) -> tuple[float, float, str]:
    """``--ambient-flicker HZ:DEPTH[:WAVEFORM]`` (:func:`acquisition.devices.mains_flicker.parse_flicker`)."""
    try:
        return parse_flicker(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _with_flicker(rig: Rig, args: argparse.Namespace) -> Rig:
    """The simulated world's lamp flickering as ``--ambient-flicker`` asks (the sim and aravis-fake rigs)."""
    if args.ambient_flicker is None:
        return rig
    world = rig.camera if isinstance(rig.camera, SimulatedCamera) else getattr(rig.camera, "world", None)
    if isinstance(world, SimulatedCamera):
        world.ambient_modulation = drawn_flicker(*args.ambient_flicker, seed=args.seed)
    return rig


def _line_time(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and 0.0 <= value <= 1000.0):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a line time in µs, 0..1000")
    return value


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
    spec = _rig_spec(args)
    count("run", 0, RUN_STEPS, "step")
    # printable: a file name given to an option may hold any bytes, the line stays one line.
    progress(
        printable(
            f"opening rig '{spec}'"
            + (
                f" (ambient {args.ambient}, scene {args.scene}, camera "
                f"{args.sim_camera or SIM_DEFAULT_CAMERA}, LEDs "
                f"{args.led_spectra or f'paper {args.leds or 7}'})"
                if spec in ("sim", "aravis-fake")
                else ""
            )
        )
    )
    # SIGTERM unwinds like Ctrl-C, so the LEDs go off and the partial sequence stays readable.
    with sigterm_as_exit(), _open(args) as rig:
        count("run", 1, RUN_STEPS, "step")
        if rig.camera_responsivities is None:
            raise UsageError(
                f"rig '{spec}': the flash solvers need the camera's responsivities; expected "
                "--responsivity FILE.csv (wavelength_nm, R, G, B) or a calibration with a camera section"
            )
        if args.export and "dng" in args.export and rig.camera.info.cfa is None:
            raise UsageError(
                f"--export {','.join(args.export)}: rig '{spec}' gives RGB (debayered) frames, and a DNG holds a raw "
                "mosaic; expected a raw (CFA) camera for dng (the sim rig's default: not --cfa none), or ome-tiff/exr for RGB"
            )
        exposure = plan_exposure(rig, args.exposure, _policy(args))
        report_exposure(exposure, list(rig.led_spectra.names))
        count("run", 2, RUN_STEPS, "step")
        with sequence_writer(rig, out, exposure) as sync_writer, AsyncSequenceWriter(sync_writer) as writer:
            if rig.name.startswith("replay:"):
                estimate, solutions, caught, captured, flash_us, stack, decided = run_two_captures(
                    rig, writer, exposure, _run_options(args)
                )
            else:
                estimate, solutions, caught, captured, flash_us, stack, decided = run_one_stream(
                    rig, writer, exposure, _run_options(args)
                )
            chosen = solutions[args.mode]
            why_degenerate = degenerate(estimate)
            writer.finish()
            true_ambient = rig.true_ambient
    count("run", 3, RUN_STEPS, "step")
    decision_ms = (decided - captured.last_frame_at) * 1e3
    progress(f"estimated the ambient and solved the flash in {decision_ms:.1f} ms after the last LED frame")
    for note in estimate.warnings:
        progress(f"warning: {note}")
    for warning in caught:
        progress(f"warning: {warning.message}")
    progress(
        (
            f"re-captured with the {args.mode} flash at {flash_us:.0f} µs: "
            if flash_us is not None
            else f"the {args.mode} flash (synthesised only): "
        )
        + ", ".join(f"{w:.3f}" for w in chosen.flash_weights)
    )
    if why_degenerate is not None:
        raise CaptureError(
            f"rig '{spec}': the ambient estimate is degenerate ({why_degenerate}): the LED-only images do not "
            f"determine the ambient (test patterns, or LEDs that do not reach the scene?); no report written. "
            f"The sequence is complete in {out / 'sequence'}"
        )
    from msflash.acquisition.app import report, run_html  # colour and matplotlib: only a run that reports needs them

    sequence = read_sequence(out / "sequence")
    progress("synthesising the computational images, previews and report")
    summary = report.write_run_report(out, sequence, estimate, solutions, args.mode, true_ambient, stack, args.target)
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
    summary["exposure"] = run_html.exposure_summary(exposure, flash_us, captured)
    summary["decision_ms"] = round(decision_ms, 3)
    summary["elapsed_s"] = round(time.perf_counter() - started, 3)
    run_html.write_run_summary(out, summary, sequence)
    count("run", RUN_STEPS, RUN_STEPS, "step")
    progress(f"done in {summary['elapsed_s']:.1f} s: {out}")
    print(out)
    return 0


def _capture(args: argparse.Namespace) -> int:
    out = Path(args.out)
    with claimed_output(out, "msflash capture"):
        if (out / "sequence" / "sequence.json").exists():
            raise UsageError(f"--out {out}: already holds a sequence; expected a new directory")
        return _capture_claimed(args, out)


def _capture_claimed(args: argparse.Namespace, out: Path) -> int:
    count("opening the rig", 0, 1, "step")  # seconds on the sim rig (its world is built): the bar shows them pass
    with sigterm_as_exit(), _open(args) as rig:
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


def _flash_power(text: str) -> float:
    """``--flash-power``: a positive number (each LED's signal in units of the ambient's)."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a positive number (each LED's signal in units of the ambient's, e.g. 1)"
        )
    return value


def _rig_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--rig",
        default=None,
        help="rig: sim (default; simulated camera + booth emulator on a pty), aravis-fake (Aravis "
        "GigE Vision fake on 127.0.0.1 streaming the simulated scene, + emulator), replay:DIR (a recorded sequence + emulator), "
        "hw (a real camera and booth; implied by --camera/--port)",
    )
    hardware = parser.add_argument_group("hardware rig (--rig hw)")
    hardware.add_argument(
        "--camera",
        default=None,
        metavar="ID",
        help="camera device id, serial number or IP address (default: the single camera found)",
    )
    hardware.add_argument(
        "--port",
        default=None,
        metavar="PATH",
        help="booth serial port, e.g. /dev/ttyACM0 (default: the single booth found)",
    )
    hardware.add_argument(
        "--interfaces",
        default="usb3",
        help="Aravis interfaces to search: usb3 (default), gige, fake, comma-separated; gige "
        "broadcasts discovery on every network interface unless --camera is an IP address",
    )
    hardware.add_argument(
        "--calibration",
        default=None,
        metavar="DIR",
        help="calibration directory with led_spectra.csv (and camera_responsivity.csv)",
    )
    hardware.add_argument(
        "--responsivity",
        default=None,
        metavar="FILE.csv",
        help="camera responsivities: wavelength_nm, R, G, B (energy); needed by the flash solvers",
    )
    hardware.add_argument(
        "--pixel-format",
        default=None,
        help="camera PixelFormat to set (default: keep the camera's); packed Mono10p, Mono12p, "
        "Bayer*10p/12p, Mono12Packed, Bayer*12Packed … are decoded",
    )
    add_camera_options(hardware)
    add_fake_camera_option(parser)
    parser.add_argument(
        "--sync",
        default="host",
        choices=tuple(SYNC_MODES),
        help="who paces the frames: host (serial command, then software trigger; default), "
        "booth (booth sets LEDs then pulses the camera trigger), camera (the camera's "
        "exposure-active line advances the booth's pattern table)",
    )
    add_booth_boot_option(parser)
    parser.add_argument(
        "--booth-protocol",
        default="msflash",
        choices=BOOTH_PROTOCOLS,
        help="what the booth at --port/--booth-port speaks: msflash (default; docs/booth-protocol.md, "
        "every --sync) or text (a plain-text line protocol, --sync host only; "
        "docs/booth-adapters.md)",
    )
    parser.add_argument(
        "--led-spectra",
        default=None,
        metavar="FILE.csv",
        help="LED spectra: first column wavelength_nm, one column per booth channel at full drive "
        "(energy); hw: the real booth's channels; sim: the emulated booth gets these channels "
        "(names and peaks from the columns; the file must cover 400-700 nm)",
    )
    sim = parser.add_argument_group("simulated world (--rig sim; --rig aravis-fake renders it too, except --cfa)")
    sim.add_argument(
        "--sim-camera",
        default=None,
        metavar="NAME|FILE.csv",
        help=f"camera: a shipped camera ({SIM_DEFAULT_CAMERA} by default; ISETCam's, the paper's 34 — an "
        "unknown name lists them) or responsivities wavelength_nm, R, G, B (energy) covering "
        "400-700 nm, as --responsivity reads them",
    )
    sim.add_argument(
        "--leds",
        type=int,
        default=None,
        choices=tuple(PAPER_LED_SUBSETS),
        help="the paper's subset of N LEDs (3: 440, 520, 660 nm … 7: all; default 7); or --led-spectra",
    )
    sim.add_argument(
        "--ambient",
        default="tungsten",
        metavar="NAME|FILE.csv",
        help=f"ambient: {', '.join(AMBIENTS)}, a CIE/colour-science illuminant (A, D50, D65, F2, "
        "F11, LED-B1, blackbody:3200 …) or a CSV wavelength_nm, value (energy) covering 400-700 nm",
    )
    sim.add_argument(
        "--scene",
        default="chart110",
        metavar="NAME|FILE.csv",
        help=f"scene: {', '.join(SIM_SCENES)} (white: a white reference for calibrate leds --white), or "
        "reflectances wavelength_nm + one column per surface (0-1, covering 400-700 nm) shown as a "
        "random mosaic of those surfaces (--seed)",
    )
    sim.add_argument(
        "--flash-power",
        type=_flash_power,
        default=None,
        metavar="P",
        help="how bright the booth is: every LED at full drive gives at least P times the ambient's "
        "mean camera signal (the weakest LED exactly P; the LEDs keep their ratios; default 1)",
    )
    sim.add_argument(
        "--booth-port",
        default=None,
        metavar="PATH",
        help="drive the booth at this port (msflash booth-emulator's pty, or a real booth) instead of "
        "an emulator in this process; --sync host only",
    )
    sim.add_argument(
        "--booth-firmware",
        action="store_true",
        help="the booth is the reference firmware running in simavr (its real LED pins, trigger output and "
        "ExposureActive input wired to the simulated camera; every --sync mode); needs the AVR toolchain",
    )
    sim.add_argument(
        "--line-time-us",
        type=_line_time,
        default=0.0,
        metavar="US",
        help="a rolling shutter: each row of the simulated camera starts US µs after the one above "
        "(default 0: a global shutter); the booth is told the skew so its pulses fall where every row exposes",
    )
    sim.add_argument(
        "--ambient-flicker",
        type=_ambient_flicker,
        default=None,
        metavar="HZ:DEPTH[:WAVEFORM]",
        help="the simulated lamp flickers on the mains: HZ the flicker frequency (100 on 50 Hz mains, 120 on 60 Hz; "
        "the true one drawn within ±1 %% with --seed), DEPTH its percent flicker (0.3 = 30 %%), WAVEFORM "
        f"{', '.join(FLICKER_WAVEFORMS)} (default sine: a filament; rectified: a fluorescent; clipped: an LED "
        "driver); each frame sees the lamp's mean over its own exposure window (default: steady, docs/flicker.md)",
    )
    sim.add_argument("--cfa", default=None, choices=SIM_CFA_CHOICES, help=SIM_CFA_HELP)
    sim.add_argument("--seed", type=int, default=0, help="noise seed (and the mosaic scene's layout)")
    parser.add_argument(
        "--exposure",
        "--exposure-us",
        dest="exposure",
        type=_exposure_value,
        default="auto",
        metavar="auto|MICROSECONDS",
        help="auto (default: meter an ambient preview, then choose each LED frame's exposure for "
        "SNR below saturation) or one exposure in microseconds for every frame",
    )
    parser.add_argument("--log-serial", default=None, help="write the booth serial transcript to this file")
    parser.add_argument(
        "--max-saturated",
        type=float,
        default=0.1,
        metavar="PERCENT",
        help="auto exposure: at most this percentage of pixels may saturate in a frame (default 0.1)",
    )
    parser.add_argument(
        "--exposure-criterion",
        choices=("bright_end", "information"),
        default="bright_end",
        help="auto exposure: bright_end (default: the brightest pixels just below saturation, so "
        "every chart patch stays usable) or information (longest exposures whose unsaturated "
        "blocks carry the most LED-only information; highlights may clip — see README)",
    )
    parser.add_argument(
        "--max-lost",
        type=float,
        default=25.0,
        metavar="PERCENT",
        help="information criterion: at most this percentage of the estimator's blocks may be lost "
        "to saturation over all frames (default 25)",
    )


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``run`` and ``capture``."""
    run = subparsers.add_parser("run", help="the main job: capture, estimate, flash, re-capture, synthesise, report")
    _rig_options(run)
    run.add_argument("--out", default=None, help="output directory (default runs/<UTC time>)")
    run.add_argument(
        "--mode",
        default="complementary",
        choices=("complementary", "matching"),
        help="flash to re-capture with (both are synthesised)",
    )
    run.add_argument("--target", default="D65", help="complementary target illuminant (name or CSV file)")
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
    _rig_options(capture)
    capture.add_argument("--out", required=True, help="output directory (the sequence goes to OUT/sequence)")
    capture.set_defaults(handler=_capture)
