"""Which rig ``run`` and ``capture`` open: the options that describe it, each checked against the rig it
fits, and the rig's typed options (:mod:`acquisition.session.rig`) built from them.

:func:`add_rig_options` adds the parser groups ``run``, ``capture`` and ``live`` share (``live`` without the
pacing options, its stream being host paced, and with ``--booth-port`` for the booth of any rig, its ``--port``
being the page's TCP port); :func:`rig_spec` reads ``--rig`` (``hw`` implied by ``--camera``/``--port``);
:func:`open_from_args` refuses an option the rig would ignore (one line, exit 2) and opens the rig through
:func:`~acquisition.session.rig.open_rig`.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from msflash.acquisition.app.camera_options import (
    FAKE_RIG_OPTIONS,
    add_camera_options,
    camera_options_from_args,
    given_camera_options,
)
from msflash.acquisition.app.cli_common import (
    UsageError,
    add_booth_boot_option,
    number_where,
    seed_int,
    serial_port,
    user_number,
    whole,
)
from msflash.acquisition.app.options import (
    SIM_CFA_CHOICES,
    SIM_CFA_HELP,
    add_fake_camera_option,
    sim_cfa,
    simulated_world,
)
from msflash.acquisition.devices.aravis.fake_models import DEFAULT_FAKE_MODEL
from msflash.acquisition.devices.mains_flicker import FLICKER_WAVEFORMS, drawn_flicker, parse_flicker
from msflash.acquisition.devices.sim_world import SIM_DEFAULT_CAMERA, SIM_SCENES
from msflash.acquisition.session.anti_flicker import ANTI_FLICKER_CHOICES
from msflash.acquisition.session.external_booth import check_booth_port
from msflash.acquisition.session.rig import (
    AravisFakeRigOptions,
    HwRigOptions,
    ReplayRigOptions,
    Rig,
    SimRigOptions,
    open_rig,
    rig_kind,
)
from msflash.acquisition.session.run import SYNC_MODES
from msflash.led_controller.adapters import BOOTH_PROTOCOLS
from msflash.led_controller.booth_interface import unsupported_sync
from msflash.processing.datasets import PAPER_LED_SUBSETS
from msflash.processing.lights import AMBIENTS
from msflash.processing.user_numbers import plain_number


def _exposure_value(text: str) -> str | float:
    """``--exposure``: ``auto`` or a positive number of microseconds."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        value = plain_number(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}': expected auto or an exposure in microseconds") from None
    if not (value > 0 and np.isfinite(value)):
        raise argparse.ArgumentTypeError(f"'{text}': expected a positive exposure in microseconds")
    return value


def rig_spec(args: argparse.Namespace) -> str:
    """The rig to open: ``--rig``, or ``hw`` when ``--camera``/``--port`` name real devices."""
    devices = args.camera is not None or args.port is not None
    if args.rig is None:
        return "hw" if devices else "sim"
    if devices and args.rig != "hw":
        raise UsageError(f"--rig {args.rig}: --camera/--port name hardware devices; expected --rig hw (or no --rig)")
    return args.rig


def open_from_args(args: argparse.Namespace) -> Rig:
    """The rig ``args`` name, opened with its options; an option it would ignore is refused first."""
    spec = rig_spec(args)
    if getattr(args, "booth_port_for_any_rig", False) and spec == "hw" and args.booth_port is not None:
        args.port, args.booth_port = args.booth_port, None  # live: --booth-port names the hw rig's booth too
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
    if args.flicker is not None and spec not in ("sim", "aravis-fake"):
        raise UsageError(
            f"--flicker: describes the simulated world's lamp, but the rig is '{spec}'; expected --rig sim or aravis-fake"
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
            HwRigOptions(
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
            ),
        )
    # The simulated world: the sim rig renders it with its own camera, aravis-fake through Aravis.
    world = simulated_world(args)
    if args.flicker is not None:  # the lamp's true frequency (within the grid's ±1 %) and phase drawn from --seed
        hz, depth, waveform = args.flicker
        world = dataclasses.replace(world, flicker=drawn_flicker(hz, depth, waveform, seed=args.seed))
    if spec == "sim":
        return open_rig(
            "sim",
            SimRigOptions(
                world,
                cfa=sim_cfa(args.cfa),
                log_serial=args.log_serial,
                booth_port=args.booth_port,
                booth_protocol=args.booth_protocol,
                booth_boot_s=args.booth_boot_s,
                booth_firmware=args.booth_firmware,
                line_time_us=args.line_time_us,
            ),
        )
    if spec == "aravis-fake":
        return open_rig(
            "aravis-fake",
            AravisFakeRigOptions(
                world,
                log_serial=args.log_serial,
                camera_options=camera_options_from_args(args),
                fake_camera=args.fake_camera or DEFAULT_FAKE_MODEL,
            ),
        )
    if rig_kind(spec) == "replay":
        return open_rig(spec, ReplayRigOptions(log_serial=args.log_serial))
    return open_rig(spec)


def _line_time(text: str) -> float:
    value = user_number(text)
    if not (math.isfinite(value) and 0.0 <= value <= 1000.0):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a line time in µs, 0..1000")
    return value


def _flicker(text: str) -> tuple[float, float, str]:
    """``--flicker HZ:DEPTH[:WAVEFORM]`` (:func:`acquisition.devices.mains_flicker.parse_flicker`)."""
    try:
        return parse_flicker(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _flash_power(text: str) -> float:
    """``--flash-power``: a positive number (each LED's signal in units of the ambient's)."""
    value = user_number(text)
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a positive number (each LED's signal in units of the ambient's, e.g. 1)"
        )
    return value


