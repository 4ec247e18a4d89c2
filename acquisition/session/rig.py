"""Rigs: a camera and a booth wired together (docs/architecture.md §4).

``sim`` (the default): a :class:`SimulatedCamera` rendering a spectral scene with the LED levels
the booth *emulator* holds at exposure time, and the real :class:`led_controller.LedBooth`
driver talking to that emulator over a real pseudo-terminal. The whole pipeline runs, with a
known ground-truth ambient, through the same driver code a real booth uses.

``aravis-fake``: :class:`~acquisition.devices.aravis.camera.AravisCamera` on the Aravis GigE Vision fake
served in this process on 127.0.0.1 (opened by address: no discovery broadcast), the emulator on a
pty and ``LedBooth``. Aravis streams (buffers, frame ids, timestamps, exposure and gain features,
software triggers) in BayerRG16; :class:`WiredFakeCamera` paints each frame with the ``sim`` rig's
world rendered under the LED levels of that frame's trigger, so the Aravis path runs inside the
whole pipeline with a known ground truth.

``replay:DIR``: :class:`~acquisition.devices.replay_camera.ReplayCamera` serving a recorded sequence, with
the emulator on a pty; re-runs estimation, flash solving and synthesis on recorded frames.

``hw`` (real use; also implied by ``--camera`` / ``--port``): :class:`HardwareCamera` around an
:class:`~acquisition.devices.aravis.camera.AravisCamera` opened by device id, serial or IP on the given
interfaces (default ``usb3``: GigE Vision discovery broadcasts, so ``gige`` only when named, and an
IP address opens one GigE camera without discovery), and :class:`led_controller.LedBooth` on
``port`` or on the single booth :func:`led_controller.discovery.find_booth` finds. Every device is
tried; :class:`RigOpenError` lists each one's failure. LED spectra (and optionally the camera's
responsivities) come from a calibration directory or CSV files (:func:`load_hw_spectra`).

The trigger wires (docs/architecture.md §4, three sync modes) are modelled in every rig:

- *booth master*: the emulator's trigger output (``on_trigger_out``) drives the camera's trigger
  input — :meth:`SimulatedCamera.trigger_line` on ``sim``; on ``aravis-fake`` (the fake has no
  input lines) the callback issues the camera's software trigger;
- *camera master*: the camera's ExposureActive output drives the emulator's input — on ``sim``
  a rising edge just before the frame reads the LED levels and a falling edge right after; on
  ``aravis-fake`` a rising edge before ``TriggerSoftware`` and a falling edge when the frame
  arrives. The booth ignores the line outside a running camera-master sequence, as firmware does.

A callback that fails on the emulator's thread is logged and kept in :attr:`Rig.line_errors`
(it must not kill the emulator); the capture then sees the missing frame.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import logging
import os
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.devices.camera import CameraInfo, RawFrame
from msflash.acquisition.devices.exposure_light import EmulatorLight, FirmwareLight, Shutter
from msflash.acquisition.devices.sim_world import (
    read_responsivity_file,
    read_spectra_file,
    sim_ambient,
    sim_camera,
    sim_leds,
    sim_scene,
)
from msflash.acquisition.devices.simulated_camera import SimulatedCamera
from msflash.acquisition.errors import CameraError, CameraSettingError, FrameLostError, RigOpenError, UsageError
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.progress import progress
from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed, SequenceWriter
from msflash.acquisition.session.external_booth import levels_reported_by, open_external_booth
from msflash.led_controller import BoothEmulator, LedBooth, serve_on_pty
from msflash.led_controller.adapters import open_booth
from msflash.led_controller.booth import DEFAULT_BOOT_S
from msflash.led_controller.booth_interface import Booth
from msflash.led_controller.errors import BoothProtocolError
from msflash.led_controller.protocol import Command, encode_request, parse_frame, parse_identify, parse_reply
from msflash.led_controller.recovery import reset_leftovers
from msflash.processing import datasets
from msflash.processing.image_formation import Scene
from msflash.processing.led_wavelength import led_peaks_nm
from msflash.processing.names import unknown_name
from msflash.processing.spectra import DEFAULT_GRID, Spectra

log = logging.getLogger(__name__)

RIG_SPECS = ("sim", "aravis-fake", "replay:DIR", "hw")
"""What ``--rig`` accepts."""

AravisFakeNominalCamera = "NikonD100"
"""ISETCam camera whose responsivities the ``aravis-fake`` rig's test-pattern form (``rendered=False``,
the capture bench's) records as *nominal* (test patterns have no spectral meaning; the flash solvers
need some camera model). The rendered form records the world's own responsivities."""


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


def _line(rig_errors: list[BaseException], what: str, action: Callable[[], None]) -> Callable[..., None]:
    """A trigger-line callback for the emulator's thread: failures are logged and kept, never raised there."""

    def fire(*_args: object) -> None:
        try:
            action()
        except Exception as err:  # noqa: BLE001 - raising would kill the emulator's thread
            log.error("%s failed: %s", what, err)
            rig_errors.append(err)

    return fire


def _emulator_for(leds: Spectra) -> BoothEmulator:
    return BoothEmulator(names=[n.replace(" ", "_") for n in leds.names], peaks_nm=led_peaks_nm(leds))


SIM_BOOTLOADER_S = 0.2
"""The bootloader window of the simulated rigs' own booth, in seconds: it resets when the driver opens its
pty, as a stock Mega does, and swallows what is sent meanwhile, but boots faster than a Mega's 1.6 s
(:data:`led_controller.usb_link.MEGA_BOOTLOADER_S`) so every simulated run does not wait for it. The
full window is what ``--booth-port`` against ``msflash booth-emulator`` or the firmware in simavr sees."""


