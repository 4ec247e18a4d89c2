"""The run folders the live page lists and serves: names, summaries, and files resolved inside one folder only.

A run folder is a direct child of the runs directory whose name is plain (:data:`RUN_NAME`) and which holds a
sequence or a report. A file is served only when its resolved path lies inside its run folder and names no
hidden part: ``..``, absolute paths, symbolic links leading out and dot-files are refused alike (None).
"""

from __future__ import annotations

import json
import re
from pathlib import Path, PurePosixPath
from typing import Any

RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")
"""A run folder's name: letters, digits, ``.``, ``_``, ``-``, not starting with a dot."""

MAX_JSON_BYTES = 16 * 1024 * 1024
"""The largest JSON file of a run the page reads (the sequence's header with its spectra is far smaller)."""


def run_folder(runs: Path, name: str) -> Path | None:
    """The run folder ``name`` under ``runs``, or None when the name is not plain or no such run exists."""
    if not RUN_NAME.fullmatch(name):
        return None
    root = runs.resolve()
    folder = (root / name).resolve()
    if folder.parent != root or not folder.is_dir():
        return None
    if not ((folder / "run.json").is_file() or (folder / "sequence" / "sequence.json").is_file()):
        return None
    return folder


def run_file(runs: Path, name: str, relative: str) -> Path | None:
    """The file ``relative`` inside run ``name``, or None (not a run, a hidden or parent part, outside it)."""
    folder = run_folder(runs, name)
    if folder is None or not relative or "\\" in relative or "\x00" in relative:
        return None
    parts = PurePosixPath(relative).parts
    if PurePosixPath(relative).is_absolute() or any(part.startswith(".") for part in parts):
        return None
    candidate = (folder / relative).resolve()
    if not candidate.is_relative_to(folder) or not candidate.is_file():
        return None
    return candidate


def read_json(path: Path) -> Any:
    """A run's JSON file, or None when it is missing, too large or not JSON."""
    try:
        if path.stat().st_size > MAX_JSON_BYTES:
            return None
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def list_runs(runs: Path) -> list[dict[str, Any]]:
    """The run folders under ``runs``, newest name first: name, whether reported, frames and the RMSE if known."""
    if not runs.is_dir():
        return []
    found = []
    for child in sorted(runs.iterdir(), key=lambda p: p.name, reverse=True):
        folder = run_folder(runs, child.name)
        if folder is None:
            continue
        summary = read_json(folder / "run.json") if (folder / "run.json").is_file() else None
        entry: dict[str, Any] = {"name": child.name, "reported": summary is not None}
        if isinstance(summary, dict):
            entry["frames"] = summary.get("frames")
            if "spectrum_rmse_vs_truth" in summary:
                entry["spectrum_rmse_vs_truth"] = summary["spectrum_rmse_vs_truth"]
        found.append(entry)
    return found


def run_files(folder: Path) -> list[str]:
    """Every file of a run folder, relative and sorted (hidden files left out)."""
    return sorted(
        str(path.relative_to(folder))
        for path in folder.rglob("*")
        if path.is_file() and not any(part.startswith(".") for part in path.relative_to(folder).parts)
    )
