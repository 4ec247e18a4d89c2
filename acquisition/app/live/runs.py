"""The run folders the live page lists and serves: names, summaries, and files resolved inside one folder only.

A run folder is a direct child of the runs directory whose name is plain (:data:`RUN_NAME`) and which holds a
sequence or a report. A file is served only when its resolved path lies inside its run folder and names no
hidden part: ``..``, absolute paths, symbolic links leading out and dot-files are refused alike (None).
"""

from __future__ import annotations

import html
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


def run_page(info: dict[str, Any]) -> str:
    """A page for a run without ``report.html`` (it stopped early): its numbers, spectra, previews and files."""
    name = html.escape(info["name"])
    summary = info.get("summary") or {}
    files = info["files"]
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>msflash run {name}</title><link rel='stylesheet' href='/static/live.css'></head>",
        f"<body class='report'><h1>Run {name}</h1><p><a href='/'>← live view</a></p>",
    ]
    if summary:
        rows = [("frames", summary.get("frames")), ("relative residual", summary.get("relative_residual"))]
        if "spectrum_rmse_vs_truth" in summary:
            rows += [
                ("spectrum RMSE vs the true ambient", summary["spectrum_rmse_vs_truth"]),
                ("best LED fit of the truth (RMSE)", summary.get("spectrum_rmse_led_bound")),
            ]
        rows.append(("re-captured flash", summary.get("recaptured_mode")))
        parts.append("<table class='summary'>")
        for label, value in rows:
            shown = f"{value:.4g}" if isinstance(value, float) else html.escape(str(value))
            parts.append(f"<tr><th>{html.escape(label)}</th><td>{shown}</td></tr>")
        parts.append("</table>")
    else:
        parts.append("<p>No report: the run did not finish (its sequence is listed below).</p>")
    charts = info.get("charts")
    if charts:
        parts.append(f"<div class='charts'>{charts['ambient']}{charts['mixes']}</div>")
    previews = [p for p in ("ambient.png", "matching.png", "complementary.png", "flash-capture.png") if p in files]
    if previews:
        parts.append("<div class='previews'>")
        for preview in previews:
            src = f"/runs/{name}/files/{html.escape(preview)}"
            parts.append(f"<figure><img src='{src}' alt='{preview}'><figcaption>{preview}</figcaption></figure>")
        parts.append("</div>")
    parts.append("<h2>Files</h2><ul class='files'>")
    for file in files:
        parts.append(f"<li><a href='/runs/{name}/files/{html.escape(file)}'>{html.escape(file)}</a></li>")
    parts.append("</ul></body></html>")
    return "\n".join(parts)
