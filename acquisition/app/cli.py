"""The ``msflash`` command line (docs/architecture.md §7).

Subcommands live in small modules that each expose ``register(subparsers)``; this module builds
the parser, dispatches, and turns errors into exit statuses: bad input → 2 with one line
``msflash: error: …``; a device or runtime failure → 1; Ctrl-C → 130 (LEDs are switched off by
the code that switched them on, in ``finally``). Anything else is a bug: the last line of defence
(:func:`_crashed`) prints one line naming the command and what failed, writes the full traceback
to a crash log (:func:`crash_log_directory`) whose path that line gives, and exits 1.

Start-up is kept short: only the module of the command being run is imported (it imports its
numerical and hardware libraries); the others are listed by name and one-line help from
:data:`COMMANDS`, so ``msflash --help`` and ``--version`` import none of them.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import logging
import os
import re
import signal
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any, NoReturn

from msflash.acquisition.app.cli_common import UsageError
from msflash.acquisition.errors import bad_input_errors, runtime_errors
from msflash.acquisition.progress import bars_wanted, close_bar
from msflash.acquisition.progress import configure as configure_progress
from msflash.acquisition.signals import Terminated, carried_stop, command_signals, received

COMMANDS: dict[str, tuple[str, str]] = {
    "estimate": ("msflash.acquisition.app.cli_process", "estimate the ambient illuminant spectrum of a sequence"),
    "flash": ("msflash.acquisition.app.cli_process", "solve the matching or complementary flash for a sequence"),
    "synthesize": ("msflash.acquisition.app.cli_process", "synthesise the computational flash image from a sequence"),
    "check": (
        "msflash.acquisition.app.cli_check",
        "check every frame file of a sequence against the SHA-256 recorded when it was written",
    ),
    "export": (
        "msflash.acquisition.app.cli_export",
        "write a sequence as DNG (raw frames), OME-TIFF (all frames), CSV (spectra) or EXR (linear images)",
    ),
    "run": (
        "msflash.acquisition.app.cli_run",
        "the main job: capture, estimate, flash, re-capture, synthesise, report",
    ),
    "capture": ("msflash.acquisition.app.cli_run", "capture an ambient + each-LED sequence on a rig"),
    "live": (
        "msflash.acquisition.app.cli_live",
        "serve a browser page on 127.0.0.1: live image, exposure, gain, LED levels, fire a sequence, its spectrum",
    ),
    "bench": ("msflash.lab.cli_bench", "measure speed as ratios in one run (processing, camera, booth)"),
    "devices": (
        "msflash.acquisition.app.cli_devices",
        "list cameras (Aravis) on the given interfaces, and booths among the serial ports",
    ),
    "booth-emulator": ("msflash.acquisition.app.cli_booth", "serve the booth firmware emulator on a pseudo-terminal"),
    "doctor": ("msflash.acquisition.app.cli_booth", "check USB3 Vision, GigE and serial setup"),
    "booth": (
        "msflash.acquisition.app.cli_booth_console",
        "booth bring-up: 'booth console PORT' is an interactive prompt",
    ),
    "study": (
        "msflash.lab.cli_study",
        "simulation studies (table1: Table 1; surfaces: Fig. 5; cameras: Fig. 6; xy: Fig. 7; "
        "failure: where estimates fail and whether they warn; pareto: accuracy vs time)",
    ),
    "evaluate": (
        "msflash.acquisition.app.cli_evaluate",
        "ΔE00 against the chart under D65 and noise, for a chart sequence",
    ),
    "colour-study": (
        "msflash.lab.cli_colour_study",
        "simulated Fig. 9 (ΔE per ambient) and Fig. 3 (noise) study",
    ),
    "calibrate": (
        "msflash.acquisition.app.cli_calibrate",
        "measure LED spectra, camera responsivities, dark and linearity",
    ),
    "local-study": (
        "msflash.lab.cli_local",
        "study local vs global ambient estimation on simulated scenes",
    ),
}
"""Subcommands in help order: name → (module whose ``register`` adds it, the help line it gives it).

