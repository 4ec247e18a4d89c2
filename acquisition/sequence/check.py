"""Is every frame of a sequence the file that was written? What ``msflash check`` reports.

A frame listed in ``sequence.json`` is

- ``intact``: its recorded SHA-256 and length (``frames[].sha256``, ``frames[].file_bytes``,
  docs/architecture.md §6) match the file, byte for byte, and the file was written for this entry;
- ``mismatched``: the file is the one written, but for another entry: what it says of itself (index,
  role, LED levels, exposure, gain; :mod:`acquisition.sequence.frame_binding`) differs from the entry
  naming it — entries swapped, duplicated or re-ordered;
- ``changed``: the file differs from the one written (other bytes, or longer);
- ``truncated``: the file is shorter than the one written;
- ``missing``: there is no such file;
- ``unreadable``: no digest is recorded and the file cannot be decoded as an image, or it is no
  regular file (a FIFO, a directory);
- ``unverified``: no digest is recorded (an older recording, another tool's) and the file decodes:
  it reads, but cannot be proven to be the file written.

Any other file inside the sequence directory (``sequence.json`` and the folder's lock file
apart) is ``undeclared``: a stray copy, a frame its entry lost, a temporary file a stopped writer
left. Only ``intact`` frames and no undeclared file make a sequence provably intact
(:attr:`SequenceCheck.intact`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Literal

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.folder_claim import LOCK_FILE
from msflash.acquisition.sequence.format import SEQUENCE_FILE, Sequence
from msflash.acquisition.sequence.frame_binding import SelfDescription, binding_problem, describe_misbinding
from msflash.acquisition.sequence.frame_digest import digest_problem, frame_state
from msflash.acquisition.sequence.image_files import read_image, read_image_header
from msflash.acquisition.sequence.reader import read_sequence
from msflash.processing.user_files import shown_path

FileState = Literal["intact", "mismatched", "changed", "truncated", "missing", "unreadable", "unverified", "undeclared"]
FILE_STATES: tuple[FileState, ...] = (
    "intact",
    "mismatched",
    "changed",
    "truncated",
    "missing",
    "unreadable",
    "unverified",
    "undeclared",
)
"""Every state :func:`check_sequence` reports, in the order the summary counts them."""


@dataclass(frozen=True)
class FileCheck:
    """One file of a sequence directory and its state."""

    file: str
    """The file, relative to the sequence directory, ``/``-separated."""
    state: FileState
    """See :data:`FILE_STATES`."""
    index: int | None
    """Its position in ``frames``, or None for an undeclared file."""
    problem: str | None
    """One line saying what is wrong, naming the file and field; None for an intact frame."""

    def to_dict(self) -> dict[str, Any]:
        """The JSON form: ``file``, ``state``, ``index``, ``problem``."""
        return {"file": self.file, "state": self.state, "index": self.index, "problem": self.problem}


@dataclass(frozen=True)
class SequenceCheck:
    """What :func:`check_sequence` found."""

    sequence: Sequence
    """The sequence as its ``sequence.json`` describes it."""
    files: tuple[FileCheck, ...]
    """Every listed frame in ``frames`` order, then every undeclared file in name order."""

    @property
    def intact(self) -> bool:
        """True if every listed frame is intact and no undeclared file lies in the directory."""
        return all(check.state == "intact" for check in self.files)

    @property
    def first_problem(self) -> str | None:
        """The first file's problem, in :attr:`files` order; None if the sequence is intact."""
        return next((check.problem for check in self.files if check.problem is not None), None)

    def counts(self) -> dict[str, int]:
        """How many files are in each state (every state present, zeros included)."""
        return {state: sum(check.state == state for check in self.files) for state in FILE_STATES}

    def summary(self) -> dict[str, Any]:
        """The one-line JSON summary: the sequence, its frame count, the counts per state, ``intact``."""
        return {
            "sequence": str(self.sequence.directory),
            "complete": self.sequence.complete,
            "frames": len(self.sequence.frames),
            **self.counts(),
            "intact_sequence": self.intact,
        }


