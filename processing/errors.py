"""Errors and warnings raised by the processing core.

Every class also inherits the matching built-in exception, so callers that know nothing of msflash
still catch them sensibly. Messages follow ``"<where>: <what is wrong>; expected <what>"``.
"""

from __future__ import annotations


class SpectralDataError(ValueError):
    """Spectral or image data that cannot be used: grid mismatch, NaN, negative values, bad shape."""


class SolverError(RuntimeError):
    """A solver failed: names the method or mode, and the residual or constraint at fault."""


class ProcessingWarning(UserWarning):
    """Base class of the warnings emitted by the processing core."""


class SpectralDataWarning(ProcessingWarning):
    """A user's spectral file is read, but not as written: readings of one wavelength averaged, or values that are
    not what the file's use assumes (a spectrometer's raw counts taken as a light)."""


class TargetUnreachableWarning(ProcessingWarning):
    """The flash cannot bring ambient + flash to the target illuminant within the LED bounds."""
