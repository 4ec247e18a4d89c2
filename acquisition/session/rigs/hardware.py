"""The ``hw`` rig: a GenICam camera through Aravis and a real booth (docs/architecture.md §4).

The rig's camera is an :class:`~acquisition.devices.aravis.camera.AravisCamera` opened by device id, serial or IP on the
given interfaces (default ``usb3``: GigE Vision discovery broadcasts, so ``gige`` only when named,
and an IP address opens one GigE camera without discovery), and the booth on ``port`` or the
single one :func:`led_controller.discovery.find_booth` finds. Every device is tried;
:class:`RigOpenError` lists each one's failure. LED spectra (and optionally the camera's
responsivities) come from a calibration directory or CSV files (:func:`hw_spectra`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from msflash.acquisition.devices.aravis.pixel_layouts import camera_pixel_layout
from msflash.acquisition.devices.sim_world import LedFiles, read_led_files, read_responsivity_file
from msflash.acquisition.errors import CameraNotFoundError, CameraSettingError, RigOpenError, UsageError
from msflash.acquisition.progress import progress
from msflash.acquisition.session.external_booth import open_checked_booth
from msflash.acquisition.session.rigs.emulated_booth import close_all
from msflash.acquisition.session.rigs.rig import Rig, sends_mono
from msflash.led_controller.booth_handshake import DEFAULT_BOOT_S
from msflash.led_controller.booth_interface import Booth
from msflash.processing.spectra import DEFAULT_GRID, Spectra

CALIBRATION_LED_FILES = ("led_spectra.csv", "leds.csv")
"""File names looked for in ``--calibration DIR`` for the LED spectra (first found wins)."""
CALIBRATION_RESPONSIVITY_FILES = ("camera_responsivity.csv", "responsivity.csv", "camera.csv")
"""File names looked for in ``--calibration DIR`` for the camera's responsivities."""


def hw_spectra(
    calibration: str | Path | None = None, led_spectra: LedFiles | None = None, responsivity: str | Path | None = None
) -> tuple[Spectra, Spectra | None, tuple[str, Path] | None]:
    """LED spectra, camera responsivities (on :data:`DEFAULT_GRID`) and the calibration they came from.

    ``calibration`` is a ``msflash calibrate`` directory (``calibration.json``, read by
    :func:`calibration.files.load_calibration`), or a directory holding ``led_spectra.csv`` (or
    ``leds.csv``) and optionally ``camera_responsivity.csv`` (or ``responsivity.csv``,
    ``camera.csv``); ``led_spectra`` / ``responsivity`` name
    the files directly and win over the directory. Files are CSV tables read by
    :func:`processing.datasets.load_spectra_csv`: first column ``wavelength_nm``, one column per LED
    (in booth channel order) or per camera channel (R, G, B), energy units, each LED at full drive
    with the true ratios between LEDs. Values outside a file's range are taken as zero. The LED
    spectra may also be spectrometer exports, one per LED in channel order (``led_spectra`` a
    tuple; :func:`acquisition.devices.sim_world.read_led_files`).

    The third item is (id, directory) when ``calibration`` is a ``msflash calibrate`` output (every
    sequence of the rig refers to it, :attr:`Rig.calibration`), else None.

    Raises
    ------
    UsageError
        Nothing gives the LED spectra, a named file or directory is missing, or a file is malformed.
    """
    led_files: LedFiles | None = None
    if led_spectra:
        led_files = Path(led_spectra) if isinstance(led_spectra, str | Path) else tuple(led_spectra)
    resp_path = Path(responsivity) if responsivity else None
    leds: Spectra | None = None
    camera: Spectra | None = None
    reference: tuple[str, Path] | None = None
    if calibration is not None:
        directory = Path(calibration)
        if not directory.is_dir():
            raise UsageError(
                f"--calibration {directory}: not a directory; expected a calibration directory "
                "(calibration.json from 'msflash calibrate', or led_spectra.csv)"
            )
        # lexists, not is_file: a calibration.json that is a FIFO or a device is refused by its reader.
        if os.path.lexists(directory / "calibration.json"):
            leds, camera, calibration_id = _load_calibration_set(directory)
            reference = (calibration_id, directory)
        else:
            if led_files is None:
                led_files = next((directory / n for n in CALIBRATION_LED_FILES if os.path.lexists(directory / n)), None)
                if led_files is None:
                    raise UsageError(
                        f"--calibration {directory}: no calibration.json or "
                        f"{' or '.join(CALIBRATION_LED_FILES)}; expected the LED spectra"
                    )
            if resp_path is None:
                resp_path = next(
                    (directory / n for n in CALIBRATION_RESPONSIVITY_FILES if os.path.lexists(directory / n)), None
                )
    if led_files is not None:
        leds = read_led_files(led_files, DEFAULT_GRID)
    if resp_path is not None:
        camera = read_responsivity_file(resp_path)
    if leds is None:
        raise UsageError(
            "rig 'hw': the LED spectra are needed for the sequence header; expected --calibration DIR "
            "or --led-spectra FILE.csv (first column wavelength_nm, one column per LED at full drive, "
            "energy units), and --responsivity FILE.csv for the flash solvers"
        )
    leds = leds.resample(DEFAULT_GRID, outside="zero")
    if camera is not None:
        if camera.count != 3:
            raise UsageError(f"{resp_path or calibration}: {camera.count} responsivity columns; expected 3 (R, G, B)")
        camera = camera.resample(DEFAULT_GRID, outside="zero")
    return leds, camera, reference


