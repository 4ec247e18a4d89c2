"""The ``aravis-fake`` rig: the Aravis GigE Vision fake on 127.0.0.1, painted with the ``sim`` world.

:class:`~acquisition.devices.aravis.camera.AravisCamera` on the fake served in this process
(opened by address: no discovery broadcast), the emulator on a pty and ``LedBooth``. Aravis
streams (buffers, frame ids, timestamps, exposure and gain features, software triggers) in
BayerRG16; :class:`~acquisition.devices.wired_fake.WiredFakeCamera` paints each frame with the
``sim`` world rendered under the LED levels of that frame's trigger (docs/architecture.md §4).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msflash.acquisition.devices.aravis.pixel_layouts import camera_pixel_layout
from msflash.acquisition.devices.mains_flicker import MainsFlicker
from msflash.acquisition.devices.sim_world import LedFiles
from msflash.acquisition.devices.simulated_camera import SimulatedCamera
from msflash.acquisition.devices.wired_fake import WiredFakeCamera
from msflash.acquisition.errors import CameraSettingError, RigOpenError, UsageError
from msflash.acquisition.session.rigs.emulated_booth import (
    close_all,
    line_callback,
    open_emulated_booth,
)
from msflash.acquisition.session.rigs.rig import Rig, sends_mono
from msflash.acquisition.session.rigs.sim import sim_world
from msflash.led_controller import BoothEmulator, LedBooth
from msflash.processing import datasets
from msflash.processing.names import unknown_name
from msflash.processing.scenes import Scene
from msflash.processing.spectra import DEFAULT_GRID, Spectra

log = logging.getLogger(__name__)

AravisFakeNominalCamera = "NikonD100"
"""ISETCam camera whose responsivities the ``aravis-fake`` rig's test-pattern form (``rendered=False``,
the capture bench's) records as *nominal* (test patterns have no spectral meaning; the flash solvers
need some camera model). The rendered form records the world's own responsivities."""

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
    led_spectra: LedFiles | Spectra | None = None,
    flash_power: float | None = None,
    patch_px: int | None = None,
    lost_packet_ratio: float = 0.0,
    camera_options: Any = None,
    fake_camera: str = "sfnc",
    flicker: MainsFlicker | None = None,
) -> Rig:
    """The ``aravis-fake`` rig: AravisCamera on the GigE fake at 127.0.0.1 + emulator on a pty + LedBooth.

    The fake is this process's own (docs/architecture.md §4): a GVCP port another program holds is
    refused, and the camera opened at 127.0.0.1 must report the fake's serial and model.

    ``fake_camera``: the fake's camera model (:data:`~acquisition.devices.aravis.fake_models.FAKE_MODELS`:
    how it names its gain; rendered frames get the gain its sensor truly applies).
    ``camera_options``: :class:`~acquisition.devices.aravis.camera_features.CameraOptions` (``--gain``,
    ``--gain-raw``, ``--feature``), applied and checked as on the hardware rig before any frame.

    ``rendered`` (the default): the frames are the ``sim`` rig's world (options as for :func:`open_sim_rig`;
    patches ``patch_px`` wide) rendered by :class:`WiredFakeCamera` into the fake's frames, in
    :data:`ARAVIS_FAKE_PIXEL_FORMAT` with the ROI the scene's size (``width``/``height`` None or equal to it),
    recorded as the ``sim`` rig records it (docs/rigs.md). ``rendered`` False: the fake's test patterns (Mono16
    unless ``pixel_format`` says otherwise; a Bayer format is recorded as its mosaic), the paper's seven LEDs and :data:`AravisFakeNominalCamera` recorded as nominal (the capture bench).

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
        from msflash.acquisition.devices.aravis.camera_features import CameraOptions
        from msflash.acquisition.devices.aravis.fake_models import FAKE_MODELS
    except ImportError as err:
        raise RigOpenError(f"rig 'aravis-fake': {err}") from err
    model = FAKE_MODELS.get(fake_camera)
    if model is None:
        raise UsageError(unknown_name("--fake-camera", fake_camera, FAKE_MODELS))
    world_options = (ambient, scene, seed, camera, n_leds, led_spectra, flash_power, patch_px, flicker)
    frames = _FakeFrames.of(rendered, world_options, width, height, pixel_format)
    closers: list = []
    opened, emulator, booth = _open_devices(
        model, serial, lost_packet_ratio, frames, camera_options or CameraOptions(), log_serial, closers
    )
    return _wired_rig(model, frames, opened, emulator, booth, closers)


def _open_devices(
    model: Any,
    serial: str,
    lost_packet_ratio: float,
    frames: _FakeFrames,
    camera_options: Any,
    log_serial: str | Path | None,
    closers: list,
) -> tuple[_OpenedFake, BoothEmulator, LedBooth]:
    """The fake's camera and the emulated booth, opened; both failures reported in one ``RigOpenError``.

    A ``CameraSettingError`` is bad input, not a device failure: raised as it is (one line, exit 2).
    """
    failures: dict[str, BaseException] = {}
    emulator = booth = opened = None
    try:
        opened = _open_fake_camera(model, serial, lost_packet_ratio, frames, camera_options, closers)
    except CameraSettingError:
        close_all(closers)
        raise
    except Exception as err:  # noqa: BLE001 - reported with the booth's failure, if any
        failures[f"camera GigE fake {serial} at 127.0.0.1"] = err
    try:
        emulator, booth = open_emulated_booth(frames.leds, log_serial, closers)
    except RigOpenError as err:
        failures["booth"] = err
    if failures:
        close_all(closers)
        listing = "; ".join(f"{device}: {err}" for device, err in failures.items())
        raise RigOpenError(f"rig 'aravis-fake': {listing}") from next(iter(failures.values()))
    assert opened is not None and emulator is not None and booth is not None
    return opened, emulator, booth


@dataclass(frozen=True)
class _FakeFrames:
    """What the fake's frames are: the rendered world (or the fake's test patterns), their size and format,
    and the LED spectra and responsivities the rig records."""

    world: SimulatedCamera | None
    width: int
    height: int
    pixel_format: str
    leds: Spectra
    responsivities: Spectra

    @classmethod
    def of(
        cls, rendered: bool, world_options: tuple, width: int | None, height: int | None, pixel_format: str | None
    ) -> _FakeFrames:
        """The ``sim`` world rendered into an RGGB mosaic the scene's size, or the fake's test patterns."""
        if not rendered:
            leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero")
            camera = datasets.isetcam_camera(AravisFakeNominalCamera).resample(DEFAULT_GRID, outside="zero")
            return cls(None, width or 64, height or 48, pixel_format or "Mono16", leds, camera)
        ambient, scene, seed, camera_name, n_leds, led_spectra, flash_power, patch_px, flicker = world_options
        world = sim_world(
            "aravis-fake",
            ambient,
            scene,
            "RGGB",
            seed,
            camera_name,
            n_leds,
            led_spectra,
            flash_power,
            ARAVIS_FAKE_PATCH_PX if patch_px is None else patch_px,
            flicker,
        )
        scene_height, scene_width = world.scene.shape
        if (width or scene_width, height or scene_height) != (scene_width, scene_height):
            raise UsageError(
                f"rig 'aravis-fake': ROI {width}x{height} but the scene is {scene_width}x{scene_height}; "
                "expected the scene's size (the rendered mosaic fills the ROI)"
            )
        pixel_format = pixel_format or ARAVIS_FAKE_PIXEL_FORMAT
        return cls(world, scene_width, scene_height, pixel_format, world.led_spectra, world.camera_responsivities)


@dataclass(frozen=True)
class _OpenedFake:
    fake: Any
    aravis: Any
    setup: Any


def _open_fake_camera(
    model: Any, serial: str, lost_packet_ratio: float, frames: _FakeFrames, options: Any, closers: list
) -> _OpenedFake:
    """The fake served on 127.0.0.1 and the camera opened on it, checked to be the rig's own, configured."""
    from msflash.acquisition.devices.aravis.camera import AravisCamera
    from msflash.acquisition.devices.aravis.camera_features import configure_camera
    from msflash.acquisition.devices.aravis.gv_fake import AravisGvFake

    if frames.world is not None:
        from msflash.acquisition.devices.aravis.fake_log import mute_unfilled_format_warning

        closers.append(mute_unfilled_format_warning())  # the pixels are rendered: its lines say nothing
    fake = AravisGvFake(
        serial=serial,
        genicam_xml=model.xml_path(),
        lost_packet_ratio=lost_packet_ratio,
        model=model.model,
        registers=model.registers,
    )
    fake.start()
    closers.append(fake.close)
    aravis = AravisCamera(fake.address, interfaces="gige")
    closers.append(aravis.close)
    opened = aravis.info
    if (opened.serial, opened.model) != (serial, model.model):
        raise RigOpenError(
            f"the camera at {fake.address} is {opened.vendor} {opened.model} serial {opened.serial}, not this "
            f"rig's fake ({model.model} serial {serial}): another program's GigE Vision camera answers there; "
            "expected the rig's own — stop the other fake"
        )
    aravis.set_pixel_format(frames.pixel_format)  # once the camera is known to be the rig's own
    aravis.set_roi(0, 0, frames.width, frames.height)
    setup = configure_camera(aravis, options, strobe=False)
    # What the format in force means (a --feature PixelFormat=… may have changed it): one the table lacks is
    # refused, and a rendered scene takes only its own mosaic's layout.
    opened = aravis.info
    camera_pixel_layout(opened)
    if frames.world is not None and opened.cfa != frames.world.sensor.cfa:
        raise CameraSettingError(
            f"aravis-fake: pixel format {opened.pixel_format} has CFA {opened.cfa}; expected "
            f"{frames.world.sensor.cfa}, the rendered mosaic's (e.g. {ARAVIS_FAKE_PIXEL_FORMAT})"
        )
    return _OpenedFake(fake, aravis, setup)


