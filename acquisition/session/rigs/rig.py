"""The open rig: a camera and a booth wired together, what sequences record of them, and closing them
(docs/architecture.md §4). The rigs themselves are built in this package's other modules, chosen
by ``--rig`` in :func:`acquisition.session.rig.open_rig`."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.devices.aravis.pixel_layouts import camera_pixel_layout
from msflash.acquisition.devices.camera import CameraInfo
from msflash.acquisition.devices.image_format import IMAGE_FEATURES, ImageFormatControl
from msflash.acquisition.errors import UsageError
from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.led_controller import BoothEmulator
from msflash.led_controller.booth_interface import Booth
from msflash.processing.led_wavelength import led_peaks_nm
from msflash.processing.spectra import Spectra

log = logging.getLogger(__name__)


def sends_mono(info: CameraInfo) -> bool:
    """Whether a camera reporting ``info`` sends mono frames (one value a pixel, no CFA), as its pixel format means
    (:func:`~acquisition.devices.aravis.pixel_layouts.camera_pixel_layout`: the one table of formats).

    Raises
    ------
    CameraSettingError
        A pixel format msflash does not decode, naming the camera and the format.
    """
    return camera_pixel_layout(info).kind == "mono"


@dataclass
class Rig:
    """An open camera + booth pair; close it (or use ``with``) to switch LEDs off and release both."""

    name: str
    """The rig spec (``sim``, ``aravis-fake``, ``replay:DIR``)."""
    camera: Any
    """The camera (a :class:`~acquisition.devices.camera.Camera`; may offer ``suggested_exposure_us``)."""
    booth: Booth
    """The booth driver (:class:`led_controller.booth_interface.Booth`: ``LedBooth`` or an adapter)."""
    led_spectra: Spectra
    """The LED spectra at full drive (what a calibration would have measured)."""
    camera_responsivities: Spectra | None
    """The camera's responsivities, if known."""
    true_ambient: Spectra | None = None
    """Ground truth, for simulated rigs."""
    _closers: list = field(default_factory=list, repr=False)
    emulator: BoothEmulator | None = None
    """The booth emulator at the far end of the pty (emulated rigs), for tests and diagnostics."""
    line_errors: list[BaseException] = field(default_factory=list)
    """Failures of trigger-line callbacks on the emulator's thread (logged, kept here)."""
    camera_extra: dict = field(default_factory=dict)
    """Extra keys for the sequence's ``camera`` entry (e.g. how a mono camera is recorded)."""
    mono: bool = False
    """The camera is monochrome: frames come as (H, W) with ``cfa`` None, the writer
    (:meth:`sequence_writer`) records them as three identical channels, and the header's
    ``camera.extra["channels"]`` says so."""
    calibration: tuple[str, Path] | None = None
    """(id, directory) of the ``msflash calibrate`` output the LED spectra and responsivities came
    from: every sequence written by :meth:`sequence_writer` refers to it."""

    def sequence_header(self) -> tuple[np.ndarray, SequenceCamera, tuple[SequenceLed, ...]]:
        """Wavelengths, camera and LED entries for a format-v1 sequence written from this rig (energy units).

        A camera reporting an empty serial (a replayed sequence recorded without one, a camera whose
        DeviceSerialNumber is blank) is recorded without ``camera.serial``: format v1 makes it optional
        but never empty.
        """
        leds = self.led_spectra.to_unit("energy")
        info = self.camera.info
        responsivity = None
        if self.camera_responsivities is not None:
            values = self.camera_responsivities.to_unit("energy").values
            responsivity = {channel: values[:, i] for i, channel in enumerate("RGB")}
        camera = SequenceCamera(
            model=info.model,
            serial=info.serial or None,
            pixel_format=info.pixel_format,
            cfa=info.cfa,
            black_level=info.black_level,
            white_level=info.white_level,
            responsivity=responsivity,
            extra={
                **({"channels": f"{info.pixel_format} replicated to R, G, B"} if self.mono else {}),
                **self.camera_extra,
            },
        )
        peaks = led_peaks_nm(self.led_spectra)  # recorded with the sequence: the one number (docs/architecture.md §6)
        entries = tuple(SequenceLed(name, leds.values[:, i], peak_nm=peaks[i]) for i, name in enumerate(leds.names))
        return leds.wavelengths_nm, camera, entries

    def image_format_changed(self) -> None:
        """Follow an image format changed after the rig opened (the live view's ``POST /api/camera-format``).

        What every later sequence records is then true of the camera: ``camera_extra["image_format"]`` holds the
        ROI, binning and pixel format in force as the camera reads them back; the open's ``camera_options`` keep
        only what still holds (the ROI, binning and image features they asked for and read back are dropped:
        the change superseded them); :attr:`mono` follows the pixel format (:func:`sends_mono`). Each sequence's
        :class:`~acquisition.devices.camera.CameraInfo` (pixel format, levels, size) is read afresh by
        :meth:`sequence_header` anyway.
        """
        camera = self.camera
        if not isinstance(camera, ImageFormatControl):
            return
        image_format = camera.image_format
        extra = {key: value for key, value in self.camera_extra.items() if key != "image_format"}
        options = extra.get("camera_options")
        if isinstance(options, dict):
            extra["camera_options"] = {
                part: _without_image_format(entries) if isinstance(entries, dict) else entries
                for part, entries in options.items()
            }
        extra["image_format"] = {**image_format.to_json(), "set": "after the rig opened (live view)"}
        self.camera_extra = extra
        self.mono = sends_mono(self.camera.info)

    def sequence_writer(self, directory: str | Path, extra: dict | None = None) -> SequenceWriter:
        """A :class:`SequenceWriter` for a sequence from this rig (header of :meth:`sequence_header`).

        A mono camera's (H, W) frames are recorded as three identical channels (:attr:`mono`); a
        rig opened from a calibration (:attr:`calibration`) writes the sequence's
        ``"calibration": {"id", "file"}`` reference (``file`` relative to the sequence directory).

        Raises
        ------
        UsageError
            The directory cannot be made or written (read-only, a file in the way): a bad output
            path, named with the system's reason, before any frame is captured.
        """
        wavelengths, camera, leds = self.sequence_header()
        if self.calibration is not None:
            calibration_id, calibration_directory = self.calibration
            file = os.path.relpath(Path(calibration_directory).resolve(), Path(directory).resolve())
            extra = {**(extra or {}), "calibration": {"id": calibration_id, "file": file}}
        try:
            return SequenceWriter(
                directory,
                wavelengths_nm=wavelengths,
                spectral_unit="energy",
                camera=camera,
                leds=leds,
                extra=extra,
                mono=self.mono,
            )
        except OSError as err:
            where = err.filename or directory
            raise UsageError(
                f"{where}: cannot write the sequence there ({err.strerror or err}); expected a "
                "writable directory (or a path where one can be made)"
            ) from err

    def close(self) -> None:
        """Switch the LEDs off, close the booth link, the emulator and the camera (each attempted).

        Raises the first failure once every device has had its chance to close.
        """
        errors = []
        for closer in reversed(self._closers):
            try:
                closer()
            except Exception as err:  # noqa: BLE001 - every device gets its chance to close
                errors.append(err)
        self._closers.clear()
        if errors:
            raise errors[0]

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: object) -> None:
        """Close the rig; leaving through an error, a failure to close is logged, not raised over it.

        When the booth's link is what failed, switching the LEDs off at close fails the same way;
        raising that would replace the error that says what happened (and where) with one about
        ``OFF``. Logged at info level: the capture that had the LEDs on has already warned when it
        could not switch them off (``acquisition.session.capture``), so by default the user reads it once.
        """
        if exc is None:
            self.close()
            return
        try:
            self.close()
        except Exception as close_err:  # noqa: BLE001 - the error in flight is the one to report
            log.info("rig '%s': closing after the error failed too: %s", self.name, close_err)


def _without_image_format(entries: dict) -> dict:
    """Camera options (as asked, or as read back) less the ROI, binning and image features a later change set."""
    kept = {key: value for key, value in entries.items() if key not in ("roi", "binning")}
    features = entries.get("features")
    if isinstance(features, dict):
        kept["features"] = {name: value for name, value in features.items() if name not in IMAGE_FEATURES}
        if not kept["features"]:
            del kept["features"]
    return kept