def _open_emulated_booth(leds: Spectra, log_serial: str | Path | None, closers: list) -> tuple[BoothEmulator, LedBooth]:
    """The booth emulator for ``leds`` served on a new pty, and the ``LedBooth`` driver on that pty.

    Each part's closer is appended to ``closers`` as soon as the part is open, so the caller's
    :func:`_close_all` undoes a partial open.

    Raises
    ------
    RigOpenError
        Naming the pty (``booth emulator on /dev/pts/N: …``) when any part fails.
    """
    port = "a new pty"
    try:
        emulator = _emulator_for(leds)
        server = serve_on_pty(emulator, bootloader_s=SIM_BOOTLOADER_S)
        closers.append(server.close)
        port = server.port
        booth = LedBooth.open(server.port, log_serial=log_serial)
        closers.append(booth.close)
        closers.append(booth.all_off)
    except Exception as err:
        raise RigOpenError(f"booth emulator on {port}: {err}") from err
    return emulator, booth


def _close_all(closers: list) -> None:
    for closer in reversed(closers):
        with contextlib.suppress(Exception):
            closer()


def check_emulated_booth(leds: Spectra, where: str) -> None:
    """Whether the booth emulator can serve one channel per LED of ``leds``; a one-line error if not.

    The emulator is built for ``leds`` as the rig would build it and asked to identify itself (its
    reply parsed by the driver's parser), so every limit of the firmware and the wire format is
    checked as it applies: 1–64 channels, names that are plain words (spaces become ``_``; no
    commas, ``*`` or non-ASCII), and an identify reply that fits one frame.

    Raises
    ------
    UsageError
        Naming ``where`` (the option or file the LEDs came from), the channels and the limit.
    """
    names = leds.names if leds.count <= 8 else (*leds.names[:3], "…", leds.names[-1])
    channels = f"{leds.count} LED channel(s) ({', '.join(names)})"
    try:
        emulator = _emulator_for(leds)
        replies: list[bytes] = []
        emulator.connect_output(replies.append)
        emulator.receive(encode_request(1, Command.IDENTIFY))
        raw = b"".join(replies).rstrip(b"\r\n")
        # The emulator refuses names whose identify reply would pass the protocol's 1024 bytes.
        frame = parse_frame(raw, where="booth emulator", command=Command.IDENTIFY)
        info = parse_identify(parse_reply(frame, Command.IDENTIFY, where="booth emulator"), raw, where="booth emulator")
    except (ValueError, BoothProtocolError) as err:
        raise UsageError(
            f"{where}: {channels}: the booth emulator cannot serve them ({err}); expected 1–64 "
            "channels named by plain ASCII words whose identify reply fits one frame"
        ) from err
    if info.channels != leds.count:
        raise UsageError(f"{where}: {channels}: the booth emulator reports {info.channels}; expected one per LED")


def _sim_world(
    rig: str,
    ambient: str | Spectra,
    scene: str | Scene | Spectra,
    cfa: str | None,
    seed: int,
    camera: str | Spectra | None,
    n_leds: int | None,
    led_spectra: str | Path | Spectra | None,
    flash_power: float | None,
    patch_px: int | None = None,
) -> SimulatedCamera:
    """The simulated world of :func:`open_sim_rig` (names and files resolved, the booth's LEDs checked).

    Raises
    ------
    UsageError
        A bad name or file, with the option or file named.
    RigOpenError
        The world could not be made (named ``rig '{rig}'``).
    """
    ambient_spd = sim_ambient(ambient) if isinstance(ambient, str) else ambient
    scene_spec = sim_scene(scene) if isinstance(scene, str) else scene
    responsivities = camera if isinstance(camera, Spectra) else sim_camera(camera)
    if isinstance(led_spectra, Spectra):
        leds, where = led_spectra, "LED spectra"
    else:
        leds = sim_leds(led_spectra, n_leds)
        where = f"--led-spectra {led_spectra}" if led_spectra is not None else f"--leds {n_leds or 7}"
    check_emulated_booth(leds, where)
    try:
        optional: dict[str, Any] = {}
        if patch_px is not None:
            optional["patch_px"] = patch_px
        if flash_power is not None:
            optional["flash_power"] = flash_power
        return SimulatedCamera.default(
            scene=scene_spec,
            ambient=ambient_spd,
            cfa=cfa,
            seed=seed,
            camera=responsivities,
            led_spectra=leds,
            **optional,
        )
    except UsageError:
        raise
    except Exception as err:
        raise RigOpenError(f"rig '{rig}': {err}") from err


