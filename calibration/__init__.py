"""msflash calibration: LED spectra, camera responsivities, dark/linearity and calibration files.

Pure (arrays and :class:`~processing.spectra.Spectra` in, results out) apart from
:mod:`calibration.spectrometer` and :mod:`calibration.files`, which read and write the text files
calibration owns (written whole, with the umask's permissions, by :mod:`calibration.file_modes`, which
acquisition's writers use too). Imports only :mod:`processing`.
"""

from msflash.calibration.errors import CalibrationError, CalibrationWarning
from msflash.one_copy import one_copy

one_copy(__name__)  # "import calibration" from the repository root: a one-line ImportError naming msflash.…

__all__ = ["CalibrationError", "CalibrationWarning"]