``bench``, ``study``, ``colour-study`` and ``local-study`` belong to the lab (``msflash.lab``, outside the
product: an import contract forbids the product to import it): they are named here, imported only when
run, and left out of the help when the lab is not installed.

The help line is what ``msflash --help`` lists without importing the module; a test checks it
against the module's own registration."""


def _signal_name(number: int) -> str:
    """``SIGTERM`` for 15, ``SIGHUP`` for 1; ``signal N`` for a number without a name.

    >>> _signal_name(1), _signal_name(15), _signal_name(99)
    ('SIGHUP', 'SIGTERM', 'signal 99')
    """
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


def msflash_version() -> str:
    """The installed msflash version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("msflash")
    except PackageNotFoundError:
        return "0+unknown"


class _VersionAction(argparse._VersionAction):
    """``--version``: the installed version, looked up only when asked (importlib.metadata takes a while to import)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        self.version = f"msflash {msflash_version()}"
        super().__call__(parser, namespace, values, option_string)


NEGATIVE_VALUE = re.compile(r"^-(?:\.?\d|inf|nan)", re.IGNORECASE)
"""A word that argparse takes as a value, not an option: a minus then a digit (``-5,0,0``, ``-1e3``, ``-.5``,
``-10:20``) or ``-inf``/``-nan`` (then refused as what the option expects). argparse's own pattern takes only
``-5`` and ``-0.5``: ``--weights -5,0,0`` was "expected one argument", naming nothing it expects. No msflash
option looks like that (a test checks), so none is shadowed."""


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors exit with status 2 and one ``msflash: error:`` line, whose
    refusal of a choice (a command, ``--solver``, ``--model``…) says which one was meant
    (:func:`processing.names.unknown_name`), and which reads a value beginning with a minus and a digit
    (:data:`NEGATIVE_VALUE`) as the value of the option before it."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_VALUE

    def error(self, message: str) -> NoReturn:
        missing = re.match(r"argument (--[\w-]+)(?:/\S+)?: expected (?:one|at least one) argument$", message)
        if missing is not None:  # the next word began with '-': an option to argparse
            option = missing.group(1)
            message += f"; a value that begins with '-' is written {option}=VALUE (a file: {option} ./-NAME)"
        raise UsageError(message)

    def _check_value(self, action: argparse.Action, value: Any) -> None:
        if action.choices is not None and value not in action.choices:
            from msflash.processing.names import unknown_name

            where = "/".join(action.option_strings) or ("command" if action.dest == "command" else action.metavar)
            raise argparse.ArgumentError(None, unknown_name(str(where or action.dest), value, list(action.choices)))


def _command_module(argv: Sequence[str]) -> str | None:
    """The module of the command named in ``argv`` (its first word not starting with ``-``), if it is one.

    >>> _command_module(["-v", "estimate", "SEQ", "--json"])
    'msflash.acquisition.app.cli_process'
    >>> _command_module(["--help"]) is None
    True
    """
    word = next((item for item in argv if not item.startswith("-")), None)
    return COMMANDS[word][0] if word in COMMANDS else None


def _present(module_name: str) -> bool:
    """Whether a command module is part of this build (found without importing it)."""
    return importlib.util.find_spec(module_name) is not None


