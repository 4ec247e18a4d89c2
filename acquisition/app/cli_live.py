"""``msflash live``: serve the live view of a rig on 127.0.0.1 (docs/architecture.md §5.4).

One process owns the camera and the booth: the page shows the live image, sets exposure, gain, each LED's level and
the camera's ROI, binning and pixel format, fires the sequence ``msflash run`` captures into a new folder of
``--runs`` and shows its spectrum, and lists the earlier runs. The rig is chosen and opened as ``run`` opens it
(:mod:`acquisition.app.rig_choice`: the same option groups, without the pacing ones, and the one opener).
aiohttp is imported when the command runs, never for ``--help``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from msflash.acquisition.app.cli_common import UsageError, check_folder_can_be_made, progress
from msflash.acquisition.app.options import TARGET_HELP, target_value
from msflash.acquisition.app.rig_choice import add_rig_options, open_from_args, rig_spec
from msflash.acquisition.session.rig import rig_kind
from msflash.acquisition.signals import STOPPING_SIGNALS, handlers_kept
from msflash.processing.user_numbers import plain_whole_number

DEFAULT_PORT = 8470


def _port(text: str) -> int:
    try:
        value = plain_whole_number(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"'{text}': expected a TCP port 0–65535 (0: any free port)")
    return value


def _live(args: argparse.Namespace) -> int:
    import asyncio
    import signal

    from msflash.acquisition.app.live.requests import bind
    from msflash.acquisition.app.live.server import LiveServer

    runs = Path(args.runs)
    check_folder_can_be_made(runs, "--runs")  # before the page is served: a run is fired long after
    spec = rig_spec(args)
    if rig_kind(spec) == "replay":
        raise UsageError(
            f"--rig {spec}: a replay serves a recorded sequence in its order, frame for frame; expected a camera "
            "that streams for the live view (--rig sim, aravis-fake or hw)"
        )
    sock = bind(args.host, args.tcp_port)  # a port in use: one line before any device is opened
    try:
        with open_from_args(args) as rig:
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
                    if signal.getsignal(sig) is not signal.SIG_IGN:  # nohup's SIGHUP stays ignored, as asked
                        loop.add_signal_handler(sig, stopping)
                await server.serve(stop)

            with handlers_kept():  # asyncio sets the signals it took to their default action when it closes
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
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1); any other address serves the page only to the URL with "
        "the session token printed at start",
    )
    live.add_argument(
        "--port", dest="tcp_port", type=_port, default=DEFAULT_PORT, help=f"TCP port (default {DEFAULT_PORT}; 0: any)"
    )
    live.add_argument("--runs", default="runs", metavar="DIR", help="folder of the run folders (default runs)")
    live.add_argument("--target", default="D65", type=target_value, help=TARGET_HELP)
    add_rig_options(live, live=True)
    live.set_defaults(handler=_live)
