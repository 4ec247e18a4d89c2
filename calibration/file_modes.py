"""The permissions msflash gives the files it writes: what the user's umask allows.

Every output is written to a temporary file (``tempfile.mkstemp``, created ``0600``) and renamed
into place, so without a ``chmod`` captures, sequence files and calibrations would be readable by
their owner only — not by the other users of a lab machine, as any file they create is.
"""

from __future__ import annotations

import os
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
