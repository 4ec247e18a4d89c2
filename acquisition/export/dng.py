"""A raw mosaic as a DNG file, written with tifffile (DNG is TIFF with its own tags).

Public objects
--------------
- :func:`write_dng`: one CFA frame, its black and white levels, ``AsShotNeutral`` and ``ColorMatrix1``.
- :data:`CFA_COLOURS`: DNG's ``CFAPattern`` codes of msflash's CFA names.

What a raw developer needs (Adobe DNG Specification 1.4): ``DNGVersion``, ``UniqueCameraModel``,
the CFA (``CFARepeatPatternDim``, ``CFAPattern``, ``CFAPlaneColor``, ``CFALayout``), ``BlackLevel``
and ``WhiteLevel``, ``ColorMatrix1`` (XYZ → camera under ``CalibrationIlluminant1``) and
``AsShotNeutral`` (the camera RGB of white under the scene's light, which it white-balances to),
and EXIF ``ExposureTime``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence as SequenceOf
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

CFA_COLOURS = {"RGGB": (0, 1, 1, 2), "BGGR": (2, 1, 1, 0), "GRBG": (1, 0, 2, 1), "GBRG": (1, 2, 0, 1)}
"""DNG ``CFAPattern`` of each CFA name, row by row over the 2×2 tile (0 red, 1 green, 2 blue)."""

_PHOTOMETRIC_CFA = 32803
_D65 = 21  # EXIF LightSource code of D65, DNG CalibrationIlluminant1
_RATIONAL, _SRATIONAL = 5, 10
_DENOMINATOR = 1_000_000


def _rationals(values: SequenceOf[float] | np.ndarray) -> tuple[int, ...]:
    """Flat (numerator, denominator) pairs, as tifffile takes RATIONAL and SRATIONAL tags."""
    pairs: list[int] = []
    for value in values:
        pairs += [round(float(value) * _DENOMINATOR), _DENOMINATOR]
    return tuple(pairs)


def write_dng(
    path: str | os.PathLike,
    mosaic: np.ndarray,
    cfa: str,
    black_level: float,
    white_level: float,
    neutral: SequenceOf[float] | np.ndarray,
    xyz_to_camera: np.ndarray,
    camera_model: str,
    description: str = "",
    exposure_us: float | None = None,
) -> Path:
    """Write one raw mosaic as a DNG (Bayer CFA, uncompressed 16-bit).

    Parameters
    ----------
    path
        The file to write (replaced if it exists; the caller decides whether it may).
    mosaic
        (H, W) integer counts in 0…65535, as the camera gave them (black level included).
    cfa
        ``RGGB``, ``BGGR``, ``GRBG`` or ``GBRG``: the colours of the top-left 2×2 tile.
    black_level, white_level
        The camera's pixel value of no light and of saturation (``BlackLevel``, ``WhiteLevel``).
    neutral
        Camera R, G, B of white under the scene's light, largest 1 (``AsShotNeutral``).
    xyz_to_camera
        3×3 XYZ → camera under D65 (``ColorMatrix1``, ``CalibrationIlluminant1`` = D65).
    camera_model
        ``UniqueCameraModel`` and ``Model``.
    description
        ``ImageDescription`` (what the frame is).
    exposure_us
        The frame's exposure, written as EXIF ``ExposureTime`` (seconds), or None.

    Raises
    ------
    ValueError
        If the mosaic is not 2-D integer counts, the CFA unknown or the neutral not three values > 0.
    """
    pixels = np.asarray(mosaic)
    if pixels.ndim != 2 or not np.issubdtype(pixels.dtype, np.integer) or pixels.size == 0:
        raise ValueError(f"{path}: mosaic of shape {pixels.shape} and type {pixels.dtype}; expected (H, W) counts")
    if pixels.min() < 0 or pixels.max() > 65535:
        raise ValueError(f"{path}: counts span {pixels.min()}…{pixels.max()}; expected 0…65535")
    if cfa not in CFA_COLOURS:
        raise ValueError(f"{path}: CFA '{cfa}'; expected one of {', '.join(CFA_COLOURS)}")
    neutral_values = [float(v) for v in neutral]
    if len(neutral_values) != 3 or not all(np.isfinite(v) and v > 0 for v in neutral_values):
        raise ValueError(f"{path}: neutral {neutral_values}; expected three values > 0")
    matrix = np.asarray(xyz_to_camera, dtype=float)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        raise ValueError(f"{path}: colour matrix of shape {matrix.shape}; expected a finite 3×3")
    model = camera_model or "unknown camera"
    tags: list[tuple[int | str, int | str, int | None, Any, bool]] = [
        (271, "s", 0, "msflash", True),  # Make
        (272, "s", 0, model, True),  # Model
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),  # DNGBackwardVersion
        (50708, "s", 0, model, True),  # UniqueCameraModel
        (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
        (33422, "B", 4, CFA_COLOURS[cfa], True),  # CFAPattern
        (50710, "B", 3, (0, 1, 2), True),  # CFAPlaneColor
        (50711, "H", 1, 1, True),  # CFALayout: rectangular
        (50713, "H", 2, (1, 1), True),  # BlackLevelRepeatDim
        (50714, _RATIONAL, 1, _rationals([black_level]), True),  # BlackLevel
        (50717, "I", 1, round(white_level), True),  # WhiteLevel
        (50721, _SRATIONAL, 9, _rationals(matrix.ravel()), True),  # ColorMatrix1
        (50778, "H", 1, _D65, True),  # CalibrationIlluminant1
        (50728, _RATIONAL, 3, _rationals(neutral_values), True),  # AsShotNeutral
    ]
    if exposure_us is not None:
        tags.append((33434, _RATIONAL, 1, (round(exposure_us), 1_000_000), True))  # ExposureTime, s
    path = Path(path)
    with tifffile.TiffWriter(path) as writer:
        writer.write(
            np.ascontiguousarray(pixels, dtype=np.uint16),
            photometric=_PHOTOMETRIC_CFA,
            subfiletype=0,
            description=description or None,
            software="msflash",
            metadata=None,
            extratags=tags,
        )
    return path
