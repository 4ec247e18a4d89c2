"""Progress on stderr for every layer of acquisition: lines, and a bar with an ETA on a terminal.

stdout stays for data. Two kinds of report:

- :func:`progress`: a diagnostic line, always shown (above the bar when one is drawn);
- :func:`count` (or :func:`counted` around a loop): one unit of long work done, ``done`` of
  ``total``. When bars are on it moves a bar with the elapsed time and an ETA (tqdm); when they are
  off it prints the unit's ``note`` line (a log keeps one line per unit).

Bars are on only when ``msflash`` turned them on (:func:`configure`, from ``cli.main``) because
stderr is a terminal and ``--json`` was not given (:func:`bars_wanted`): a pipe, a file, a test's
captured stream or a notebook get lines only, and nothing of tqdm is imported.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
from collections.abc import Callable, Iterator
from typing import Any, TextIO

_state: dict[str, Any] = {"bars": False, "bar": None, "label": None}
"""Whether bars are drawn, and the open bar (a tqdm) with its label: one bar at a time."""


def bars_wanted(json_output: bool, stream: TextIO | None = None) -> bool:
    """Whether to draw bars: ``stream`` (default stderr) is a terminal, ``--json`` was not given, TERM is not dumb.

    >>> import io
    >>> bars_wanted(False, io.StringIO())
    False
    """
    if json_output or os.environ.get("TERM") == "dumb":
        return False
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def configure(*, bars: bool) -> None:
    """Turn bars on or off for this command (``cli.main`` does, once the options are parsed); closes an open bar."""
    close_bar()
    _state["bars"] = bars


def progress(message: str) -> None:
    """A progress or diagnostic line on stderr (stdout stays for data), written above the bar when one is drawn."""
    line = f"msflash: {message}"
    bar = _state["bar"]
    if bar is not None:
        bar.write(line, file=sys.stderr)
        return
    sys.stderr.write(line + "\n")
    sys.stderr.flush()


def count(label: str, done: int, total: int, unit: str = "", note: str | None = None) -> None:
    """``done`` of ``total`` ``unit``\\ s of ``label`` finished: the bar moves, or ``note`` is printed.

    The bar is opened at the first count of a label (``done`` may be 0: opened before the first
    unit) and closed when ``done`` reaches ``total`` or by :func:`close_bar`. Counts of another
    label while it is open are work inside one of its units (a run's frames inside its capture
    step): they show beside the bar, ``frame 3/9``, instead of replacing it.
    """
    if not _state["bars"]:
        if note:
            progress(note)
        return
    bar = _state["bar"]
    if bar is not None and _state["label"] != label:
        bar.set_postfix_str(f"{label}: {done}/{total}{' ' + unit if unit else ''}")
        return
    if bar is None or bar.total != total:
        bar = _open_bar(label, total, unit)
    bar.set_postfix_str("", refresh=False)
    bar.update(max(0, done - bar.n))
    bar.refresh()  # units take longer than tqdm's display interval: show each one
    if done >= total:
        close_bar()


def close_bar() -> None:
    """Close the open bar, if any (on a terminal its line is cleared)."""
    bar, _state["bar"], _state["label"] = _state["bar"], None, None
    if bar is not None:
        bar.close()


@contextlib.contextmanager
def counted(label: str, total: int, unit: str = "") -> Iterator[Callable[[str | None], None]]:
    """A loop of ``total`` units: the block calls ``advance(note)`` after each; the bar is closed however it ends.

    ``note`` is the unit's line when no bar is drawn (None: nothing is printed then).
    """
    done = 0

    def advance(note: str | None = None) -> None:
        nonlocal done
        done += 1
        count(label, done, total, unit, note)

    try:
        yield advance
    finally:
        if _state["label"] == label:
            close_bar()


def _open_bar(label: str, total: int, unit: str) -> Any:
    close_bar()
    from tqdm import tqdm  # only when a bar is drawn: start-up and piped runs never import it

    size = shutil.get_terminal_size()
    bar = tqdm(
        total=total,
        desc=f"msflash: {label}",
        unit=f" {unit}" if unit else "it",
        file=sys.stderr,
        leave=False,
        # A terminal reporting no size (a fresh pty: 0 × 0) gets 80 × 24; tqdm would draw nothing in 0 rows.
        ncols=size.columns,
        nrows=size.lines,
        mininterval=0.2,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt}{unit} [{elapsed}<{remaining}]{postfix}",
    )
    _state["bar"], _state["label"] = bar, label
    return bar
