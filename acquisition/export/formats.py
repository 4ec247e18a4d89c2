"""The export formats and the option naming them (no heavy import: ``run`` parses ``--export`` with it)."""

from __future__ import annotations

from msflash.acquisition.errors import UsageError
from msflash.processing.names import unknown_name

EXPORT_FORMATS = ("dng", "ome-tiff", "csv", "exr")
"""DNG of raw frames, OME-TIFF of every frame, CSV of spectra, EXR of linear images."""


def parse_formats(text: str, option: str = "--to") -> tuple[str, ...]:
    """Formats from ``dng`` or ``dng,csv`` (order kept, repeats dropped).

    Raises
    ------
    UsageError
        Naming the option and the unknown name.

    Examples
    --------
    >>> parse_formats("dng, csv,dng")
    ('dng', 'csv')
    """
    names = [name.strip().lower() for name in text.split(",")]
    unknown = [name for name in names if name not in EXPORT_FORMATS]
    if unknown:
        raise UsageError(
            f"{option} {text}: "
            + unknown_name("format", unknown[0], EXPORT_FORMATS)
            + " (one or more, comma-separated)"
        )
    return tuple(dict.fromkeys(names))
