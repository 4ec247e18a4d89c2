"""``msflash estimate`` and ``flash`` over many sequences: a day's time-lapse, a recorded study.

The sequences are the command's arguments, each a sequence folder (holding ``sequence.json``), a run
or capture folder (holding one in ``sequence/``) or a folder of those (its sub-folders holding one, in name order: :func:`sequence_inputs`).
Each sequence goes through :mod:`acquisition.session.one_sequence`, the route of a single run, on a
dask client (:mod:`acquisition.session.dask_map`), so its numbers are those of a one-by-one run.
Each gives a :class:`SequenceRecord`, in input order: its JSON object, or the one-line error that
refused it, with the notes a single run prints on stderr. A failed sequence does not stop the others.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msflash.acquisition.errors import UsageError, bad_input_errors, runtime_errors
from msflash.acquisition.sequence.locate import SEQUENCE_FILE, SEQUENCE_FOLDER, holds_sequence
from msflash.acquisition.session import one_sequence
from msflash.acquisition.session.dask_map import LOCAL, SERIAL, dask_mapper

NAME_FIELD = "{name}"
"""In ``flash --out`` over many sequences: replaced by each sequence folder's name."""


@dataclass(frozen=True)
class SequenceRecord:
    """One sequence's outcome: its JSON object, or its error and exit status (2 refused input, 1 otherwise)."""

    sequence: str
    payload: dict[str, Any] | None
    notes: tuple[str, ...] = ()
    error: str | None = None
    status: int = 0

    def json_object(self) -> dict[str, Any]:
        """What the command prints for this sequence: the single run's object, or the sequence, error and status."""
        if self.payload is not None:
            return self.payload
        return {"sequence": self.sequence, "error": self.error, "status": self.status}


def sequence_inputs(arguments: Sequence[str]) -> tuple[list[str], bool]:
    """The sequences named by the arguments, and whether any argument was a folder of sequences.

    An argument is kept as it is (the reader will name what is wrong with it) unless it is a folder
    that is no sequence, run or capture folder and whose sub-folders are: then those sub-folders, in
    name order (a day's sequences, or a folder of runs).

    >>> sequence_inputs(["/nonexistent/a", "/nonexistent/b"])
    (['/nonexistent/a', '/nonexistent/b'], False)
    """
    sequences: list[str] = []
    expanded = False
    for argument in arguments:
        path = Path(argument)
        inner: list[str] = []
        try:
            if path.is_dir() and not holds_sequence(path):
                inner = sorted(
                    os.path.join(argument, child.name)
                    for child in path.iterdir()
                    if child.is_dir() and holds_sequence(child)
                )
        except OSError:  # unreadable: the reader names it
            inner = []
        if inner:
            sequences.extend(inner)
            expanded = True
        else:
            sequences.append(argument)
    return sequences, expanded


def for_scheduler(scheduler: str, paths: Sequence[str]) -> list[str]:
    """``paths`` as the scheduler's workers must see them: absolute for a scheduler at an address (its
    workers run elsewhere, in other folders, and must share the files), as given on this machine.

    >>> for_scheduler("local", ["day/0800"])
    ['day/0800']
    >>> for_scheduler("tcp://10.0.0.2:8786", ["/data/day/0800"])
    ['/data/day/0800']
    """
    if scheduler in (LOCAL, SERIAL):
        return list(paths)
    return [os.path.abspath(path) for path in paths]


def output_paths(template: str | None, sequences: Sequence[str]) -> list[str | None]:
    """``flash --out`` for each sequence: ``{name}`` replaced by the sequence folder's name.

    Raises
    ------
    UsageError
        Several sequences and no ``{name}``, or two sequences whose outputs would be the same file.

    >>> output_paths("out/{name}.exr", ["day/0800", "day/0900"])
    ['out/0800.exr', 'out/0900.exr']
    """
    if template is None:
        return [None] * len(sequences)
    if NAME_FIELD not in template:
        raise UsageError(
            f"--out {template}: {len(sequences)} sequences would write the same file; expected a path holding "
            f"{NAME_FIELD} (each sequence folder's name), e.g. out/{NAME_FIELD}.exr"
        )
    outputs = [template.replace(NAME_FIELD, sequence_name(sequence)) for sequence in sequences]
    seen: dict[str, str] = {}
    for sequence, output in zip(sequences, outputs, strict=True):
        if output in seen:
            raise UsageError(
                f"--out {template}: {seen[output]} and {sequence} would both write {output}; expected sequence "
                "folders with different names"
            )
        seen[output] = sequence
    return list(outputs)


