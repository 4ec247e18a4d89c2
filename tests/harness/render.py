"""The harness's renderer: one :class:`HarnessCase` → a format-v1 sequence on disk and its truth.

Independent of msflash's simulator: reflectance × light × camera are integrated here on a 1-nm
grid (:data:`tests.harness.tables.FINE_NM`) from the measured tables of :mod:`tests.harness.tables`,
while the sequence carries its LED spectra and responsivities sampled on the case's own, coarser
grid — as a lab that measured them does. Frames get photon (Poisson) and read noise, a black level,
quantisation at the case's bit depth, clipping, optional cos⁴ vignetting (the same in every frame),
unequal exposures and gains, a specular strip that clips, and a Bayer mosaic for raw cases. Files
are written by :func:`tests.processing.unseen_sequences._write` (OpenImageIO, 16-bit TIFF).

The ambient is scaled so that on a white surface its signal is ``ratio`` times the mean single-LED
signal; every LED frame is the ambient plus one LED at full drive.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tests.harness import tables
from tests.processing.unseen_sequences import _cfa_index, _write

PATCH_PX = 16
"""Side of one surface patch in pixels."""
PATCH_ROWS, PATCH_COLUMNS = 8, 10
"""Patches per column and per row: frames are 128 × 160 pixels (+ a 6-pixel specular strip)."""
SPECULAR_GAIN = 2.5
"""The specular strip reflects the light itself at this multiple of a white surface (it clips)."""
TEXTURE = 0.05
"""Pixel-scale texture: each pixel's reflectance times 1 ± this (fixed pattern, every frame)."""
BASE_EXPOSURE_US = 10000.0
REFERENCE_PATCH_FILE = "reference_patch.json"
REFERENCE_CHART_FILE = "reference_chart.json"
"""Beside ``sequence.json``: the white card's rectangle (an unknown key would do, but a sidecar keeps the sequence
exactly what a user's would be)."""


@dataclass(frozen=True)
class HarnessCase:
    """One rendered sequence: its scene, camera, flash, light and capture conditions."""

    name: str
    split: str
    seed: int
    camera: str
    light: str
    """A library label (:func:`tests.harness.tables.lights`) or ``leds:w1,w2,…`` (a combination of the LEDs)."""
    light_type: str
    leds: str = "paper7"
    """An LED set of :func:`tests.harness.tables.led_set_names`."""
    cfa: str | None = None
    bits: int = 16
    black: int = 0
    grid: tuple[float, float, float] = (400.0, 700.0, 10.0)
    unit: str = "energy"
    ratio: float = 1.0
    """Ambient signal over the mean single-LED signal, on a white surface (all channels)."""
    exposures: str = "equal"
    """``equal`` or ``unequal`` (each frame its own exposure time and gain)."""
    vignetting: float = 1.0
    """Relative illumination in the frame's corners (cos⁴ falloff); 1 is none."""
    specular: bool = False
    peak: float = 0.8
    """Brightest diffuse sample of the brightest frame, as a fraction of the range above black."""
    full_well_e: float = 12000.0
    """Electrons at the white level at gain 1 (photon noise); ``inf`` for none."""
    read_noise_e: float = 4.0
    """Read noise in electrons (before the gain)."""
    surface_sets: tuple[str, ...] = ("munsell", "objects", "macbeth")
    n_surfaces: int = 40

    @property
    def mosaic(self) -> str:
        """``RGB`` or ``Bayer``."""
        return "RGB" if self.cfa is None else "Bayer"

    @property
    def led_count(self) -> int:
        """Number of LEDs in the flash."""
        return len(tables.led_set(self.leds).names)

    @property
    def grid_label(self) -> str:
        """The wavelength grid as ``start–stop/step``."""
        start, stop, step = self.grid
        return f"{start:g}–{stop:g}/{step:g}"


@dataclass(frozen=True)
class Truth:
    """What a rendered sequence was made from, in the sequence's spectral unit on its grid."""

    directory: Path
    wavelengths_nm: np.ndarray
    ambient: np.ndarray
    """The true ambient spectrum."""
    led_spd: np.ndarray
    """The LED spectra as written, (n, k)."""


def grid_nm(grid: tuple[float, float, float]) -> np.ndarray:
    """The wavelengths of a ``(start, stop, step)`` grid."""
    start, stop, step = grid
    return np.arange(start, stop + step / 2, step, dtype=float)


