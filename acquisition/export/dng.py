"""A raw mosaic as a DNG file (DNG 1.4: TIFF with its own tags, and EXIF in its own IFD).

What a raw developer needs (Adobe DNG Specification 1.4): ``DNGVersion``, ``UniqueCameraModel``,
the CFA (``CFARepeatPatternDim``, ``CFAPattern``, ``CFAPlaneColor``, ``CFALayout``), ``BlackLevel``
and ``WhiteLevel``, ``ColorMatrix1`` (XYZ → camera under ``CalibrationIlluminant1``) and
``AsShotNeutral`` (the camera RGB of white under the scene's light, which it white-balances to),
and ``Orientation``. The capture goes in the EXIF IFD that IFD0's ``ExifIFD`` points to, where
EXIF 2.32 and ``exiftool -validate`` want it: ``ExposureTime``, ``DateTimeOriginal`` with
``SubSecTimeOriginal`` and ``OffsetTimeOriginal`` (the frame's wall-clock time, UTC), and
``ISOSpeedRatings`` only when the camera's ISO equivalence is known — a machine-vision camera's gain
has none, and a made-up ISO would mislead a developer's noise reduction more than none
(docs/decisions/dng-exif.md). The file is written byte by byte (:mod:`.tiff_ifd`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence as SequenceOf
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from msflash.acquisition.export.tiff_ifd import (
    Tag,
    ascii_tag,
    byte_tag,
    long_tag,
    rational_tag,
    short_tag,
    srational_tag,
    undefined_tag,
    write_tiff,
)

CFA_COLOURS = {"RGGB": (0, 1, 1, 2), "BGGR": (2, 1, 1, 0), "GRBG": (1, 0, 2, 1), "GBRG": (1, 2, 0, 1)}
"""DNG ``CFAPattern`` of each CFA name, row by row over the 2×2 tile (0 red, 1 green, 2 blue)."""

ORIENTATION_TOP_LEFT = 1
"""EXIF/TIFF ``Orientation`` 1: row 0 at the top, column 0 at the left — the sensor's readout, as recorded."""
EXIF_VERSION = b"0232"
"""EXIF 2.32: the version that defines ``OffsetTimeOriginal``."""

_PHOTOMETRIC_CFA = 32803
_D65 = 21  # EXIF LightSource code of D65, DNG CalibrationIlluminant1
_SENSITIVITY_ISO_SPEED = 3  # EXIF SensitivityType: ISOSpeedRatings holds the ISO speed


