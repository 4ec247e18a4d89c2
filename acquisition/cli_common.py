"""Conventions shared by every ``msflash`` subcommand module.

Each command module exposes ``register(subparsers)``; each subparser it adds calls
``set_defaults(handler=function)`` where ``function(args) -> int`` returns the exit status.
Bad input raises :class:`UsageError` (exit 2, one line ``msflash: error: …``); device and runtime
failures raise the package error roots (exit 1). ``--json`` output goes through :func:`print_json`.
"""

from __future__ import annotations

import json
import sys
from typing import Any

from acquisition.image_io import json_default


class UsageError(ValueError):
    """Bad input from the user (a file, field or option); the CLI exits with status 2."""


def dumps_json(payload: dict[str, Any]) -> str:
    """One JSON object as text (numpy arrays and scalars converted)."""
    return json.dumps(payload, default=json_default, allow_nan=False)


def print_json(payload: dict[str, Any]) -> None:
    """Print one JSON object on stdout (the ``--json`` contract of DESIGN §7)."""
    sys.stdout.write(dumps_json(payload) + "\n")
    sys.stdout.flush()


def progress(message: str) -> None:
    """A progress or diagnostic line on stderr (stdout stays for data)."""
    sys.stderr.write(f"msflash: {message}\n")
    sys.stderr.flush()