def add_rig_options(parser: argparse.ArgumentParser, live: bool = False) -> None:
    """The rig's options; ``live``: without ``--port`` (the page's TCP port there) and the pacing options."""
    parser.add_argument(
        "--rig",
        default=None,
        help="rig: sim (default; simulated camera + booth emulator on a pty), aravis-fake (Aravis "
        "GigE Vision fake on 127.0.0.1 streaming the simulated scene, + emulator), replay:DIR (a recorded sequence + emulator), "
        "hw (a real camera and booth; implied by --camera" + ("" if live else "/--port") + ")",
    )
    _add_hardware_options(parser, booth_port=not live)
    _add_booth_options(parser, sync=not live)
    _add_world_options(parser, booth_port_help=_LIVE_BOOTH_PORT_HELP if live else None)
    if live:
        parser.add_argument("--log-serial", default=None, help="write the booth serial transcript to this file")
        parser.set_defaults(port=None, sync="host", booth_port_for_any_rig=True)
    else:
        _add_pacing_options(parser)


_LIVE_BOOTH_PORT_HELP = (
    "the booth's serial port: hw (default: the single booth found), or, on sim, a booth in another process "
    "(msflash booth-emulator's pty) instead of an emulator in this process"
)


def _add_hardware_options(parser: argparse.ArgumentParser, booth_port: bool = True) -> None:
    """``--camera``, ``--port`` (unless not ``booth_port``), … and the camera options: the hardware rig."""
    hardware = parser.add_argument_group("hardware rig (--rig hw)")
    hardware.add_argument(
        "--camera",
        default=None,
        metavar="ID",
        help="camera device id, serial number or IP address (default: the single camera found)",
    )
    if booth_port:
        hardware.add_argument(
            "--port",
            type=serial_port,
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


def _add_booth_options(parser: argparse.ArgumentParser, sync: bool = True) -> None:
    """The fake camera model and the booth: who paces (unless not ``sync``), protocol, boot time, LED spectra."""
    add_fake_camera_option(parser)
    if sync:
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
        action=_LedFilesAction,
        metavar="FILE",
        help="LED spectra: a table (first column wavelength_nm, one column per booth channel at full drive, "
        "energy), or spectrometer exports of the LEDs, the option once per channel in channel order (read as "
        "'calibrate leds' reads them); hw: the real booth's channels; sim: the emulated booth gets these channels "
        "(names and peaks from the columns or file names; a table must cover 400-700 nm)",
    )


class _LedFilesAction(argparse.Action):
    """``--led-spectra``: given once, its file (a string, as every other path option); given again, the files in
    channel order (a tuple: one spectrometer export per LED)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        given = getattr(namespace, self.dest, None)
        if given is None:
            setattr(namespace, self.dest, values)
        else:
            setattr(namespace, self.dest, (*((given,) if isinstance(given, str) else given), values))


def _add_world_options(parser: argparse.ArgumentParser, booth_port_help: str | None = None) -> None:
    """The simulated world, and a booth outside this process."""
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
        type=whole,
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
        type=serial_port,
        default=None,
        metavar="PATH",
        help=booth_port_help
        or "drive the booth at this port (msflash booth-emulator's pty, or a real booth) instead of "
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
        "--flicker",
        type=_flicker,
        default=None,
        metavar="HZ:DEPTH[:WAVEFORM]",
        help="the ambient lamp flickers on the mains: HZ its flicker frequency (100 on 50 Hz mains, 120 on 60 Hz; "
        "the true one drawn within ±1 %% from --seed, as is its phase), DEPTH its percent flicker (0.3 = 30 %%), "
        f"WAVEFORM {', '.join(FLICKER_WAVEFORMS)} (default sine: a filament; rectified: a fluorescent; clipped: an "
        "LED driver); each frame sees the lamp's mean over its own exposure window (default: steady; docs/flicker.md)",
    )
    sim.add_argument("--cfa", default=None, choices=SIM_CFA_CHOICES, help=SIM_CFA_HELP)
    sim.add_argument("--seed", type=seed_int, default=0, help="noise seed (and the mosaic scene's layout)")


def _percent_below(upper: float) -> Callable[[str], float]:
    """argparse type of a percentage in [0, ``upper``): the range in the unit the user types (the policy's own
    check named the fraction, ``--max-saturated 101`` as "max_saturated_fraction 1.01; expected 0 ≤ f < 0.5")."""
    return number_where(lambda value: 0 <= value < upper, f"a percentage, 0 ≤ PERCENT < {upper:g}")


def _add_pacing_options(parser: argparse.ArgumentParser) -> None:
    """``--exposure``, ``--log-serial``, ``--sync`` and what paces the frames."""
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
    parser.add_argument(
        "--anti-flicker",
        default="off",
        choices=ANTI_FLICKER_CHOICES,
        help="exposures of whole flicker periods of mains lamps where the exposure allows: 50 (10 ms periods) or 60 "
        "(8.33 ms) the mains in Hz, auto (50 ms: whole periods of both), off (default); shorter exposures are kept "
        "and named in a warning (the estimate reads each frame's ambient gain; docs/flicker.md)",
    )
    parser.add_argument("--log-serial", default=None, help="write the booth serial transcript to this file")
    parser.add_argument(
        "--max-saturated",
        type=_percent_below(50.0),
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
        type=_percent_below(100.0),
        default=25.0,
        metavar="PERCENT",
        help="information criterion: at most this percentage of the estimator's blocks may be lost "
        "to saturation over all frames (default 25)",
    )
