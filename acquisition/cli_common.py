"""Conventions shared by every ``msflash`` subcommand module.

Each command module exposes ``register(subparsers)``; each subparser it adds calls
``set_defaults(handler=function)`` where ``function(args) -> int`` returns the exit status.
Bad input raises :class:`UsageError` (exit 2, one line ``msflash: error: …``); device and runtime
failures raise the package error roots (exit 1). ``--json`` output goes through :func:`print_json`.
"""

from __future__ import annotations

import argparse

import json
import math
import sys
from typing import Any

import numpy as np

from acquisition.image_io import json_default


class UsageError(ValueError):
    """Bad input from the user (a file, field or option); the CLI exits with status 2."""


def positive_int(text: str) -> int:
    """argparse type: a whole number ≥ 1 (argparse names the option and exits 2).

    >>> positive_int("3")
    3
    """
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}': expected a whole number ≥ 1") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"'{text}': expected a whole number ≥ 1")
    return value


def _strict(value: Any) -> Any:
    """``value`` with numpy arrays/scalars made plain and non-finite numbers made ``None``.

    JSON has no NaN or infinity; a reader would choke on Python's ``NaN``/``Infinity`` tokens,
    so an undefined figure (say, the condition number of a degenerate fit) is written as null.
    """
    if isinstance(value, dict):
        return {key: _strict(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_strict(item) for item in value]
    if isinstance(value, np.ndarray | np.generic):
        return _strict(json_default(value))
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps_json(payload: dict[str, Any]) -> str:
    """One JSON object as text (numpy converted; NaN and infinities written as null)."""
    return json.dumps(_strict(payload), allow_nan=False)


def print_json(payload: dict[str, Any]) -> None:
    """Print one JSON object on stdout (the ``--json`` contract of DESIGN §7)."""
    sys.stdout.write(dumps_json(payload) + "\n")
    sys.stdout.flush()


def progress(message: str) -> None:
    """A progress or diagnostic line on stderr (stdout stays for data)."""
    sys.stderr.write(f"msflash: {message}\n")
    sys.stderr.flush()
