"""Progress and diagnostic lines on stderr, for every layer of acquisition (stdout stays for data)."""

from __future__ import annotations

import sys


def progress(message: str) -> None:
    """A progress or diagnostic line on stderr (stdout stays for data)."""
    sys.stderr.write(f"msflash: {message}\n")
    sys.stderr.flush()