def _load_calibration_set(directory: Path) -> tuple[Spectra | None, Spectra | None, str]:
    """LED spectra, responsivities and id of a ``msflash calibrate`` directory (``calibration.json``)."""
    try:
        from msflash.calibration.files import load_calibration
    except ImportError as err:
        raise UsageError(f"--calibration {directory}: calibration files unreadable here ({err})") from err
    try:
        found = load_calibration(directory)
    except (OSError, ValueError) as err:
        raise UsageError(str(err)) from err
    except Exception as err:  # CalibrationError's base is the calibration package's choice
        raise UsageError(str(err)) from err
    for note in found.notes:  # negative noise clipped on reading
        progress(note)
    leds = found.led_spectra.to_unit("energy") if found.led_spectra is not None else None
    camera = found.camera_responsivities.to_unit("energy") if found.camera_responsivities is not None else None
    return leds, camera, found.id


def _open_hw_camera(
    camera: str | None, interfaces: str, sync: str, pixel_format: str | None, options: Any = None
) -> tuple[Any, Any]:
    """The camera, opened and configured (profile options overridden by ``options``), and its setup."""
    from msflash.acquisition.devices.aravis.camera import AravisCamera
    from msflash.acquisition.devices.aravis.camera_features import CameraOptions, configure_camera
    from msflash.acquisition.devices.aravis.discovery import list_devices, parse_interfaces

    names = parse_interfaces(interfaces)
    if camera is None:
        found = list_devices(names)
        if len(found) != 1:
            listing = ", ".join(f"{e.device_id} (serial {e.serial})" for e in found) or "none"
            raise CameraNotFoundError(
                f"camera: {'no camera' if not found else f'{len(found)} cameras'} on {','.join(names)} "
                f"(found: {listing}); expected one — pass --camera ID (device id, serial or IP) "
                "or --interfaces"
            )
        camera = found[0].device_id
    opened = AravisCamera(camera, interfaces=names, pixel_format=pixel_format)
    try:
        setup = configure_camera(opened, options or CameraOptions(), strobe=sync == "camera")
        camera_pixel_layout(opened.info)  # a format msflash does not decode is refused here, before the booth opens
    except BaseException:
        opened.close()
        raise
    return opened, setup


