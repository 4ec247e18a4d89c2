"""The ``replay:DIR`` rig: a recorded sequence served by :class:`ReplayCamera`, the emulator on a pty.

Re-runs estimation, flash solving and synthesis on recorded frames; every plan is checked against
the recording (:class:`~acquisition.errors.ReplayMismatchError` names the first differing step).
"""

from __future__ import annotations

import logging
from pathlib import Path

from msflash.acquisition.errors import RigOpenError
from msflash.acquisition.session.rigs.emulated_booth import (
    close_all,
    line_callback,
    open_emulated_booth,
)
from msflash.acquisition.session.rigs.rig import Rig

log = logging.getLogger(__name__)


def open_replay_rig(directory: str | Path, log_serial: str | Path | None = None) -> Rig:
    """The ``replay:DIR`` rig: ReplayCamera on a recorded sequence + emulator on a pty + LedBooth."""
    from msflash.acquisition.devices.replay_camera import ReplayCamera
    from msflash.acquisition.sequence.locate import locate_sequence

    camera = ReplayCamera.open(locate_sequence(directory, "--rig replay:"))  # RecordingError: missing, malformed
    sequence = camera.sequence
    leds = sequence.led_spectra()
    responsivities = sequence.camera_responsivities()
    closers: list = [camera.close]
    try:
        emulator, booth = open_emulated_booth(leds, log_serial, closers)
    except RigOpenError as err:
        close_all(closers)
        raise RigOpenError(f"rig 'replay:{directory}': {err}") from err
    line_errors: list[BaseException] = []
    emulator.on_trigger_out = line_callback(line_errors, "replay trigger line", camera.trigger_line)
    camera.exposure_line = emulator.exposure_active
    return Rig(
        f"replay:{directory}",
        camera,
        booth,
        leds,
        responsivities,
        None,
        closers,
        emulator=emulator,
        line_errors=line_errors,
        camera_extra=dict(sequence.camera.extra),
    )
