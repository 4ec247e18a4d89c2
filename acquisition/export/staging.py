"""An export's folder appears complete or not at all, one export at a time per name, nothing left behind.

:func:`staged_export` claims the output *name* first (an exclusive lock on ``.NAME.export-lock`` beside
it, holding the exporter's PID: :func:`acquisition.sequence.folder_claim.lock_exclusively`), so of two
exports racing into one ``--out`` the second is told at once which process has it. Holding the claim,
it removes the staging folders (``.NAME.XXXXXXXX.export-tmp``) of exports that were killed (SIGKILL
leaves one; no signal handler runs) — any whose own lock no live process holds — with a note each. The
files are then written into a new staging folder, renamed to the output once all are written, and on
any failure the staging folder is removed.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from msflash.acquisition.errors import OutputWriteError, UsageError
from msflash.acquisition.sequence.folder_claim import lock_exclusively, release_lock, try_lock
from msflash.acquisition.signals import hold_stopping_signals
from msflash.calibration.file_modes import default_file_mode

LOCK_SUFFIX = ".export-lock"
STAGING_SUFFIX = ".export-tmp"


def _lock_for(parent: Path, name: str) -> Path:
    return parent / f".{name}{LOCK_SUFFIX}"


def _staged_name(entry: str) -> str | None:
    """The output name a staging folder was for (``.NAME.XXXXXXXX.export-tmp``), or None."""
    if not (entry.startswith(".") and entry.endswith(STAGING_SUFFIX)):
        return None
    stem = entry[1 : -len(STAGING_SUFFIX)]
    name, dot, _random = stem.rpartition(".")
    return name if dot and name else None


def remove_stale_staging(parent: Path, own_name: str) -> list[Path]:
    """Remove the staging folders in ``parent`` left by exports that were killed; the folders removed.

    A staging folder is stale when no live process holds its output name's lock: for ``own_name``
    this process holds it; for another name the lock is tried without waiting (a live export keeps
    its folder). A staging folder without a lock file at all is stale.
    """
    removed: list[Path] = []
    try:
        entries = sorted(os.scandir(parent), key=lambda e: e.name)
    except OSError:
        return removed
    for entry in entries:
        name = _staged_name(entry.name)
        if name is None or not entry.is_dir(follow_symlinks=False):
            continue
        lock = _lock_for(parent, name)
        handle = None
        if name != own_name and lock.exists():
            handle = try_lock(lock)
            if handle is None:
                continue  # a live export is writing it
        try:
            shutil.rmtree(entry.path)
            removed.append(Path(entry.path))
        except OSError:
            pass
        finally:
            if handle is not None:
                release_lock(lock, handle)
    return removed


def check_not_inside(out: Path, folder: Path, option: str, what: str) -> None:
    """Refuse an output folder inside ``folder`` (the sequence being exported).

    Raises
    ------
    UsageError
        Naming the option, the output and the folder.
    """
    try:
        inside = out.resolve().is_relative_to(folder.resolve())
    except OSError:
        inside = False
    if inside:
        raise UsageError(
            f"{option} {out}: is inside {what} {folder}; expected a folder outside it (files written there "
            "would be undeclared files of the sequence, which msflash check refuses)"
        )


@contextlib.contextmanager
def staged_export(out: Path, option: str, check_out: Callable[[Path, str], None], notes: list[str]) -> Iterator[Path]:
    """Claim ``out``'s name, then yield a staging folder that becomes ``out`` when the block ends without error.

    ``check_out`` checks ``out`` is still free once the name is claimed (another export may have finished it);
    notes for the user (stale staging folders removed) are appended to ``notes``.

    Raises
    ------
    FolderInUseError
        Another live export is writing ``out``: its PID and command are named (exit 2).
    UsageError
        ``out`` cannot be created in its folder, or :func:`check_out` refuses it.
    OutputWriteError
        Writing or renaming failed (disk full…): nothing is left behind.
    """
    parent = out.parent
    lock = _lock_for(parent, out.name)
    try:
        handle = lock_exclusively(
            lock,
            f"msflash export into {out}",
            lambda holder: (
                f"{option} {out}: another export is writing it: {holder}; expected a folder no other "
                f"export is writing (wait for it, or choose another {option})"
            ),
            taken_over=str(out),
        )
    except OSError as err:
        raise UsageError(
            f"{option} {out}: cannot be created in {parent} ({err.strerror or err}); expected a writable folder"
        ) from None
    try:
        check_out(out, option)
        for path in remove_stale_staging(parent, out.name):
            notes.append(f"removed {path}, the unfinished folder of an export that was stopped (killed?)")
        # A stopping signal (Ctrl-C, SIGTERM, SIGHUP) between the staging folder's creation and the cleanup
        # below taking charge of it would leave the folder behind: it is held pending until then.
        release_signals = hold_stopping_signals()
        try:
            staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=STAGING_SUFFIX, dir=parent))
        except OSError as err:
            release_signals()
            raise UsageError(
                f"{option} {out}: cannot be created in {parent} ({err.strerror or err}); expected a writable folder"
            ) from None
        try:
            release_signals()  # a signal held meanwhile is raised here
            mode = default_file_mode()
            staging.chmod(mode | (mode & 0o444) >> 2)  # mkdtemp's 0700 would keep other lab users out
            yield staging
            staging.rename(out)
        except OSError as err:
            with contextlib.suppress(OSError):
                shutil.rmtree(staging)
            raise OutputWriteError(
                f"{option} {out}: could not be written ({err.strerror or err}); expected a writable disk with room "
                "for it (nothing was left)"
            ) from None
        except BaseException:
            with contextlib.suppress(OSError):
                shutil.rmtree(staging)
            raise
    finally:
        release_lock(lock, handle)
