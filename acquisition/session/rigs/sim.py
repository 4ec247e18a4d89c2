"""The ``sim`` rig: a :class:`SimulatedCamera` and a booth (docs/architecture.md §4).

The camera renders a spectral scene with the LED levels the booth holds at exposure time, each
row integrating the booth's drive over its own exposure window
(:mod:`acquisition.devices.exposure_light`). The booth is the emulator on a pty in this process
(the default; its trigger output is the camera's trigger line), the booth at ``--booth-port``
(:mod:`acquisition.session.external_booth`, host pacing only), or the reference firmware in simavr
(``--booth-firmware``, wired as a real rig is). The whole pipeline runs with a known ground-truth
ambient, through the same driver code a real booth uses.
"""

from __future__ import annotations

import logging
import queue
import threading
from pathlib import Path
from typing import Any

from msflash.acquisition.devices.exposure_light import EmulatorLight, FirmwareLight, Shutter
from msflash.acquisition.devices.mains_flicker import MainsFlicker
from msflash.acquisition.devices.sim_default import SIM_DEFAULT_CFA
from msflash.acquisition.devices.sim_world import (
    LedFiles,
    led_files_shown,
    sim_ambient,
    sim_camera,
    sim_leds,
    sim_scene,
)
from msflash.acquisition.devices.simulated_camera import SimulatedCamera
from msflash.acquisition.errors import CameraError, RigOpenError, UsageError
from msflash.acquisition.session.external_booth import levels_reported_by, open_external_booth
from msflash.acquisition.session.rigs.emulated_booth import (
    check_emulated_booth,
    close_all,
    line_callback,
    open_emulated_booth,
)
from msflash.acquisition.session.rigs.rig import Rig
from msflash.led_controller import LedBooth
from msflash.led_controller.booth_handshake import DEFAULT_BOOT_S
from msflash.led_controller.booth_interface import Booth
from msflash.processing.scenes import Scene
from msflash.processing.spectra import Spectra

log = logging.getLogger(__name__)


def sim_world(
    rig: str,
    ambient: str | Spectra,
    scene: str | Scene | Spectra,
    cfa: str | None,
    seed: int,
    camera: str | Spectra | None,
    n_leds: int | None,
    led_spectra: LedFiles | Spectra | None,
    flash_power: float | None,
    patch_px: int | None = None,
    flicker: MainsFlicker | None = None,
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
        where = f"--led-spectra {led_files_shown(led_spectra)}" if led_spectra is not None else f"--leds {n_leds or 7}"
    check_emulated_booth(leds, where)
    try:
        optional: dict[str, Any] = {}
        if patch_px is not None:
            optional["patch_px"] = patch_px
        if flash_power is not None:
            optional["flash_power"] = flash_power
        world = SimulatedCamera.default(
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
    world.ambient_modulation = flicker  # each frame sees the lamp's mean over its own exposure window
    return world


def open_sim_rig(
    ambient: str | Spectra = "tungsten",
    scene: str | Scene | Spectra = "chart110",
    cfa: str | None = SIM_DEFAULT_CFA,
    seed: int = 0,
    camera: str | Spectra | None = None,
    n_leds: int | None = None,
    led_spectra: LedFiles | Spectra | None = None,
    log_serial: str | Path | None = None,
    flash_power: float | None = None,
    booth_port: str | None = None,
    booth_protocol: str = "msflash",
    booth_boot_s: float = DEFAULT_BOOT_S,
    booth_firmware: bool = False,
    line_time_us: float = 0.0,
    flicker: MainsFlicker | None = None,
) -> Rig:
    """The simulated rig: SimulatedCamera + BoothEmulator on a pty + the LedBooth driver.

    Parameters
    ----------
    ambient, scene, camera, n_leds, led_spectra, flash_power, seed, flicker
        The world (:class:`acquisition.session.rig.SimWorldOptions` says each; names and CSV files
        resolved by :mod:`acquisition.devices.sim_world`, or spectra / a :class:`Scene` on the sim
        grid). The emulated booth gets one channel per LED, named and peaked as they are
        (:func:`check_emulated_booth`).
    cfa, log_serial, line_time_us
        Raw mosaic layout (default :data:`SIM_DEFAULT_CFA`; None for RGB frames), serial transcript file, rolling
        shutter (0: global).
    booth_port, booth_protocol, booth_boot_s
        ``--booth-port``: the booth at this port (``msflash booth-emulator`` on a pty, or a real
        booth; host pacing only, :attr:`Rig.emulator` None), what it speaks and how long it may
        take to boot after its port's open reset it (:mod:`acquisition.session.external_booth`).
    booth_firmware
        ``--booth-firmware``: the reference firmware in simavr (:func:`open_firmware_booth`),
        wired as a real rig is, so all three sync modes run on its real LED pins.

    Raises
    ------
    UsageError
        A bad name or file, with the option or file named (before anything is opened).
    RigOpenError
        The world or the emulated booth failed to open.
    """
    if booth_firmware and booth_port is not None:
        raise UsageError(
            "--booth-firmware: the booth is the firmware in simavr, so --booth-port has no use; expected one of them"
        )
    world = sim_world("sim", ambient, scene, cfa, seed, camera, n_leds, led_spectra, flash_power, flicker=flicker)
    try:
        world.shutter = Shutter(line_time_us=float(line_time_us))
    except CameraError as err:
        raise UsageError(f"--line-time-us {line_time_us}: expected a line time ≥ 0 µs") from err
    closers: list = [world.close]
    try:
        if booth_port is not None:
            booth = open_external_booth(
                booth_port, world.led_spectra, log_serial, closers, booth_protocol, boot_s=booth_boot_s
            )
            world.led_levels_source = levels_reported_by(booth)
            return _rig(world, booth, closers)
        if booth_firmware:
            line_errors: list[BaseException] = []
            booth = open_firmware_booth(world, log_serial, closers, line_errors)
            return _rig(world, booth, closers, line_errors=line_errors, camera_extra={"booth": "firmware in simavr"})
        return _with_emulated_booth(world, log_serial, closers)
    except Exception as err:
        close_all(closers)
        if isinstance(err, UsageError):
            raise
        raise RigOpenError(f"rig 'sim': {err}") from err


def _rig(world: SimulatedCamera, booth: Booth, closers: list, **extra: Any) -> Rig:
    return Rig(
        "sim",
        world,
        booth,
        world.led_spectra,
        world.camera_responsivities,
        world.true_ambient,
        closers,
        mono=world.mono,
        **extra,
    )


def _with_emulated_booth(world: SimulatedCamera, log_serial: str | Path | None, closers: list) -> Rig:
    """The sim rig's own booth: the emulator on a pty, its drive and trigger output wired to the camera."""
    line_errors: list[BaseException] = []
    emulator, booth = open_emulated_booth(world.led_spectra, log_serial, closers)
    # Exposure-time coupling: each row of the camera integrates the emulator's drive (PWM at its
    # phase, pulses) over its exposure window, raising ExposureActive over the flash window.
    world.exposure_light = EmulatorLight(emulator)
    # Booth master: the booth's trigger output is the camera's trigger input.
    emulator.on_trigger_out = line_callback(line_errors, "sim camera trigger line", world.trigger_line)
    return _rig(world, booth, closers, emulator=emulator, line_errors=line_errors)


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
            line_callback(line_errors, "simavr camera trigger line", world.trigger_line)()

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