def open_sim_rig(
    ambient: str | Spectra = "tungsten",
    scene: str | Scene | Spectra = "chart110",
    cfa: str | None = None,
    seed: int = 0,
    camera: str | Spectra | None = None,
    n_leds: int | None = None,
    led_spectra: str | Path | Spectra | None = None,
    log_serial: str | Path | None = None,
    flash_power: float | None = None,
    booth_port: str | None = None,
    booth_protocol: str = "msflash",
    booth_boot_s: float = DEFAULT_BOOT_S,
    booth_firmware: bool = False,
    line_time_us: float = 0.0,
) -> Rig:
    """The simulated rig: SimulatedCamera + BoothEmulator on a pty + the LedBooth driver.

    Parameters
    ----------
    ambient, scene, camera
        As the CLI's ``--ambient``, ``--scene``, ``--sim-camera`` (a name or a CSV file, resolved
        by :mod:`acquisition.devices.sim_world`), or spectra / a :class:`Scene` already on the sim grid.
        ``camera`` None is :data:`acquisition.devices.sim_world.SIM_DEFAULT_CAMERA`.
    n_leds, led_spectra
        The paper's subset of ``n_leds`` LEDs or the booth's LEDs (a CSV file, one column per
        channel, or spectra); neither gives the paper's 7. The emulated booth gets one channel
        per LED, named and peaked as they are (:func:`check_emulated_booth`).
    cfa, seed, log_serial
        Raw mosaic layout, noise (and mosaic) seed, serial transcript file.
    flash_power
        ``--flash-power``: every LED at full drive gives at least this many times the ambient's
        mean camera signal (:meth:`SimulatedCamera.default`); None is its default, 1.
    booth_port
        ``--booth-port``: drive the booth at this port (``msflash booth-emulator`` on a pty, or a
        real booth) instead of an emulator in this process (:mod:`acquisition.external_booth`; host
        pacing only, :attr:`Rig.emulator` None).
    booth_protocol
        ``--booth-protocol``: what the booth at ``booth_port`` speaks (``msflash`` or ``text``,
        :data:`led_controller.adapters.BOOTH_PROTOCOLS`).
    booth_boot_s
        ``--booth-boot-s``: how long the booth at ``booth_port`` may take to boot after its port's open
        reset it (:data:`led_controller.booth.DEFAULT_BOOT_S`).
    booth_firmware
        ``--booth-firmware``: the booth is the reference firmware in simavr
        (:func:`open_firmware_booth`), wired to the camera as a real rig is (trigger output,
        ExposureActive), so all three sync modes run; the frames integrate its real LED pins.
    line_time_us
        ``--line-time-us``: the simulated camera's rolling shutter (row ``r`` starts ``r`` line
        times after row 0); 0, the default, is a global shutter.

    The camera renders each row under the booth's drive integrated over that row's exposure
    window (:mod:`acquisition.devices.exposure_light`): PWM cut at its phase, pulses where the
    booth placed them.

    Raises
    ------
    UsageError
        A bad name or file, with the option or file named (before anything is opened).
    RigOpenError
        The world or the emulated booth failed to open.
    """
    closers: list = []
    line_errors: list[BaseException] = []
    if booth_firmware and booth_port is not None:
        raise UsageError(
            "--booth-firmware: the booth is the firmware in simavr, so --booth-port has no use; expected one of them"
        )
    world = _sim_world("sim", ambient, scene, cfa, seed, camera, n_leds, led_spectra, flash_power)
    try:
        world.shutter = Shutter(line_time_us=float(line_time_us))
    except CameraError as err:
        raise UsageError(f"--line-time-us {line_time_us}: expected a line time ≥ 0 µs") from err
    try:
        closers.append(world.close)
        if booth_port is not None:
            booth = open_external_booth(
                booth_port, world.led_spectra, log_serial, closers, booth_protocol, boot_s=booth_boot_s
            )
            world.led_levels_source = levels_reported_by(booth)
            return Rig("sim", world, booth, world.led_spectra, world.camera_responsivities, world.true_ambient, closers)
        if booth_firmware:
            booth = open_firmware_booth(world, log_serial, closers, line_errors)
            return Rig(
                "sim",
                world,
                booth,
                world.led_spectra,
                world.camera_responsivities,
                world.true_ambient,
                closers,
                line_errors=line_errors,
                camera_extra={"booth": "firmware in simavr"},
            )
        emulator, booth = _open_emulated_booth(world.led_spectra, log_serial, closers)

        # Exposure-time coupling: each row of the camera integrates the emulator's drive (PWM at its
        # phase, pulses) over its exposure window, raising ExposureActive over the flash window.
        world.exposure_light = EmulatorLight(emulator)
        # Booth master: the booth's trigger output is the camera's trigger input.
        emulator.on_trigger_out = _line(line_errors, "sim camera trigger line", world.trigger_line)
    except Exception as err:
        _close_all(closers)
        if isinstance(err, UsageError):
            raise
        raise RigOpenError(f"rig 'sim': {err}") from err
    return Rig(
        "sim",
        world,
        booth,
        world.led_spectra,
        world.camera_responsivities,
        world.true_ambient,
        closers,
        emulator=emulator,
        line_errors=line_errors,
    )


def open_firmware_booth(
    world: SimulatedCamera, log_serial: str | Path | None, closers: list, line_errors: list
) -> LedBooth:
    """The reference firmware in simavr wired to ``world`` as on a real rig; ``LedBooth`` on its pty.

    The firmware is built (``make``) and run by :class:`led_controller.firmware_sim.SimulatedBooth`;
    its trigger output starts the camera's exposures (booth master: a thread takes each pulse
    the harness reports, so the harness's reader is never blocked), its ExposureActive input is
    driven over each exposure's flash window by the harness (camera master), and every frame
    integrates its LED pins over the rows' windows (:class:`FirmwareLight`). Closers are appended
    as parts open.

    Raises
    ------
    UsageError
        The LEDs are not the firmware's 7 channels, or the AVR toolchain is missing.
    RigOpenError
        The build or the simulator failed.
    """
    from msflash.led_controller import firmware_sim

    reason = firmware_sim.toolchain_missing()
    if reason:
        raise UsageError(f"--booth-firmware: {reason}")
    if world.led_spectra.count != firmware_sim.SIM_CHANNELS:
        raise UsageError(
            f"--booth-firmware: the firmware image drives {firmware_sim.SIM_CHANNELS} LEDs but the simulated booth has "
            f"{world.led_spectra.count}; expected --leds {firmware_sim.SIM_CHANNELS} (or no --leds/--led-spectra)"
        )
    try:
        firmware_sim.build()
        sim = firmware_sim.SimulatedBooth()
    except firmware_sim.FirmwareSimError as err:
        raise RigOpenError(f"--booth-firmware: {err}") from err
    closers.append(sim.close)
    light = FirmwareLight(sim)
    world.exposure_light = light
    pulses: queue.Queue[float | None] = queue.Queue()

    def take_pulses() -> None:
        while (time_us := pulses.get()) is not None:
            light.triggered(time_us)
            _line(line_errors, "simavr camera trigger line", world.trigger_line)()

    worker = threading.Thread(target=take_pulses, name="simavr trigger line", daemon=True)
    worker.start()
    sim.on_pulse = lambda pulse: pulses.put(pulse.time_us)

    def stop_worker() -> None:
        sim.on_pulse = None
        pulses.put(None)
        worker.join(timeout=10.0)

    closers.append(stop_worker)
    try:
        booth = LedBooth.open(sim.port, timeout_s=5.0, log_serial=log_serial)
    except Exception as err:
        raise RigOpenError(f"booth firmware in simavr on {sim.port}: {err}") from err
    closers.append(booth.close)
    closers.append(booth.all_off)
    return booth


