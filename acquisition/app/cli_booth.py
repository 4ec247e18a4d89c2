"""``msflash booth-emulator`` and ``msflash doctor``."""

from __future__ import annotations

import argparse
import math
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from msflash.acquisition.app.cli_common import (
    UsageError,
    add_booth_boot_option,
    boot_seconds,
    number,
    print_json,
    progress,
    seed_int,
    serial_port,
    whole,
)
from msflash.acquisition.signals import received, sigterm_as_exit
from msflash.led_controller.booth_probe import PROBE_PROTOCOLS, probe_booth
from msflash.led_controller.doctor import Finding, run_doctor
from msflash.led_controller.emulator import DEFAULT_NAMES, DEFAULT_PEAKS_NM, BoothEmulator
from msflash.led_controller.emulator_faults import FaultInjector, emulator_state, parse_fault_spec, write_state_file
from msflash.led_controller.emulator_pty import serve_on_pty
from msflash.led_controller.errors import BoothError
from msflash.led_controller.usb_link import FTDI_LATENCY_S, MEGA_BOOTLOADER_S


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``booth-emulator`` and ``doctor`` subcommands."""
    _register_emulator(subparsers)
    _register_doctor(subparsers)


def _register_emulator(subparsers: argparse._SubParsersAction) -> None:
    """``booth-emulator``: the firmware emulator on a new pty, its board's link and random faults."""
    emu = subparsers.add_parser(
        "booth-emulator",
        help="serve the booth firmware emulator on a pseudo-terminal",
        description="Serve the msflash booth emulator on a new pty; prints the port path on stdout "
        "and runs until Ctrl-C.",
    )
    emu.add_argument("--names", default=",".join(DEFAULT_NAMES), help="comma-separated channel names")
    emu.add_argument(
        "--peaks-nm",
        default=",".join(f"{p:g}" for p in DEFAULT_PEAKS_NM),
        help="comma-separated peak wavelengths in nm, one per name",
    )
    emu.add_argument("--watchdog-s", type=number, default=3.0, help="host-silence timeout (0 disables)")
    link = emu.add_argument_group("the board's link (a stock Arduino Mega's by default)")
    link.add_argument(
        "--no-auto-reset",
        action="store_true",
        help="a board with auto-reset disabled (10 µF RESET–GND, or RESET-EN cut): opening the port does not "
        "reset it; by default every open resets it as a stock Mega's does (LEDs off, the bootloader "
        "swallowing what is sent for --bootloader-s, then the firmware's BOOT banner)",
    )
    link.add_argument(
        "--bootloader-s",
        type=boot_seconds,
        default=MEGA_BOOTLOADER_S,
        metavar="S",
        help="how long the bootloader owns the port after a reset, in wall-clock seconds (default %(default)g)",
    )
    link.add_argument(
        "--latency-ms",
        type=boot_seconds,
        default=FTDI_LATENCY_S * 1000,
        metavar="MS",
        help="the USB-serial chip's latency timer: replies shorter than a USB packet wait for its next tick "
        "(default %(default)g, an FTDI chip's; 0: none)",
    )
    link.add_argument(
        "--serial",
        default=None,
        metavar="TEXT",
        help="the serial in the board's EEPROM (ID's SERIAL=; default: never set); SERIAL <text> changes it",
    )
    emu.add_argument(
        "--fault",
        default=None,
        metavar="KIND:P,…",
        help="random link faults, each KIND at most once: drop:P / flip:P (a byte lost / a bit flipped "
        "in an outgoing frame), garble:P (a bit flipped in a request), stall:P[:SECONDS] (stop "
        "answering, for good without SECONDS), close:P (hang up); P per frame, e.g. "
        "drop:0.01,flip:0.001",
    )
    emu.add_argument("--seed", type=seed_int, default=0, help="seed of the fault draws (default 0)")
    emu.add_argument(
        "--fault-after",
        type=whole,
        default=0,
        metavar="N",
        help="let the first N requests through unfaulted (default 0)",
    )
    emu.add_argument(
        "--state-file",
        type=Path,
        default=None,
        metavar="FILE.json",
        help="keep the booth's state (LEDs, sequencer, watchdog, faults injected) in this JSON file, "
        "rewritten when it changes and at exit",
    )
    emu.set_defaults(handler=booth_emulator)


