"""How the simulated camera renders a frame of its world: under constant light, under light that changes over the
exposure (each row integrates the booth's drive over its own window, a rolling shutter), and under a modulated
ambient (mains flicker) between host-paced frames.

:class:`SimRendering` is the renderer part of :class:`~acquisition.devices.simulated_camera.SimulatedCamera`
(a mixin over its state, declared here): every frame goes through :func:`processing.image_formation.render_frame`
(eq. 1–3 of the paper) with this camera's noise generator, one render at a time (the caller holds the render lock).
"""

from __future__ import annotations

import numpy as np

from msflash.acquisition.devices.exposure_light import (
    AmbientModulation,
    ExposureLight,
    ExposureRequest,
    RowLight,
    Shutter,
    ambient_over_rows,
)
from msflash.acquisition.errors import CameraError
from msflash.acquisition.plan import CaptureStep
from msflash.processing.image_formation import MixedIllumination, render_frame, total_illumination
from msflash.processing.scenes import Scene
from msflash.processing.sensor import SensorModel
from msflash.processing.spectra import Spectra

FREE_RUNNING_GAP_S = (0.015, 0.060)
"""From one frame's readout to the next exposure under a modulated ambient without a light over time: host pacing
(a serial command, a trigger) spaces frames by a few tens of ms, drawn from the seed (docs/flicker.md)."""


