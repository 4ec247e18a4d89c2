"""One owner per output folder (issue 19): a run, a capture or a sequence writer claims its folder.

:func:`claim_folder` takes an exclusive ``fcntl.flock`` on ``<folder>/.msflash-lock``, held until
the claim is released (or the process dies: the kernel drops the lock, so a killed writer never
leaves a folder locked). The file holds the holder's PID and command, so a second process is told
who has the folder: :class:`~acquisition.errors.FolderInUseError`, exit 2. A lock file left by a
dead process (it is removed on release, so one left means the holder was killed) is taken over
with a note on stderr. While holding the claim, the temporary files a killed writer left
(``.NAME.XXXX.tmp…``, from :func:`acquisition.sequence.image_files.write_image` and the ``sequence.json``
replacement) are removed with a note: no other process can be writing them.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

from msflash.acquisition.errors import FolderInUseError

LOCK_FILE = ".msflash-lock"
"""Name of the lock file inside a claimed folder."""

_log = logging.getLogger(__name__)


def _holder(lock: Path) -> str:
    """The PID and command of the holder, as it wrote them (it may still be writing: a few tries)."""
    text = ""
    for _ in range(50):
        with contextlib.suppress(OSError):
            text = lock.read_text(encoding="utf-8", errors="replace")
        if text.endswith("\n"):
            break
        time.sleep(0.01)
    pid, _, rest = text.partition("\n")
    return f"msflash process {pid or '(unknown)'} ({' '.join(rest.split()) or 'starting'})"


def _is_stale_temporary(name: str) -> bool:
    return name.startswith(".") and ".tmp" in name and name != LOCK_FILE


class FolderClaim:
    """An exclusive claim on a folder; :meth:`release` (or leaving the ``with`` block) gives it up."""

    def __init__(self, folder: Path, handle: int) -> None:
        self.folder = folder
        self.lock = folder / LOCK_FILE
        self._handle: int | None = handle

    def release(self) -> None:
        """Remove the lock file (still holding the lock, so no one can be relying on it) and unlock."""
        handle, self._handle = self._handle, None
        if handle is not None:
            release_lock(self.lock, handle)

    def __enter__(self) -> FolderClaim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __del__(self) -> None:
        self.release()

    def clean_stale_temporaries(self, *subfolders: str) -> list[Path]:
        """Remove the temporary files a killed writer left in the folder and ``subfolders``; a note each."""
        removed = []
        for directory in (self.folder, *(self.folder / s for s in subfolders)):
            with contextlib.suppress(OSError):
                for entry in os.scandir(directory):
                    if entry.is_file(follow_symlinks=False) and _is_stale_temporary(entry.name):
                        with contextlib.suppress(FileNotFoundError):
                            os.unlink(entry.path)
                            removed.append(Path(entry.path))
        for path in removed:
            _log.warning(
                "%s: removed a temporary file left by a writer that was stopped (not part of any sequence)", path
            )
        return removed


def _holder_alive(folder: Path) -> bool:
    """Whether the lock file names a live process (read only: a reader must never take the lock,
    which would make a writer starting at that moment see the folder in use)."""
    try:
        pid = int((folder / LOCK_FILE).read_text(encoding="utf-8", errors="replace").partition("\n")[0])
    except (OSError, ValueError):
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # alive, another user's
    return True


def stale_temporaries(folder: str | os.PathLike, *subfolders: str) -> list[Path]:
    """Temporary files a stopped writer left in ``folder`` and ``subfolders`` ([] while a live
    process holds the folder: its temporary files are work in progress). Nothing is removed."""
    folder = Path(folder)
    if _holder_alive(folder):
        return []
    found: list[Path] = []
    for directory in (folder, *(folder / s for s in subfolders)):
        with contextlib.suppress(OSError):
            found.extend(
                Path(e.path)
                for e in os.scandir(directory)
                if _is_stale_temporary(e.name) and e.is_file(follow_symlinks=False)
            )
    return sorted(found)


def claim_folder(folder: str | os.PathLike, what: str = "writing") -> FolderClaim:
    """Claim ``folder`` (created if needed) for this process; ``what`` it does there (``"msflash run"``) is
    recorded for a second process's message.

    Raises
    ------
    FolderInUseError
        Another live process holds the folder; the message names it and its PID.
    OSError
        The folder or its lock file cannot be created (callers name it as a bad output path).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    handle = lock_exclusively(
        folder / LOCK_FILE,
        what,
        lambda holder: (
            f"{folder}: in use by {holder}; expected a folder no other run is "
            "writing (wait for it, or choose another --out)"
        ),
        taken_over=f"{folder}",
    )
    return FolderClaim(folder, handle)


def lock_exclusively(lock: Path, what: str, in_use: Callable[[str], str], *, taken_over: str) -> int:
    """An exclusive ``flock`` on the file ``lock`` (created), holding this process's PID and ``what``.

    The building block of :func:`claim_folder` and of claims on a name before its folder exists
    (:func:`claim_name`). A lock file whose holder died is taken over with a note naming
    ``taken_over``; ``in_use`` builds the :class:`FolderInUseError`'s message from a live holder's description.
    Returns the open handle holding the lock (release it with :func:`release_lock`).
    """
    while True:
        handle = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(handle)
            raise FolderInUseError(in_use(_holder(lock))) from None
        # The holder before us may have removed the file between our open and our lock: then we
        # hold a lock on a file no one else can see, and must lock the one now at that path.
        try:
            same = os.path.samestat(os.fstat(handle), os.stat(lock))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(handle)
    previous = os.read(handle, 4096).decode("utf-8", errors="replace")
    if previous.strip():
        pid = previous.partition("\n")[0]
        _log.warning(
            "%s: taking over from msflash process %s, which stopped without releasing it (killed?)", taken_over, pid
        )
    os.ftruncate(handle, 0)
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    os.pwrite(handle, f"{os.getpid()}\n{what}, since {started}\n".encode("utf-8", errors="replace"), 0)
    return handle


def release_lock(lock: Path, handle: int) -> None:
    """Remove ``lock`` (still holding it, so no one can be relying on it) and unlock ``handle``."""
    with contextlib.suppress(OSError):
        if os.path.samestat(os.fstat(handle), os.stat(lock)):
            os.unlink(lock)
    os.close(handle)


def try_lock(lock: Path) -> int | None:
    """The lock on ``lock`` if no live process holds it (its holder died), else None; never waits."""
    try:
        handle = os.open(lock, os.O_RDWR | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(handle)
        return None
    return handle
