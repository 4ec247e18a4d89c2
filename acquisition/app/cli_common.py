"""Conventions shared by every ``msflash`` subcommand module.

Each command module exposes ``register(subparsers)``; each subparser it adds calls
``set_defaults(handler=function)`` where ``function(args) -> int`` returns the exit status.
Bad input raises :class:`UsageError` (exit 2, one line ``msflash: error: …``); device and runtime
failures raise the package error roots (exit 1). ``--json`` output goes through :func:`print_json`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import stat
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from msflash.acquisition.errors import UsageError as UsageError  # re-exported: every command raises it
from msflash.acquisition.progress import progress as progress  # re-exported: every command reports with it
from msflash.processing.user_files import check_output_name, shown_path
from msflash.processing.user_numbers import plain_number, plain_whole_number


def whole_number(lowest: int, highest: int | None = None, unit: str = "") -> Callable[[str], int]:
    """argparse type: a whole number in ``lowest`` … ``highest`` (no upper end when None), of ``unit`` when given
    (argparse names the option and exits 2).

    >>> whole_number(1)("3"), whole_number(8, 256, "pixels")("12")
    (3, 12)
    """
    what = f"a whole number of {unit}" if unit else "a whole number"
    expected = f"{what} ≥ {lowest}" if highest is None else f"{what}, {lowest}-{highest}"

    def whole(text: str) -> int:
        try:
            value = plain_whole_number(text)
        except ValueError:
            value = lowest - 1
        if value < lowest or (highest is not None and value > highest):
            raise argparse.ArgumentTypeError(f"'{text}': expected {expected}")
        return value

    return whole


def number_where(accept: Callable[[float], bool], expected: str) -> Callable[[str], float]:
    """argparse type: a number ``accept`` takes (a text that is no number is NaN to it), refused as ``expected``.

    >>> number_where(lambda value: 0 <= value < 50, "a percentage, 0 ≤ PERCENT < 50")("0.1")
    0.1
    """

    def number(text: str) -> float:
        value = user_number(text)
        if not accept(value):
            raise argparse.ArgumentTypeError(f"'{text}': expected {expected}")
        return value

    return number


def user_number(text: str) -> float:
    """The finite number a user wrote in ``text`` (:func:`processing.user_numbers.plain_number`), or NaN for anything
    else (``1_0``, ``١٢``, ``inf``, ``nan``, ``0x10``), which every argparse type here then refuses as what it expects.

    >>> user_number("2.5"), user_number("1_0")
    (2.5, nan)
    """
    try:
        return plain_number(text)
    except ValueError:
        return math.nan


def number(text: str) -> float:
    """argparse type of a plain finite number (the type every numeric option without a range of its own takes,
    instead of ``float``, which reads ``1_0`` as 10, ``١٢`` as 12 and ``inf``/``nan`` as numbers).

    >>> number("0.25")
    0.25
    """
    try:
        return plain_number(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def whole(text: str) -> int:
    """argparse type of a plain whole number of any sign (instead of ``int``, which reads ``1_0`` and ``١٢``).

    >>> whole("-3")
    -3
    """
    try:
        return plain_whole_number(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


positive_int = whole_number(1)
"""argparse type: a whole number ≥ 1."""

seed_int = whole_number(0)
"""argparse type of ``--seed``: a whole number ≥ 0, what numpy's generators take (a negative seed reached them as a
ValueError: exit 1 or a crash, naming neither the option nor what it expects)."""


def boot_seconds(text: str) -> float:
    """argparse type of ``--booth-boot-s``: a finite number of seconds ≥ 0 (0: no wait).

    >>> boot_seconds("2.5"), boot_seconds("0")
    (2.5, 0.0)
    """
    value = user_number(text)
    if not (0 <= value < math.inf):
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a number of seconds ≥ 0 (how long a booth that resets when its port "
            "opens takes to boot; 0 for a board with auto-reset disabled)"
        )
    return value


_PORT_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISREG, "a regular file"), (stat.S_ISFIFO, "a FIFO"))


def serial_port(text: str) -> str:
    """argparse type of every option naming a booth's serial port (``booth console PORT``, ``doctor --port``,
    ``--port``, ``--booth-port``): a pyserial URL (``socket://…``, ``loop://``) as given, else a path to a character
    device. A path that does not exist, or is a file or a folder, is bad input, refused when the line is parsed
    (exit 2, naming the path) — before a rig opens or an LED fires; a device that is there but does not answer is
    the device's failure (exit 1) when it is opened.

    >>> serial_port("/dev/null"), serial_port("socket://127.0.0.1:7000")
    ('/dev/null', 'socket://127.0.0.1:7000')
    """
    if "://" in text:
        return text
    shown = shown_path(text)
    try:
        mode = os.stat(text).st_mode
    except (FileNotFoundError, NotADirectoryError, ValueError):
        raise argparse.ArgumentTypeError(
            f"'{shown}': no such port; expected an existing serial device such as /dev/ttyACM0 (run 'msflash doctor' "
            "or 'msflash devices' to list booths)"
        ) from None
    except OSError as err:
        raise argparse.ArgumentTypeError(
            f"'{shown}': cannot look at it ({err.strerror or err}); expected a serial device such as /dev/ttyACM0"
        ) from None
    if not stat.S_ISCHR(mode):
        kind = next((name for test, name in _PORT_KINDS if test(mode)), "not a device")
        raise argparse.ArgumentTypeError(
            f"'{shown}': {kind}; expected a serial device (a character device such as /dev/ttyACM0) or a pyserial URL"
        )
    return text


def add_booth_boot_option(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--booth-boot-s S``: how long to let a booth that resets when its port opens boot (docs/booth-firmware.md §4)."""
    from msflash.led_controller.booth_handshake import DEFAULT_BOOT_S

    parser.add_argument(
        "--booth-boot-s",
        type=boot_seconds,
        default=DEFAULT_BOOT_S,
        metavar="S",
        help="after opening the booth's port, wait up to S seconds, sending nothing, for the booth to boot: "
        "a stock Arduino Mega resets when its port opens and its bootloader swallows what is sent for "
        "1.5–2 s; the wait ends at the firmware's boot banner (default %(default)g; 0: ask at once, for a "
        "board with auto-reset disabled)",
    )


def _strict(value: Any) -> Any:
    """``value`` with numpy arrays/scalars made plain and non-finite numbers made ``None``.

    JSON has no NaN or infinity; a reader would choke on Python's ``NaN``/``Infinity`` tokens,
    so an undefined figure (say, the condition number of a degenerate fit) is written as null.
    numpy is not imported here: when it is not loaded yet, no value can be a numpy object.
    """
    if isinstance(value, dict):
        return {key: _strict(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_strict(item) for item in value]
    numpy = sys.modules.get("numpy")
    if numpy is not None and isinstance(value, numpy.ndarray | numpy.generic):
        from msflash.acquisition.sequence.image_files import json_default

        return _strict(json_default(value))
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps_json(payload: dict[str, Any]) -> str:
    """One JSON object as text (numpy converted; NaN and infinities written as null)."""
    return json.dumps(_strict(payload), allow_nan=False)


def print_json(payload: dict[str, Any]) -> None:
    """Print one JSON object on stdout (the ``--json`` contract of docs/architecture.md §7)."""
    sys.stdout.write(dumps_json(payload) + "\n")
    sys.stdout.flush()


def output_directory(path: str | os.PathLike | None) -> Path | None:
    """``--out DIR`` created before any work, or a UsageError naming it (None stays None).

    Studies and evaluations write their folder at the end: a path that cannot be a folder (a file
    there, or under it) must fail before minutes of computing, as one line, not a traceback.
    """
    if path is None or path == "":
        return None
    out = Path(path)
    check_output_name(out, "--out", UsageError)
    blocking = next((p for p in (out, *out.parents) if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise UsageError(f"--out {out}: {blocking} is a file; expected a folder (or a path where one can be made)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(
            f"--out {out}: cannot create the folder ({err.strerror or err}); expected a writable path"
        ) from None
    return out


def check_folder_can_be_made(path: Path, option: str) -> None:
    """Refuse ``option``'s folder ``path`` unless it is a folder or can be made as one; a folder made to find out
    is removed again, with the parents made for it (``live --runs /proc/x`` served the page and failed only when
    a sequence was fired).

    Raises
    ------
    UsageError
        Naming ``option``, the path and why it cannot be made.
    """
    created = _missing_folders(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(
            f"{option} {path}: cannot make the folder ({err.strerror or err}); expected a folder or a path where "
            "one can be made"
        ) from None
    _remove_empty(created)


def _missing_folders(path: str | os.PathLike) -> list[Path]:
    """The folders of ``path`` and its parents that do not exist yet, deepest first: what making it makes."""
    return [folder for folder in (Path(path), *Path(path).parents) if not os.path.lexists(folder)]


def _remove_empty(folders: list[Path]) -> None:
    """Remove ``folders`` (deepest first, as :func:`_missing_folders` lists them) while each is empty."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            break


@contextlib.contextmanager
def claimed_output(path: str | os.PathLike, what: str) -> Iterator[Path]:
    """``--out DIR`` created and claimed for this process while the block runs (one owner per folder,
    :mod:`acquisition.sequence.folder_claim`): a second msflash writing it gets exit 2 naming the holder.

    Raises
    ------
    UsageError
        A file in the way, no write access, or a folder that cannot hold the lock file.
    """
    from msflash.acquisition.sequence.folder_claim import claim_folder

    created = _missing_folders(path)
    out = output_directory(path)
    assert out is not None  # a path was given
    try:
        claim = claim_folder(out, what)
    except OSError as err:
        raise UsageError(
            f"--out {out}: cannot write there ({err.strerror or err}); expected a writable directory"
        ) from err
    try:
        with claim:
            yield out
    except BaseException:
        # A command refused before it wrote anything leaves no folder it created, its parents included
        # (the claim's lock is gone; a folder something was written to stays).
        _remove_empty(created)
        raise