def _light_energy(case: HarnessCase, wavelengths: np.ndarray, led_energy: np.ndarray) -> np.ndarray:
    if case.light.startswith("physics:"):
        from tests.harness.physics_cases import light_of
        from tests.harness.physics_lights import on_grid

        fine = light_of(case).energy()
        # The rendering grid gets the 1-nm spectrum itself; a sequence's grid what a spectroradiometer of that
        # bandwidth reports (a narrow line between two samples is shared by both, not lost).
        return fine if np.array_equal(wavelengths, tables.FINE_NM) else on_grid(fine, wavelengths)
    if case.light.startswith("leds:"):
        return led_energy @ np.array([float(v) for v in case.light[5:].split(",")])
    return tables.lights().column(case.light).on(wavelengths)[:, 0]


def _surfaces(case: HarnessCase, rng: np.random.Generator) -> np.ndarray:
    """Reflectances on the fine grid, (fine, n_surfaces), drawn without replacement from the case's sets."""
    pool = tables.surfaces(tuple(case.surface_sets)).values
    chosen = rng.choice(pool.shape[1], size=min(case.n_surfaces, pool.shape[1]), replace=False)
    return np.clip(pool[:, chosen], 0.0, 1.0)


def _vignetting(height: int, width: int, corner: float) -> np.ndarray:
    """cos⁴ relative illumination, 1 at the centre and ``corner`` in the corners."""
    if corner >= 1.0:
        return np.ones((height, width))
    y, x = np.mgrid[0:height, 0:width]
    radius = np.hypot(y - (height - 1) / 2, x - (width - 1) / 2)
    focal = radius.max() / math.tan(math.acos(corner**0.25))
    return np.cos(np.arctan(radius / focal)) ** 4


@dataclass(frozen=True)
class CommonNoise:
    """Two renderings of one case that differ in the ambient's per-frame gain and in nothing else (common random
    numbers, for the flicker study's paired arms).

    Each frame's photon count is drawn once for the steady lamp (ambient gain 1), from a generator of its own
    (``seed``, frame index); a rendering whose ambient gain is larger adds Poisson(λ − λ₀) more photons (superposition),
    one whose gain is smaller keeps each photon with probability λ ÷ λ₀ (thinning), from a second generator. Both are
    exact Poisson(λ) draws, and at gain 1 the count is λ₀'s draw itself. The read-noise field is the same in both.
    DN per unit response is set from the frames at ``scale_gains`` (elementwise at least 1), so both arms share one
    camera scale instead of each being rescaled to its own brightest frame.
    """

    seed: int
    scale_gains: Sequence[float]


def _photons(lam: np.ndarray, steady_lam: np.ndarray, seed: int, index: int) -> tuple[np.ndarray, np.ndarray]:
    """Electrons at mean ``lam`` coupled to the draw at ``steady_lam`` (see :class:`CommonNoise`), and the frame's
    standard-normal read-noise field."""
    base = np.random.default_rng([seed, index])
    steady = base.poisson(steady_lam)
    read = base.standard_normal(lam.shape)
    extra = np.random.default_rng([seed, index, 1])
    added = steady + extra.poisson(np.maximum(lam - steady_lam, 0.0))
    ratio = np.divide(lam, steady_lam, out=np.ones_like(lam), where=steady_lam > 0)
    kept = extra.binomial(steady, np.clip(ratio, 0.0, 1.0))
    return np.where(lam >= steady_lam, added, kept), read


