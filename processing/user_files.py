"""The one safe way to open a file a user named.

Every path option and every file a sequence or a calibration names is read through here:

- :func:`check_user_file` refuses, *before anything opens the file*, what is not a regular file
  (a FIFO would block the open or the read for ever, ``/dev/zero`` would fill memory, a directory
  or a symlink loop gives an obscure error) and a file larger than the cap for its kind;
- :func:`read_user_bytes` and :func:`read_user_text` then read at most ``cap + 1`` bytes from a
  descriptor opened non-blocking and checked again with ``fstat``, so a file swapped after the
  check, or one whose size ``stat`` under-reports, still cannot block or grow memory past the cap;
- :func:`check_output_name` refuses an output path the filesystem cannot hold (a name longer
  than it allows), which ``Path.exists`` raises on rather than answers;
- :func:`shown_path` prints any file name on one line, whatever bytes it holds (undecodable
  bytes as ``\\xNN``, control characters escaped).

Readers that open files themselves (OpenImageIO) call :func:`check_user_file` first. Errors are
``SpectralDataError`` unless the caller passes its own error type; messages follow
``"<file>: <what is wrong>; expected <what>"``, one line, which the CLI maps to exit status 2.
"""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Callable
from pathlib import Path

from msflash.processing.errors import SpectralDataError

MiB = 1 << 20

#: Caps per kind of file, in bytes. Spectral tables and spectrometer exports are a few hundred
#: lines; a sequence or calibration document a few thousand; a frame image at most some hundred MB.
SPECTRAL_TABLE_MAX_BYTES = 16 * MiB
TEXT_EXPORT_MAX_BYTES = 16 * MiB
JSON_MAX_BYTES = 16 * MiB
IMAGE_MAX_BYTES = 4096 * MiB

_TYPES = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


TABLE_SUFFIXES = (".csv", ".txt")
"""Names of spectral tables: an option's value ending so is read as a file, whether or not it exists."""


def names_a_file(text: str | os.PathLike[str], is_name: Callable[[str], bool] | None = None) -> bool:
    """Whether an option that takes a name or a file (``--target D65|FILE``, the sim rig's ``--ambient``,
    ``--scene``, ``--sim-camera``) names a file: a table suffix, a path separator, or a word on disk that is
    not a directory and not a name the option knows (``is_name``, asked only then).

    Anything existing but a directory counts (a FIFO, a device, a symlink loop), so the file reader refuses it by
    what it is instead of it being looked up as a name. A directory does not, nor does a file whose name the option
    knows: a folder or a file ``D65`` in the working directory leaves ``--target D65`` (the default) the illuminant,
    and ``./D65`` reads the file. ``--target runs/`` is read as a file, and refused as a directory.

    >>> names_a_file("D65"), names_a_file("lamp.CSV"), names_a_file("spectra/lamp")
    (False, True, True)
    """
    text = os.fspath(text)
    if Path(text).suffix.lower() in TABLE_SUFFIXES or any(sep in text for sep in (os.sep, os.altsep) if sep):
        return True
    if not os.path.lexists(text) or os.path.isdir(text):
        return False
    return is_name is None or not is_name(text)


def known_to(lookup: Callable[[str], object]) -> Callable[[str], bool]:
    """An ``is_name`` for :func:`names_a_file`: whether ``lookup`` (an option's reader of a name, raising
    ``SpectralDataError`` for a name it does not know) knows the word."""

    def is_name(word: str) -> bool:
        try:
            lookup(word)
        except SpectralDataError:
            return False
        return True

    return is_name


def shown_path(path: str | bytes | os.PathLike) -> str:
    """``path`` as one printable line: undecodable bytes as ``\\xNN``, control characters escaped.

    >>> shown_path(b"spectra\\xff.csv")
    'spectra\\\\xff.csv'
    >>> shown_path("a\\nb.csv")
    'a\\\\nb.csv'
    """
    return printable(os.fsencode(path).decode("utf-8", "backslashreplace"))


def printable(text: str) -> str:
    """``text`` with its non-printable characters (controls, NUL, lone surrogates) escaped, for a
    one-line message quoting a user's file name or contents.

    >>> printable("a\\x00b\\tc µm")
    'a\\\\x00b\\\\tc µm'
    """
    return "".join(
        c if c.isprintable() else c.encode("unicode_escape", "backslashreplace").decode("ascii") for c in text
    )


def _size(n: int) -> str:
    return f"{n / MiB:.1f} MiB" if n >= MiB else f"{n} bytes"


def _file_type(mode: int) -> str | None:
    for test, name in _TYPES:
        if test(mode):
            return name
    return None if stat.S_ISREG(mode) else "not a regular file"