class WiredFakeCamera:
    """An ``AravisCamera`` on the GigE fake with the trigger wires the fake lacks, emulated, and a scene.

    The fake honours only software triggers and has no ExposureActive output, so:

    - every plan is prepared on the fake with software triggering;
    - booth master (``plan.trigger == "booth"``): :meth:`trigger` is a no-op and the emulator's
      trigger output calls :meth:`trigger_line`, which issues the software trigger;
    - camera master (``"camera"``): :meth:`trigger` raises the emulator's ExposureActive line and
      issues the software trigger; the frame's arrival lowers it (exposure over).

    The fake latches a software trigger in a register that its stream thread polls and clears
    (``TriggerSoftware`` at 0x30c, about 1 kHz): two triggers between polls make one frame. A real
    trigger input takes every edge, so booth pulses go through a queue and a thread that issues
    each software trigger only once the fake has acknowledged the previous one.

    **The scene** (``world`` given, the ``aravis-fake`` rig's default): Aravis does the streaming
    (buffers, frame ids, timestamps), the exposure and gain features and the triggering; the
    pixels of each frame it delivers are replaced by ``world``'s rendering
    (:meth:`SimulatedCamera.render`) under the booth's LED levels *at the moment that frame was
    triggered* — read from the emulator when the software trigger is issued (host-paced), when
    the booth pulses the trigger line (booth master; the levels travel with the pulse through the
    queue) or after ExposureActive is raised (camera master) — with the exposure and gain the
    camera read back for that frame. Levels wait in a first-in first-out queue, one per issued
    trigger, and are taken in frame order. The fake's own pixel generator cannot be given the
    scene: ``arv_fake_camera_set_fill_pattern`` takes a C callback whose closure argument has
    scope ``call`` and no destroy notify in Aravis 0.8's typelib
    (``GIRepository``: ``fill_pattern_callback`` scope ``GI_SCOPE_TYPE_CALL``, closure 1, destroy
    -1), so PyGObject frees the Python callback when ``set_fill_pattern`` returns, while the fake
    calls it for every later frame from its stream thread.

    Without ``world`` (the capture bench's transport figures) frames are the fake's test pattern,
    blind to the LED levels (Mono16: ``256 (x + y + frame_id) mod 65535`` scaled by gain and exposure,
    ``arv_fake_camera_diagonal_ramp`` in Aravis 0.8.26); mono frames come as (H, W) and the writer
    records them as three identical channels (:attr:`Rig.mono`).
    """

    TRIGGER_REGISTER = 0x30C
    """The fake's TriggerSoftware register (see ``genicam/fake_sfnc.xml``): 1 until the fake takes the trigger."""

    def __init__(
        self,
        camera: Any,
        emulator: BoothEmulator,
        fake: Any = None,
        errors: list[BaseException] | None = None,
        world: SimulatedCamera | None = None,
        true_gain: Callable[[], float] | None = None,
    ) -> None:
        self.aravis = camera
        self.world = world
        """The scene's renderer, or None to keep the fake's test patterns."""
        self._true_gain = true_gain
        """The linear gain the twin's sensor applies now (its camera model's truth, from the fake's
        registers); None renders at the gain the camera read back for the frame."""
        self._emulator = emulator
        self._fake = fake
        self._errors = errors if errors is not None else []
        self._mode = "software"
        self._exposing = False
        self._pulses: queue.Queue[tuple[float, ...] | None] = queue.Queue()
        self._pulse_thread: threading.Thread | None = None
        self._pending: collections.deque[tuple[float, ...]] = collections.deque()
        self._pending_lock = threading.Lock()
        self._rendered_levels: list[tuple[float, ...]] = []

    @property
    def suggested_exposure_us(self) -> float:
        """An exposure that suits the scene (the world's reference exposure), 10 ms for test patterns."""
        suggested = self.world.suggested_exposure_us if self.world is not None else None
        return float(suggested or 10_000.0)

    @property
    def sensor(self) -> Any:
        """The rendered sensor's model (noise, levels), or None for test patterns."""
        return self.world.sensor if self.world is not None else None

    @property
    def rendered_levels(self) -> tuple[tuple[float, ...], ...]:
        """The LED levels each frame delivered so far was rendered under, in order."""
        with self._pending_lock:
            return tuple(self._rendered_levels)

    @property
    def info(self) -> CameraInfo:
        """The fake's identity and pixel format; with a scene, the rendered sensor's black and white levels,
        else mono frames delivered as RGB."""
        info = self.aravis.info
        if self.world is None:
            return dataclasses.replace(info, cfa=None)
        return dataclasses.replace(
            info,
            black_level=self.world.sensor.black_level,
            white_level=self.world.sensor.white_level,
            extra={**info.extra, "pixels": f"rendered scene ({self.world.info.model})"},
        )

    @property
    def exposure_range_us(self) -> tuple[float, float] | None:
        """The fake's exposure limits in microseconds (what ``--exposure`` is checked against)."""
        return self.aravis.exposure_range_us

    def check_step_gain(self, gain: float) -> None:
        """Refuse a plan step's linear ``gain`` the camera cannot take (``AravisCamera.check_step_gain``)."""
        self.aravis.check_step_gain(gain)

    def prepare(self, plan: CapturePlan) -> None:
        """Prepare the fake for ``plan`` with software triggering whatever the sync mode."""
        self._mode = plan.trigger
        self.aravis.prepare(dataclasses.replace(plan, trigger="software"))

    def start(self) -> None:
        """Start acquisition (and, for booth-paced plans, the thread that turns pulses into triggers)."""
        self._exposing = False
        with self._pending_lock:
            self._pending.clear()
        self._forget_latched_trigger()
        self.aravis.start()
        if self._mode == "booth":
            self._pulses = queue.Queue()
            self._pulse_thread = threading.Thread(
                target=self._issue_pulses, name="aravis-fake trigger line", daemon=True
            )
            self._pulse_thread.start()

    def _issue_pulses(self) -> None:
        while (levels := self._pulses.get()) is not None:
            try:
                self._wait_trigger_taken()
                self._software_trigger(levels)
            except Exception as err:  # noqa: BLE001 - the capture sees the missing frame
                log.error("aravis-fake trigger line: %s", err)
                self._errors.append(err)

    def _forget_latched_trigger(self) -> None:
        """Clear a software trigger the fake latched but has not taken (before each acquisition starts).

        A real camera ignores triggers while it is not acquiring; the fake keeps the last one in
        its register and takes it when the next acquisition starts, sending a frame nobody
        triggered (seen after a capture stopped mid-table to take a lost frame again: the booth's
        last pulses were still being issued).
        """
        if self._fake is not None:
            self._fake.write_register(self.TRIGGER_REGISTER, 0)

    def _wait_trigger_taken(self, timeout_s: float = 1.0) -> None:
        if self._fake is None:
            return
        deadline = time.monotonic() + timeout_s
        while self._fake.read_register(self.TRIGGER_REGISTER) != 0 and time.monotonic() < deadline:
            time.sleep(0.0005)

    def _software_trigger(self, levels: tuple[float, ...]) -> None:
        """Issue the fake's software trigger for a frame to be rendered under ``levels``.

        The levels are queued first: the frame may arrive (on another thread) before the trigger
        call returns. A trigger that fails takes its levels back (only one thread triggers at a time).
        """
        with self._pending_lock:
            self._pending.append(levels)
        try:
            self.aravis.trigger()
        except BaseException:
            with self._pending_lock:
                self._pending.pop()
            raise

    def trigger(self) -> None:
        """Host-paced: software trigger; camera master: ExposureActive high, then software trigger."""
        if self._mode == "booth":
            return
        if self._mode == "camera":
            self._emulator.exposure_active(True)
            self._exposing = True
        self._software_trigger(self._emulator.levels)

    def trigger_line(self) -> None:
        """The booth pulsed the trigger input: queue a software trigger with the levels it exposes."""
        self._pulses.put(self._emulator.levels)

    def next_frame(self, timeout_s: float) -> RawFrame:
        """The next frame, (H, W); in camera master the exposure line falls when it arrives.

        With a scene, its pixels are the scene rendered under the levels of its trigger, at the
        exposure the camera reports for it and the gain the twin's sensor applies (its camera
        model's truth, read from the fake's registers: what msflash believes it set is not asked).
        """
        try:
            frame = self.aravis.next_frame(timeout_s)
        except FrameLostError:
            self._take_levels()  # that trigger's frame is gone
            raise
        finally:
            if self._exposing:
                self._exposing = False
                self._emulator.exposure_active(False)
        levels = self._take_levels()
        if self.world is None:
            return frame
        if levels is None:
            raise CameraError(
                f"aravis-fake: frame {frame.frame_id} arrived with no trigger issued for it; expected "
                "one frame per trigger"
            )
        gain = self._true_gain() if self._true_gain is not None else frame.gain
        pixels = self.world.render(levels, frame.exposure_us, gain)
        if pixels.shape != frame.pixels.shape:
            raise CameraError(
                f"aravis-fake: the scene renders {pixels.shape} but the fake delivers "
                f"{frame.pixels.shape}; expected the ROI to be the scene's size"
            )
        with self._pending_lock:
            self._rendered_levels.append(levels)
        return dataclasses.replace(frame, pixels=pixels)

    def _take_levels(self) -> tuple[float, ...] | None:
        with self._pending_lock:
            return self._pending.popleft() if self._pending else None

    def stop(self) -> None:
        """Stop acquisition and the trigger-line thread (a trigger not yet taken is forgotten at the next start)."""
        if self._pulse_thread is not None:
            self._pulses.put(None)
            self._pulse_thread.join(timeout=5.0)
            self._pulse_thread = None
        self.aravis.stop()

    def close(self) -> None:
        """Release the fake camera."""
        self.aravis.close()


