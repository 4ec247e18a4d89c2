"""The ``sim`` rig's ready-made world: a chart, an ambient, an LED set and a camera, with the booth as bright as a
flash and an exposure scale that leaves room for it (:meth:`SimulatedCamera.default
<acquisition.devices.simulated_camera.SimulatedCamera.default>` renders it).

:func:`default_world` resolves each part onto one wavelength grid, scales the booth as a whole so the weakest LED
the camera sees gives ``flash_power`` × the ambient's mean camera signal (:func:`flash_power_scale`, from
:func:`led_signals`), and sets the scale (electrons per unit signal per µs) so that at the reference exposure the
ambient's brightest diffuse pixel reads its share of full scale with room for any one LED on top. Why the booth
is set by its weakest visible LED: docs/decisions/sim-flash-power.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from msflash.acquisition.errors import CameraError
from msflash.processing import datasets, lights
from msflash.processing.image_formation import (
    MixedIllumination,
    expected_response,
    exposure_for_peak,
    total_illumination,
)
from msflash.processing.scenes import Scene, chart_scene, mosaic_scene, white_reference_scene
from msflash.processing.sensor import SensorModel, machine_vision_sensor
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid

SIM_DEFAULT_CFA = "RGGB"
"""The ``sim`` rig's camera sends a raw RGGB mosaic, 12-bit (:func:`processing.sensor.machine_vision_sensor`),
as colour machine-vision cameras do; ``cfa=None`` asks for RGB frames, ``cfa=MONO`` a monochrome sensor."""
MONO = "mono"
"""``cfa`` of a monochrome sensor: no colour filter, ``Mono12`` frames of one value a pixel
(:func:`mono_responsivities`), as monochrome machine-vision cameras send."""


def mono_responsivities(responsivities: Spectra) -> Spectra:
    """The bare sensor of a colour camera: the sum of its R, G and B responsivities in each of the three channels.

    Without its colour filter array a pixel sees what its three filters passed between them (to the filters'
    overlap and their losses: a model, not a measured mono curve). The three channels are that one curve, as a
    sequence records a mono camera's responsivity (docs/architecture.md §6).
    """
    curve = responsivities.values.sum(axis=1, keepdims=True)
    name = responsivities.metadata.get("camera") or responsivities.source or "camera"
    mono = responsivities.replace(values=np.repeat(curve, 3, axis=1), source=f"{responsivities.source} (R+G+B, mono)")
    mono.metadata["camera"] = f"{name} mono"
    return mono


@dataclass(frozen=True)
class DefaultWorld:
    """What :func:`default_world` resolves: the constructor's arguments of a :class:`SimulatedCamera`."""

    scene: Scene
    ambient: Spectra
    led_spectra: Spectra
    """The booth's LEDs at full drive, scaled as a whole to ``flash_power``."""
    responsivities: Spectra
    sensor: SensorModel
    scale: float
    """Electrons per unit ``Σ r c i Δλ`` per microsecond."""
    camera_name: str
    seed: int
    """The mosaic scene's layout (and a camera's noise)."""
    reference_exposure_us: float
    """The exposure ``scale`` is set for."""
    second_ambient: Spectra | None = None
    ambient_map: np.ndarray | None = None
    mono: bool = False
    """A monochrome sensor (``cfa`` :data:`MONO`): ``responsivities`` one curve in R, G and B."""


