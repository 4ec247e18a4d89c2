"""msflash — the computational multispectral flash (Blasinski & Farrell, ICCP 2017), for notebooks.

A recorded sequence (an ambient frame, then ambient + each LED; docs/architecture.md §6) goes
through five steps, each one function here::

    >>> import msflash
    >>> sequence = msflash.read_sequence("runs/demo/sequence")          # doctest: +SKIP
    >>> estimate = msflash.estimate_ambient(sequence)                    # eq. 4-6  # doctest: +SKIP
    >>> flash = msflash.solve_flash(sequence, estimate, "complementary")  # eq. 8-9  # doctest: +SKIP
    >>> image = msflash.synthesize_flash(sequence, flash)                # doctest: +SKIP
    >>> preview = msflash.render_preview(sequence, image)                # doctest: +SKIP

``docs/python-api.md`` has a worked example that runs as a doctest. The code lives in four
subpackages, all importable under this name: ``msflash.acquisition`` (cameras, booth sessions,
sequence files, the command line), ``msflash.calibration``, ``msflash.processing`` (the maths)
and ``msflash.led_controller`` (the booth driver and emulator); docs/architecture.md §2.

Importing ``msflash`` is cheap: each function imports what it needs when it is called, so the
command line (which starts under this package) pays nothing for the public face.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:  # pragma: no cover - names for the annotations only
    import numpy as np

    from msflash.acquisition.sequence.format import Sequence
    from msflash.acquisition.session.one_sequence import SequenceEstimate
    from msflash.processing.flash import FlashSolution

__version__ = "0.1.0"
__all__ = ["read_sequence", "estimate_ambient", "solve_flash", "synthesize_flash", "render_preview", "__version__"]

_log = logging.getLogger("msflash")


def read_sequence(path: str | Path, calibration: str | Path | None = None) -> Sequence:
    """Read a recorded sequence: a sequence folder, a run or capture folder holding one, or its ``sequence.json``.

    Whatever ``msflash estimate`` accepts as its sequence, this accepts too (the same
    :func:`~msflash.acquisition.sequence.locate.locate_sequence` decides).

    Parameters
    ----------
    path
        The sequence folder, the ``--out`` folder of ``msflash run``/``capture`` (which holds it in
        ``sequence/``), or its ``sequence.json`` (docs/architecture.md §6).
    calibration
        A calibration folder written by ``msflash calibrate``; its LED spectra and camera
        responsivities replace the sequence's. ``None`` uses the calibration the sequence names,
        if any. What was applied is logged on the ``msflash`` logger.

    Returns
    -------
    Sequence
        The sequence's metadata; frames are read when a step needs them.

    Raises
    ------
    msflash.acquisition.errors.RecordingError
        The file is missing, malformed or names frames or calibrations that are not usable; the
        message names the file and the field.
    """
    from msflash.acquisition.session.one_sequence import read_calibrated

    return read_calibrated(str(path), None if calibration is None else str(calibration), _log.info)


def estimate_ambient(
    sequence: Sequence,
    solver: str = "tikhonov",
    alpha: float | str = "auto",
    *,
    method: str = "auto",
    model: str = "led",
    tiles: int | None = None,
    bin_factor: int | None = None,
) -> SequenceEstimate:
    """The ambient illuminant's spectrum as a mix of the LED spectra, from the pixels (eq. 4–6).

    Exactly what ``msflash estimate SEQ --json`` prints, with the same options and defaults (``solver``
    is its ``--solver``, ``alpha`` its ``--alpha``, ``method``, ``model``, ``tiles`` and ``bin_factor``
    its ``--method``, ``--model``, ``--tiles`` and ``--bin``): inverse-variance weighted statistics of
    the ambient and LED-only frames, a non-negative Tikhonov solve (α by the discrepancy principle when
    ``alpha="auto"``), and a band holding pixel noise and the LED model's own error
    (docs/ambient-estimate.md). The numbers are the command's to the last digit, in its unit.

    ``method`` is a name of the one method table
    (:data:`msflash.acquisition.session.one_sequence.ESTIMATE_METHODS`): ``global``, ``local``, ``auto`` (the
    LED span, one ambient or tiles), ``prior``, ``family`` or ``models`` (the light models beyond the LEDs'
    span; ``models`` is ``--model auto``). The frames are read one at a time (peak memory about one frame
    plus the statistics).

    Returns
    -------
    SequenceEstimate
        ``.spectrum`` (in the sequence's spectral unit, ``.spectrum.unit``: what the JSON's
        ``spectrum`` holds), ``.ambient_weights`` (w_a), ``.spectrum_std`` (±1σ, same unit;
        ``.band_meaning`` says what it covers), ``.warnings`` and ``.payload``, the whole JSON object.
    """
    _require_sequence(sequence, "estimate_ambient")
    from msflash.acquisition.session.one_sequence import (
        LIGHT_MODELS,
        EstimateSettings,
        SequenceEstimate,
        estimate_read,
        with_method,
    )

    defaults = EstimateSettings()
    settings = EstimateSettings(
        solver=solver,
        alpha=alpha,
        model=model,
        tiles=defaults.tiles if tiles is None else tiles,
        bin_factor=defaults.bin_factor if bin_factor is None else bin_factor,
    )
    # One method table: a light model's name (prior, family, models) picks it; global|local|auto the LED span's
    # (and, with model=prior|family|auto, how the LED side beside the light models is taken).
    if method in LIGHT_MODELS or model == "led":
        settings = with_method(settings, method)
    else:
        from dataclasses import replace

        settings = replace(settings, method=method)
    return SequenceEstimate.of(estimate_read(sequence, settings, _log.warning))


def solve_flash(
    sequence: Sequence, estimate: SequenceEstimate, mode: str = "matching", target: str | os.PathLike[str] = "D65"
) -> FlashSolution:
    """The LED mix that matches the ambient (eq. 7) or complements it towards ``target`` (eq. 8–9).

    Parameters
    ----------
    mode
        ``"matching"`` or ``"complementary"``.
    target
        For ``complementary``: an illuminant name (D65, A, FL2, …), or a file: a table
        ``wavelength_nm, value`` in energy units or a spectrometer export of the light (its warnings —
        rows averaged, raw counts — said once per version of the file). A ``pathlib.Path`` is always a file,
        even one named like an illuminant; a string is read as ``--target`` reads it.

    Returns
    -------
    FlashSolution
        ``.flash_weights`` (one drive level per LED, 0–1), ``.relative_error``, ``.warnings``.
    """
    _require_sequence(sequence, "solve_flash")
    if not hasattr(estimate, "ambient_weights"):
        _refuse("solve_flash", "estimate", estimate, "the result of msflash.estimate_ambient(sequence)")
    if not isinstance(target, str | os.PathLike):
        _refuse("solve_flash", "target", target, "an illuminant name (D65, A, …) or the path of a CSV file")
    from msflash.acquisition.session.analysis import solve_sequence_flash
    from msflash.acquisition.session.sequence_spectra import is_target_file, target_file_spectrum

    if isinstance(target, os.PathLike):  # a path, even named like an illuminant: read as "./D65" would be
        target = os.fspath(target)
        target = target if os.sep in target else os.path.join(os.curdir, target)
    if mode == "complementary" and is_target_file(target):
        target_file_spectrum(target)  # read as the command line reads --target: its warnings said here
    return solve_sequence_flash(sequence, mode, estimate.ambient_weights, target)


def synthesize_flash(sequence: Sequence, flash: FlashSolution | np.ndarray) -> np.ndarray:
    """The image under ambient + flash, synthesised from the frames already taken: ``m_a + Σ w_k m_f,k``.

    A flickering lamp's extra share in the LED frames is read from the frames and taken out, so the image holds
    the ambient once, as the ambient frame does (docs/flicker.md). Each frame is read from disk once, feeding
    both the flicker check and the sum (:func:`msflash.acquisition.session.analysis.synthesize_checked`).

    Returns
    -------
    numpy.ndarray
        Linear values per µs·gain, the frames' shape (a mosaic stays a mosaic).
    """
    import numpy as np

    from msflash.acquisition.session.analysis import synthesize_checked

    _require_sequence(sequence, "synthesize_flash")
    if flash is None or isinstance(flash, str | bytes):  # np.asarray(None) is one NaN weight: "1 flash weights"
        _refuse("synthesize_flash", "flash", flash, "the result of msflash.solve_flash, or one weight per LED")

    weights = flash.flash_weights if hasattr(flash, "flash_weights") else np.asarray(flash, dtype=float)
    image, _saturated, _frames, _flicker = synthesize_checked(sequence, weights)
    return image


def render_preview(sequence: Sequence, image: np.ndarray) -> np.ndarray:
    """An 8-bit sRGB preview of a linear image of the sequence (demosaiced if the camera has a CFA).

    The camera's colours go to sRGB through a matrix fitted on a chart when the sequence carries
    the camera's responsivities; otherwise the camera's channels are shown as they are.
    """
    import numpy as np

    from msflash.acquisition.app.report import preview_image
    from msflash.acquisition.errors import UsageError

    _require_sequence(sequence, "render_preview")
    if not isinstance(image, np.ndarray) or image.ndim not in (2, 3) or not np.issubdtype(image.dtype, np.number):
        _refuse("render_preview", "image", image, "a numeric image, (H, W) or (H, W, 3), such as synthesize_flash's")
    finite = np.isfinite(image)
    if not finite.all():
        raise UsageError(
            f"msflash.render_preview: image holds {image.size - int(np.count_nonzero(finite))} NaN or infinite "
            f"values of {image.size}; expected finite linear values"
        )
    return preview_image(sequence, image)


def _require_sequence(sequence: object, function: str) -> None:
    """Refuse anything but a read sequence as ``sequence`` (a path passed in its place failed with an
    AttributeError deep inside)."""
    from msflash.acquisition.sequence.format import Sequence

    if not isinstance(sequence, Sequence):
        _refuse(function, "sequence", sequence, "a sequence read by msflash.read_sequence(path)")


def _refuse(function: str, name: str, value: object, expected: str) -> NoReturn:
    """Raise the UsageError of a wrong argument: the function, the parameter, what it was and what it expects."""
    from msflash.acquisition.errors import UsageError

    shown = " ".join(repr(value).split())  # one line (an array's repr spans several)
    shown = shown if len(shown) <= 60 else shown[:57] + "..."
    raise UsageError(f"msflash.{function}: {name} is {type(value).__name__} {shown}; expected {expected}")