def _register_doctor(subparsers: argparse._SubParsersAction) -> None:
    """``doctor``: the host's cameras and booths, or one named port asked who it is."""
    doc = subparsers.add_parser(
        "doctor", help="check USB3 Vision, GigE and serial setup", description="Check the host for cameras and booths."
    )
    doc.add_argument("--json", action="store_true", help="print one JSON object")
    doc.add_argument(
        "--port",
        type=serial_port,
        default=None,
        help="ask the booth on PORT who it is (only this port is opened; nothing is sent to other ports); "
        "prints its firmware, channels and names, or what answered instead (exit 1; a PORT that does not exist: "
        "exit 2)",
    )
    doc.add_argument(
        "--booth-protocol",
        choices=PROBE_PROTOCOLS,
        default="msflash",
        help="the protocol to ask --port in: msflash (our firmware) or text (plain-text booth); default %(default)s",
    )
    doc.add_argument("--timeout-s", type=number, default=1.0, help="--port: reply timeout in seconds (default 1)")
    add_booth_boot_option(doc)
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
        raise UsageError(
            f"--watchdog-s {args.watchdog_s}: not a finite time ≥ 0; expected 0 (off) or a positive number of seconds"
        )
    try:
        return BoothEmulator(
            names=names, peaks_nm=peaks, watchdog_s=args.watchdog_s, serial=getattr(args, "serial", None)
        )
    except ValueError as err:
        raise UsageError(f"booth-emulator: {err}") from err


def _faults_from_args(args: argparse.Namespace, emulator: BoothEmulator) -> FaultInjector | None:
    if getattr(args, "fault_after", 0) < 0:
        raise UsageError(f"--fault-after {args.fault_after}: negative; expected a number of requests ≥ 0")
    if getattr(args, "fault", None) is None:
        return None
    try:
        rates = parse_fault_spec(args.fault)
    except ValueError as err:
        raise UsageError(str(err)) from err
    return FaultInjector(emulator, rates, seed=args.seed, after=args.fault_after)


def booth_emulator(args: argparse.Namespace, *, stop: threading.Event | None = None) -> int:
    """Serve the emulator; print its port path on stdout; run until Ctrl-C/SIGTERM (or ``stop``).

    A ``close`` fault ends the command (exit 0) once the link is hung up; ``--state-file`` is
    written last, before the emulator is stopped (stopping switches its LEDs off).
    """
    emulator = _emulator_from_args(args)
    injector = _faults_from_args(args, emulator)
    state_file: Path | None = getattr(args, "state_file", None)
    stop = stop or threading.Event()
    auto_reset = not getattr(args, "no_auto_reset", False)
    bootloader_s = float(getattr(args, "bootloader_s", MEGA_BOOTLOADER_S))
    latency_s = float(getattr(args, "latency_ms", FTDI_LATENCY_S * 1000)) / 1000
    link = {"auto_reset": auto_reset, "bootloader_s": bootloader_s, "latency_s": latency_s}
    with (
        sigterm_as_exit(),
        serve_on_pty(emulator, auto_reset=auto_reset, bootloader_s=bootloader_s, latency_s=latency_s) as server,
    ):
        last: dict | None = None

        def record() -> None:
            nonlocal last
            state = emulator_state(emulator, injector, port=server.port, link="closed" if server.closed else "open")
            if state_file is not None and state != last:
                write_state_file(state_file, state)
                last = state

        # From the moment the port is printed a client may connect and press Ctrl-C: the handler covers it.
        try:
            record()
        except OSError as err:
            raise UsageError(
                f"--state-file {state_file}: cannot write it ({err.strerror or err}); expected a file "
                "path in a writable directory"
            ) from err
        try:
            sys.stdout.write(server.port + "\n")
            sys.stdout.flush()
            progress(
                f"booth emulator on {server.port} ({len(emulator.names)} channels; "
                + (
                    f"resets when its port opens, bootloader {link['bootloader_s']:g} s"
                    if link["auto_reset"]
                    else "auto-reset disabled"
                )
                + f", USB latency {link['latency_s'] * 1000:g} ms)"
                + (f", faults {args.fault} (seed {args.seed})" if injector is not None else "")
                + "; Ctrl-C to stop"
            )
            while not stop.wait(0.05 if state_file is not None else 0.2):
                record()
                if server.closed:
                    progress("booth emulator: the link was hung up (fault close); stopped")
                    break
        except (KeyboardInterrupt, SystemExit) as caught:
            received(caught)
            progress("booth emulator stopped")
        finally:
            if state_file is not None:
                record()
    return 0


