"""Rigs: a camera and a booth wired together (DESIGN §4).

``sim`` (the default): a :class:`SimulatedCamera` rendering a spectral scene with the LED levels
the booth *emulator* holds at exposure time, and the real :class:`led_controller.LedBooth`
driver talking to that emulator over a real pseudo-terminal. The whole pipeline runs, with a
known ground-truth ambient, through the same driver code a real booth uses.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from acquisition.cli_common import UsageError
from acquisition.errors import RigOpenError
from acquisition.sequence_format import SequenceCamera, SequenceLed
from acquisition.simulated_camera import SimulatedCamera
from led_controller import BoothEmulator, LedBooth, serve_on_pty
from processing.datasets import AMBIENTS
from processing.spectra import Spectra


@dataclass
class Rig:
    """An open camera + booth pair; close it (or use ``with``) to switch LEDs off and release both."""

    name: str
    """The rig spec (``sim``…)."""
    camera: SimulatedCamera
    """The camera."""
    booth: LedBooth
    """The booth driver."""
    led_spectra: Spectra
    """The LED spectra at full drive (what a calibration would have measured)."""
    camera_responsivities: Spectra | None
    """The camera's responsivities, if known."""
    true_ambient: Spectra | None = None
    """Ground truth, for simulated rigs."""
    _closers: list = field(default_factory=list, repr=False)

    def sequence_header(self) -> tuple[np.ndarray, SequenceCamera, tuple[SequenceLed, ...]]:
        """Wavelengths, camera and LED entries for a format-v1 sequence written from this rig (energy units)."""
        leds = self.led_spectra.to_unit("energy")
        info = self.camera.info
        responsivity = None
        if self.camera_responsivities is not None:
            values = self.camera_responsivities.to_unit("energy").values
            responsivity = {channel: values[:, i] for i, channel in enumerate("RGB")}
        camera = SequenceCamera(
            model=info.model, serial=info.serial, pixel_format=info.pixel_format, cfa=info.cfa,
            black_level=info.black_level, white_level=info.white_level, responsivity=responsivity,
        )
        entries = tuple(SequenceLed(name, leds.values[:, i]) for i, name in enumerate(leds.names))
        return leds.wavelengths_nm, camera, entries

    def close(self) -> None:
        """Switch the LEDs off, close the booth link, the emulator and the camera (each attempted)."""
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

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_sim_rig(ambient: str = "tungsten", scene: str = "chart110", cfa: str | None = None, seed: int = 0,
                 camera: str = "NikonD100", n_leds: int = 7, log_serial: str | Path | None = None) -> Rig:
    """The simulated rig: SimulatedCamera + BoothEmulator on a pty + the LedBooth driver."""
    if ambient not in AMBIENTS:
        raise UsageError(f"--ambient '{ambient}': unknown; expected one of {', '.join(AMBIENTS)}")
    closers: list = []
    try:
        world = SimulatedCamera.default(scene=scene, ambient=ambient, cfa=cfa, seed=seed, camera=camera, n_leds=n_leds)  # type: ignore[arg-type]
        closers.append(world.close)
        names = world.led_spectra.names
        peaks = [float(world.led_spectra.wavelengths_nm[np.argmax(world.led_spectra.values[:, i])])
                 for i in range(world.led_spectra.count)]
        emulator = BoothEmulator(names=[n.replace(" ", "_") for n in names], peaks_nm=peaks)
        server = serve_on_pty(emulator)
        closers.append(server.close)
        booth = LedBooth.open(server.port, log_serial=log_serial)
        closers.append(booth.close)
        closers.append(booth.all_off)
        # Exposure-time coupling: the camera renders with what the emulator's LEDs are doing.
        world.led_levels_source = lambda: emulator.levels
    except Exception as err:
        for closer in reversed(closers):
            with contextlib.suppress(Exception):
                closer()
        if isinstance(err, UsageError):
            raise
        raise RigOpenError(f"rig 'sim': {err}") from err
    return Rig("sim", world, booth, world.led_spectra, world.camera_responsivities, world.true_ambient, closers)


def open_rig(spec: str, **options: object) -> Rig:
    """Open a rig by its ``--rig`` spec."""
    if spec == "sim":
        return open_sim_rig(**options)  # type: ignore[arg-type]
    raise UsageError(f"--rig '{spec}': not available yet; expected 'sim'")