def render(
    case: HarnessCase,
    directory: Path,
    *,
    ambient_gains: Sequence[float] | None = None,
    exposures_us: Sequence[float] | None = None,
    frame_extra: Sequence[dict] | None = None,
    common_noise: CommonNoise | None = None,
) -> Truth:
    """Write ``case`` as a format-v1 sequence in ``directory`` (TIFF frames); return its truth.

    The keywords serve the flicker harness (:mod:`tests.harness.flicker`), one value per frame (the
    ambient frame first): ``ambient_gains`` multiply the ambient's light in each frame (a flickering lamp:
    the mean of its waveform over that frame's exposure window, relative to its mean); ``exposures_us``
    replace the exposure times the case draws (the random draws stay the same, so the scene and noise
    stream are the same with and without them); ``frame_extra`` are added to each frame's entry
    (``timestamp_ns``); ``common_noise`` pairs renderings that differ only in ``ambient_gains`` (:class:`CommonNoise`;
    without it the photon draws of two such renderings differ, the Poisson stream diverging at the first frame whose
    mean differs). The truth is the lamp's mean spectrum.
    """
    rng = np.random.default_rng(case.seed)
    fine = tables.FINE_NM
    quanta = fine / 550.0  # photons per unit energy (any constant)
    led_table = tables.led_set(case.leds)
    led_fine = led_table.on(fine)
    k = led_fine.shape[1]
    cam_fine = tables.camera(case.camera).on(fine)
    light_fine = _light_energy(case, fine, led_fine)
    surfaces = _surfaces(case, rng)

    def responses(spd_energy: np.ndarray) -> np.ndarray:
        """(surfaces + white + specular, 3) photon responses to one unit of ``spd_energy``."""
        photons = spd_energy * quanta
        body = (surfaces * photons[:, None]).T @ cam_fine
        white = photons @ cam_fine
        return np.vstack([body, white[None], SPECULAR_GAIN * white[None]])

    white_row, glossy_row = surfaces.shape[1], surfaces.shape[1] + 1
    led_resp = np.stack([responses(led_fine[:, i]) for i in range(k)])
    ambient_unit = responses(light_fine)
    scale = case.ratio * led_resp[:, white_row].sum(axis=1).mean() / ambient_unit[white_row].sum()
    gains = np.ones(k + 1) if ambient_gains is None else np.asarray(ambient_gains, dtype=float)
    if gains.shape != (k + 1,):
        raise ValueError(f"ambient_gains: {gains.shape}; expected one gain per frame ({k + 1})")

    def lit(frame_gains: np.ndarray) -> list[np.ndarray]:
        return [ambient_unit * scale * frame_gains[0]] + [
            ambient_unit * scale * frame_gains[i + 1] + led_resp[i] for i in range(k)
        ]

    frames = lit(gains)
    steady_frames = lit(np.ones(k + 1))

    # The scene: patches of the drawn surfaces (repeated to fill), a fixed texture, a specular strip.
    labels = rng.integers(0, surfaces.shape[1], (PATCH_ROWS, PATCH_COLUMNS))
    white_at = (int(rng.integers(PATCH_ROWS)), int(rng.integers(PATCH_COLUMNS)))
    labels[white_at] = white_row  # one white patch (a chart's)
    patch_labels = labels.copy()
    labels = np.repeat(np.repeat(labels, PATCH_PX, 0), PATCH_PX, 1)
    white_x = white_at[1] * PATCH_PX
    if case.specular:
        middle = labels.shape[1] // 2
        white_x += 6 if white_x >= middle else 0
        labels = np.concatenate([labels[:, :middle], np.full((labels.shape[0], 6), glossy_row), labels[:, middle:]], 1)
    height, width = labels.shape
    texture = 1.0 + TEXTURE * rng.uniform(-1.0, 1.0, (height, width))
    texture[labels == glossy_row] = 1.0
    shading = texture * _vignetting(height, width, case.vignetting)

    # Exposures and gains; then DN per unit response so the brightest diffuse sample hits ``peak``.
    if case.exposures == "unequal":
        exposure = BASE_EXPOSURE_US * rng.uniform(0.4, 2.5, k + 1)
        gain = rng.choice([1.0, 2.0, 4.0], k + 1)
    else:
        exposure, gain = np.full(k + 1, BASE_EXPOSURE_US), np.ones(k + 1)
    if exposures_us is not None:
        exposure = np.asarray(exposures_us, dtype=float)
    code_max = 2**case.bits - 1
    span = code_max - case.black
    scaled = frames if common_noise is None else lit(np.maximum(np.asarray(common_noise.scale_gains, float), 1.0))
    brightest = max(float(f[: white_row + 1].max()) * e * g for f, e, g in zip(scaled, exposure, gain))
    dn_per_response = case.peak * span / brightest
    electrons_per_dn = case.full_well_e / span
    read_dn = case.read_noise_e / electrons_per_dn if math.isfinite(case.full_well_e) else 0.0
    sites = None
    if case.cfa is not None:
        sites = np.tile(_cfa_index(case.cfa), (height // 2 + 1, width // 2 + 1))[:height, :width]

    entries = []
    for index, response in enumerate(frames):
        role = "ambient" if index == 0 else "led"

        def dn(response: np.ndarray, index: int = index) -> np.ndarray:
            mean = response[labels] * (dn_per_response * exposure[index] * gain[index]) * shading[:, :, None]
            return mean if sites is None else np.take_along_axis(mean, sites[:, :, None], axis=2)[:, :, 0]

        mean_dn = dn(response)
        if common_noise is not None and math.isfinite(case.full_well_e):
            to_electrons = electrons_per_dn / gain[index]
            electrons, read = _photons(
                np.maximum(mean_dn * to_electrons, 0.0),
                np.maximum(dn(steady_frames[index]) * to_electrons, 0.0),
                common_noise.seed,
                index,
            )
            noisy = electrons / to_electrons + read * read_dn * gain[index]
        elif math.isfinite(case.full_well_e):
            electrons = rng.poisson(np.maximum(mean_dn * electrons_per_dn / gain[index], 0.0))
            noisy = electrons * gain[index] / electrons_per_dn + rng.normal(0.0, read_dn * gain[index], mean_dn.shape)
        else:
            noisy = mean_dn
        data = np.clip(np.rint(noisy + case.black), 0, code_max).astype(np.uint16)
        file = f"frames/{index:02d}_{role}.tif"
        _write(directory / file, data, "tiff")
        levels = np.zeros(k)
        if index:
            levels[index - 1] = 1.0
        entries.append(
            {
                "file": file,
                "role": role,
                "led_levels": levels.tolist(),
                "exposure_us": float(exposure[index]),
                "gain": float(gain[index]),
                **(frame_extra[index] if frame_extra is not None else {}),
            }
        )

    # What the sequence says: spectra sampled on the case's grid, in its unit.
    nm = grid_nm(case.grid)
    to_unit = nm / 550.0 if case.unit == "photons" else np.ones_like(nm)
    led_written = led_table.on(nm) * to_unit[:, None]
    cam_q = tables.camera(case.camera).on(nm)
    cam_written = cam_q if case.unit == "photons" else cam_q * (nm / 550.0)[:, None]
    truth = _light_energy(case, nm, led_table.on(nm)) * scale * to_unit
    document = {
        "format": "msflash-sequence",
        "version": 1,
        "complete": True,
        "wavelengths_nm": nm.tolist(),
        "spectral_unit": case.unit,
        "camera": {
            "model": f"harness {case.camera}",
            "pixel_format": "BayerRG16" if case.cfa else "RGB16",
            "cfa": case.cfa,
            "black_level": float(case.black),
            "white_level": float(code_max),
            "responsivity": {c: cam_written[:, i].tolist() for i, c in enumerate("RGB")},
        },
        "leds": [{"name": n, "spd": led_written[:, i].tolist()} for i, n in enumerate(led_table.names)],
        "frames": entries,
    }
    (directory / "sequence.json").write_text(json.dumps(document))
    # Where the white card is (x, y, width, height in pixels, 2 pixels in from its edges): what a user gives
    # `--reference-patch` (a flat reflectance with the scene's ±5 % texture and vignetting).
    patch = [white_x + 2, white_at[0] * PATCH_PX + 2, PATCH_PX - 4, PATCH_PX - 4]
    (directory / REFERENCE_PATCH_FILE).write_text(json.dumps(patch))
    # A colour chart's worth of the scene's surfaces (up to 24, each at its first patch) with their reflectances:
    # what `--reference-chart` reads (as a user's chart with the maker's reflectances would be).
    chart, seen = [], set()
    for row, column in np.ndindex(*patch_labels.shape):
        surface = int(patch_labels[row, column])
        if surface >= surfaces.shape[1] or surface in seen or len(chart) >= 24:
            continue
        seen.add(surface)
        x = column * PATCH_PX
        if case.specular and x >= PATCH_COLUMNS * PATCH_PX // 2:
            x += 6
        chart.append(
            {
                "rect": [x + 2, row * PATCH_PX + 2, PATCH_PX - 4, PATCH_PX - 4],
                "wavelengths_nm": fine[::5].tolist(),
                "reflectance": np.round(surfaces[::5, surface], 5).tolist(),
            }
        )
    (directory / REFERENCE_CHART_FILE).write_text(json.dumps({"patches": chart}))
    return Truth(directory, nm, truth, led_written)