def _command_module_or_none(name: str) -> ModuleType | None:
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as err:
        if err.name == name:
            return None  # a command module not present in this build
        raise


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser, whose subcommands set ``handler``; with ``argv`` naming a command, only that command's
    module registers its options (the others are listed by name and help line); else every module does."""
    parser = _Parser(
        prog="msflash", description="Computational multispectral flash: capture, estimate, flash, synthesise."
    )
    parser.add_argument("--version", action=_VersionAction)
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more diagnostics on stderr (-vv: serial byte trace)"
    )
    parser.add_argument(
        "--memory-budget",
        metavar="SIZE",
        help="most memory a read may decode (800M, 2G …; accepted anywhere on the line); default 25%% of the "
        "memory available. A frame (or a stack of frames) past it is refused unread, exit 2",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    wanted = None if argv is None else _command_module(argv)
    registered: set[str] = set()
    for command, (module_name, summary) in COMMANDS.items():
        if module_name in registered:
            continue
        if argv is None or module_name == wanted:
            registered.add(module_name)
            module = _command_module_or_none(module_name)
            if module is not None:
                module.register(subparsers)
        elif _present(module_name):
            subparsers.add_parser(command, help=summary)
    return parser


CAPTURE_COMMANDS = frozenset({"run", "capture"})
"""Commands that write a sequence: their stop line says what they kept (:func:`_what_was_kept`)."""
BOOTH_COMMANDS = frozenset({"live", "booth", "booth-emulator", "bench"})
"""Commands that drive a booth (or serve one) but write no sequence: their stop line says the LEDs are off."""


def _stop_line(words: Sequence[str], how: str) -> str:
    r"""The one line a stopped command ends with: how it stopped and, for a capture, what it kept.

    Only what is true of the command: a capture's LEDs and sequence, a booth's LEDs, nothing more for
    the rest (``estimate``, ``export``, ``devices``, ``doctor``, ``calibrate`` … drive no LED and capture
    no frame).

    >>> _stop_line(["export", "SEQ", "--to", "dng"], "interrupted")
    'msflash: interrupted\n'
    >>> _stop_line(["booth", "console", "/dev/ttyACM0"], "interrupted")
    'msflash: interrupted; LEDs off\n'
    """
    command = next((word for word in words if not word.startswith("-")), None)
    if command in CAPTURE_COMMANDS:
        return f"msflash: {how}; LEDs off{_what_was_kept()}\n"
    if command in BOOTH_COMMANDS:
        return f"msflash: {how}; LEDs off\n"
    return f"msflash: {how}\n"


def _what_was_kept() -> str:
    """What a stopped command leaves, truthfully: the sequence it wrote, complete or cut short (marked so), or none."""
    written = sys.modules.get("msflash.acquisition.sequence.writer")  # loaded only if a sequence was touched
    latest = written.latest_sequence_written() if written is not None else None
    if latest is None:
        # Stopped before its sequence was begun (the rig still opening, the exposure being metered): no frame
        # was kept, and the --out folder it made, still empty, is removed (cli_common.claimed_output).
        return "; stopped before the sequence began: no frame was captured"
    from msflash.processing.user_files import printable

    directory, complete = printable(str(latest[0])), latest[1]
    if complete:
        return f"; the sequence in {directory} was complete before the stop and stays so"
    return f"; frames captured so far are kept (marked incomplete) in {directory}"


def _take_memory_budget(words: list[str]) -> list[str]:
    """``words`` without ``--memory-budget SIZE`` (wherever it stands), the budget set from it (or reset).

    >>> _take_memory_budget(["estimate", "SEQ", "--memory-budget", "2G"])
    ['estimate', 'SEQ']
    """
    from msflash.acquisition.sequence.memory_budget import parse_size, set_memory_budget

    budget = None
    kept: list[str] = []
    rest = iter(words)
    for word in rest:
        if word == "--":
            kept += [word, *rest]
            break
        if word == "--memory-budget" or word.startswith("--memory-budget="):
            value = word.partition("=")[2] if "=" in word else next(rest, None)
            if value is None:
                raise UsageError("--memory-budget: expected a size such as 800M or 2G")
            budget = parse_size(value)
            continue
        kept.append(word)
    set_memory_budget(budget)
    return kept


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``msflash``; returns the exit status (tests call this directly).

    Every stopping signal unwinds the command as Ctrl-C does (an export's staging folder, a half-written image, a
    local dask cluster are cleaned up by the blocks they unwind; LEDs go off), from the first instruction to the
    last (:func:`~acquisition.signals.command_signals`): one landing while the line is parsed or the command's
    module imported, or just as the command finished, is said in one line too; a second one cannot cut the
    cleanup the first one unwinds.
    """
    words = list(argv if argv is not None else sys.argv[1:])
    written = sys.modules.get("msflash.acquisition.sequence.writer")
    if written is not None:  # an earlier command in this process (tests, a notebook) wrote one
        written.forget_latest_sequence()
    with command_signals() as signals:
        try:
            status, exit_at_once = _outcome(words)
            signals.quiet()  # from here a signal is recorded, and said below
        except (KeyboardInterrupt, Terminated) as stop:  # the first signal, landing while an outcome was written
            status, exit_at_once = _stopped(words, stop), False
        signals.close()  # a stop lost at the very end and delivered again is recorded by now, to be said below
        if signals.raised is None and signals.late:  # it landed as the command finished: said, not lost
            number = signals.late[0]
            status = _stopped(words, KeyboardInterrupt() if number == signal.SIGINT else Terminated(128 + number))
        if argv is None and exit_at_once:
            _exit_at_once(status)
    return status