def open_hw_rig(
    camera: str | None = None,
    port: str | None = None,
    interfaces: str = "usb3",
    calibration: str | Path | None = None,
    led_spectra: LedFiles | None = None,
    responsivity: str | Path | None = None,
    log_serial: str | Path | None = None,
    sync: str = "host",
    pixel_format: str | None = None,
    camera_options: Any = None,
    booth_protocol: str = "msflash",
    booth_boot_s: float = DEFAULT_BOOT_S,
) -> Rig:
    """The hardware rig: a GenICam camera by id/serial/IP + a booth on ``port`` (or the one discovered).

    Parameters
    ----------
    camera
        Aravis device id, serial number or IPv4 address; None takes the single camera found on
        ``interfaces`` (``usb3`` by default; ``gige`` broadcasts discovery unless ``camera`` is an IP address).
    port
        The booth's serial port (``/dev/ttyACM0``, a pty path, a pyserial URL); None discovers it.
    calibration, led_spectra, responsivity
        Where the LED spectra and camera responsivities come from (:func:`hw_spectra`).
    sync
        ``host``, ``booth`` or ``camera``: camera master configures a strobe output (Line1 unless
        ``camera_options`` or the camera profile name another line).
    camera_options
        :class:`~acquisition.devices.aravis.camera_features.CameraOptions` (trigger/strobe lines, gain, ROI, binning,
        features), overriding the camera profile's.
    booth_protocol
        ``--booth-protocol``: what the booth at ``port`` speaks (``msflash``, the default, or ``text``,
        :data:`led_controller.adapters.BOOTH_PROTOCOLS`); discovery finds msflash booths only.

    Raises
    ------
    UsageError
        No LED spectra given (checked before any device is opened).
    CameraSettingError
        A camera option the camera cannot take (bad input; the booth is not opened).
    RigOpenError
        One or both devices failed to open; the message lists each device's failure.
    """
    leds, responsivities, reference = hw_spectra(calibration, led_spectra, responsivity)
    closers: list = []
    failures: list[str] = []
    errors: list[BaseException] = []
    aravis = booth = setup = None
    try:
        aravis, setup = _open_hw_camera(camera, interfaces, sync, pixel_format, camera_options)
        closers.append(aravis.close)
    except CameraSettingError:
        raise  # bad input, not a device failure: one line, exit 2
    except ImportError as err:
        failures.append(f"camera{f' {camera!r}' if camera else ''}: Aravis unavailable ({err}); run setup.sh")
        errors.append(err)
    except (OSError, ValueError) as err:  # CameraError is an OSError; bad interface names ValueError
        message = str(err)
        failures.append(message if message.startswith("camera") else f"camera {camera!r}: {message}")
        errors.append(err)
    try:
        booth = _open_hw_booth(port, booth_protocol, log_serial, booth_boot_s, leds, closers)
    except Exception as err:  # noqa: BLE001 - reported with the camera's failure, if any
        message = str(err)
        failures.append(message if message.startswith("booth") else f"booth: {message}")
        errors.append(err)
    if failures:
        close_all(closers)
        raise RigOpenError(f"rig 'hw': {'; '.join(failures)}") from errors[0]
    assert aravis is not None and booth is not None
    return _hw_rig(aravis, setup, booth, leds, responsivities, reference, closers)


def _open_hw_booth(
    port: str | None, protocol: str, log_serial: str | Path | None, boot_s: float, leds: Spectra, closers: list
) -> Booth:
    """The booth at ``port`` (or the one discovery finds), checked to have one channel per LED and cleared
    of a killed run's leftovers; its closers appended as it opens."""
    from msflash.led_controller.discovery import find_booth

    booth_port = port if port is not None else find_booth().device
    mismatch = ("the LED spectra have", "one spectrum per channel")
    return open_checked_booth(booth_port, protocol, log_serial, boot_s, leds, closers, mismatch)


def _hw_rig(
    aravis: Any,
    setup: Any,
    booth: Booth,
    leds: Spectra,
    responsivities: Spectra | None,
    reference: tuple[str, Path] | None,
    closers: list,
) -> Rig:
    """The hardware rig, recording the camera's gain, its options as read back and a mono camera as such (its
    (H, W) frames are written as three identical channels)."""
    info = aravis.info
    extra: dict = {"gain": aravis.gain_record()}
    if setup is not None and not setup.options.empty:
        extra["camera_options"] = setup.to_dict()  # what was asked (profile + options) and read back
    mono = sends_mono(info)
    if responsivities is None:
        extra["responsivity_note"] = "not given (--responsivity or a calibration directory): flash solvers unavailable"
    return Rig(
        "hw", aravis, booth, leds, responsivities, None, closers, camera_extra=extra, mono=mono, calibration=reference
    )