def check_user_file(
    path: str | bytes | os.PathLike,
    kind: str,
    max_bytes: int,
    error: type[Exception] = SpectralDataError,
    name: str | None = None,
) -> os.stat_result:
    """Check, without opening it, that ``path`` is a regular file of at most ``max_bytes``.

    Symbolic links are followed; a loop of them is refused. ``kind`` says what was expected
    ("a spectral table (CSV)", …) and ends every message; ``name`` replaces the path at its start
    (a file named by a document: ``"<document>: <field> '<value>'"``).

    Raises
    ------
    error
        (``SpectralDataError`` by default) naming the file: missing, unreadable, a symlink loop,
        a directory, FIFO, device or socket, or larger than ``max_bytes``.
    """
    shown = shown_path(path) if name is None else printable(name)
    try:
        info = os.stat(path)
    except FileNotFoundError as err:
        raise error(f"{shown}: cannot be read (no such file); expected {kind}") from err
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise error(f"{shown}: is a loop of symbolic links; expected {kind}") from err
        raise error(f"{shown}: cannot be read ({err.strerror or err}); expected {kind}") from err
    return _check_stat(shown, info, kind, max_bytes, error)


def _check_stat(shown: str, info: os.stat_result, kind: str, max_bytes: int, error: type[Exception]) -> os.stat_result:
    what = _file_type(info.st_mode)
    if what is not None:
        raise error(f"{shown}: is {what}; expected {kind}, a regular file")
    if info.st_size > max_bytes:
        raise error(f"{shown}: is {_size(info.st_size)}; expected {kind} of at most {_size(max_bytes)}")
    return info


def read_user_bytes(
    path: str | bytes | os.PathLike,
    kind: str,
    max_bytes: int,
    error: type[Exception] = SpectralDataError,
) -> bytes:
    """The bytes of the user's file ``path``, checked as :func:`check_user_file` checks it.

    The file is opened non-blocking (a FIFO swapped in after the check cannot block the open),
    checked again on its descriptor, and read for at most ``max_bytes + 1`` bytes.
    """
    shown = shown_path(path)
    check_user_file(path, kind, max_bytes, error)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        handle = os.open(path, flags)
    except OSError as err:
        raise error(f"{shown}: cannot be read ({err.strerror or err}); expected {kind}") from err
    try:
        _check_stat(shown, os.fstat(handle), kind, max_bytes, error)
        chunks: list[bytes] = []
        left = max_bytes + 1
        while left > 0:
            chunk = os.read(handle, min(left, 1 << 20))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
    except OSError as err:
        raise error(f"{shown}: cannot be read ({err.strerror or err}); expected {kind}") from err
    finally:
        os.close(handle)
    data = b"".join(chunks)
    if len(data) > max_bytes:
        raise error(f"{shown}: is larger than {_size(max_bytes)}; expected {kind} of at most {_size(max_bytes)}")
    return data


def read_user_text(
    path: str | bytes | os.PathLike,
    kind: str,
    max_bytes: int,
    error: type[Exception] = SpectralDataError,
    encoding: str = "utf-8",
) -> str:
    """The text of the user's file ``path`` (see :func:`read_user_bytes`), decoded strictly."""
    data = read_user_bytes(path, kind, max_bytes, error)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as err:
        raise error(
            f"{shown_path(path)}: is not UTF-8 text ({err.reason} at byte {err.start}); expected {kind}"
        ) from err


def check_output_name(path: str | os.PathLike, option: str, error: type[Exception] = SpectralDataError) -> None:
    """Refuse an output ``path`` the filesystem cannot hold, before anything is created.

    ``Path.exists`` and ``mkdir`` raise ``OSError`` (``ENAMETOOLONG``) for a name longer than the
    filesystem allows instead of answering, so this is asked first, with a one-line answer.

    Raises
    ------
    Exception
        ``error``: one line naming ``option`` and the path.

    Examples
    --------
    >>> check_output_name("/tmp/" + "x" * 300, "--out", ValueError)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: --out /tmp/xxx…x (300 characters): a name in it is longer than the filesystem allows; expected ...
    >>> check_output_name("/tmp/new-folder", "--out", ValueError)
    """
    text = os.fsdecode(path)
    limit = _name_max(path)
    longest = max(text.split(os.sep), key=lambda part: len(os.fsencode(part)))
    if len(os.fsencode(longest)) > limit:
        shown = text.replace(longest, f"{longest[:3]}…{longest[-1:]} ({len(longest)} characters)")
        raise error(
            f"{option} {shown_path(shown)}: a name in it is longer than the filesystem allows; expected names of at "
            f"most {limit} bytes"
        )
    try:
        os.lstat(path)
    except OSError as err:  # absent is the usual case; a whole path past PATH_MAX is refused here
        if err.errno == errno.ENAMETOOLONG:
            raise error(
                f"{option} {shown_path(text[:60])}… ({len(text)} characters): longer than the filesystem allows; "
                "expected a shorter path"
            ) from None


def _name_max(path: str | os.PathLike) -> int:
    """The longest file name the filesystem holding ``path`` (or its nearest existing folder) accepts."""
    folder = os.path.abspath(os.fsdecode(path))
    while folder != os.path.dirname(folder):
        folder = os.path.dirname(folder)
        try:
            return int(os.pathconf(folder, "PC_NAME_MAX"))
        except OSError:
            continue
    return 255