def _outcome(words: list[str]) -> tuple[int, bool]:
    """Parse ``words``, run the command; its exit status (errors turned into one line) and whether it asked to
    leave at once (:func:`_exit_at_once`)."""
    try:
        words = _take_memory_budget(words)
        parser = build_parser(words)
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning  # from the parsing on: a --target file's warning is read then
            args = parser.parse_args(words)
            _quiet_libraries(args.verbose)
            configure_progress(bars=bars_wanted(bool(getattr(args, "json", False))))
            if not getattr(args, "handler", None):
                parser.print_help(sys.stderr)
                return 2, False
            status = int(args.handler(args))
        return status, bool(getattr(args, "exit_at_once", False))
    except (KeyboardInterrupt, Terminated) as stop:
        return _stopped(words, stop), False
    except BrokenPipeError:
        # The reader of stdout went away (``msflash estimate SEQ | head``): stop quietly, and keep
        # Python from complaining again when it flushes stdout at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141, False
    except bad_input_errors() as err:
        sys.stderr.write(f"msflash: error: {_one_line(err)}\n")
        return _or_its_stop(words, err, 2), False
    except runtime_errors() as err:
        sys.stderr.write(f"msflash: error: {_one_line(err)}\n")
        return _or_its_stop(words, err, 1), False
    except Exception as err:  # the last line of defence: a bug, not bad input (KeyboardInterrupt/SystemExit pass)
        return _or_its_stop(words, err, _crashed(words, err)), False
    finally:
        close_bar()


def _or_its_stop(words: Sequence[str], error: BaseException, status: int) -> int:
    """``status``, the error's (its line written); or, when the error was raised by a cleanup that a stop unwound
    (:func:`~acquisition.signals.carried_stop`), the stop's, its line written after the error's."""
    stop = carried_stop(error)
    return status if stop is None else _stopped(words, stop)


def _stopped(words: Sequence[str], stop: BaseException) -> int:
    """The stop line of a command stopped by Ctrl-C (130) or SIGTERM/SIGHUP (128 + the signal's number), written."""
    received(stop)  # acted on here: dropping it stops nothing twice
    if isinstance(stop, KeyboardInterrupt):
        line, code = _stop_line(words, "interrupted"), 130
    else:
        given = getattr(stop, "code", None)  # Terminated is a SystemExit: 128 + the signal's number
        code = int(given) if isinstance(given, int) else 128 + signal.SIGTERM
        line = _stop_line(words, f"terminated ({_signal_name(code - 128)})")
    with contextlib.suppress(OSError):  # after SIGHUP the terminal may be gone
        sys.stderr.write(line)
    return code


def _exit_at_once(code: int) -> None:
    """End the process now, its work done (a command that set ``exit_at_once``, run as the program).

    ``msflash live`` sets it once the LEDs are off and the rig is closed, to skip the interpreter's teardown
    (its final collection took most of the 2 s ``live`` promises to be gone in: docs/reliability.md §7).
    Output and log records are flushed first.
    """
    close_bar()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