def sequence_name(sequence: str) -> str:
    """What ``{name}`` stands for: the run, capture or sequence folder the user named, however named.

    ``runs/0800``, ``runs/0800/sequence`` and ``runs/0800/sequence/sequence.json`` are all ``0800``
    (the inner names are the same in every run: taken as they are, every sequence of ``runs/*/sequence``
    would be named ``sequence``).

    >>> sequence_name("/data/runs/0800/sequence/sequence.json"), sequence_name("/data/day/0900")
    ('0800', '0900')
    """
    path = Path(sequence).resolve()
    if path.name == SEQUENCE_FILE:
        path = path.parent
    if path.name == SEQUENCE_FOLDER and not (path.parent / SEQUENCE_FILE).exists():
        path = path.parent
    return path.name


def _failure(sequence: str, err: Exception, notes: list[str]) -> SequenceRecord:
    """The record of a sequence that failed: one line naming it, status 2 for refused input, else 1."""
    text = str(err) or type(err).__name__
    if isinstance(err, FileNotFoundError) and err.filename:
        text = f"{err.filename}: not found"
    if isinstance(err, bad_input_errors()):
        status = 2
    elif isinstance(err, runtime_errors()):
        status = 1
    else:
        status, text = 1, f"unexpected {type(err).__name__}: {text} — a bug"
    text = " ".join(text.split())
    if sequence not in text:
        text = f"{sequence}: {text}"
    return SequenceRecord(sequence, None, tuple(notes), text, status)


def estimate_record(job: tuple[str, one_sequence.EstimateSettings]) -> SequenceRecord:
    """``msflash estimate`` of one sequence as a record (what a dask worker runs)."""
    return _record(job, one_sequence.estimate_one)


def flash_record(job: tuple[str, one_sequence.FlashSettings]) -> SequenceRecord:
    """``msflash flash`` of one sequence as a record (what a dask worker runs)."""
    return _record(job, one_sequence.flash_one)


def _record(job: tuple[str, Any], command: Callable[[str, Any, Callable[[str], None]], Any]) -> SequenceRecord:
    sequence, settings = job
    notes: list[str] = []
    try:
        result = command(sequence, settings, notes.append)
    except Exception as err:  # every failure is this sequence's, reported for it; the others go on
        return _failure(sequence, err, notes)
    return SequenceRecord(sequence, result.payload, tuple(notes))


def run_many(
    record: Callable[[Any], SequenceRecord],
    jobs: Sequence[Any],
    scheduler: str = "local",
    workers: int | None = None,
    *,
    verbose: bool = False,
) -> Generator[SequenceRecord, None, None]:
    """``record`` over ``jobs`` on ``scheduler`` (:func:`~acquisition.session.dask_map.dask_mapper`), in order.

    Each record is yielded as soon as it and those before it are done. ``record`` keeps a sequence's
    own errors in its record; a job that does not come back at all (its worker process died, dask
    gave up on it) is reported the same way, as that sequence's failure, and the others go on.
    """
    with dask_mapper(scheduler, workers, verbose=verbose) as mapper:
        yield from mapper(record, jobs, on_error=_lost)


def _lost(job: tuple[str, Any], err: Exception) -> SequenceRecord:
    """The record of a sequence whose job did not come back (its worker process died, say): status 1."""
    if type(err).__name__ != "KilledWorker":
        return _failure(job[0], err, [])
    text = " ".join(str(err).split())
    return SequenceRecord(
        job[0], None, (), f"{job[0]}: its worker process died, here and on dask's retries ({text})", 1
    )


def exit_status(records: Sequence[SequenceRecord]) -> int:
    """0 when every sequence succeeded, 2 when any was refused as bad input, else 1.

    >>> exit_status([SequenceRecord("a", {}), SequenceRecord("b", None, error="b: x", status=1)])
    1
    """
    statuses = {record.status for record in records}
    return 2 if 2 in statuses else (1 if 1 in statuses else 0)