def default_world(
    scene: Literal["chart110", "macbeth", "white"] | Scene | Spectra = "chart110",
    ambient: str | Spectra = "tungsten",
    cfa: str | None = SIM_DEFAULT_CFA,
    seed: int = 0,
    camera: str | Spectra = "NikonD100",
    n_leds: int = 7,
    led_spectra: Spectra | None = None,
    flash_power: float = 1.0,
    reference_exposure_us: float = 10_000.0,
    ambient_peak_fraction: float = 0.25,
    sensor: SensorModel | None = None,
    patch_px: int = 8,
    specular_strip_px: int = 4,
    grid: WavelengthGrid = DEFAULT_GRID,
    second_ambient: str | Spectra | None = None,
    ambient_map: np.ndarray | None = None,
) -> DefaultWorld:
    """The ``sim`` rig's world (by default the paper's 110-surface chart, tungsten, the paper's 7 LEDs and ISETCam's
    NikonD100 behind a 12-bit raw RGGB sensor, :func:`processing.sensor.machine_vision_sensor`).

    Parameters
    ----------
    scene
        ``"chart110"`` (the paper's 110 surfaces), ``"macbeth"``, ``"white"`` (a white reference filling the frame,
        for ``msflash calibrate leds --white``), a :class:`Scene`, or reflectances (a random mosaic of those
        surfaces drawn with ``seed``, :func:`processing.scenes.mosaic_scene`).
    ambient, camera
        A name (:func:`processing.lights.light_spectrum`; :func:`processing.datasets.camera_responsivities`) or
        a spectrum (R, G, B responsivities) covering ``grid``.
    cfa
        The raw mosaic's Bayer layout (default :data:`SIM_DEFAULT_CFA`), None for RGB frames, or :data:`MONO` for
        a monochrome sensor (``camera``'s bare sensor, :func:`mono_responsivities`).
    n_leds, led_spectra
        The paper's LED subset (3–7), or the booth's LEDs (one spectrum per channel covering ``grid``; their
        ratios are kept, their power set by ``flash_power``).
    flash_power
        The weakest LED the camera sees (:data:`VISIBLE_LED_FRACTION`) gives exactly ``flash_power`` × the
        ambient's mean camera signal over the diffuse scene, every other one at least that
        (:func:`flash_power_scale`; the booth is scaled as a whole).
    reference_exposure_us, ambient_peak_fraction
        At ``reference_exposure_us`` and gain 1 the brightest diffuse pixel under the ambient alone reads
        ``ambient_peak_fraction`` of full scale, or less if the ambient plus the brightest LED at full drive would
        then read more than :data:`FLASH_PEAK_FRACTION` (room for the flash, for captures at one exposure).
    specular_strip_px
        The height of a saturating highlight strip under the chart (0: none).
    second_ambient, ambient_map
        A second ambient (name or spectrum) and the (H, W) map in [0, 1] of its share at each pixel (see
        :class:`SimulatedCamera`); LED power and exposure are then set on the mixed ambient.
    """
    scene = _scene_on_grid(scene, seed, patch_px, specular_strip_px, grid)
    ambient_spd = lights.light_spectrum(ambient, grid) if isinstance(ambient, str) else ambient.resample(grid)
    second_spd = _second_ambient(second_ambient, ambient_spd, ambient_map, grid)
    metered_ambient = ambient_spd if second_spd is None or ambient_map is None else (
        MixedIllumination.two_ambients(ambient_spd, second_spd, ambient_map)
    )  # fmt: skip
    leds = (datasets.paper_led_subset(n_leds) if led_spectra is None else led_spectra).resample(grid)
    responsivities = (datasets.camera_responsivities(camera) if isinstance(camera, str) else camera).resample(grid)
    mono = cfa == MONO
    if mono:
        responsivities, cfa = mono_responsivities(responsivities), None
    sensor = sensor if sensor is not None else machine_vision_sensor(cfa)
    if cfa is not None and sensor.cfa != cfa:
        raise CameraError(f"simulated camera: cfa '{cfa}' but the sensor model has '{sensor.cfa}'; expected one")
    # LED power relative to the ambient, measured the way the camera sees it (mean signal over
    # the diffuse scene), so it holds whatever the ambient's spectrum.
    diffuse = Scene(scene.reflectances, scene.labels, scene.shading)
    booth = leds.replace(
        values=leds.values * flash_power_scale(diffuse, metered_ambient, leds, responsivities, flash_power)
    )
    camera_name = responsivities.metadata.get("camera") or (
        camera if isinstance(camera, str) else responsivities.source
    )
    exposure = _exposure_at_unit_scale(scene, ambient_spd, metered_ambient, booth, responsivities, sensor,
                                       ambient_peak_fraction)  # fmt: skip
    scale = exposure / reference_exposure_us
    return DefaultWorld(
        scene, ambient_spd, booth, responsivities, sensor, scale, str(camera_name), seed, reference_exposure_us,
        second_spd, ambient_map, mono,
    )  # fmt: skip


def _scene_on_grid(
    scene: Literal["chart110", "macbeth", "white"] | Scene | Spectra,
    seed: int,
    patch_px: int,
    specular_strip_px: int,
    grid: WavelengthGrid,
) -> Scene:
    """``scene`` by name (``white``, a chart), as a mosaic of reflectances, or as given; on ``grid``."""
    if scene == "white":
        scene = white_reference_scene()
    elif isinstance(scene, str):
        scene = chart_scene(scene, patch_px=patch_px, specular_strip_px=specular_strip_px)
    elif isinstance(scene, Spectra):
        scene = mosaic_scene(scene, seed=seed, patch_px=patch_px, specular_strip_px=specular_strip_px)
    return Scene(scene.reflectances.resample(grid), scene.labels, scene.shading, scene.specular, scene.specular_gain)


