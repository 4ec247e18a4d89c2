"""Shared builders for the processing and CLI tests (not fixtures: plain, cached functions).

Everything is small (a chart of ~50×56 pixels, 7 LEDs, 31 wavelengths) so a whole test module
runs in a fraction of a second.
"""

from __future__ import annotations

import json
import math
import subprocess
import time
from collections.abc import Callable, Sequence
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.acquisition.session.analysis import DEFAULT_BIN_FACTOR, FrameStack, block_factor
from msflash.acquisition.session.estimate_stream import SAMPLE_WEIGHTING
from msflash.led_controller import protocol
from msflash.processing import datasets, lights
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.image_formation import expected_response, exposure_for_peak, render_frame
from msflash.processing.scenes import Scene, chart_scene
from msflash.processing.sensor import SensorModel, mosaic
from msflash.processing.spectra import DEFAULT_GRID, Spectra
from msflash.processing.statistics import FrameStackSpec, SequenceStatistics

GRID = DEFAULT_GRID
CAMERA_NAME = "NikonD100"
SAMPLES_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "samples"
"""The two independent sample sequences (/work/shared/samples)."""

# One tolerance per kind of check (colour-science style).
EXACT = 1e-9
"""Algebraic identities computed two ways in float64 (relative)."""
WEIGHTS_EXACT = 1e-6
"""Weights recovered from noise-free float64 frames."""
WEIGHTS_QUANTISED = 2e-3
"""Weights recovered from noise-free but 16-bit-quantised rendered frames (±0.5 DN on ~10⁴ DN)."""
WEIGHTS_ILL_POSED = 1e-4
"""Weights of an ambient outside the LEDs' span computed two ways: they are large and of mixed sign
(the unscaled Gram matrix has a condition number ~1e10), so round-off is amplified; the fitted
*image* still agrees to :data:`WEIGHTS_EXACT`."""
FLOAT32 = 1e-5
"""Results delivered as float32 images (relative to the image's peak)."""
SOLVER = 1e-7
"""Optimality / feasibility of the small QP solver (relative to the problem's scale)."""


@cache
def leds() -> Spectra:
    """The paper's 7 LEDs on the default grid, energy units."""
    return datasets.paper_leds().resample(GRID, outside="zero")


@cache
def leds_photons() -> Spectra:
    """The paper's 7 LEDs on the default grid, photons (the processing unit)."""
    return leds().to_unit("photons")


@cache
def camera(name: str = CAMERA_NAME) -> Spectra:
    """An ISETCam camera's responsivities on the default grid, photons."""
    return datasets.isetcam_camera(name).resample(GRID, outside="zero").to_unit("photons")


@cache
def chart(specular_strip_px: int = 0) -> Scene:
    """The paper's 110-patch chart, 4-pixel patches (51×56 pixels, plus an optional specular strip)."""
    return chart_scene("chart110", patch_px=4, border_px=1, specular_strip_px=specular_strip_px)


def photons_spd(values: np.ndarray, name: str = "ambient") -> Spectra:
    """One SPD in photons on the default grid."""
    return Spectra(GRID, np.asarray(values, dtype=float), (name,), kind="spd", unit="photons", source=name)


def led_mix(weights: Sequence[float], led_spectra: Spectra | None = None) -> Spectra:
    """The SPD ``I w`` (photons) of a mix of LEDs."""
    spectra = leds_photons() if led_spectra is None else led_spectra
    return photons_spd(spectra.values @ np.asarray(weights, dtype=float), "LED mix")


def ambient(name: str = "tungsten") -> Spectra:
    """A shipped ambient in photons, peak-normalised in photons."""
    spd = lights.ambient_spectrum(name, GRID).to_unit("photons")
    return spd.replace(values=spd.values / spd.values.max())


def one_hot_levels(k: int) -> np.ndarray:
    """One frame per LED, each at full drive."""
    return np.eye(k)


def illumination(ambient_spd: Spectra, led_spectra: Spectra, levels: Sequence[float]) -> Spectra:
    """Ambient plus LEDs at ``levels``, photons."""
    return photons_spd(
        ambient_spd.to_unit("photons").values[:, 0] + led_spectra.values @ np.asarray(levels, float), "illumination"
    )