def _quiet_libraries(verbose: int) -> None:
    """Log records on stderr from WARNING up, INFO with ``-v``, DEBUG with ``-vv``: ours and every library's.

    The level is set on the handler as well as on the root logger: dask.distributed sets its own loggers to INFO.
    """
    level = logging.WARNING - 10 * min(verbose, 2)
    root = logging.getLogger()
    if not root.handlers:  # else someone else (a test's log capture, a notebook) owns logging: left alone
        ours = logging.StreamHandler(sys.stderr)
        ours.setFormatter(logging.Formatter("msflash: %(name)s: %(message)s"))
        ours.set_name(_LOG_HANDLER)
        root.addHandler(ours)
    for handler in root.handlers:
        if handler.get_name() == _LOG_HANDLER:
            handler.setLevel(level)
            root.setLevel(level)


_LOG_HANDLER = "msflash-stderr"


CRASH_LOG_ENV = "MSFLASH_CRASH_DIR"
"""Environment variable naming the crash-log directory (overrides :func:`crash_log_directory`'s default)."""


def crash_log_directory() -> Path:
    """Where crash logs go: ``$MSFLASH_CRASH_DIR``, else ``$XDG_STATE_HOME/msflash`` (default
    ``~/.local/state/msflash``)."""
    if os.environ.get(CRASH_LOG_ENV):
        return Path(os.environ[CRASH_LOG_ENV])
    state = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return Path(state) / "msflash"


def _command_name(words: Sequence[str]) -> str:
    return next((w for w in words if not w.startswith("-")), "msflash")


def _crashed(words: Sequence[str], err: Exception) -> int:
    """One line on stderr naming the command and what failed, the traceback in a crash log; status 1."""
    import time
    import traceback

    command = _command_name(words)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    text = (
        f"msflash {msflash_version()} crashed\ncommand: msflash {' '.join(map(repr, words))}\n"
        f"python: {sys.version.split()[0]}\n\n" + "".join(traceback.format_exception(err))
    )
    where = "nowhere (the crash log could not be written)"
    for directory in (crash_log_directory(), Path(os.environ.get("TMPDIR") or "/tmp")):
        path = directory / f"crash-{stamp}-{os.getpid()}.log"
        try:
            directory.mkdir(parents=True, exist_ok=True)
            with open(path, "x", encoding="utf-8", errors="backslashreplace") as stream:
                stream.write(text)
        except OSError:
            continue
        where = str(path)
        break
    message = " ".join((str(err) or "").split())
    if len(message) > 300:
        message = message[:300] + "…"
    sys.stderr.write(
        f"msflash: {command}: unexpected {type(err).__name__}"
        f"{': ' + message if message else ''} — a bug; details in {where}\n"
    )
    return 1


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: object = None,
    line: str | None = None,
) -> None:
    """A warning as one line saying what it means, not a source line the user cannot act on.

    numpy's RuntimeWarnings (invalid value, divide by zero, overflow) mean a computation met
    NaN, infinity or zero where the code did not expect it: the result it printed may hold NaN.
    """
    text = " ".join(str(message).split())
    if issubclass(category, RuntimeWarning) and " encountered in " in text:  # numpy's floating-point errors
        sys.stderr.write(
            f"msflash: warning: a numerical step met {text!r} (numpy); results computed from it "
            "may hold NaN or infinity — check the input for empty, saturated or constant frames\n"
        )
        return
    sys.stderr.write(f"msflash: warning: {text} ({category.__name__})\n")


def _one_line(err: BaseException) -> str:
    text = str(err) or type(err).__name__
    if isinstance(err, FileNotFoundError) and err.filename:
        text = f"{err.filename}: not found"
    return " ".join(text.split())


if __name__ == "__main__":
    sys.exit(main())