ARAVIS_FAKE_PIXEL_FORMAT = "BayerRG16"
"""The ``aravis-fake`` rig's pixel format with a scene (added to msflash's fake XML): a 16-bit RGGB mosaic."""
ARAVIS_FAKE_PATCH_PX = 16
"""Chart patch size of the ``aravis-fake`` rig's scene: the default chart is then 200 × 186 pixels, each
patch 8 × 8 quads of the mosaic (the ``sim`` rig's 8-pixel patches give a noisier estimate from a mosaic;
docs/architecture.md §4 has the figures)."""


def open_aravis_fake_rig(
    log_serial: str | Path | None = None,
    width: int | None = None,
    height: int | None = None,
    pixel_format: str | None = None,
    serial: str = "MSFRIG01",
    rendered: bool = True,
    ambient: str | Spectra = "tungsten",
    scene: str | Scene | Spectra = "chart110",
    seed: int = 0,
    camera: str | Spectra | None = None,
    n_leds: int | None = None,
    led_spectra: str | Path | Spectra | None = None,
    flash_power: float | None = None,
    patch_px: int | None = None,
    lost_packet_ratio: float = 0.0,
    camera_options: Any = None,
    fake_camera: str = "sfnc",
    **_ignored: object,
) -> Rig:
    """The ``aravis-fake`` rig: AravisCamera on the GigE fake at 127.0.0.1 + emulator on a pty + LedBooth.

    Holds the machine-wide GVCP port lock (:func:`~acquisition.devices.aravis.camera.gvcp_port_lock`)
    until closed. The fake is this process's own: a port another program holds is refused
    (``AravisGvFake.start``), and the camera opened at 127.0.0.1 must report the fake's serial and
    model, or the rig does not open (a fake of another process answers there otherwise).

    ``fake_camera``: the fake's camera model (:data:`~acquisition.devices.aravis.fake_models.FAKE_MODELS`:
    how it names its gain; rendered frames get the gain its sensor truly applies).
    ``camera_options``: :class:`~acquisition.devices.aravis.camera_features.CameraOptions` (``--gain``,
    ``--gain-raw``, ``--feature``), applied and checked as on the hardware rig before any frame.

    ``rendered`` (the default): the frames are the ``sim`` rig's world (``ambient``,
    ``scene``, ``seed``, ``camera``, ``n_leds``, ``led_spectra``, ``flash_power`` as for
    :func:`open_sim_rig`; a chart's patches ``patch_px`` wide, default :data:`ARAVIS_FAKE_PATCH_PX`)
    rendered by :class:`WiredFakeCamera` into the fake's frames, in :data:`ARAVIS_FAKE_PIXEL_FORMAT`
    (RGGB) with the ROI the scene's size (``width``/``height`` None or equal to it; the default
    chart is 200 × 186). The rig records the world's LED spectra, responsivities and true
    ambient, as the ``sim`` rig does.

    ``lost_packet_ratio``: the fraction of stream packets the fake drops, a lossy link (its frames
    arrive incomplete now and then, as on a congested GigE Vision network).

    ``rendered`` False: the frames are the fake's test patterns (``pixel_format`` default Mono16,
    ``width`` × ``height`` default 64 × 48): the paper's seven LEDs, ISETCam's
    :data:`AravisFakeNominalCamera` recorded as nominal — the capture bench's transport figures.

    Raises
    ------
    UsageError
        A bad world option (named), or a ``width``/``height`` other than the scene's.
    CameraSettingError
        A camera option the fake's camera cannot take (bad input; the booth is not opened).
    RigOpenError
        The fake, the emulated booth or the world failed to open, or another camera answered.
    """
    try:
        from msflash.acquisition.devices.aravis import camera as aravis_camera
        from msflash.acquisition.devices.aravis.camera_features import CameraOptions, configure_camera
        from msflash.acquisition.devices.aravis.fake_models import FAKE_MODELS
    except ImportError as err:
        raise RigOpenError(f"rig 'aravis-fake': {err}") from err
    model = FAKE_MODELS.get(fake_camera)
    if model is None:
        raise UsageError(unknown_name("--fake-camera", fake_camera, FAKE_MODELS))
    world = None
    if rendered:
        world = _sim_world(
            "aravis-fake",
            ambient,
            scene,
            "RGGB",
            seed,
            camera,
            n_leds,
            led_spectra,
            flash_power,
            ARAVIS_FAKE_PATCH_PX if patch_px is None else patch_px,
        )
        scene_height, scene_width = world.scene.shape
        if (width or scene_width, height or scene_height) != (scene_width, scene_height):
            raise UsageError(
                f"rig 'aravis-fake': ROI {width}x{height} but the scene is {scene_width}x{scene_height}; "
                "expected the scene's size (the rendered mosaic fills the ROI)"
            )
        width, height = scene_width, scene_height
        pixel_format = pixel_format or ARAVIS_FAKE_PIXEL_FORMAT
        leds, responsivities = world.led_spectra, world.camera_responsivities
    else:
        width, height, pixel_format = width or 64, height or 48, pixel_format or "Mono16"
        leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero")
        responsivities = datasets.isetcam_camera(AravisFakeNominalCamera).resample(DEFAULT_GRID, outside="zero")
    closers: list = []
    line_errors: list[BaseException] = []
    failures: dict[str, BaseException] = {}
    emulator = booth = setup = None
    try:
        if world is not None:
            from msflash.acquisition.devices.aravis.fake_log import mute_unfilled_format_warning

            closers.append(mute_unfilled_format_warning())  # the pixels are rendered: its lines say nothing
        fake = aravis_camera.AravisGvFake(
            serial=serial,
            genicam_xml=model.xml_path(),
            lost_packet_ratio=lost_packet_ratio,
            model=model.model,
            registers=model.registers,
        )
        fake.start()
        closers.append(fake.close)
        aravis = aravis_camera.AravisCamera(fake.address, interfaces="gige")
        closers.append(aravis.close)
        opened = aravis.info
        if (opened.serial, opened.model) != (serial, model.model):
            raise RigOpenError(
                f"the camera at {fake.address} is {opened.vendor} {opened.model} serial {opened.serial}, not this "
                f"rig's fake ({model.model} serial {serial}): another program's GigE Vision camera answers there; "
                "expected the rig's own — stop the other fake"
            )
        aravis.set_pixel_format(pixel_format)  # once the camera is known to be the rig's own
        aravis.set_roi(0, 0, width, height)
        opened = aravis.info
        if world is not None and opened.cfa != world.sensor.cfa:
            raise RigOpenError(
                f"pixel format {pixel_format} has CFA {opened.cfa}; expected {world.sensor.cfa}, the rendered mosaic's"
            )
        setup = configure_camera(aravis, camera_options or CameraOptions(), strobe=False)
    except CameraSettingError:
        _close_all(closers)
        raise  # bad input, not a device failure: one line, exit 2
    except Exception as err:  # noqa: BLE001 - reported with the booth's failure, if any
        failures[f"camera GigE fake {serial} at 127.0.0.1"] = err
        aravis = None
    try:
        emulator, booth = _open_emulated_booth(leds, log_serial, closers)
    except RigOpenError as err:
        failures["booth"] = err
    if failures:
        _close_all(closers)
        listing = "; ".join(f"{device}: {err}" for device, err in failures.items())
        raise RigOpenError(f"rig 'aravis-fake': {listing}") from next(iter(failures.values()))
    assert aravis is not None and emulator is not None and booth is not None and setup is not None
    wired = WiredFakeCamera(
        aravis, emulator, fake, line_errors, world=world, true_gain=lambda: model.true_gain(fake.read_register)
    )
    closers.insert(closers.index(aravis.close) + 1, wired.stop)  # before the AravisCamera and the fake are released
    emulator.on_trigger_out = _line(line_errors, "aravis-fake trigger line", wired.trigger_line)
    camera_record: dict = {"fake_camera": model.name, "gain": aravis.gain_record()}
    if not setup.options.empty:
        camera_record["camera_options"] = setup.to_dict()
    if world is None:
        extra = {
            "responsivity_note": f"nominal: ISETCam {AravisFakeNominalCamera}; the fake's test patterns have no spectral meaning",
            **camera_record,
        }
        return Rig(
            "aravis-fake",
            wired,
            booth,
            leds,
            responsivities,
            None,
            closers,
            emulator=emulator,
            line_errors=line_errors,
            camera_extra=extra,
            mono=pixel_format.startswith("Mono"),
        )
    extra = {
        "pixels": f"the Aravis fake's frames, pixels rendered by {world.info.model} under the booth's LEDs "
        "at each frame's trigger",
        **camera_record,
    }
    return Rig(
        "aravis-fake",
        wired,
        booth,
        leds,
        responsivities,
        world.true_ambient,
        closers,
        emulator=emulator,
        line_errors=line_errors,
        camera_extra=extra,
    )


