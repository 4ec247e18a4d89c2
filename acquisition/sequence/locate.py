"""The sequence folder a user meant: a sequence folder, a run or capture folder, or a ``sequence.json``.

``msflash run --out D`` and ``msflash capture --out D`` write the sequence to ``D/sequence``; every
command reading one (``estimate``, ``flash``, ``synthesize``, ``evaluate``, ``check``, ``calibrate``,
``--rig replay:``, ``export``) takes ``D``, ``D/sequence`` or ``D/sequence/sequence.json`` alike
through :func:`locate_sequence`, the one place that decides, and refuses anything else with one
line naming the folder and what was expected.
"""

from __future__ import annotations

import os
from pathlib import Path

from msflash.acquisition.errors import RecordingError
from msflash.processing.user_files import shown_path

SEQUENCE_FILE = "sequence.json"
"""The file that makes a folder a sequence (docs/architecture.md §6)."""

SEQUENCE_FOLDER = "sequence"
"""Where ``run`` and ``capture`` put the sequence inside their ``--out`` folder."""

EXPECTED = (
    f"expected a sequence folder (holding {SEQUENCE_FILE}) or a run or capture folder holding one "
    f"({SEQUENCE_FOLDER}/{SEQUENCE_FILE})"
)


def locate_sequence(path: str | os.PathLike, what: str = "") -> Path:
    """The folder holding ``sequence.json`` meant by ``path`` (a sequence folder, a run or capture folder, or a
    ``sequence.json`` file); ``what`` is how the command names the argument in its error (``"--rig replay:"``).

    Raises
    ------
    RecordingError
        One line naming ``path`` and what was expected: nothing there, no sequence in or under it
        (the folders under it that hold one are named), or both a sequence and a ``sequence``
        subfolder holding another (ambiguous).

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as run:
    ...     _ = (Path(run) / "sequence").mkdir()
    ...     _ = (Path(run) / "sequence" / "sequence.json").write_text("{}")
    ...     locate_sequence(run) == locate_sequence(Path(run) / "sequence") == Path(run) / "sequence"
    True
    """
    given = Path(path)
    shown = f"{what}{shown_path(given)}"
    # Present is enough to decide: a sequence.json that is a FIFO, a device or a symlink loop is the
    # reader's to refuse, naming what it is (processing/user_files.py).
    if given.name == SEQUENCE_FILE and os.path.lexists(given) and not given.is_dir():
        return given.parent
    if not os.path.lexists(given):
        raise RecordingError(f"{shown}: not found; {EXPECTED}")
    if not given.is_dir():
        raise RecordingError(f"{shown}: is not a folder; {EXPECTED}")
    here = os.path.lexists(given / SEQUENCE_FILE)
    inside = os.path.lexists(given / SEQUENCE_FOLDER / SEQUENCE_FILE)
    if here and inside:
        raise RecordingError(
            f"{shown}: holds both a sequence ({SEQUENCE_FILE}) and another in {SEQUENCE_FOLDER}/; "
            f"expected one — name {shown_path(given / SEQUENCE_FOLDER)} for the inner one"
        )
    if here:
        return given
    if inside:
        return given / SEQUENCE_FOLDER
    below = _sequences_below(given)
    hint = f" (found one in {', '.join(below[:3])}{' …' if len(below) > 3 else ''}: name it)" if below else ""
    raise RecordingError(f"{shown}: no {SEQUENCE_FILE} in it or in {SEQUENCE_FOLDER}/{hint}; {EXPECTED}")


def _sequences_below(folder: Path) -> list[str]:
    """The folders one level down that :func:`locate_sequence` would accept (runs in a folder of runs), sorted."""
    try:
        children = sorted(child for child in folder.iterdir() if child.is_dir())
    except OSError:
        return []
    return [shown_path(child) for child in children if holds_sequence(child)]


def holds_sequence(folder: Path) -> bool:
    """Whether :func:`locate_sequence` finds a sequence in ``folder`` itself or in its ``sequence/``
    (a sequence, run or capture folder), without reading it."""
    return os.path.lexists(folder / SEQUENCE_FILE) or os.path.lexists(folder / SEQUENCE_FOLDER / SEQUENCE_FILE)


ARGUMENT_HELP = "a sequence folder, or a run or capture folder holding one in sequence/"
"""The help line of every argument :func:`locate_sequence` reads."""