def linear_frames(
    ambient_spd: Spectra,
    *,
    led_spectra: Spectra | None = None,
    levels: np.ndarray | None = None,
    scene: Scene | None = None,
    cam: Spectra | None = None,
    exposures: Sequence[float] | None = None,
    gains: Sequence[float] | None = None,
    black: float = 0.0,
    cfa: str | None = None,
) -> tuple[np.ndarray, list[np.ndarray], FrameStackSpec]:
    """Noise-free float64 frames ``black + exposure·gain·m`` (no quantisation, no clipping).

    Returns the ambient frame, the LED frames (ambient + LEDs at each row of ``levels``) and the
    matching spec (white level far above every value).
    """
    led_spectra = leds_photons() if led_spectra is None else led_spectra
    k = led_spectra.count
    levels = one_hot_levels(k) if levels is None else np.asarray(levels, dtype=float)
    scene = chart() if scene is None else scene
    cam = camera() if cam is None else cam
    n = levels.shape[0] + 1
    exposures = [1.0] * n if exposures is None else list(exposures)
    gains = [1.0] * n if gains is None else list(gains)
    illuminants = [ambient_spd] + [illumination(ambient_spd, led_spectra, row) for row in levels]
    frames = []
    for spd, exposure, gain in zip(illuminants, exposures, gains, strict=True):
        frame = expected_response(scene, spd, cam, exposure_us=exposure, gain=gain) + black
        frames.append(mosaic(frame, cfa) if cfa else frame)
    spec = FrameStackSpec(
        black_level=black,
        white_level=1e30,
        ambient_scale=1.0 / (exposures[0] * gains[0]),
        led_scales=tuple(1.0 / (e * g) for e, g in zip(exposures[1:], gains[1:])),
        led_levels=levels,
    )
    return frames[0], frames[1:], spec


def rendered_frames(
    ambient_spd: Spectra,
    *,
    led_spectra: Spectra | None = None,
    scene: Scene | None = None,
    cam: Spectra | None = None,
    sensor: SensorModel | None = None,
    noise: bool = False,
    seed: int = 0,
    peak_fraction: float = 0.9,
    gains: Sequence[float] | None = None,
) -> tuple[np.ndarray, list[np.ndarray], list[float], list[float]]:
    """Integer frames through :func:`render_frame`: ambient then one frame per LED at full drive.

    Each frame's exposure puts its brightest chart pixel at ``peak_fraction`` of full scale
    (so exposures differ frame to frame). Returns frames and their exposures and gains.
    """
    led_spectra = leds_photons() if led_spectra is None else led_spectra
    scene = chart() if scene is None else scene
    cam = camera() if cam is None else cam
    sensor = SensorModel() if sensor is None else sensor
    k = led_spectra.count
    gains = [1.0] * (k + 1) if gains is None else list(gains)
    rng = np.random.default_rng(seed)
    illuminants = [ambient_spd] + [illumination(ambient_spd, led_spectra, row) for row in one_hot_levels(k)]
    frames, exposures = [], []
    for spd, gain in zip(illuminants, gains, strict=True):
        exposure = exposure_for_peak(scene, spd, cam, sensor, peak_fraction, gain=gain)
        frames.append(render_frame(scene, spd, cam, sensor, exposure, gain=gain, rng=rng, noise=noise))
        exposures.append(exposure)
    return frames[0], frames[1:], exposures, gains


def spec_for(
    sensor: SensorModel, exposures: Sequence[float], gains: Sequence[float], levels: np.ndarray
) -> FrameStackSpec:
    """The frame stack spec of rendered frames."""
    return FrameStackSpec(
        black_level=sensor.black_level,
        white_level=sensor.white_level,
        ambient_scale=1.0 / (exposures[0] * gains[0]),
        led_scales=tuple(1.0 / (e * g) for e, g in zip(exposures[1:], gains[1:])),
        led_levels=levels,
    )


def write_test_sequence(
    directory: Path,
    ambient_spd: Spectra | None = None,
    *,
    cfa: str | None = None,
    noise: bool = False,
    responsivity: bool = True,
    gains: Sequence[float] | None = None,
) -> Path:
    """A complete sequence (energy units, 7 paper LEDs, NikonD100) rendered into ``directory``."""
    ambient_spd = ambient("tungsten") if ambient_spd is None else ambient_spd
    sensor = SensorModel(cfa=cfa)
    ambient_frame, led_frames, exposures, gains = rendered_frames(ambient_spd, sensor=sensor, noise=noise, gains=gains)
    cam_energy = camera().to_unit("energy")
    seq_camera = SequenceCamera(
        model="test-render",
        serial=None,
        pixel_format="BayerRG16" if cfa else "RGB16",
        cfa=cfa,
        black_level=sensor.black_level,
        white_level=sensor.white_level,
        responsivity={c: cam_energy.column(c) for c in ("R", "G", "B")} if responsivity else None,
    )
    led_entries = [SequenceLed(name, leds().column(name)) for name in leds().names]
    k = len(led_entries)
    with SequenceWriter(
        directory, wavelengths_nm=GRID.wavelengths_nm, spectral_unit="energy", camera=seq_camera, leds=led_entries
    ) as writer:
        writer.add_frame(ambient_frame, "ambient", [0.0] * k, exposure_us=exposures[0], gain=gains[0])
        for index, frame in enumerate(led_frames):
            writer.add_frame(
                frame, "led", one_hot_levels(k)[index], exposure_us=exposures[index + 1], gain=gains[index + 1]
            )
    return directory