def _second_ambient(
    second_ambient: str | Spectra | None, ambient: Spectra, ambient_map: np.ndarray | None, grid: WavelengthGrid
) -> Spectra | None:
    """The second ambient on ``grid`` in the first's unit, or None; refused without its map (or a map without it)."""
    second = None
    if second_ambient is not None:
        second = (
            lights.light_spectrum(second_ambient, grid)
            if isinstance(second_ambient, str)
            else second_ambient.resample(grid)
        ).to_unit(ambient.unit)
    if (second is None) != (ambient_map is None):
        raise CameraError("simulated camera: second_ambient and ambient_map go together; expected both or neither")
    return second


def _exposure_at_unit_scale(
    scene: Scene,
    ambient: Spectra,
    metered_ambient: Spectra | MixedIllumination,
    booth: Spectra,
    responsivities: Spectra,
    sensor: SensorModel,
    ambient_peak_fraction: float,
) -> float:
    """The exposure (at scale 1) giving the ambient's brightest diffuse pixel ``ambient_peak_fraction`` of full scale,
    or less where the ambient plus one LED at full drive would read more than :data:`FLASH_PEAK_FRACTION`."""
    dark = ambient.replace(values=np.zeros_like(ambient.values))
    return min(
        exposure_for_peak(scene, metered_ambient, responsivities, sensor, ambient_peak_fraction),
        *(
            exposure_for_peak(
                scene,
                _plus(metered_ambient, total_illumination(dark, booth, on)),
                responsivities,
                sensor,
                FLASH_PEAK_FRACTION,
            )
            for on in np.eye(booth.count)
        ),
    )


VISIBLE_LED_FRACTION = 0.01
"""An LED giving less than this share of the strongest LED's camera signal is one the camera hardly
sees: it does not set the booth's power (raising the booth until it matched the ambient would blind
the camera in every other LED's frame)."""
FLASH_PEAK_FRACTION = 0.9
"""At the sim's reference exposure, the ambient plus any one LED at full drive reads at most this share of full scale."""


def _plus(ambient: Spectra | MixedIllumination, light: Spectra) -> Spectra | MixedIllumination:
    """An ambient (uniform or spatially varying) plus a uniform light."""
    if isinstance(ambient, MixedIllumination):
        return ambient.plus(light)
    return ambient.replace(values=ambient.values + light.to_unit(ambient.unit).values)


def led_signals(
    scene: Scene, ambient: Spectra | MixedIllumination, led_spectra: Spectra, camera_responsivities: Spectra
) -> np.ndarray:
    """Each LED's mean camera signal at full drive over ``scene`` (all pixels and channels), in units of the ambient's.

    Raises
    ------
    CameraError
        If the ambient gives no signal in this camera.
    """
    ambient_signal = float(np.mean(expected_response(scene, ambient, camera_responsivities, 1.0)))
    if ambient_signal <= 0:
        raise CameraError(
            "simulated camera: the ambient gives no signal in this camera; expected light within the "
            "camera's sensitivity"
        )
    spd = led_spectra.to_unit("photons")
    dark = spd.replace(values=np.zeros((spd.grid.size, 1)), names=("dark",))
    return (
        np.array(
            [
                float(np.mean(expected_response(scene, total_illumination(dark, spd, on), camera_responsivities, 1.0)))
                for on in np.eye(spd.count)
            ]
        )
        / ambient_signal
    )


def flash_power_scale(
    scene: Scene,
    ambient: Spectra | MixedIllumination,
    led_spectra: Spectra,
    camera_responsivities: Spectra,
    flash_power: float = 1.0,
) -> float:
    """The factor on ``led_spectra`` making the weakest LED the camera sees give ``flash_power`` × the ambient.

    Signals are :func:`led_signals` (mean over ``scene``, all channels); LEDs below
    :data:`VISIBLE_LED_FRACTION` of the strongest do not count. One factor for the whole booth,
    so the LEDs keep their ratios and every LED the camera sees gives at least ``flash_power`` ×
    the ambient.

    Raises
    ------
    CameraError
        If ``flash_power`` is not a positive finite number, or the ambient or every LED gives no
        signal in this camera.
    """
    if not (np.isfinite(flash_power) and flash_power > 0):
        raise CameraError(
            f"simulated camera: flash power {flash_power}; expected a positive number (each LED's "
            "signal in units of the ambient's)"
        )
    signals = led_signals(scene, ambient, led_spectra, camera_responsivities)
    strongest = float(np.max(signals)) if signals.size else 0.0
    if strongest <= 0:
        raise CameraError(
            "simulated camera: the LEDs give no signal in this camera; expected light within the camera's sensitivity"
        )
    weakest = float(np.min(signals[signals >= VISIBLE_LED_FRACTION * strongest]))
    return flash_power / weakest
