"""A camera that renders a spectral scene: the ``sim`` rig's camera, with known ground truth.

:class:`SimulatedCamera` implements the :class:`~acquisition.devices.camera.Camera` protocol. Each frame
is rendered through :mod:`processing.image_formation` (eq. 1–3 of the paper, photon and read
noise, black level, saturation, optional Bayer mosaic) under the true ambient plus the LEDs at the
levels in force *at exposure time* — read from an injected ``led_levels_source`` (the booth
emulator in the ``sim`` rig) when the frame is triggered.

Triggering
----------
- ``plan.trigger == "software"`` or ``"camera"``: :meth:`SimulatedCamera.trigger` renders one frame.
- ``plan.trigger == "booth"``: :meth:`trigger` is a no-op, as the protocol says for cameras paced
  by a hardware line; the booth (emulator) pulses :meth:`SimulatedCamera.trigger_line` instead.

Frames are rendered synchronously and queued (:mod:`acquisition.devices.frame_queue`): :meth:`next_frame`
raises :class:`~acquisition.errors.FrameTimeoutError` at once when no trigger can be on its way, and a frame
that cannot be made (bad LED levels, a render error) is queued as its error, raised in the frame's place.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from msflash.acquisition.devices.camera import CameraInfo, RawFrame
from msflash.acquisition.devices.exposure_light import (
    AmbientModulation,
    ExposureLight,
    Shutter,
)
from msflash.acquisition.devices.frame_queue import TriggeredFrames
from msflash.acquisition.devices.image_format import ImageFormat, ImageFormatRequest, ImageLimits
from msflash.acquisition.devices.sim_default import default_world
from msflash.acquisition.devices.sim_readout import SimReadout
from msflash.acquisition.devices.sim_rendering import SimRendering
from msflash.acquisition.errors import CameraError
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.processing.image_formation import MixedIllumination
from msflash.processing.scenes import Scene
from msflash.processing.sensor import SensorModel
from msflash.processing.spectra import Spectra, require_same_grid

LedLevelsSource = Callable[[], Sequence[float]]
"""Returns the drive level (0–1) of every LED channel at the moment it is called."""


class SimulatedCamera(SimRendering, TriggeredFrames):
    """Renders ``scene`` under ``ambient`` + LEDs at the levels of ``led_levels_source``.

    Parameters
    ----------
    ambient
        The true ambient spectrum ``i_a`` (one spectrum; its scale is the ambient's power).
    led_spectra
        ``I``, (n_wavelengths, k): each LED at full drive, with the true ratios between LEDs.
    scale
        Electrons per unit ``Σ r c i Δλ`` per microsecond (see :mod:`processing.image_formation`).
    led_levels_source
        Called at each exposure for the LED levels; None uses each plan step's own levels.
    seed
        Frames are reproducible for a given seed and trigger order.
    frame_interval_ns
        Extra simulated time between frames, for timestamps (no real waiting happens).
    second_ambient, ambient_map
        A spatially varying ambient (issue 9): pixel ``x`` sees ``(1 − m(x)) · ambient +
        m(x) · second_ambient`` with ``m = ambient_map`` (H, W) in [0, 1] (a boundary, a
        gradient). Both None (the default) keep the single uniform ambient.
    mono
        A monochrome sensor: no CFA (``sensor.cfa`` None), ``camera_responsivities`` its one curve in all three
        channels; it sends ``Mono12`` (or ``Mono8``) frames of shape (H, W), as a monochrome machine-vision
        camera does (each rendered with its own noise: one channel of an RGB render).

    All spectra must share one grid (resample first); mismatches raise ``SpectralDataError``.
    """

    def __init__(
        self,
        scene: Scene,
        ambient: Spectra,
        led_spectra: Spectra,
        camera_responsivities: Spectra,
        sensor: SensorModel,
        scale: float = 1.0,
        led_levels_source: LedLevelsSource | None = None,
        seed: int = 0,
        noise: bool = True,
        name: str = "SimulatedCamera",
        frame_interval_ns: int = 2_000_000,
        second_ambient: Spectra | None = None,
        ambient_map: np.ndarray | None = None,
        mono: bool = False,
    ) -> None:
        require_same_grid(scene.reflectances, ambient, led_spectra, camera_responsivities)
        self.ambient_illumination: MixedIllumination | None = None
        """The spatially varying ambient, or None for a uniform one."""
        if (second_ambient is None) != (ambient_map is None):
            raise CameraError(
                f"simulated camera '{name}': second_ambient and ambient_map go together; expected both or neither"
            )
        if second_ambient is not None and ambient_map is not None:
            require_same_grid(ambient, second_ambient)
            if np.shape(ambient_map) != scene.shape:
                raise CameraError(
                    f"simulated camera '{name}': ambient_map has shape {np.shape(ambient_map)}; "
                    f"expected the scene's {scene.shape}"
                )
            self.ambient_illumination = MixedIllumination.two_ambients(ambient, second_ambient, ambient_map)
        if camera_responsivities.count != 3:
            raise CameraError(f"simulated camera '{name}': {camera_responsivities.count} channels; expected R, G, B")
        if mono and (sensor.cfa is not None or np.ptp(camera_responsivities.values, axis=1).any()):
            raise CameraError(
                f"simulated camera '{name}': a mono sensor with CFA {sensor.cfa} or unlike channels; expected no CFA "
                "and one responsivity curve in R, G and B"
            )
        self.mono = mono
        self.scene = scene
        self.ambient = ambient
        self.led_spectra = led_spectra
        self.camera_responsivities = camera_responsivities
        self.sensor = sensor
        self.scale = float(scale)
        self.led_levels_source = led_levels_source
        """Called at exposure time for the LED levels; may be set after construction (rig wiring)."""
        self.noise = noise
        self.seed = seed
        self.suggested_exposure_us: float | None = None
        """An exposure that suits this world (set by :meth:`default`), or None."""
        super().__init__()
        self._name = name
        self._label = f"simulated camera '{name}'"
        self._rng = np.random.default_rng(seed)
        self._frame_interval_ns = int(frame_interval_ns)
        self._render_lock = threading.Lock()
        self._next_step = 0
        self._frame_id = 0
        self._clock_ns = 0
        self._rendered_levels: list[tuple[float, ...]] = []
        self.exposure_light: ExposureLight | None = None
        """Light over time (the booth's drive, :mod:`acquisition.devices.exposure_light`): when set,
        every row integrates it over its own exposure window instead of taking constant levels."""
        self.shutter = Shutter()
        """Trigger latency and rolling-shutter line time (used with :attr:`exposure_light`)."""
        self.ambient_modulation: AmbientModulation | None = None
        """The ambient's intensity over time, integrated per row (None: steady); e.g. mains flicker
        (:class:`acquisition.devices.mains_flicker.MainsFlicker`). Frames are then dated by their exposure's
        start on the light's clock."""
        self.true_ambient_gains: list[float] = []
        """The ambient's relative intensity in each frame rendered so far (its mean over rows; 1 when steady)."""
        self._free_end_s = 0.0
        self._pacing_rng = np.random.default_rng([seed, 0x0F11C7E5, 1])
        self._latency_rng = np.random.default_rng(seed + 7919)
        self.readout = SimReadout(scene.shape, sensor.cfa, sensor.bit_depth, mono=mono)
        """Binning, ROI and pixel format applied to each rendered frame (:mod:`acquisition.devices.sim_readout`)."""

    # -- ground truth and identity ------------------------------------------------------------
    @property
    def true_ambient(self) -> Spectra:
        """The ambient spectrum the frames are rendered under (ground truth for reports)."""
        return self.ambient

    @property
    def rendered_levels(self) -> tuple[tuple[float, ...], ...]:
        """The LED levels used for each frame rendered so far, in order."""
        with self._condition:
            return tuple(self._rendered_levels)

    @property
    def info(self) -> CameraInfo:
        """Identity and pixel encoding as read out now; ``extra`` names the ground-truth spectra."""
        image = self.readout.format
        black, white = self.readout.levels(self.sensor.black_level, self.sensor.white_level)
        return CameraInfo(
            vendor="msflash",
            model=self._name,
            serial=f"SIM-{self.seed}",
            pixel_format=image.pixel_format,
            cfa=self.sensor.cfa,
            black_level=black,
            white_level=white,
            width=image.roi[2],
            height=image.roi[3],
            extra={
                "simulated": True,
                "bit_depth": self.readout.out_bits,
                "ambient": self.ambient.source,
                "leds": self.led_spectra.names,
                "responsivity": self.camera_responsivities.source,
                **({"binning": list(image.binning)} if image.binning != (1, 1) else {}),
            },
        )

    # -- the image format, between acquisitions ------------------------------------------------
    @property
    def image_format(self) -> ImageFormat:
        """ROI, binning and pixel format in force."""
        return self.readout.format

    def image_limits(self) -> ImageLimits:
        """What this camera allows now (:class:`~acquisition.devices.sim_readout.SimReadout`'s rules)."""
        return self.readout.limits(self._label)

    def set_image_format(self, request: ImageFormatRequest) -> ImageFormat:
        """Stop streaming and take ``request``; ``CameraSettingError`` (nothing changed) for what the twin refuses.

        Frames queued before are dropped (their size is the old one); the next ``prepare`` starts afresh.
        """
        self._check_open()
        readout = self.readout.applied(request, self._label)
        with self._condition:
            self._started = False
            self._queue.clear()
            self.readout = readout
        return readout.format

    # -- the Camera protocol ------------------------------------------------------------------
    def prepare(self, plan: CapturePlan) -> None:
        """Take the steps' exposures and gains from ``plan``; the next trigger renders step 0."""
        self._check_open()
        if not plan.steps:
            raise CameraError(f"simulated camera '{self._name}': empty capture plan; expected at least one step")
        if plan.n_leds != self.led_spectra.count:
            raise CameraError(
                f"simulated camera '{self._name}': plan drives {plan.n_leds} LEDs but the world has "
                f"{self.led_spectra.count} ({', '.join(self.led_spectra.names)}); expected the same count"
            )
        for step in plan.steps:
            if not (step.exposure_us >= 0 and step.gain > 0):
                raise CameraError(
                    f"simulated camera '{self._name}': step {step.index} ({step.label}) has exposure "
                    f"{step.exposure_us} µs and gain {step.gain}; expected exposure ≥ 0 and gain > 0"
                )
        with self._condition:
            self._plan = plan
            self._next_step = 0
            self._queue.clear()

    def start(self) -> None:
        """Start acquisition; frames queued before are dropped."""
        self._check_open()
        if self._plan is None:
            raise CameraError(f"simulated camera '{self._name}': start() before prepare(plan); expected a plan")
        with self._condition:
            self._queue.clear()
            self._started = True

    def trigger(self) -> None:
        """Render the next step's frame (software/camera triggering); a no-op when the booth triggers."""
        plan = self._require_started()
        if plan.trigger == "booth":
            return
        self._render_next(plan)

    def trigger_line(self) -> None:
        """The hardware trigger input: render the next step's frame whatever the trigger mode.

        The booth emulator calls this when it pulses the camera's trigger line (booth master).
        """
        self._render_next(self._require_started())

    # -- internals ----------------------------------------------------------------------------
    def _timeout_message(self, timeout_s: float, why: str) -> str:
        plan = self._plan
        if plan is not None and self._next_step < len(plan.steps):
            step = plan.steps[self._next_step]
            where = f"step {step.index} ({step.label})"
        else:
            where = "after the last step"
        return (
            f"simulated camera '{self._name}': no frame within {timeout_s:g} s for {where}: {why}; "
            "expected trigger() (or the booth's trigger line) before next_frame()"
        )

    def _levels_for(self, step: CaptureStep) -> tuple[float, ...]:
        """The LED levels at exposure time: from the injected source, else the plan step."""
        raw = self.led_levels_source() if self.led_levels_source is not None else step.led_levels
        return self._checked_levels(raw, f"step {step.index} ({step.label})")

    def _checked_levels(self, raw: object, where: str) -> tuple[float, ...]:
        """``raw`` as one float per LED in [0, 1]; a ``CameraError`` naming ``where`` otherwise."""
        try:
            levels = tuple(float(v) for v in raw)  # type: ignore[attr-defined]
        except (TypeError, ValueError) as err:
            raise CameraError(
                f"simulated camera '{self._name}': LED levels {raw!r} are not numbers; "
                "expected a tuple of floats in [0, 1]"
            ) from err
        if len(levels) != self.led_spectra.count or not all(0.0 <= v <= 1.0 for v in levels):
            raise CameraError(
                f"simulated camera '{self._name}': LED levels {levels} at {where}; "
                f"expected {self.led_spectra.count} values in [0, 1]"
            )
        return levels

    def render(
        self, levels: Sequence[float], exposure_us: float, gain: float, start_s: float | None = None
    ) -> np.ndarray:
        """One frame of this world under the LEDs at ``levels`` (0–1 each), exposed ``exposure_us`` at linear
        ``gain``: the one renderer of the simulated world (:meth:`trigger` and the ``aravis-fake`` rig's
        :class:`acquisition.devices.wired_fake.WiredFakeCamera` use it), reproducible for a seed and render order.

        Parameters
        ----------
        start_s
            Under a modulated ambient (mains flicker), the exposure's start on the light's clock: a camera's own
            timestamp (the ``aravis-fake`` rig's), so the lamp keeps the time the frames are stamped with. None:
            host pacing's simulated clock (:meth:`_mains_start`).

        Returns
        -------
        numpy.ndarray
            Raw values as :attr:`readout` delivers them (the sensor model's, binned, cut to the ROI, in the
            pixel format): (H, W) for a mosaic, else (H, W, 3).

        Raises
        ------
        CameraError
            Levels that are not one number in [0, 1] per LED, or an exposure < 0 or gain ≤ 0.
        """
        checked = self._checked_levels(levels, f"exposure {exposure_us:g} µs")
        if not (exposure_us >= 0 and gain > 0):
            raise CameraError(
                f"simulated camera '{self._name}': exposure {exposure_us} µs and gain {gain}; "
                "expected exposure ≥ 0 and gain > 0"
            )
        with self._render_lock:
            if self.ambient_modulation is not None:
                return self.readout.read(
                    self._render_free_running(checked, float(exposure_us), float(gain), start_s)[0]
                )
            return self.readout.read(self._render(checked, float(exposure_us), float(gain)))

    def _render_next(self, plan: CapturePlan) -> None:
        with self._condition:
            if self._next_step >= len(plan.steps):
                raise CameraError(
                    f"simulated camera '{self._name}': trigger {self._next_step + 1} but the plan has "
                    f"{len(plan.steps)} steps; expected one trigger per step"
                )
            step = plan.steps[self._next_step]
            self._next_step += 1
            self._begin_frame()
        with self._render_lock:  # one render at a time keeps the noise stream in trigger order
            try:
                start_s: float | None = None
                if self.exposure_light is not None:
                    levels, pixels, start_s = self._render_exposed(step, hardware_trigger=plan.trigger == "booth")
                elif self.ambient_modulation is not None:
                    levels = self._levels_for(step)
                    pixels, start_s = self._render_free_running(levels, step.exposure_us, step.gain)
                else:
                    levels = self._levels_for(step)
                    pixels = self._render(levels, step.exposure_us, step.gain)
                with self._condition:
                    self._frame_id += 1
                    self._clock_ns += int(step.exposure_us * 1000) + self._frame_interval_ns
                    # Under a modulated ambient the timestamp is the exposure's start on the light's clock, as a
                    # camera's own clock dates its exposures (what the flicker fit reads).
                    stamp = self._clock_ns if start_s is None else int(round(start_s * 1e9))
                    frame = RawFrame(self.readout.read(pixels), self._frame_id, stamp, step.exposure_us, step.gain)
                    self._rendered_levels.append(levels)
            except BaseException as err:
                # next_frame raises it in this frame's place: on the booth's trigger line nobody else
                # would see it, and the capture would report a lost frame instead of the cause.
                self._fail_frame(err)
                raise
            # Delivered under the render lock, so frames queue in trigger order.
            self._end_frame(frame)

    # -- a ready-made world -------------------------------------------------------------------
    @classmethod
    def default(
        cls, led_levels_source: LedLevelsSource | None = None, noise: bool = True, **world: Any
    ) -> SimulatedCamera:
        """The ``sim`` rig's world (:func:`~acquisition.devices.sim_default.default_world` of the keywords
        ``world``) rendered by this camera; its ``seed`` also seeds the noise, ``led_levels_source`` and ``noise``
        are the constructor's, and ``suggested_exposure_us`` is set to its ``reference_exposure_us``."""
        made = default_world(**world)
        simulated = cls(
            made.scene,
            made.ambient,
            made.led_spectra,
            made.responsivities,
            made.sensor,
            scale=made.scale,
            led_levels_source=led_levels_source,
            seed=made.seed,
            noise=noise,
            name=f"SimulatedCamera ({made.camera_name})",
            second_ambient=made.second_ambient,
            ambient_map=made.ambient_map,
            mono=made.mono,
        )
        simulated.suggested_exposure_us = made.reference_exposure_us
        return simulated
