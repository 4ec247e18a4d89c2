"""Rigs: a camera and a booth wired together (docs/architecture.md §4), opened by ``--rig`` from a table.

:data:`RIG_BUILDERS` is the table (the idea of colour's method tables): each kind of rig, the
frozen dataclass of its options (:class:`SimRigOptions`, :class:`AravisFakeRigOptions`,
:class:`ReplayRigOptions`, :class:`HwRigOptions`) and the function that builds it
(:mod:`acquisition.session.rigs`). :func:`open_rig` looks the spec up, checks the options are that
kind's and builds the rig; the command line fills the options from its arguments.

The kinds (each builder's docstring has the details): ``sim`` (the default; :class:`SimulatedCamera` and the
real :class:`led_controller.LedBooth` driver on the booth emulator over a pty, with a known ground-truth
ambient), ``aravis-fake`` (:class:`~acquisition.devices.aravis.camera.AravisCamera` on the Aravis GigE fake at
127.0.0.1, painted with the ``sim`` world), ``replay:DIR`` (:class:`~acquisition.devices.replay_camera.ReplayCamera`
serving a recorded sequence) and ``hw`` (real use, also implied by ``--camera`` / ``--port``; every device is
tried and :class:`RigOpenError` lists each one's failure).

The trigger wires of the three sync modes are modelled in every rig (docs/rigs.md): booth master, the
emulator's trigger output drives the camera's trigger input; camera master, the camera's ExposureActive
output drives the emulator's input. A callback that fails on the emulator's thread is logged and kept in :attr:`Rig.line_errors`
(it must not kill the emulator); the capture then sees the missing frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from msflash.acquisition.devices.mains_flicker import MainsFlicker
from msflash.acquisition.devices.sim_default import SIM_DEFAULT_CFA
from msflash.acquisition.devices.sim_world import LedFiles
from msflash.acquisition.errors import UsageError
from msflash.acquisition.session.rigs.aravis_fake import open_aravis_fake_rig
from msflash.acquisition.session.rigs.hardware import open_hw_rig
from msflash.acquisition.session.rigs.replay import open_replay_rig
from msflash.acquisition.session.rigs.rig import Rig
from msflash.acquisition.session.rigs.sim import open_sim_rig
from msflash.led_controller.booth_handshake import DEFAULT_BOOT_S
from msflash.processing.names import unknown_name
from msflash.processing.scenes import Scene
from msflash.processing.spectra import Spectra

if TYPE_CHECKING:
    from msflash.acquisition.devices.aravis.camera_features import CameraOptions

RIG_SPECS = ("sim", "aravis-fake", "replay:DIR", "hw")
"""What ``--rig`` accepts."""


@dataclass(frozen=True)
class SimWorldOptions:
    """The simulated world the ``sim`` and ``aravis-fake`` rigs render (``--ambient``, ``--scene``, …)."""

    ambient: str | Spectra = "tungsten"
    """``--ambient``: a light's name, a CSV file, or spectra on the sim grid."""
    scene: str | Scene | Spectra = "chart110"
    """``--scene``: a scene's name, a CSV file of reflectances, or a :class:`Scene`."""
    seed: int = 0
    """``--seed``: noise (and mosaic) seed."""
    camera: str | Spectra | None = None
    """``--sim-camera``: the simulated camera's responsivities (None: the default camera)."""
    n_leds: int | None = None
    """``--leds``: the paper's subset of this many LEDs (None and no ``led_spectra``: the paper's 7)."""
    led_spectra: LedFiles | Spectra | None = None
    """``--led-spectra``: the booth's LEDs, one column per channel (or one spectrometer export per channel)."""
    flash_power: float | None = None
    """``--flash-power``: every LED at full drive gives at least this many times the ambient's signal."""
    flicker: MainsFlicker | None = None
    """``--flicker``: the ambient lamp's mains flicker (None: steady; :mod:`acquisition.devices.mains_flicker`)."""

    def as_arguments(self) -> dict[str, Any]:
        """The world as keyword arguments of :func:`open_sim_rig` and :func:`open_aravis_fake_rig`."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class SimRigOptions:
    """The ``sim`` rig's options (:func:`~acquisition.session.rigs.sim.open_sim_rig`)."""

    world: SimWorldOptions = field(default_factory=SimWorldOptions)
    cfa: str | None = SIM_DEFAULT_CFA
    """``--cfa``: raw Bayer mosaic frames with this layout (default the sim camera's raw RGGB; None for RGB)."""
    log_serial: str | Path | None = None
    booth_port: str | None = None
    """``--booth-port``: a booth outside this process (host pacing only)."""
    booth_protocol: str = "msflash"
    booth_boot_s: float = DEFAULT_BOOT_S
    booth_firmware: bool = False
    """``--booth-firmware``: the reference firmware in simavr."""
    line_time_us: float = 0.0
    """``--line-time-us``: the camera's rolling shutter (0: global)."""


