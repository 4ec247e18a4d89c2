"""Errors of the calibration package (docs/architecture.md §7).

``CalibrationError`` is a ``ValueError``: every calibration failure is bad input (a file, a
field, a measurement) and the message names where, what and what was expected:
``"<file>:<line>: <what is wrong>; expected <what>"``.
"""

from __future__ import annotations


class CalibrationError(ValueError):
    """A calibration input or file is unusable; the message names file, field and expectation."""


class CalibrationWarning(UserWarning):
    """A measurement is usable but suspect (saturated, noisy, poorly fitted)."""