def open_replay_rig(directory: str | Path, log_serial: str | Path | None = None, **_ignored: object) -> Rig:
    """The ``replay:DIR`` rig: ReplayCamera on a recorded sequence + emulator on a pty + LedBooth."""
    from msflash.acquisition.devices.replay_camera import ReplayCamera
    from msflash.acquisition.sequence.locate import locate_sequence

    camera = ReplayCamera.open(locate_sequence(directory, "--rig replay:"))  # RecordingError: missing, malformed
    sequence = camera.sequence
    leds = sequence.led_spectra()
    responsivities = sequence.camera_responsivities()
    closers: list = [camera.close]
    try:
        emulator, booth = _open_emulated_booth(leds, log_serial, closers)
    except RigOpenError as err:
        _close_all(closers)
        raise RigOpenError(f"rig 'replay:{directory}': {err}") from err
    line_errors: list[BaseException] = []
    emulator.on_trigger_out = _line(line_errors, "replay trigger line", camera.trigger_line)
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


def open_rig(spec: str, **options: Any) -> Rig:
    """Open a rig by its ``--rig`` spec: ``sim``, ``aravis-fake``, ``replay:DIR`` or ``hw``."""
    if spec == "hw":
        return open_hw_rig(**options)
    if spec == "sim":
        return open_sim_rig(**options)
    if spec == "aravis-fake":
        return open_aravis_fake_rig(**options)
    if spec.startswith("replay:") and len(spec) > len("replay:"):
        return open_replay_rig(spec[len("replay:") :], log_serial=options.get("log_serial"))
    raise UsageError(unknown_name("--rig", spec, RIG_SPECS))