@dataclass(frozen=True)
class AravisFakeRigOptions:
    """The ``aravis-fake`` rig's options (:func:`~acquisition.session.rigs.aravis_fake.open_aravis_fake_rig`)."""

    world: SimWorldOptions = field(default_factory=SimWorldOptions)
    log_serial: str | Path | None = None
    camera_options: CameraOptions | None = None
    """``--gain``, ``--gain-raw``, ``--feature``: applied and checked as on the hardware rig."""
    fake_camera: str = "sfnc"
    """``--fake-camera``: the fake's camera model."""


@dataclass(frozen=True)
class ReplayRigOptions:
    """The ``replay:DIR`` rig's options (the directory is in the spec)."""

    log_serial: str | Path | None = None


@dataclass(frozen=True)
class HwRigOptions:
    """The ``hw`` rig's options (:func:`~acquisition.session.rigs.hardware.open_hw_rig`)."""

    camera: str | None = None
    """``--camera``: device id, serial or IP; None takes the single camera found."""
    port: str | None = None
    """``--port``: the booth's serial port; None discovers it."""
    interfaces: str = "usb3"
    calibration: str | Path | None = None
    led_spectra: LedFiles | None = None
    responsivity: str | Path | None = None
    log_serial: str | Path | None = None
    sync: str = "host"
    """``--sync``: camera master configures a strobe output."""
    pixel_format: str | None = None
    camera_options: CameraOptions | None = None
    booth_protocol: str = "msflash"
    booth_boot_s: float = DEFAULT_BOOT_S


RigOptions = SimRigOptions | AravisFakeRigOptions | ReplayRigOptions | HwRigOptions
"""The options of any rig kind."""


def _sim(spec: str, options: SimRigOptions) -> Rig:
    return open_sim_rig(
        **options.world.as_arguments(),
        cfa=options.cfa,
        log_serial=options.log_serial,
        booth_port=options.booth_port,
        booth_protocol=options.booth_protocol,
        booth_boot_s=options.booth_boot_s,
        booth_firmware=options.booth_firmware,
        line_time_us=options.line_time_us,
    )


def _aravis_fake(spec: str, options: AravisFakeRigOptions) -> Rig:
    return open_aravis_fake_rig(
        **options.world.as_arguments(),
        log_serial=options.log_serial,
        camera_options=options.camera_options,
        fake_camera=options.fake_camera,
    )


def _replay(spec: str, options: ReplayRigOptions) -> Rig:
    return open_replay_rig(spec[len("replay:") :], log_serial=options.log_serial)


def _hw(spec: str, options: HwRigOptions) -> Rig:
    return open_hw_rig(**{f.name: getattr(options, f.name) for f in fields(options)})


@dataclass(frozen=True)
class RigBuilder:
    """One kind of rig in :data:`RIG_BUILDERS`: its options' dataclass and how it is built."""

    options: type
    """The frozen dataclass of this kind's options."""
    build: Callable[[str, Any], Rig]
    """``build(spec, options)``: the open rig."""


RIG_BUILDERS: dict[str, RigBuilder] = {
    "sim": RigBuilder(SimRigOptions, _sim),
    "aravis-fake": RigBuilder(AravisFakeRigOptions, _aravis_fake),
    "replay": RigBuilder(ReplayRigOptions, _replay),
    "hw": RigBuilder(HwRigOptions, _hw),
}
"""Every ``--rig`` kind, by name (``replay:DIR`` is the ``replay`` kind)."""


def rig_kind(spec: str) -> str:
    """The kind of rig ``spec`` names (``replay:DIR`` → ``replay``).

    Raises
    ------
    UsageError
        An unknown spec, with every spec ``--rig`` accepts.
    """
    kind = "replay" if spec.startswith("replay:") and len(spec) > len("replay:") else spec
    if kind not in RIG_BUILDERS or kind == "replay" and not spec.startswith("replay:"):
        raise UsageError(unknown_name("--rig", spec, RIG_SPECS))
    return kind


def open_rig(spec: str, options: RigOptions | None = None) -> Rig:
    """Open a rig by its ``--rig`` spec (``sim``, ``aravis-fake``, ``replay:DIR`` or ``hw``) with its options.

    ``options`` None takes the kind's defaults.

    Raises
    ------
    UsageError
        An unknown spec (one line listing the specs), or what the rig's builder refuses.
    TypeError
        Options of another kind of rig (a programming error).
    """
    builder = RIG_BUILDERS[rig_kind(spec)]
    chosen = builder.options() if options is None else options
    if not isinstance(chosen, builder.options):
        raise TypeError(f"open_rig({spec!r}): {type(chosen).__name__} given; expected {builder.options.__name__}")
    return builder.build(spec, chosen)
