"""``msflash live``: serve the live view of a rig on 127.0.0.1 (docs/architecture.md §5.4).

One process owns the camera and the booth: the page shows the live image, sets exposure, gain and each
LED's level, fires the sequence ``msflash run`` captures into a new folder of ``--runs`` and shows its
spectrum, and lists the earlier runs. aiohttp is imported when the command runs, never for ``--help``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from msflash.acquisition.app.cli_common import UsageError, add_booth_boot_option, progress
from msflash.acquisition.app.options import (
    SIM_CFA_CHOICES,
    SIM_CFA_HELP,
    add_fake_camera_option,
    sim_cfa,
    simulated_world,
    target_value,
)
from msflash.acquisition.devices.sim_world import SIM_DEFAULT_CAMERA, SIM_SCENES
from msflash.acquisition.session.rig import (
    AravisFakeRigOptions,
    HwRigOptions,
    ReplayRigOptions,
    Rig,
    SimRigOptions,
    open_rig,
    rig_kind,
)
from msflash.acquisition.signals import STOPPING_SIGNALS
from msflash.processing.datasets import PAPER_LED_SUBSETS
from msflash.processing.lights import AMBIENTS

DEFAULT_PORT = 8470


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"'{text}': expected a TCP port 0–65535 (0: any free port)")
    return value


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"'{text}': expected a positive number")
    return value


def _open(args: argparse.Namespace) -> Rig:
    spec = args.rig or ("hw" if args.camera is not None else "sim")
    hw_only = [
        option
        for option, value in (
            ("--camera", args.camera),
            ("--calibration", args.calibration),
            ("--responsivity", args.responsivity),
        )
        if value is not None
    ]
    if hw_only and spec != "hw":
        raise UsageError(f"{hw_only[0]}: describes a hardware rig, but the rig is '{spec}'; expected --rig hw")
    if args.cfa is not None and spec != "sim":
        raise UsageError(f"--cfa: describes the simulated rig's camera, but the rig is '{spec}'; expected --rig sim")
    if args.fake_camera is not None and spec != "aravis-fake":
        raise UsageError(f"--fake-camera: picks the aravis-fake rig's camera model, but the rig is '{spec}'")
    if args.booth_port is not None and spec not in ("sim", "hw"):
        raise UsageError(f"--booth-port: the rig '{spec}' has its own emulated booth; expected --rig sim or hw")
    world = simulated_world(args)
    if spec == "sim":
        return open_rig(
            "sim",
            SimRigOptions(
                world,
                cfa=sim_cfa(args.cfa),
                log_serial=args.log_serial,
                booth_port=args.booth_port,
                booth_boot_s=args.booth_boot_s,
            ),
        )
    if spec == "aravis-fake":
        return open_rig(
            "aravis-fake",
            AravisFakeRigOptions(world, log_serial=args.log_serial, fake_camera=args.fake_camera or "sfnc"),
        )
    if spec == "hw":
        return open_rig(
            "hw",
            HwRigOptions(
                camera=args.camera,
                port=args.booth_port,
                interfaces=args.interfaces,
                calibration=args.calibration,
                led_spectra=args.led_spectra,
                responsivity=args.responsivity,
                log_serial=args.log_serial,
                booth_boot_s=args.booth_boot_s,
            ),
        )
    if rig_kind(spec) == "replay":
        return open_rig(spec, ReplayRigOptions(log_serial=args.log_serial))
    return open_rig(spec)


def _live(args: argparse.Namespace) -> int:
    import asyncio

    from msflash.acquisition.app.live.requests import bind
    from msflash.acquisition.app.live.server import LiveServer

    runs = Path(args.runs)
    if runs.exists() and not runs.is_dir():
        raise UsageError(f"--runs {runs}: not a directory; expected a folder for the run folders")
    sock = bind(args.host, args.port)  # a port in use: one line before any device is opened
    try:
        with _open(args) as rig:
            server = LiveServer(rig, runs, sock, target=args.target)
            progress(f"live view of rig '{rig.name}' at {server.url} (Ctrl-C stops it and switches the LEDs off)")
            progress(f"session token (every change the page makes carries it): {server.token}")
            print(server.url, flush=True)

            async def serve() -> None:
                stop = asyncio.Event()
                loop = asyncio.get_running_loop()

                def stopping() -> None:
                    # A fired sequence stops before its next frame: LEDs off, the frames written kept.
                    if server.stop_sequence() and not stop.is_set():
                        progress(
                            "stopping the sequence in progress before its next frame (LEDs off; the frames "
                            "written so far stay, the sequence marked incomplete)"
                        )
                    stop.set()

                for sig in STOPPING_SIGNALS:  # SIGHUP: the terminal closed
                    loop.add_signal_handler(sig, stopping)
                await server.serve(stop)

            asyncio.run(serve())
    finally:
        sock.close()
    progress("live view stopped; LEDs off")
    args.exit_at_once = True  # run as the program: leave without the interpreter's teardown (cli._exit_at_once)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``live``."""
    live = subparsers.add_parser(
        "live",
        help="serve a browser page on 127.0.0.1: live image, exposure, gain, LED levels, fire a sequence, its spectrum",
    )
    live.add_argument(
        "--rig",
        default=None,
        choices=("sim", "aravis-fake", "hw"),
        help="sim (default: simulated camera + booth emulator on a pty), aravis-fake (Aravis GigE fake on "
        "127.0.0.1 + emulator), hw (a real camera and booth; implied by --camera)",
    )
    live.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1); any other address serves the page only to the URL with "
        "the session token printed at start",
    )
    live.add_argument("--port", type=_port, default=DEFAULT_PORT, help=f"TCP port (default {DEFAULT_PORT}; 0: any)")
    live.add_argument("--runs", default="runs", metavar="DIR", help="folder of the run folders (default runs)")
    live.add_argument(
        "--target", default="D65", type=target_value, help="complementary target illuminant (name or CSV file)"
    )
    add_fake_camera_option(live)
    hardware = live.add_argument_group("hardware rig (--rig hw)")
    hardware.add_argument("--camera", default=None, metavar="ID", help="camera device id, serial number or IP")
    hardware.add_argument(
        "--booth-port",
        default=None,
        metavar="PATH",
        help="the booth's serial port (hw; default: the single booth found) or, on sim, a booth in another process",
    )
    add_booth_boot_option(hardware)
    hardware.add_argument("--interfaces", default="usb3", help="Aravis interfaces to search (default usb3)")
    hardware.add_argument("--calibration", default=None, metavar="DIR", help="calibration directory")
    hardware.add_argument("--responsivity", default=None, metavar="FILE.csv", help="camera responsivities")
    live.add_argument("--led-spectra", default=None, metavar="FILE.csv", help="LED spectra, one column per channel")
    live.add_argument("--log-serial", default=None, help="write the booth serial transcript to this file")
    sim = live.add_argument_group("simulated world (--rig sim or aravis-fake)")
    sim.add_argument(
        "--sim-camera", default=None, metavar="NAME|FILE.csv", help=f"camera (default {SIM_DEFAULT_CAMERA})"
    )
    sim.add_argument("--leds", type=int, default=None, choices=tuple(PAPER_LED_SUBSETS), help="the paper's N LEDs")
    sim.add_argument("--ambient", default="tungsten", metavar="NAME|FILE.csv", help=f"ambient: {', '.join(AMBIENTS)} …")
    sim.add_argument("--scene", default="chart110", metavar="NAME|FILE.csv", help=f"scene: {', '.join(SIM_SCENES)} …")
    sim.add_argument("--flash-power", type=_positive, default=None, metavar="P", help="booth brightness (default 1)")
    sim.add_argument("--cfa", default=None, choices=SIM_CFA_CHOICES, help=SIM_CFA_HELP)
    sim.add_argument("--seed", type=int, default=0, help="noise seed")
    live.set_defaults(handler=_live)