class SimRendering:
    """The frames of a simulated world (the state below is :class:`SimulatedCamera`'s, set by its constructor)."""

    scene: Scene
    ambient: Spectra
    led_spectra: Spectra
    camera_responsivities: Spectra
    sensor: SensorModel
    scale: float
    noise: bool
    ambient_illumination: MixedIllumination | None
    exposure_light: ExposureLight | None
    shutter: Shutter
    ambient_modulation: AmbientModulation | None
    true_ambient_gains: list[float]
    _name: str
    _rng: np.random.Generator
    _pacing_rng: np.random.Generator
    _latency_rng: np.random.Generator
    _free_end_s: float

    def _render(
        self, levels: tuple[float, ...], exposure_us: float, gain: float, ambient_gain: float = 1.0
    ) -> np.ndarray:
        """The frame under ``levels`` (checked), the ambient × ``ambient_gain``; the caller holds the render lock."""
        if self.ambient_illumination is not None and ambient_gain != 1.0:  # two ambients: scaled per pixel
            light = RowLight(0.0, np.broadcast_to(np.asarray(levels, dtype=float), (self.scene.shape[0], len(levels))))
            return self._render_rows(light, np.full(self.scene.shape[0], ambient_gain), exposure_us, gain)
        self.true_ambient_gains.append(ambient_gain)
        ambient = (
            self.ambient if ambient_gain == 1.0 else self.ambient.replace(values=self.ambient.values * ambient_gain)
        )
        illumination = total_illumination(ambient, self.led_spectra, levels)
        if self.ambient_illumination is not None:
            dark = self.ambient.replace(values=np.zeros_like(self.ambient.values))
            illumination = self.ambient_illumination.plus(total_illumination(dark, self.led_spectra, levels))  # type: ignore[assignment]
        return self._render_light(illumination, exposure_us, gain)

    def _render_light(self, illumination: Spectra | MixedIllumination, exposure_us: float, gain: float) -> np.ndarray:
        return render_frame(
            self.scene,
            illumination,
            self.camera_responsivities,
            self.sensor,
            exposure_us,
            gain,
            self.scale,
            rng=self._rng,
            noise=self.noise,
        )

    def _render_rows(self, light: RowLight, ambient: np.ndarray | None, exposure_us: float, gain: float) -> np.ndarray:
        """A frame whose row ``r`` saw the LEDs at ``light.led_levels[r]`` and the ambient × ``ambient[r]``.

        Rows that all saw the same light render as any frame does (:meth:`_render`); otherwise the
        illumination is a per-pixel mix of the ambient and each LED (light is additive).
        """
        rows = light.led_levels
        uniform_leds = bool(np.all(rows == rows[:1]))
        if uniform_leds and (
            ambient is None or (self.ambient_illumination is None and bool(np.all(ambient == ambient[0])))
        ):
            # One light for every row (a global shutter): the ambient scaled as a whole.
            return self._render(
                tuple(float(v) for v in rows[0]), exposure_us, gain, 1.0 if ambient is None else float(ambient[0])
            )
        self.true_ambient_gains.append(1.0 if ambient is None else float(np.mean(ambient)))
        height, width = self.scene.shape
        leds = self.led_spectra.to_unit("photons")
        if self.ambient_illumination is not None:
            base = self.ambient_illumination
            ambient_spectra, ambient_weights = base.spectra, base.weights
        else:
            ambient_spectra = self.ambient.to_unit("photons")
            ambient_weights = np.ones((height, width, 1))
        factor = np.ones(height) if ambient is None else ambient
        spectra = Spectra(
            ambient_spectra.grid,
            np.hstack([ambient_spectra.values, leds.values]),
            tuple(ambient_spectra.names) + tuple(leds.names),
            kind="spd",
            unit="photons",
            source=self.ambient.source,
        )
        led_weights = np.broadcast_to(rows[:, None, :], (height, width, leds.count))
        weights = np.concatenate([ambient_weights * factor[:, None, None], led_weights], axis=-1)
        return self._render_light(MixedIllumination(spectra, weights), exposure_us, gain)

    @property
    def readout_skew_us(self) -> float:
        """First row's start to the last row's (rolling shutter), µs; 0 for a global shutter."""
        return self.shutter.skew_us(self.scene.shape[0])

    def _render_exposed(
        self, step: CaptureStep, hardware_trigger: bool
    ) -> tuple[tuple[float, ...], np.ndarray, float | None]:
        """The frame of ``step`` under :attr:`exposure_light`; its mean levels (over rows), pixels, and the
        exposure's start on the modulated ambient's clock (s, :meth:`_mains_start`), or None when it is steady."""
        assert self.exposure_light is not None
        shutter = self.shutter
        request = ExposureRequest(
            exposure_us=float(step.exposure_us),
            rows=self.scene.shape[0],
            line_time_us=shutter.line_time_us,
            latency_us=shutter.latency_us + float(self._latency_rng.uniform(0.0, shutter.latency_jitter_us)),
            hardware_trigger=hardware_trigger,
        )
        light = self.exposure_light.expose(request)
        rows = np.asarray(light.led_levels, dtype=float)
        if rows.shape != (request.rows, self.led_spectra.count) or not np.all((rows >= 0) & (rows <= 1)):
            raise CameraError(
                f"simulated camera '{self._name}': exposure light gave levels of shape {rows.shape}; expected "
                f"({request.rows}, {self.led_spectra.count}) values in [0, 1]"
            )
        start = None
        ambient = None
        if self.ambient_modulation is not None:
            start = self._mains_start(step.exposure_us, request.skew_us * 1e-6)
            ambient = ambient_over_rows(self.ambient_modulation, RowLight(start, rows), request)
        mean = tuple(float(v) for v in rows.mean(axis=0))
        return mean, self._render_rows(light, ambient, step.exposure_us, step.gain), start

    def _mains_start(self, exposure_us: float, skew_s: float) -> float:
        """The next exposure's start on the modulated ambient's clock (s).

        Frames follow one another as host pacing spaces them, :data:`FREE_RUNNING_GAP_S` apart after the last
        one's readout, drawn from the seed: a run is reproducible, and a short exposure meets a mains flicker at
        an unrelated phase each frame (the mains keeps no time with the booth or the camera). The LEDs keep
        their own clock (:attr:`exposure_light`).
        """
        gap = float(self._pacing_rng.uniform(*FREE_RUNNING_GAP_S))
        start = self._free_end_s + self.shutter.readout_us * 1e-6 + gap
        self._free_end_s = start + skew_s + exposure_us * 1e-6
        return start

    def _render_free_running(
        self, levels: tuple[float, ...], exposure_us: float, gain: float, start_s: float | None = None
    ) -> tuple[np.ndarray, float]:
        """A frame under a modulated ambient without a light over time (:attr:`exposure_light` None): the pixels
        and the exposure's start (s) on the ambient's clock (:meth:`_mains_start`); every row sees the ambient's
        mean over its own window."""
        request = ExposureRequest(exposure_us, self.scene.shape[0], self.shutter.line_time_us, 0.0, False)
        start = self._mains_start(exposure_us, request.skew_us * 1e-6) if start_s is None else start_s
        light = RowLight(start, np.broadcast_to(np.asarray(levels, dtype=float), (request.rows, len(levels))))
        ambient = ambient_over_rows(self.ambient_modulation, light, request)
        return self._render_rows(light, ambient, exposure_us, gain), start