def _wired_rig(model: Any, frames: _FakeFrames, opened: _OpenedFake, emulator: Any, booth: Any, closers: list) -> Rig:
    """The rig: the fake's camera wired to the emulator (trigger line, rendered levels), with what it records."""
    fake, aravis, world = opened.fake, opened.aravis, frames.world
    line_errors: list[BaseException] = []
    wired = WiredFakeCamera(
        aravis, emulator, fake, line_errors, world=world, true_gain=lambda: model.true_gain(fake.read_register)
    )
    closers.insert(closers.index(aravis.close) + 1, wired.stop)  # before the AravisCamera and the fake are released
    emulator.on_trigger_out = line_callback(line_errors, "aravis-fake trigger line", wired.trigger_line)
    extra: dict = {"fake_camera": model.name, "gain": aravis.gain_record()}
    if not opened.setup.options.empty:
        extra["camera_options"] = opened.setup.to_dict()
    if world is None:
        nominal = f"nominal: ISETCam {AravisFakeNominalCamera}; the fake's test patterns have no spectral meaning"
        extra = {"responsivity_note": nominal, **extra}
    else:
        pixels = (
            f"the Aravis fake's frames, pixels rendered by {world.info.model} under the booth's LEDs "
            "at each frame's trigger"
        )
        extra = {"pixels": pixels, **extra}
    return Rig(
        "aravis-fake",
        wired,
        booth,
        frames.leds,
        frames.responsivities,
        world.true_ambient if world is not None else None,
        closers,
        emulator=emulator,
        line_errors=line_errors,
        camera_extra=extra,
        mono=world is None and sends_mono(wired.info),
    )
