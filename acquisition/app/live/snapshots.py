"""Snapshots of the live view: the raw frame as a TIFF and its sRGB rendering as a PNG, written whole or not at all.

Each file is written to a hidden temporary file in the target folder, flushed to disk, then **linked** to its
name (``os.link`` fails when the name exists, so an existing file is never replaced, even by another process
racing for it) and the temporary removed. A name that is taken gets ``-2``, ``-3``… (the TIFF and the PNG of
one snapshot share their stem). A failure leaves no partial file behind.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from PIL import Image

MAX_TRIES = 1000
"""Stems tried (``-2``… ``-1000``) before giving up on a folder."""


def _write_new(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; FileExistsError when the name is taken."""
    descriptor, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(descriptor, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.link(temporary, path)  # never replaces: an existing name raises FileExistsError
    finally:
        os.unlink(temporary)


def write_snapshot(
    folder: Path, raw: np.ndarray, srgb8: np.ndarray, metadata: dict[str, Any], stem: str | None = None
) -> tuple[Path, Path]:
    """Write ``raw`` as ``<stem>.tiff`` and ``srgb8`` as ``<stem>.png`` (and ``<stem>.json``) into ``folder``.

    ``stem`` defaults to the UTC time; a stem whose TIFF, PNG or JSON exists is never reused. Returns the
    TIFF's and the PNG's paths.
    """
    folder.mkdir(parents=True, exist_ok=True)
    base = stem or datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    description = json.dumps(metadata, sort_keys=True)
    tiff = io.BytesIO()
    tifffile.imwrite(tiff, raw, description=description)
    png = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(srgb8, dtype=np.uint8)).save(png, "PNG")
    for n in range(1, MAX_TRIES + 1):
        name = base if n == 1 else f"{base}-{n}"
        tiff_path, png_path, json_path = (folder / f"{name}{suffix}" for suffix in (".tiff", ".png", ".json"))
        if png_path.exists() or json_path.exists():
            continue
        try:
            _write_new(tiff_path, tiff.getvalue())
        except FileExistsError:
            continue
        _write_new(png_path, png.getvalue())
        _write_new(json_path, (description + "\n").encode())
        return tiff_path, png_path
    raise FileExistsError(f"{folder / base}: {MAX_TRIES} snapshots of that name exist; expected a free name")