# -- the hardware rig --------------------------------------------------------------------------

CALIBRATION_LED_FILES = ("led_spectra.csv", "leds.csv")
"""File names looked for in ``--calibration DIR`` for the LED spectra (first found wins)."""
CALIBRATION_RESPONSIVITY_FILES = ("camera_responsivity.csv", "responsivity.csv", "camera.csv")
"""File names looked for in ``--calibration DIR`` for the camera's responsivities."""


def load_hw_spectra(
    calibration: str | Path | None = None, led_spectra: str | Path | None = None, responsivity: str | Path | None = None
) -> tuple[Spectra, Spectra | None]:
    """LED spectra and camera responsivities for the hardware rig, on :data:`DEFAULT_GRID`
    (:func:`hw_spectra` without the calibration reference)."""
    leds, camera, _ = hw_spectra(calibration, led_spectra, responsivity)
    return leds, camera


def hw_spectra(
    calibration: str | Path | None = None, led_spectra: str | Path | None = None, responsivity: str | Path | None = None
) -> tuple[Spectra, Spectra | None, tuple[str, Path] | None]:
    """LED spectra, camera responsivities (on :data:`DEFAULT_GRID`) and the calibration they came from.

    ``calibration`` is a ``msflash calibrate`` directory (``calibration.json``, read by
    :func:`calibration.files.load_calibration`), or a directory holding ``led_spectra.csv`` (or
    ``leds.csv``) and optionally ``camera_responsivity.csv`` (or ``responsivity.csv``,
    ``camera.csv``); ``led_spectra`` / ``responsivity`` name
    the files directly and win over the directory. Files are CSV tables read by
    :func:`processing.datasets.load_spectra_csv`: first column ``wavelength_nm``, one column per LED
    (in booth channel order) or per camera channel (R, G, B), energy units, each LED at full drive
    with the true ratios between LEDs. Values outside a file's range are taken as zero.

    The third item is (id, directory) when ``calibration`` is a ``msflash calibrate`` output (every
    sequence of the rig refers to it, :attr:`Rig.calibration`), else None.

    Raises
    ------
    UsageError
        Nothing gives the LED spectra, a named file or directory is missing, or a file is malformed.
    """
    led_path = Path(led_spectra) if led_spectra else None
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
            if led_path is None:
                led_path = next((directory / n for n in CALIBRATION_LED_FILES if os.path.lexists(directory / n)), None)
                if led_path is None:
                    raise UsageError(
                        f"--calibration {directory}: no calibration.json or "
                        f"{' or '.join(CALIBRATION_LED_FILES)}; expected the LED spectra"
                    )
            if resp_path is None:
                resp_path = next(
                    (directory / n for n in CALIBRATION_RESPONSIVITY_FILES if os.path.lexists(directory / n)), None
                )
    if led_path is not None:
        leds = read_spectra_file(led_path, "spd")
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


