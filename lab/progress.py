"""How a long computation says how far it got, without knowing who listens.

``processing`` is maths: it draws no bar and imports no terminal library (a contract in
``pyproject.toml``). A study takes a ``progress`` argument and, after each unit of work, calls
:func:`report_count`; whoever passed ``progress`` decides what the user sees. A plain
``Callable[[str], None]`` (``print``, ``list.append``) gets one line per unit, as before; an object
that also has ``count`` (:class:`CountedProgress`) gets the numbers instead, and the command line's
(``acquisition/progress.py``) draws them as a bar with an ETA on a terminal.
"""

from __future__ import annotations

import time
from typing import Protocol, runtime_checkable


class Progress(Protocol):
    """Anything taking one line of progress text (``print``, ``list.append``, the app's reporter)."""

    def __call__(self, message: str, /) -> None: ...


@runtime_checkable
class CountedProgress(Protocol):
    """A :class:`Progress` that also takes counts: ``done`` of ``total`` units of ``label`` finished."""

    def __call__(self, message: str, /) -> None: ...

    def count(self, label: str, done: int, total: int, unit: str, note: str) -> None:
        """``done`` of ``total`` ``unit``\\ s of ``label`` are finished; ``note`` is the same as one line of text."""
        ...


def report_count(
    progress: Progress | None, label: str, done: int, total: int, unit: str, started: float | None = None
) -> None:
    """Tell ``progress`` (if any) that ``done`` of ``total`` ``unit``\\ s of ``label`` are finished.

    Parameters
    ----------
    progress
        The caller's reporter: a :class:`CountedProgress` gets the numbers, any other
        :class:`Progress` one line of text; None: nothing is reported.
    label, unit
        What is being counted: ``"table1"``, ``"camera"``.
    done, total
        Units finished so far, and in all.
    started
        ``time.perf_counter()`` when the work started: the line then says how long it has taken.

    Examples
    --------
    >>> lines = []
    >>> report_count(lines.append, "table1", 3, 34, "camera")
    >>> lines
    ['table1: camera 3/34 done']
    """
    if progress is None:
        return
    elapsed = "" if started is None else f" ({time.perf_counter() - started:.1f} s)"
    note = f"{label}: {unit} {done}/{total} done{elapsed}"
    if isinstance(progress, CountedProgress):
        progress.count(label, done, total, unit, note)
    else:
        progress(note)
