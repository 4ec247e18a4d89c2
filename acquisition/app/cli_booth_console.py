"""``msflash booth console PORT``: an interactive prompt for bringing up a booth.

The logic (parsing, checking, explaining) is :mod:`led_controller.console`; this module only
opens the booth, feeds it lines from stdin and prints what comes back. LEDs go off on every exit
(``quit``, end of input, Ctrl-C, an error), as ``LedBooth``'s context manager does.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from msflash.acquisition.app.cli_common import UsageError, add_booth_boot_option, number, serial_port
from msflash.acquisition.signals import sigterm_as_exit
from msflash.led_controller.adapters import BOOTH_PROTOCOLS, open_booth
from msflash.led_controller.adapters.text_booth import TextBooth
from msflash.led_controller.booth import LedBooth
from msflash.led_controller.console import BoothConsole, ConsoleQuit
from msflash.processing.user_numbers import plain_number, plain_whole_number


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``booth`` command with its ``console`` subcommand."""
    booth = subparsers.add_parser(
        "booth",
        help="booth bring-up: 'booth console PORT' is an interactive prompt",
        description="Tools for one booth on a serial port.",
    )
    actions = booth.add_subparsers(dest="booth_command", metavar="ACTION")
    console = actions.add_parser(
        "console",
        help="type booth commands; see each frame and what it means",
        description="Open the booth on PORT and read commands (levels 0.5 0 1 …, table …, status, help) "
        "from stdin; each is checked, framed, sent, and its reply explained. LEDs off on exit.",
    )
    console.add_argument("port", type=serial_port, help="serial port of the booth (e.g. /dev/ttyACM0)")
    console.add_argument(
        "--booth-protocol",
        choices=BOOTH_PROTOCOLS,
        default=BOOTH_PROTOCOLS[0],
        help="the booth's protocol: msflash (our firmware) or text (plain-text booth); default %(default)s",
    )
    console.add_argument("--timeout-s", type=number, default=2.0, help="reply timeout of each command in seconds")
    add_booth_boot_option(console)
    console.set_defaults(handler=booth_console)
    booth.set_defaults(handler=_booth_without_action)


def _booth_without_action(args: argparse.Namespace) -> int:
    raise UsageError("booth: no action given; expected 'msflash booth console PORT'")


def booth_console(args: argparse.Namespace) -> int:
    """Run the console until ``quit`` or the end of stdin."""
    if not args.timeout_s > 0:
        raise UsageError(f"--timeout-s {args.timeout_s}: expected a positive number of seconds")
    with tempfile.TemporaryDirectory(prefix="msflash-console-") as folder:
        transcript = Path(folder) / "transcript.txt"
        with sigterm_as_exit():
            booth = open_booth(
                args.port,
                args.booth_protocol,
                log_serial=transcript,
                timeout_s=args.timeout_s,
                boot_s=args.booth_boot_s,
            )
            assert isinstance(booth, LedBooth | TextBooth)  # what open_booth opens
            with booth:  # LEDs off on every way out, as each driver's context manager does
                _prompt(BoothConsole(booth, transcript, plain_number, plain_whole_number))  # the one number parser
        _say(["LEDs off"])
    return 0


def _prompt(console: BoothConsole) -> None:
    """Show the booth's identity, then run typed lines until ``quit`` or the end of stdin."""
    interactive = sys.stdin.isatty()
    try:
        _say(console.execute("id"))
        _say(["type help for the commands; quit (or end of input) switches the LEDs off"])
        while True:
            try:
                line = input("booth> ") if interactive else sys.stdin.readline()
            except EOFError:
                break
            if not interactive:
                if not line:
                    break
                _say([f"booth> {line.rstrip()}"])
            try:
                _say(console.execute(line))
            except ConsoleQuit:
                break
    finally:
        console.close()


def _say(lines: list[str]) -> None:
    for line in lines:
        sys.stdout.write(line + "\n")
    sys.stdout.flush()