class HardwareCamera:
    """An :class:`~acquisition.devices.aravis.camera.AravisCamera` as the hardware rig's camera.

    Forwards the :class:`~acquisition.devices.camera.Camera` protocol; mono frames come as (H, W) and
    the writer records them as three identical channels (:attr:`Rig.mono`; format v1 holds RGB
    or raw mosaics, and the sequence's ``camera.extra`` says so). Offers what exposure planning
    asks of a camera: :attr:`exposure_range_us` and :attr:`noise_model` (from the camera's
    profile, when it knows the conversion gain).
    """

    suggested_exposure_us = 10_000.0

    def __init__(self, camera: Any, setup: Any = None) -> None:
        self.aravis = camera
        self.setup = setup
        """The :class:`~acquisition.devices.aravis.camera_features.CameraSetup` applied when the rig opened, or None."""

    @property
    def info(self) -> CameraInfo:
        """The camera's identity (a mono camera has ``cfa`` None and (H, W) frames)."""
        return self.aravis.info

    @property
    def exposure_range_us(self) -> tuple[float, float] | None:
        """The camera's exposure limits in microseconds, if it reports them."""
        return getattr(self.aravis, "exposure_range_us", None)

    @property
    def noise_model(self) -> Any:
        """Conversion gain and read noise from the camera profile, or None."""
        return getattr(self.aravis, "noise_model", None)

    def check_step_gain(self, gain: float) -> None:
        """Refuse a plan step's linear ``gain`` the camera cannot take (``AravisCamera.check_step_gain``)."""
        self.aravis.check_step_gain(gain)

    def prepare(self, plan: CapturePlan) -> None:
        """Prepare the camera for ``plan`` (each step's gain multiplies ``--gain``'s, which the camera holds)."""
        self.aravis.prepare(plan)

    def start(self) -> None:
        """Start acquisition."""
        self.aravis.start()

    def trigger(self) -> None:
        """Software trigger (a no-op when a line paces the camera)."""
        self.aravis.trigger()

    def next_frame(self, timeout_s: float) -> RawFrame:
        """The next frame as the camera delivers it ((H, W) for mono and mosaics)."""
        return self.aravis.next_frame(timeout_s)

    def stop(self) -> None:
        """Stop acquisition."""
        self.aravis.stop()

    def close(self) -> None:
        """Release the camera."""
        self.aravis.close()


def _open_hw_camera(
    camera: str | None, interfaces: str, sync: str, pixel_format: str | None, options: Any = None
) -> tuple[Any, Any]:
    """The camera, opened and configured (profile options overridden by ``options``), and its setup."""
    from msflash.acquisition.devices.aravis import camera as aravis_camera
    from msflash.acquisition.devices.aravis.camera_features import CameraOptions, configure_camera

    names = aravis_camera.parse_interfaces(interfaces)
    if camera is None:
        found = aravis_camera.list_devices(names)
        if len(found) != 1:
            listing = ", ".join(f"{e.device_id} (serial {e.serial})" for e in found) or "none"
            raise aravis_camera.CameraNotFoundError(
                f"camera: {'no camera' if not found else f'{len(found)} cameras'} on {','.join(names)} "
                f"(found: {listing}); expected one — pass --camera ID (device id, serial or IP) "
                "or --interfaces"
            )
        camera = found[0].device_id
    opened = aravis_camera.AravisCamera(camera, interfaces=names, pixel_format=pixel_format)
    try:
        setup = configure_camera(opened, options or CameraOptions(), strobe=sync == "camera")
    except BaseException:
        opened.close()
        raise
    return opened, setup


def open_hw_rig(
    camera: str | None = None,
    port: str | None = None,
    interfaces: str = "usb3",
    calibration: str | Path | None = None,
    led_spectra: str | Path | None = None,
    responsivity: str | Path | None = None,
    log_serial: str | Path | None = None,
    sync: str = "host",
    pixel_format: str | None = None,
    camera_options: Any = None,
    booth_protocol: str = "msflash",
    booth_boot_s: float = DEFAULT_BOOT_S,
    **_ignored: object,
) -> Rig:
    """The hardware rig: a GenICam camera by id/serial/IP + a booth on ``port`` (or the one discovered).

    Parameters
    ----------
    camera
        Aravis device id, serial number or IPv4 address; None takes the single camera found on
        ``interfaces``.
    port
        The booth's serial port (``/dev/ttyACM0``, a pty path, a pyserial URL); None discovers it.
    interfaces
        Aravis interfaces to enable (``usb3`` by default; ``gige`` broadcasts discovery unless
        ``camera`` is an IP address; ``fake`` is Aravis's in-process test camera).
    calibration, led_spectra, responsivity
        Where the LED spectra and camera responsivities come from (:func:`hw_spectra`).
    sync
        ``host``, ``booth`` or ``camera``: camera master configures a strobe output (Line1 unless
        ``camera_options`` or the camera profile name another line).
    pixel_format
        PixelFormat to set, or None to keep the camera's.
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
    from msflash.led_controller.discovery import find_booth

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
        booth_port = port if port is not None else find_booth().device
        booth = open_booth(booth_port, booth_protocol, log_serial=log_serial, boot_s=booth_boot_s)
        closers.append(booth.close)
        closers.append(booth.all_off)
        if booth.info.channels != leds.count:
            raise RigOpenError(
                f"booth {booth_port}: {booth.info.channels} channels ({', '.join(booth.info.names)}) but the LED "
                f"spectra have {leds.count} ({', '.join(leds.names)}); expected one spectrum per channel"
            )
        if isinstance(booth, LedBooth):  # an adapter switches its LEDs off when it opens
            for note in reset_leftovers(booth):  # a killed run's LEDs and raised watchdog
                log.warning("%s", note)
    except Exception as err:  # noqa: BLE001 - reported with the camera's failure, if any
        message = str(err)
        failures.append(message if message.startswith("booth") else f"booth: {message}")
        errors.append(err)
    if failures:
        _close_all(closers)
        raise RigOpenError(f"rig 'hw': {'; '.join(failures)}") from errors[0]
    assert aravis is not None and booth is not None
    hardware = HardwareCamera(aravis, setup)
    info = aravis.info
    extra: dict = {"gain": aravis.gain_record()}
    if setup is not None and not setup.options.empty:
        extra["camera_options"] = setup.to_dict()  # what was asked (profile + options) and read back
    mono = info.cfa is None and info.pixel_format.startswith("Mono")
    if responsivities is None:
        extra["responsivity_note"] = "not given (--responsivity or a calibration directory): flash solvers unavailable"
    return Rig(
        "hw", hardware, booth, leds, responsivities, None, closers, camera_extra=extra, mono=mono, calibration=reference
    )
