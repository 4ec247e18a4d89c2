"""``msflash booth-emulator`` and ``msflash doctor``."""

from __future__ import annotations

import argparse
import math
import sys
import threading
from pathlib import Path

from msflash.acquisition.app.cli_common import UsageError, print_json, progress
from msflash.led_controller.booth import sigterm_as_exit
from msflash.led_controller.doctor import run_doctor
from msflash.led_controller.emulator import DEFAULT_NAMES, DEFAULT_PEAKS_NM, BoothEmulator, serve_on_pty


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``booth-emulator`` and ``doctor`` subcommands."""
    emu = subparsers.add_parser(
        "booth-emulator",
        help="serve the booth firmware emulator on a pseudo-terminal",
        description="Serve the msflash booth emulator on a new pty; prints the port path on stdout "
        "and runs until Ctrl-C.",
    )
    emu.add_argument("--names", default=",".join(DEFAULT_NAMES), help="comma-separated channel names")
    emu.add_argument(
        "--peaks-nm", default=",".join(f"{p:g}" for p in DEFAULT_PEAKS_NM),
        help="comma-separated peak wavelengths in nm, one per name",
    )
    emu.add_argument("--watchdog-s", type=float, default=3.0, help="host-silence timeout (0 disables)")
    emu.set_defaults(handler=booth_emulator)

    doc = subparsers.add_parser(
        "doctor", help="check USB3 Vision, GigE and serial setup", description="Check the host for cameras and booths."
    )
    doc.add_argument("--json", action="store_true", help="print one JSON object")
    doc.add_argument("--sysfs-root", type=Path, default=Path("/sys"), help=argparse.SUPPRESS)
    doc.add_argument("--dev-root", type=Path, default=Path("/dev"), help=argparse.SUPPRESS)
    doc.add_argument("--proc-root", type=Path, default=Path("/proc"), help=argparse.SUPPRESS)
    doc.set_defaults(handler=doctor)


def _emulator_from_args(args: argparse.Namespace) -> BoothEmulator:
    names = [n for n in args.names.split(",") if n]
    try:
        peaks = [float(p) for p in args.peaks_nm.split(",") if p]
    except ValueError as err:
        raise UsageError(f"--peaks-nm {args.peaks_nm!r}: not numbers; expected e.g. 440,480,500") from err
    if len(names) != len(peaks):
        raise UsageError(f"--names/--peaks-nm: {len(names)} names but {len(peaks)} peaks; expected one peak per name")
    if not 0 <= args.watchdog_s < math.inf:
        raise UsageError(f"--watchdog-s {args.watchdog_s}: not a finite time ≥ 0; expected 0 (off) or a positive "
                         "number of seconds")
    try:
        return BoothEmulator(names=names, peaks_nm=peaks, watchdog_s=args.watchdog_s)
    except ValueError as err:
        raise UsageError(f"booth-emulator: {err}") from err


def booth_emulator(args: argparse.Namespace, *, stop: threading.Event | None = None) -> int:
    """Serve the emulator; print its port path on stdout; run until Ctrl-C/SIGTERM (or ``stop``)."""
    emulator = _emulator_from_args(args)
    stop = stop or threading.Event()
    with sigterm_as_exit(), serve_on_pty(emulator) as server:
        # From the moment the port is printed a client may connect and press Ctrl-C: the handler covers it.
        try:
            sys.stdout.write(server.port + "\n")
            sys.stdout.flush()
            progress(f"booth emulator on {server.port} ({len(emulator.names)} channels); Ctrl-C to stop")
            while not stop.wait(0.2):
                pass
        except (KeyboardInterrupt, SystemExit):
            progress("booth emulator stopped")
    return 0


def doctor(args: argparse.Namespace) -> int:
    """Run the host checks; exit 1 if any check failed."""
    findings = run_doctor(sysfs_root=args.sysfs_root, dev_root=args.dev_root, proc_root=args.proc_root)
    failed = any(f.status == "fail" for f in findings)
    if getattr(args, "json", False):
        print_json({"ok": not failed, "findings": [f.as_dict() for f in findings]})
    else:
        for f in findings:
            sys.stdout.write(f"{f.status.upper():5} {f.check}: {f.message}\n")
            if f.remedy and f.status != "ok":
                sys.stdout.write(f"      remedy: {f.remedy}\n")
    return 1 if failed else 0
