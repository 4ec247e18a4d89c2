"""How msflash writes a file: whole or not at all, with the permissions the user's umask allows.

Every output is written to a temporary file (``tempfile.mkstemp``, created ``0600``) and renamed
into place, so without a ``chmod`` captures, sequence files and calibrations would be readable by
their owner only — not by the other users of a lab machine, as any file they create is.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from functools import cache
from pathlib import Path


def _read_umask() -> int:
    """The process's umask: from ``/proc/self/status`` (Linux), else by setting and restoring it."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@cache
def default_file_mode() -> int:
    """``0o666`` less the umask: the mode ``open(path, "w")`` would have given a new file.

    >>> default_file_mode() & 0o600
    384
    """
    return 0o666 & ~_read_umask()


@contextlib.contextmanager
def replacing(path: Path, suffix: str = ".tmp") -> Iterator[str]:
    """A temporary file beside ``path`` to write, renamed over ``path`` when the block ends without error.

    The temporary is hidden (``.NAME.XXXXXXXX`` + ``suffix``) so a crash leaves an obviously stray file,
    never a truncated one under the real name; it has :func:`default_file_mode`. When the block raises,
    the temporary is removed and the error propagates; ``path`` is left as it was.
    """
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.fchmod(handle, default_file_mode())  # mkstemp's 0600 would keep other lab users out
    os.close(handle)
    try:
        yield temporary
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


def write_whole(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through :func:`replacing`, flushed to disk before the rename."""
    with replacing(path) as temporary, open(temporary, "w", encoding="utf-8") as stream:
        stream.write(text)
        stream.flush()
        os.fsync(stream.fileno())