def check_sequence(directory: str | os.PathLike) -> SequenceCheck:
    """Check every frame file of a sequence against its record, and look for undeclared files.

    Frames with a recorded digest are hashed, not decoded (the digest proves the bytes are those
    written); frames without one are decoded (:func:`acquisition.sequence.image_files.read_image`) to tell
    ``unverified`` from ``unreadable``.

    Returns
    -------
    SequenceCheck
        One :class:`FileCheck` per listed frame, then one per undeclared file.

    Raises
    ------
    RecordingError
        If ``sequence.json`` itself cannot be read or is invalid (the field named): there is then
        no record to check the frames against.
    """
    sequence = read_sequence(directory, require_files=False)
    files = [_check_frame(sequence, index) for index in range(len(sequence.frames))]
    files = _check_bindings(sequence, files)
    files.extend(_undeclared(sequence))
    return SequenceCheck(sequence, tuple(files))


def _said(sequence: Sequence, index: int) -> SelfDescription | None:
    try:
        return SelfDescription.from_attributes(read_image_header(sequence.frame_path(index)).attributes)
    except RecordingError:
        return None


def _check_bindings(sequence: Sequence, files: list[FileCheck]) -> list[FileCheck]:
    """Mark the intact and unverified frames whose files were written for another entry."""
    readable = {"intact", "unverified"}
    said = [_said(sequence, i) if check.state in readable else None for i, check in enumerate(files)]
    said_indices = [description.index if description is not None else None for description in said]
    checked = []
    for index, (check, description) in enumerate(zip(files, said)):
        frame = sequence.frames[index]
        where = f"{sequence.path}: frames[{index}].file '{frame.file}'"
        problem = None
        if description is not None:
            problem = binding_problem(
                where, description, index, frame.role, frame.led_levels, frame.exposure_us, frame.gain
            )
        if problem is None:
            checked.append(check)
            continue
        how = describe_misbinding(index, description.index if description else None, said_indices)
        checked.append(FileCheck(frame.file, "mismatched", index, f"{how}: {problem}"))
    return checked


def _check_frame(sequence: Sequence, index: int) -> FileCheck:
    frame = sequence.frames[index]
    path = sequence.frame_path(index)
    where = f"{sequence.path}: frames[{index}].file '{frame.file}'"
    if frame.digest is not None:
        try:
            state, found = frame_state(path, frame.digest)
        except RecordingError as err:
            return FileCheck(frame.file, "unreadable", index, f"{where}: {err}")
        problem = None if state == "intact" else digest_problem(where, state, found, frame.digest)
        return FileCheck(frame.file, state, index, problem)
    if not os.path.lexists(path):
        return FileCheck(frame.file, "missing", index, f"{where} is missing; expected the frame file on disk")
    try:
        read_image(path)
    except RecordingError as err:
        return FileCheck(frame.file, "unreadable", index, f"{where}: {err}")
    return FileCheck(
        frame.file,
        "unverified",
        index,
        f"{where} has no recorded SHA-256 (recorded before frame digests, or by another tool): it "
        "reads, but cannot be proven to be the file written; expected frames[].sha256 and file_bytes",
    )


def _undeclared(sequence: Sequence) -> list[FileCheck]:
    root = sequence.directory
    listed = {os.path.normpath(frame.file) for frame in sequence.frames}
    ignored = {SEQUENCE_FILE, LOCK_FILE}
    found = []
    for folder, subfolders, names in os.walk(root):
        subfolders.sort()
        for name in names:
            relative = os.path.relpath(os.path.join(folder, name), root)
            if relative in ignored or os.path.normpath(relative) in listed:
                continue
            found.append(relative.replace(os.sep, "/"))
    return [
        FileCheck(
            relative,
            "undeclared",
            None,
            f"{shown_path(root / relative)}: is not listed in {SEQUENCE_FILE}"
            f"{' (a temporary file a stopped writer left)' if _temporary(relative) else ''}; expected only "
            "the frames the sequence lists (move it out, or restore its entry)",
        )
        for relative in sorted(found)
    ]


def _temporary(relative: str) -> bool:
    name = relative.rsplit("/", 1)[-1]
    return name.startswith(".") and ".tmp" in name
