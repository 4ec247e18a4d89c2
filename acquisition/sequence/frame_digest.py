"""Frame files provably as written: their SHA-256 and length, taken when written, compared when read.

Both fields are optional in format v1 (older recordings and independent samples have neither), so
a frame without them is read as before; a frame with them is refused with one line naming it when
its file differs. ``file_bytes`` is what tells a truncated file (shorter than written) from a
changed one; the hash alone cannot.
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Literal

from msflash.acquisition.errors import RecordingError
from msflash.processing.user_files import shown_path

SHA256_PATTERN = re.compile(r"[0-9a-f]{64}")
"""What ``frames[].sha256`` holds: 64 lowercase hexadecimal digits."""

_CHUNK_BYTES = 1 << 20
"""Bytes hashed per read (one buffer, reused)."""

FrameState = Literal["intact", "changed", "truncated", "missing"]


@dataclass(frozen=True)
class FileDigest:
    """A file's content, summarised: what ``frames[].sha256`` and ``frames[].file_bytes`` record."""

    sha256: str
    """SHA-256 of the file's bytes, 64 lowercase hexadecimal digits."""
    file_bytes: int
    """The file's length in bytes."""

    def short(self) -> str:
        """The first 12 hexadecimal digits, enough to tell two digests apart in a message."""
        return self.sha256[:12]


def digest_open_file(stream: BinaryIO) -> FileDigest:
    """The digest of an open file, read from its start (its position is left at its end).

    Examples
    --------
    >>> import io
    >>> digest_open_file(io.BytesIO(b"abc"))
    FileDigest(sha256='ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad', file_bytes=3)
    """
    stream.seek(0)
    digest = hashlib.sha256()
    buffer = bytearray(_CHUNK_BYTES)
    view = memoryview(buffer)
    total = 0
    while size := stream.readinto(buffer):  # type: ignore[attr-defined]
        digest.update(view[:size])
        total += size
    return FileDigest(digest.hexdigest(), total)


def frame_state(path: Path, recorded: FileDigest) -> tuple[FrameState, FileDigest | None]:
    """Is the file at ``path`` the one recorded? Its state and, when it could be read, its digest.

    ``truncated``: shorter than recorded (an interrupted copy, a full disk); ``changed``: any
    other difference (same length, different bytes, or longer); ``missing``: no such file.

    Raises
    ------
    RecordingError
        If ``path`` is not a regular file (a FIFO, a device, a directory) or cannot be read
        (permissions, I/O error).
    """
    try:
        # Non-blocking, so a FIFO put in a frame's place cannot hang the reader; refused below.
        handle = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        return "missing", None
    except OSError as err:
        raise RecordingError(
            f"{shown_path(path)}: cannot be opened ({err.strerror}); expected a readable frame image"
        ) from None
    # Checked before ``fdopen``, which itself refuses a directory with an IsADirectoryError.
    if not stat.S_ISREG(os.fstat(handle).st_mode):
        os.close(handle)
        raise RecordingError(f"{shown_path(path)}: is not a regular file; expected a frame image")
    with os.fdopen(handle, "rb") as stream:
        try:
            found = digest_open_file(stream)
        except OSError as err:
            raise RecordingError(
                f"{shown_path(path)}: cannot be read ({err.strerror}); expected a readable frame image"
            ) from None
    if found == recorded:
        return "intact", found
    if found.file_bytes < recorded.file_bytes:
        return "truncated", found
    return "changed", found


def digest_problem(where: str, state: FrameState, found: FileDigest | None, recorded: FileDigest) -> str:
    """One line saying how a frame file differs from its record (``state`` not ``intact``).

    Examples
    --------
    >>> digest_problem("f.tiff", "truncated", FileDigest("0" * 64, 10), FileDigest("1" * 64, 99))
    'f.tiff is truncated: 10 bytes of the 99 written; expected the frame file as written (restore it from a copy)'
    """
    if state == "missing" or found is None:
        return f"{where} is missing; expected the frame file written with SHA-256 {recorded.short()}…"
    if state == "truncated":
        return (
            f"{where} is truncated: {found.file_bytes} bytes of the {recorded.file_bytes} written; "
            "expected the frame file as written (restore it from a copy)"
        )
    return (
        f"{where} has changed since it was written: SHA-256 {found.short()}… ({found.file_bytes} bytes), "
        f"recorded {recorded.short()}… ({recorded.file_bytes} bytes); expected the frame file as written "
        "(restore it from a copy)"
    )


def check_frame_digest(path: Path, recorded: FileDigest, where: str) -> None:
    """Refuse a frame file that is not, byte for byte, the one ``recorded`` (``where`` names it in the message).

    Raises
    ------
    RecordingError
        One line naming the frame, what differs (length or SHA-256) and what was expected.
    """
    state, found = frame_state(path, recorded)
    if state != "intact":
        raise RecordingError(digest_problem(where, state, found, recorded))
