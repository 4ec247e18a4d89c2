"""Errors of the acquisition layer (cameras, capture, recording).

Each class also inherits the matching built-in exception. Messages follow
``"<where>: <what is wrong>; expected <what>"`` and add a remedy when one is known.
"""

from __future__ import annotations

from msflash.led_controller.errors import BoothError
from msflash.processing.errors import SolverError, SpectralDataError


class UsageError(ValueError):
    """Bad input from the user (a file, field or option); the CLI exits with status 2."""


class CameraError(OSError):
    """A camera failed or refused a setting; the message names the camera and the feature."""


class CameraSettingError(CameraError, ValueError):
    """A camera option or feature value the camera cannot take (bad input, exit 2).

    The message names the camera, the option or feature, and what the camera allows (entries,
    range, type).
    """


class CameraNotFoundError(CameraError, LookupError):
    """No camera matched; the message lists what was found."""


class FrameTimeoutError(CameraError, TimeoutError):
    """No frame arrived in time; the message names the step and the timeout."""


class CaptureError(RuntimeError):
    """A capture sequence could not complete."""


class DroppedFrameError(CaptureError):
    """A frame was lost or incomplete; frames already saved stay saved."""


class CaptureCancelled(CaptureError):
    """A capture stopped between frames because it was asked to (``msflash live`` stopping); the
    frames already written stay, the sequence ``complete: false``, the LEDs off."""


class ReplayMismatchError(CaptureError):
    """The plan differs from the recording being replayed; names the first differing step and field."""


class OutputWriteError(CaptureError):
    """Writing what msflash produces failed (disk full, directory gone, I/O error).

    A runtime failure, not bad input: the message names what was being written and the cause, and
    says what is safe on disk (a sequence's frames so far stay readable with ``complete: false``;
    a run's report fails after its sequence is complete).
    """


class BoothStepError(CaptureError, BoothError):
    """The booth failed (no reply, a damaged frame, a lost link) during a capture step; names the step.

    Also a :class:`led_controller.errors.BoothError`: callers catching the driver's errors still do.
    """


class RigOpenError(CaptureError):
    """One or more devices of a rig failed to open; every device's failure is listed."""


class RecordingError(CaptureError, ValueError):
    """A sequence on disk is malformed; the message names the file and the field."""


class CameraDisconnectedError(CameraError, ConnectionError):
    """The camera stopped answering (GigE Vision ``control-lost``, unplugged, powered off)."""


class FrameLostError(CameraError, DroppedFrameError):
    """A frame arrived incomplete or the frame counter skipped; names the camera, step and frame id.

    It is both a camera failure and a dropped frame, so a capture runner catching
    :class:`DroppedFrameError` handles it as it handles any other lost frame.
    """


class FolderInUseError(RecordingError):
    """An output folder is being written by another msflash process; names the folder and its PID.

    Bad input (exit 2): the user pointed two runs at one folder.
    """


def bad_input_errors() -> tuple[type[BaseException], ...]:
    """The errors that mean refused input (exit status 2): the command line's and the many-sequence path's one list.

    The calibration package's error is among them when that package is installed (processing-only
    use may leave it out).
    """
    errors: list[type[BaseException]] = [UsageError, RecordingError, CameraSettingError, SpectralDataError]
    errors.append(FileNotFoundError)
    try:
        from msflash.calibration.errors import CalibrationError
    except ImportError:
        pass
    else:
        errors.append(CalibrationError)
    return tuple(errors)


def runtime_errors() -> tuple[type[BaseException], ...]:
    """Device and runtime failures (exit status 1, one line): cameras, captures, solvers, the booth."""
    return (CameraError, CaptureError, SolverError, BoothError)