def aravis_finding(import_camera: Callable[[], Any] | None = None) -> Finding:
    """Whether the Aravis 0.8 typelib imports (``gi.require_version('Aravis', '0.8')``): no camera without it.

    ``import_camera`` imports msflash's Aravis camera module (the one place that imports ``gi``); tests
    pass their own to stand for a machine without the typelib, which cannot be uninstalled here.
    """

    def default_import() -> Any:
        from msflash.acquisition.devices.aravis import camera

        return camera

    try:
        camera = (import_camera or default_import)()
    except ImportError as err:
        return Finding(
            "aravis.typelib",
            "fail",
            f"Aravis cannot be used: {err}",
            "sudo apt install gir1.2-aravis-0.8 python3-gi (setup.sh installs them); without it only the sim "
            "and replay rigs work",
        )
    version = getattr(getattr(camera, "Aravis", None), "_version", "0.8")
    return Finding("aravis.typelib", "ok", f"the Aravis {version} typelib imports (GObject introspection)")


def doctor(args: argparse.Namespace) -> int:
    """Run the host checks; exit 1 if any check warned or failed. With ``--port``: ask that one booth who it is."""
    if getattr(args, "port", None) is not None:
        return _doctor_port(args)
    findings = [
        aravis_finding(),
        *run_doctor(sysfs_root=args.sysfs_root, dev_root=args.dev_root, proc_root=args.proc_root),
    ]
    failed = any(f.status in ("fail", "warn") for f in findings)
    if getattr(args, "json", False):
        print_json({"ok": not failed, "findings": [f.as_dict() for f in findings]})
    else:
        for f in findings:
            sys.stdout.write(f"{f.status.upper():5} {f.check}: {f.message}\n")
            if f.remedy and f.status != "ok":
                sys.stdout.write(f"      remedy: {f.remedy}\n")
    return 1 if failed else 0


def _doctor_port(args: argparse.Namespace) -> int:
    """``doctor --port P``: the booth's identity in ``--booth-protocol``, or one line and exit 1 (a port that does not
    exist was refused when parsed, exit 2, as by every command that takes a port)."""
    if not args.timeout_s > 0:
        raise UsageError(f"--timeout-s {args.timeout_s}: expected a positive number of seconds")
    try:
        found = probe_booth(args.port, args.booth_protocol, timeout_s=args.timeout_s, boot_s=args.booth_boot_s)
    except BoothError as err:  # the device's answer (or silence): a device failure, exit 1, as every command's
        raise BoothError(f"{err} (--booth-protocol {args.booth_protocol})") from err
    if getattr(args, "json", False):
        print_json({"ok": True, "booth": {**found.__dict__, "names": list(found.names)}})
        return 0
    sys.stdout.write(
        f"OK    booth.identity: booth {found.port} answers --booth-protocol {found.protocol}: "
        f"firmware {found.firmware!r}; {found.channels} channels: {' '.join(found.names)}"
        + (
            f"; serial {found.serial}"
            if found.serial
            else "; serial not set (booth console: serial TEXT)"
            if found.protocol == "msflash"
            else ""
        )
        + "\n"
    )
    return 0
