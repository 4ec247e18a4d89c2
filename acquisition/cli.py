"""The ``msflash`` command line (DESIGN §7).

Subcommands live in small modules that each expose ``register(subparsers)``; this module builds
the parser, dispatches, and turns errors into exit statuses: bad input → 2 with one line
``msflash: error: …``; a device or runtime failure → 1; Ctrl-C → 130 (LEDs are switched off by
the code that switched them on, in ``finally``). Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

from acquisition.cli_common import UsageError
from acquisition.errors import CameraError, CaptureError, RecordingError
from processing.errors import SolverError, SpectralDataError
from led_controller.booth import Terminated

COMMAND_MODULES = (
    "acquisition.cli_process",
    "acquisition.cli_run",
    "acquisition.cli_bench",
    "acquisition.cli_devices",
    "acquisition.cli_booth",
    "acquisition.cli_study",
    "acquisition.cli_evaluate",
    "acquisition.cli_calibrate",
    "acquisition.cli_local",
)
"""Modules contributing subcommands, in help order."""

_BAD_INPUT = (UsageError, RecordingError, SpectralDataError, FileNotFoundError)


def _bad_input_errors() -> tuple[type[BaseException], ...]:
    errors: list[type[BaseException]] = list(_BAD_INPUT)
    try:
        from calibration.errors import CalibrationError
    except ImportError:  # the calibration package is optional for processing-only use
        pass
    else:
        errors.append(CalibrationError)
    return tuple(errors)


def _runtime_errors() -> tuple[type[BaseException], ...]:
    errors: list[type[BaseException]] = [CameraError, CaptureError, SolverError]
    try:
        from led_controller.errors import BoothError
    except ImportError:  # the booth package is optional for processing-only use
        pass
    else:
        errors.append(BoothError)
    return tuple(errors)


def msflash_version() -> str:
    """The installed msflash version."""
    try:
        return version("msflash")
    except PackageNotFoundError:
        return "0+unknown"


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors exit with status 2 and one ``msflash: error:`` line."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    """The full parser with every available subcommand."""
    parser = _Parser(prog="msflash", description="Computational multispectral flash: capture, estimate, flash, synthesise.")
    parser.add_argument("--version", action="version", version=f"msflash {msflash_version()}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more diagnostics on stderr (-vv: serial byte trace)")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as err:
            if err.name == name:
                continue  # a command module not present in this build
            raise
        module.register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``msflash``; returns the exit status (tests call this directly)."""
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        logging.basicConfig(
            level=logging.WARNING - 10 * min(args.verbose, 2), format="msflash: %(name)s: %(message)s",
            stream=sys.stderr,
        )
        if not getattr(args, "handler", None):
            parser.print_help(sys.stderr)
            return 2
        return int(args.handler(args))
    except KeyboardInterrupt:
        sys.stderr.write("msflash: interrupted; LEDs off; frames captured so far are kept (marked incomplete)\n")
        return 130
    except Terminated as stop:
        sys.stderr.write("msflash: terminated (SIGTERM); LEDs off; frames captured so far are kept (marked "
                         "incomplete)\n")
        return int(stop.code) if isinstance(stop.code, int) else 143
    except BrokenPipeError:
        # The reader of stdout went away (``msflash estimate SEQ | head``): stop quietly, and keep
        # Python from complaining again when it flushes stdout at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except _bad_input_errors() as err:
        sys.stderr.write(f"msflash: error: {_one_line(err)}\n")
        return 2
    except _runtime_errors() as err:
        sys.stderr.write(f"msflash: error: {_one_line(err)}\n")
        return 1


def _one_line(err: BaseException) -> str:
    text = str(err) or type(err).__name__
    if isinstance(err, FileNotFoundError) and err.filename:
        text = f"{err.filename}: not found"
    return " ".join(text.split())


if __name__ == "__main__":
    sys.exit(main())