def exif_time(moment: datetime) -> tuple[str, str, str]:
    """``DateTimeOriginal``, ``SubSecTimeOriginal`` and ``OffsetTimeOriginal`` of an aware time, in UTC.

    >>> exif_time(datetime(2026, 3, 1, 12, 30, 5, 250000, tzinfo=UTC))
    ('2026:03:01 12:30:05', '250000', '+00:00')
    """
    if moment.tzinfo is None:
        raise ValueError(f"capture time {moment.isoformat()}: no time zone; expected an aware time (UTC)")
    utc = moment.astimezone(UTC)
    return utc.strftime("%Y:%m:%d %H:%M:%S"), f"{utc.microsecond:06d}", "+00:00"


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
    captured_at: datetime | None = None,
    iso_speed: float | None = None,
) -> Path:
    """Write one raw mosaic as a DNG (Bayer CFA, uncompressed 16-bit).

    Parameters
    ----------
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
    description
        ``ImageDescription`` (what the frame is; 7-bit ASCII, anything else written as ``?``).
    exposure_us
        The frame's exposure, written as EXIF ``ExposureTime`` (seconds), or None.
    captured_at
        When the frame was captured (an aware time): EXIF ``DateTimeOriginal``, ``SubSecTimeOriginal``,
        ``OffsetTimeOriginal`` (UTC) and IFD0's ``DateTime``; None writes no date.
    iso_speed
        The frame's ISO speed (``ISOSpeedRatings``, ``SensitivityType`` ISO speed), or None when the
        camera's ISO equivalence is unknown (then no ISO tag at all).

    Raises
    ------
    ValueError
        If the mosaic is not 2-D integer counts, the CFA unknown, the neutral not three values > 0,
        the matrix not a finite 3×3, the time naive or the ISO outside 1…65535.
    """
    pixels, neutral_values, matrix = _checked(path, mosaic, cfa, neutral, xyz_to_camera, iso_speed)
    model = camera_model or "unknown camera"
    ifd0 = _raw_ifd(model, cfa, black_level, white_level, matrix, neutral_values)
    if description:
        ifd0.append(ascii_tag(270, description))  # ImageDescription
    exif = [undefined_tag(36864, EXIF_VERSION)]
    if exposure_us is not None:
        exif.append(rational_tag(33434, float(exposure_us) / 1e6))  # ExposureTime, s
    if captured_at is not None:
        stamp, subseconds, offset = exif_time(captured_at)
        ifd0.append(ascii_tag(306, stamp))  # DateTime
        exif += [
            ascii_tag(36867, stamp),  # DateTimeOriginal
            ascii_tag(36880, offset),  # OffsetTime (of DateTime)
            ascii_tag(36881, offset),  # OffsetTimeOriginal
            ascii_tag(37520, subseconds),  # SubSecTime
            ascii_tag(37521, subseconds),  # SubSecTimeOriginal
        ]
    if iso_speed is not None:
        exif += [short_tag(34855, round(iso_speed)), short_tag(34864, _SENSITIVITY_ISO_SPEED)]
    return write_tiff(path, np.asarray(pixels, dtype=np.uint16), ifd0, exif)


def _checked(
    path: str | os.PathLike,
    mosaic: np.ndarray,
    cfa: str,
    neutral: SequenceOf[float] | np.ndarray,
    xyz_to_camera: np.ndarray,
    iso_speed: float | None,
) -> tuple[np.ndarray, list[float], np.ndarray]:
    """The mosaic, the neutral and the matrix as :func:`write_dng` writes them, or its ``ValueError``."""
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
    if iso_speed is not None and not 1 <= round(iso_speed) <= 65535:
        raise ValueError(f"{path}: ISO speed {iso_speed}; expected 1…65535 or None (unknown)")
    return pixels, neutral_values, matrix


def _raw_ifd(
    model: str, cfa: str, black_level: float, white_level: float, matrix: np.ndarray, neutral: list[float]
) -> list[Tag]:
    """IFD0's tags of a raw CFA image: identity, the CFA, the levels and the colour (DNG 1.4)."""
    return [
        long_tag(254, 0),  # NewSubfileType: the main (raw) image
        short_tag(262, _PHOTOMETRIC_CFA),
        ascii_tag(271, "msflash"),  # Make
        ascii_tag(272, model),  # Model
        short_tag(274, ORIENTATION_TOP_LEFT),
        rational_tag(282, (1, 1)),  # XResolution
        rational_tag(283, (1, 1)),  # YResolution
        short_tag(296, 1),  # ResolutionUnit: none (a sensor's pixels have no print size)
        ascii_tag(305, "msflash"),  # Software
        short_tag(33421, 2, 2),  # CFARepeatPatternDim
        byte_tag(33422, *CFA_COLOURS[cfa]),  # CFAPattern
        byte_tag(50706, 1, 4, 0, 0),  # DNGVersion
        byte_tag(50707, 1, 1, 0, 0),  # DNGBackwardVersion
        ascii_tag(50708, model),  # UniqueCameraModel
        byte_tag(50710, 0, 1, 2),  # CFAPlaneColor
        short_tag(50711, 1),  # CFALayout: rectangular
        short_tag(50713, 1, 1),  # BlackLevelRepeatDim
        rational_tag(50714, float(black_level)),  # BlackLevel
        long_tag(50717, round(white_level)),  # WhiteLevel
        srational_tag(50721, *matrix.ravel()),  # ColorMatrix1
        rational_tag(50728, *neutral),  # AsShotNeutral
        short_tag(50778, _D65),  # CalibrationIlluminant1
    ]
