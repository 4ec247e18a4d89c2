"""Is a frame's pixel range possible for its declared black and white levels?

A frame holding values above ``camera.white_level`` — a 16-bit file of 12-bit data declared with
the wrong white level, a corrupt or mis-scaled file — or far below ``camera.black_level`` would
otherwise be linearised without a word, and every estimate from it would be wrong. One function,
:func:`check_frame_levels`, called by :meth:`acquisition.sequence.format.Sequence.load_frame`
(which every route that reads a sequence's frames goes through: ``estimate``, ``flash``,
``synthesize``, ``evaluate``, ``run --from-disk``, ``--rig replay:``), refuses such a frame with
one line naming the file, how many pixels, the range found and the range expected. Frames a live
``run`` keeps in memory (straight from the camera, before they are read back) are not checked here.

The rule
--------
- **Above white**: any value above ``white_level`` is refused; values *at* white are saturated
  pixels, which is normal. Float frames (EXR, often normalised to white 1.0) get a relative
  tolerance of :data:`FLOAT_WHITE_RTOL` for rounding; NaN and ±inf are refused as well.
- **White beyond the bit depth**: an integer frame whose ``white_level`` is above the largest
  value its type holds (1e30 on 16-bit data) is refused: it could never saturate.
- **Below black**: read noise puts dark pixels a little below black, so values down to
  ``black − margin`` are accepted, with ``margin = BLACK_MARGIN_FRACTION × (white − black) ×
  max(gain, 1)``: a stated bound, since a frame alone cannot tell its read noise from an offset.
  Read noise is well under 0.5 % of full scale at unity gain on the sensors msflash knows
  (docs/architecture.md §10), so 2 % is ≥ 4σ of even a noisy sensor, and it grows with the
  frame's gain as read noise in DN does.
  What it catches is an offset: a black level declared for another bit depth or another camera
  mode (black 256 declared for data whose black is 0, or 4096 for a 12-bit black of 256 in a
  16-bit container).

The pixels are counted only when a bound is crossed (otherwise one ``min`` and one ``max``).
"""

from __future__ import annotations

import numpy as np

from msflash.acquisition.errors import RecordingError

BLACK_MARGIN_FRACTION = 0.02
"""How far below black (a share of ``white − black``, times the frame's gain if above 1) read noise may reach."""
FLOAT_WHITE_RTOL = 1e-6
"""Relative tolerance above white for float frames (float32 rounding of a normalised white)."""


def black_margin(black_level: float, white_level: float, gain: float = 1.0) -> float:
    """How far below ``black_level`` a frame's values may lie (read noise), in pixel units.

    Examples
    --------
    >>> black_margin(256, 4095)
    76.78
    """
    return BLACK_MARGIN_FRACTION * (white_level - black_level) * max(float(gain), 1.0)


def check_frame_levels(
    pixels: np.ndarray, black_level: float, white_level: float, gain: float = 1.0, where: str = "frame"
) -> None:
    """Refuse a frame whose values the declared levels cannot produce.

    ``pixels``: the frame as read, integer counts or floats of any shape; ``gain``: the frame's (the margin
    below black grows with it); ``where`` names the frame in the message.

    Raises
    ------
    RecordingError
        One line: how many pixels lie above white, below ``black − margin`` or are not finite,
        the range found, and the range expected.

    Examples
    --------
    >>> check_frame_levels(np.array([250, 4095], dtype=np.uint16), 256, 4095)
    >>> check_frame_levels(np.array([300, 4000], dtype=np.uint16), 256, 1e30, where="f.tiff")
    Traceback (most recent call last):
    ...
    msflash.acquisition.errors.RecordingError: f.tiff: camera.white_level 1e+30 is above the largest value of this 16-bit \
frame (65535); expected the white level of the frames' bit depth (at most 65535)
    >>> check_frame_levels(np.array([300, 65535], dtype=np.uint16), 256, 4095, where="f.tiff")
    Traceback (most recent call last):
    ...
    msflash.acquisition.errors.RecordingError: f.tiff: 1 of 2 pixels above camera.white_level 4095 (values 300…65535); \
expected values in 179.2…4095 (black_level 256 minus a read-noise margin of 76.78, up to white_level 4095): \
a white level declared for another bit depth (12-bit data in a 16-bit file?) or a corrupt file
    """
    if pixels.size == 0:
        return
    _check_white_fits_dtype(pixels, white_level, where)
    low_bound = black_level - black_margin(black_level, white_level, gain)
    floating = np.issubdtype(pixels.dtype, np.floating)
    high_bound = white_level + (FLOAT_WHITE_RTOL * abs(white_level) if floating else 0.0)
    low, high = pixels.min(), pixels.max()  # NaN propagates through both in floats
    if low >= low_bound and high <= high_bound:
        return
    problems = []
    if floating:
        finite = np.isfinite(pixels)
        if not finite.all():
            problems.append(
                f"{int(pixels.size - np.count_nonzero(finite))} of {pixels.size} pixels not finite (NaN or ±inf)"
            )
            values = pixels[finite]
            low, high = (values.min(), values.max()) if values.size else (np.nan, np.nan)
    above = int(np.count_nonzero(pixels > high_bound)) if high > high_bound else 0
    below = int(np.count_nonzero(pixels < low_bound)) if low < low_bound else 0
    if above:
        problems.append(f"{above} of {pixels.size} pixels above camera.white_level {white_level:g}")
    if below:
        problems.append(
            f"{below} of {pixels.size} pixels below camera.black_level {black_level:g} by more than read noise allows"
        )
    raise RecordingError(
        f"{where}: {' and '.join(problems)} (values {_value(low)}…{_value(high)}); expected "
        f"values in {low_bound:.4g}…{white_level:g} (black_level {black_level:g} minus a read-noise margin of "
        f"{black_margin(black_level, white_level, gain):.4g}, up to white_level {white_level:g}): "
        f"{_likely_causes(above > 0, below > 0)}"
    )


def _check_white_fits_dtype(pixels: np.ndarray, white_level: float, where: str) -> None:
    """Refuse a white level no value of an integer frame can reach: saturation would never be seen, and the
    DNG and EXR exports would carry a level their fields cannot hold."""
    if np.issubdtype(pixels.dtype, np.integer) and white_level > np.iinfo(pixels.dtype).max:
        largest = np.iinfo(pixels.dtype).max
        raise RecordingError(
            f"{where}: camera.white_level {white_level:g} is above the largest value of this "
            f"{pixels.dtype.itemsize * 8}-bit frame ({largest}); expected the white level of the frames' bit depth "
            f"(at most {largest})"
        )


def _likely_causes(above: bool, below: bool) -> str:
    """What most likely made values above white or below black, the last a corrupt file."""
    causes = []
    if above:
        causes.append("a white level declared for another bit depth (12-bit data in a 16-bit file?)")
    if below:
        causes.append("a black level declared for another camera mode or bit depth")
    causes.append("a corrupt file")
    return " or ".join(causes)


def _value(value: float) -> str:
    return f"{float(value):.6g}"