def rewrite_sequence(source: Path, target: Path, frame: Callable[[int, str, np.ndarray], np.ndarray]) -> Path:
    """The sequence at ``source`` written again by the project's writer to ``target``, each frame's pixels replaced by
    ``frame(index, role, pixels)`` (same camera, LEDs, levels, exposures and gains)."""
    sequence = read_sequence(source)
    with SequenceWriter(
        target,
        wavelengths_nm=sequence.wavelengths_nm,
        spectral_unit=sequence.spectral_unit,
        camera=sequence.camera,
        leds=sequence.leds,
    ) as writer:
        for index, entry in enumerate(sequence.frames):
            pixels = frame(index, entry.role, sequence.load_frame(index))
            writer.add_frame(pixels, entry.role, entry.led_levels, entry.exposure_us, entry.gain)
        writer.finish()
    return target


def direct_lstsq_weights(
    ambient_frame: np.ndarray, led_frames: Sequence[np.ndarray], spec: FrameStackSpec
) -> np.ndarray:
    """Least-squares fit of the linear ambient image by the linear LED-only images (all samples)."""
    a = (ambient_frame.astype(float) - spec.black_level) * spec.ambient_scale
    diffs = [(f.astype(float) - spec.black_level) * s - a for f, s in zip(led_frames, spec.led_scales)]
    stacked = np.stack([d.reshape(-1) for d in diffs])
    only = spec.unmixing @ stacked
    return np.linalg.lstsq(only.T, a.reshape(-1), rcond=None)[0]


def spectrum_rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """The paper's spectrum RMSE: estimate max-normalised, truth least-squares scaled onto it."""
    estimate = np.asarray(estimate, float) / np.max(estimate)
    truth = np.asarray(truth, float)
    scaled = truth * (truth @ estimate) / (truth @ truth)
    return float(np.sqrt(np.mean((estimate - scaled) ** 2)))


def wait_for_frames(process: subprocess.Popen[bytes], sequence_json: Path, n: int, timeout_s: float = 120.0) -> None:
    """Wait until a capture child has written ``n`` frames into ``sequence_json`` (fails the test if it ends first or times out)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            pytest.fail(
                f"capture ended (status {process.returncode}) before {n} frames: {process.stderr.read().decode()}"
            )
        try:
            if len(json.loads(sequence_json.read_text())["frames"]) >= n:
                return
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            pass
        time.sleep(0.01)
    process.kill()
    pytest.fail(f"no {n} frames in {sequence_json} within {timeout_s} s")


def forget_digests(directory: Path) -> None:
    """Drop every frame's ``sha256`` and ``file_bytes`` from ``directory``'s ``sequence.json``.

    The sequence then reads as one recorded before frame digests existed (or by another tool), so a
    test can replace a frame file to exercise the checks behind the digest (size, channels, levels).
    """
    path = directory / "sequence.json"
    document = json.loads(path.read_text())
    for frame in document["frames"]:
        frame.pop("sha256", None)
        frame.pop("file_bytes", None)
    path.write_text(json.dumps(document, indent=1))


class PipedLines:
    """A non-interactive stdin holding ``text``: what a pipe gives an interactive command (the booth console)."""

    def __init__(self, text: str) -> None:
        self._lines = text.splitlines(keepends=True)

    def isatty(self) -> bool:
        return False

    def readline(self) -> str:
        return self._lines.pop(0) if self._lines else ""


def levels_close(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether two level vectors agree to within one 16-bit wire step."""
    return len(a) == len(b) and all(math.isclose(x, y, abs_tol=1.0 / protocol.LEVEL_MAX) for x, y in zip(a, b))


def sequence_statistics(
    stack: FrameStack, cfa: str | None = None, bin_factor: int = DEFAULT_BIN_FACTOR
) -> SequenceStatistics:
    """The sufficient statistics of eq. 4–6 of a loaded frame stack in one call: the reference the streamed
    statistics (``EstimateStream``, what the product computes) are checked against."""
    return accumulate_statistics(
        stack.ambient,
        stack.led_frames,
        stack.spec,
        bin_factor=block_factor(stack.ambient.shape, cfa, bin_factor),
        cfa_period=2 if cfa is not None else 1,
        weighting=SAMPLE_WEIGHTING,
    )
