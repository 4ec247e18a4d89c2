"""An independent sequence generator: what another lab's tool would write in format v1 (docs/architecture.md §6).

Deliberately shares no code with msflash: its own spectral tables (read from the shared CSV files
with its own reader, resampled with ``np.interp``), its own renderer (reflectance × light ×
camera, photon and read noise, black level, clipping, Bayer mosaics), its own JSON and its own
OpenImageIO writing (16-bit TIFF, 16-bit PNG, float EXR). Only msflash's *output* is compared
with the truth it keeps (:class:`Rendered`).

A :class:`Case` names one choice of camera, container, bit depth, wavelength grid, spectral unit,
LED set and levels, light, ambient-to-flash ratio, exposures, frame order. :func:`render_case`
writes it and returns the truth; :func:`check_case` runs ``msflash estimate``, ``flash`` (both
modes) and ``synthesize`` on it in-process (``acquisition.app.cli.main``) and measures the estimate
against the best non-negative LED fit of the truth.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import traceback
import warnings
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
from scipy.optimize import nnls

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
"""The shared spectral data (/work/shared/data); the generator reads nothing of msflash's."""
_LOCAL_DATA = Path(__file__).resolve().parents[2] / "processing" / "data"
"""Fallback copy of the same tables shipped with msflash (identical files, other layout)."""

FULL_WELL_E = 12000.0
"""Electrons at the white level for gain 1 (sets the photon noise)."""
READ_NOISE_DN = 1.5
"""Read noise in DN of a 16-bit container at the data's bit depth."""


# -- spectral tables ------------------------------------------------------------------------------
def _csv(path: Path) -> tuple[np.ndarray, list[str], np.ndarray]:
    """(wavelengths, column names, values) of a shared CSV (``#`` comments, header row)."""
    lines = [line for line in path.read_text(encoding="utf-8-sig").splitlines() if line and not line.startswith("#")]
    header = lines[0].split(",")
    rows = np.array([[float(v) if v.strip() else np.nan for v in line.split(",")] for line in lines[1:]])
    return rows[:, 0], header[1:], rows[:, 1:]


def _data(*candidates: str) -> Path:
    for candidate in candidates:
        for root in (DATA, _LOCAL_DATA):
            if (root / candidate).is_file():
                return root / candidate
    raise FileNotFoundError(f"none of {candidates} under {DATA} or {_LOCAL_DATA}")


def _on(wavelengths: np.ndarray, source_nm: np.ndarray, values: np.ndarray, outside: str = "zero") -> np.ndarray:
    """Columns of ``values`` linearly interpolated onto ``wavelengths`` (zero or edge value outside)."""
    values = np.nan_to_num(np.atleast_2d(values.T).T, nan=0.0)
    out = np.empty((wavelengths.size, values.shape[1]))
    for j in range(values.shape[1]):
        if outside == "zero":
            out[:, j] = np.interp(wavelengths, source_nm, values[:, j], left=0.0, right=0.0)
        else:
            out[:, j] = np.interp(wavelengths, source_nm, values[:, j])
    return out


@cache
def _paper34() -> tuple[np.ndarray, list[str], np.ndarray]:
    return _csv(_data("cameras/paper34_cameras_400_700_10nm.csv"))


def camera_names() -> list[str]:
    """The 34 cameras of the paper (Jiang 2013 + ISETCam)."""
    _, names, _ = _paper34()
    return list(dict.fromkeys(n.split("|")[0] for n in names))


def camera_photons(name: str, wavelengths: np.ndarray) -> np.ndarray:
    """Quantal R, G, B responsivities, (n, 3): one of the 34, ``isetcam:NAME`` (its own grid) or ``gaussian``."""
    if name == "gaussian":
        return np.column_stack(
            [np.exp(-0.5 * ((wavelengths - peak) / width) ** 2) for peak, width in ((605, 35), (535, 40), (455, 30))]
        )
    if name.startswith("isetcam:"):
        nm, _, values = _csv(_data(f"cameras/isetcam/{name[8:]}.csv"))
        return _on(wavelengths, nm, values)
    nm, names, values = _paper34()
    columns = [names.index(f"{name}|{c}") for c in "RGB"]
    return _on(wavelengths, nm, values[:, columns])


def paper_leds_energy(
    wavelengths: np.ndarray, which: tuple[int, ...] = tuple(range(7))
) -> tuple[list[str], np.ndarray]:
    """The paper's 7 LEDs (energy), a subset of them."""
    nm, names, values = _csv(
        _data("paper/csv/ximeaLights_energy_380_1068_4nm.csv", "paper/ximeaLights_energy_380_1068_4nm.csv")
    )
    return [names[i] for i in which], _on(wavelengths, nm, values[:, list(which)])


def booth8_energy(wavelengths: np.ndarray) -> tuple[list[str], np.ndarray]:
    """An 8-channel booth: Gaussians 416–656 nm, FWHM 20–30 nm, one broad phosphor-like LED (energy)."""
    peaks = (416, 450, 484, 518, 552, 588, 622, 656)
    fwhms = (20, 22, 24, 26, 110, 28, 30, 24)  # channel 5: phosphor-converted amber, broad
    sigmas = np.array(fwhms) / 2.3548
    powers = (0.6, 1.0, 0.8, 0.7, 1.4, 0.9, 1.0, 0.5)
    values = np.column_stack(
        [p * np.exp(-0.5 * ((wavelengths - c) / s) ** 2) for c, s, p in zip(peaks, sigmas, powers)]
    )
    return [f"b{c}" for c in peaks], values


def luxeon8_energy(wavelengths: np.ndarray) -> tuple[list[str], np.ndarray]:
    """ISETCam's 8 Luxeon Rebel LEDs."""
    nm, names, values = _csv(_data("leds/isetcam/LuxeonLEDSpectra_8LED.csv"))
    return names, _on(wavelengths, nm, values)


@cache
def _reflectances() -> tuple[np.ndarray, np.ndarray]:
    nm, _, values = _csv(
        _data("paper/csv/natural100_reflectance_400_700_10nm.csv", "paper/natural100_reflectance_400_700_10nm.csv")
    )
    greys = np.logspace(0, math.log10(0.05), 10)
    return nm, np.column_stack([values, np.tile(greys, (nm.size, 1))])


def reflectances(wavelengths: np.ndarray) -> np.ndarray:
    """Natural-100 + a 10-step grey strip (110 surfaces), edge values held outside 400–700 nm."""
    nm, values = _reflectances()
    return np.clip(_on(wavelengths, nm, values, outside="edge"), 0.0, 1.0)


def _planck(wavelengths: np.ndarray, kelvin: float) -> np.ndarray:
    c2 = 1.4388e7  # nm·K
    return (
        (560.0 / wavelengths) ** 5
        * (math.exp(c2 / (kelvin * 560.0)) - 1.0)
        / (np.exp(c2 / (kelvin * wavelengths)) - 1.0)
    )


def _gauss(wavelengths: np.ndarray, peak: float, fwhm: float) -> np.ndarray:
    return np.exp(-0.5 * ((wavelengths - peak) / (fwhm / 2.3548)) ** 2)


def light_energy(name: str, wavelengths: np.ndarray) -> np.ndarray:
    """A light's SPD (energy): A, D50/D65/D75, F2/F7/F11, warmLED, green, orange, underwater."""
    import colour  # the CIE tables (colour-science); msflash's own illuminant code is not used

    if name == "A":
        return _planck(wavelengths, 2848.0 * 1.4388 / 1.4350)
    if name in ("D50", "D65", "D75"):
        xy = colour.temperature.CCT_to_xy_CIE_D(int(name[1:]) * 100 * 1.4388 / 1.4380)
        sd = colour.sd_CIE_illuminant_D_series(xy)
        return _on(wavelengths, sd.wavelengths, sd.values[:, None], outside="edge")[:, 0]
    if name in ("F2", "F7", "F11"):
        sd = colour.SDS_ILLUMINANTS["FL" + name[1:]]
        return _on(wavelengths, sd.wavelengths, sd.values[:, None])[:, 0]
    if name == "warmLED":
        return 0.45 * _gauss(wavelengths, 450, 20) + _gauss(wavelengths, 600, 130)
    if name == "green":
        return _gauss(wavelengths, 530, 45) + 0.02
    if name == "orange":
        return _gauss(wavelengths, 605, 35) + 0.02
    if name == "underwater":
        nm, _, absorption = _csv(_data("water/pope_fry_1997_380_700_2p5nm.csv"))
        a = _on(wavelengths, nm, absorption, outside="edge")[:, 0]
        a = np.where(wavelengths > 700, a[wavelengths <= 700][-1] * np.exp((wavelengths - 700) / 40.0), a)
        return light_energy("D65", wavelengths) * np.exp(-a * 6.0)
    raise ValueError(f"unknown light {name}")


# -- cases ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    """One sequence another lab might send."""

    name: str
    camera: str = "Canon 5DMarkII"
    container: str = "tiff"
    """``tiff`` (16-bit), ``tiff-lzw`` (16-bit, LZW, ``.TIF``), ``png`` (16-bit), ``exr`` (float, normalised to
    white 1.0) or ``exr-half`` (the same in half floats)."""
    cfa: str | None = None
    bits: int = 16
    black: int = 0
    grid: tuple[float, float, float] = (400, 700, 10)
    unit: str = "energy"
    leds: str = "paper7"
    """``paper7``, ``paper:i,j,…`` (a subset), ``booth8`` or ``luxeon8``."""
    levels: str = "one_hot"
    """``one_hot``, ``half`` (every other LED at 0.5) or ``pairs`` (two LEDs per frame, full rank)."""
    light: str = "A"
    ratio: float = 1.0
    """Mean ambient signal over the mean single-LED signal (white surface, all channels)."""
    exposures: str = "equal"
    """``equal`` or ``varying`` (exposure and gain differ frame to frame)."""
    specular: bool = False
    peak: float = 0.8
    """Brightest diffuse sample of the brightest frame, as a fraction of the white level's range."""
    order: str = "ambient_first"
    """``ambient_first``, ``leds_first``, ``extra_dark``, ``extra_flash``, ``unknown_keys``."""
    seed: int = 0
    patch_px: int = 8
    crop: int = 0
    """Rows and columns cut off the bottom right (odd frame sizes)."""
    texture: float = 0.0
    """Pixel-scale texture: every pixel's reflectance times 1 ± this (uniform, the same in every frame)."""
    quirks: tuple[str, ...] = ()
    """``windows_paths`` (frame paths with ``\\`` separators, as ``str(WindowsPath)`` gives), ``measured_spectra``
    (LED spectra and responsivities as a spectrometer gives them: ±0.3 % of the peak of noise, negative in
    the tails)."""


@dataclass(frozen=True)
class Rendered:
    """A written sequence and the truth it was rendered from."""

    directory: Path
    wavelengths_nm: np.ndarray
    truth: np.ndarray
    """The true ambient SPD in the sequence's spectral unit."""
    led_spd: np.ndarray
    """The LEDs as written (sequence unit), (n, k)."""
    responsivity: np.ndarray
    """The camera's R, G, B responsivities as written (sequence unit), (n, 3)."""
    d65: np.ndarray
    """CIE D65 in the sequence unit (the complementary flash's default target)."""
    levels: np.ndarray
    """LED frames' levels, (n_led_frames, k), in sequence order of the LED frames."""
    frames: list[dict] = field(default_factory=list)
    """The frame entries as written."""
    black: float = 0.0
    white: float = 65535.0


def _led_set(case: Case, wavelengths: np.ndarray) -> tuple[list[str], np.ndarray]:
    if case.leds == "paper7":
        return paper_leds_energy(wavelengths)
    if case.leds.startswith("paper:"):
        return paper_leds_energy(wavelengths, tuple(int(i) for i in case.leds[6:].split(",")))
    if case.leds == "booth8":
        return booth8_energy(wavelengths)
    if case.leds == "luxeon8":
        return luxeon8_energy(wavelengths)
    if case.leds.startswith("gauss:"):  # N narrow LEDs spread evenly over 410–680 nm
        peaks = np.linspace(410, 680, int(case.leds[6:]))
        return [f"g{p:.0f}" for p in peaks], np.column_stack([_gauss(wavelengths, p, 22) for p in peaks])
    raise ValueError(case.leds)


def _levels(kind: str, k: int) -> np.ndarray:
    if kind == "one_hot":
        return np.eye(k)
    if kind == "half":
        return np.diag([0.5 if i % 2 else 1.0 for i in range(k)])
    if kind == "pairs":
        return np.eye(k) + np.eye(k, k=1)  # frame j lights LEDs j and j+1 (the last one alone)
    if kind == "shuffled":  # one LED per frame, not in the order of ``leds``
        return np.eye(k)[np.random.default_rng(k).permutation(k)]
    if kind == "twice":  # every LED at full and at half drive: more frames than LEDs
        return np.vstack([np.eye(k), 0.5 * np.eye(k)])
    raise ValueError(kind)


def _cfa_index(cfa: str) -> np.ndarray:
    """Channel (0 R, 1 G, 2 B) of each site of the 2×2 period."""
    return np.array(["RGB".index(c) for c in cfa]).reshape(2, 2)


def _label_map(case: Case, n_surfaces: int) -> tuple[np.ndarray, int, int]:
    columns = 11
    rows = math.ceil(n_surfaces / columns)
    p = case.patch_px
    labels = np.repeat(np.repeat(np.arange(rows * columns).reshape(rows, columns), p, 0), p, 1)
    labels = np.where(labels < n_surfaces, labels, n_surfaces - 1)  # pad with the darkest grey
    if case.specular:
        strip = np.full((labels.shape[0], 6), n_surfaces)  # a glossy highlight: label n_surfaces
        middle = labels.shape[1] // 2
        labels = np.concatenate([labels[:, :middle], strip, labels[:, middle:]], axis=1)
    return labels, labels.shape[0], labels.shape[1]


def render_case(case: Case, directory: Path) -> Rendered:
    """Write ``case`` as a format-v1 sequence in ``directory``; return the truth."""
    rng = np.random.default_rng(case.seed)
    start, stop, step = case.grid
    nm = np.arange(start, stop + step / 2, step, dtype=float)
    photons = nm / 550.0  # energy → photons per unit energy (any constant)
    led_names, led_e = _led_set(case, nm)
    k = len(led_names)
    cam_q = camera_photons(case.camera, nm)
    light_e = light_energy(case.light, nm)
    surfaces = reflectances(nm)
    n_surfaces = surfaces.shape[1]

    # Responses per surface (rows) per channel to one unit of each light: photon counts Σ r_q·ρ·E·λ.
    def responses(spd_e: np.ndarray) -> np.ndarray:
        body = (surfaces * (spd_e * photons)[:, None]).T @ cam_q * step
        glossy = 2.5 * ((spd_e * photons) @ cam_q) * step  # specular: the light itself, 2.5× white
        return np.vstack([body, glossy[None]])

    white_row = n_surfaces - 10  # the first grey (reflectance 1)
    led_response = np.stack([responses(led_e[:, i]) for i in range(k)])  # (k, surfaces+1, 3)
    ambient_unit = responses(light_e)
    mean_led = led_response[:, white_row].sum(axis=1).mean()
    ambient_scale = case.ratio * mean_led / ambient_unit[white_row].sum()
    ambient_resp = ambient_unit * ambient_scale
    truth_e = light_e * ambient_scale

    levels = _levels(case.levels, k)
    plan: list[tuple[str, np.ndarray]] = [("ambient", np.zeros(k))] + [("led", row) for row in levels]
    if case.order == "leds_first":
        plan = plan[1:] + plan[:1]
    if case.order == "extra_dark":
        plan = [("dark", np.zeros(k))] + plan
    if case.order == "extra_flash":
        plan = plan + [("flash", np.linspace(0.2, 0.9, k))]

    labels, height, width = _label_map(case, n_surfaces)
    code_max = 2**case.bits - 1
    white_dn = float(code_max)
    span = white_dn - case.black
    diffuse_rows = slice(0, n_surfaces)
    # Response (photon units) of every planned frame at unit exposure and gain.
    # ``flicker:a``: the ambient's intensity differs frame to frame by up to ±a (mains-driven lamps, short exposures).
    flicker = next((float(q[8:]) for q in case.quirks if q.startswith("flicker:")), 0.0)
    drift = 1.0 + flicker * rng.uniform(-1.0, 1.0, len(plan))
    frame_resp = [
        ambient_resp * (role != "dark") * (1.0 if role == "ambient" else drift[j])
        + np.tensordot(row, led_response, axes=1)
        for j, (role, row) in enumerate(plan)
    ]
    brightest = max(float(r[diffuse_rows].max()) for r in frame_resp)
    base_exposure = 10000.0
    counts_per_response = case.peak * span / (brightest * base_exposure)  # DN per (response · µs) at gain 1
    electrons_per_dn = FULL_WELL_E / span
    entries, pixels_list = [], []
    shading = 1.0 + case.texture * np.random.default_rng(case.seed + 1).uniform(-1.0, 1.0, (height, width))
    for index, ((role, row), response) in enumerate(zip(plan, frame_resp)):
        if case.exposures == "varying":
            gain = float(rng.choice([1.0, 1.5, 2.0]))
            own = max(float(response[diffuse_rows].max()), 1e-12)
            exposure = float(np.round(base_exposure * (brightest / own) * rng.uniform(0.55, 0.95) / gain))
            exposure = min(exposure, 8 * base_exposure)
        else:
            gain, exposure = 1.0, base_exposure
        mean_dn = response * counts_per_response * exposure * gain  # (surfaces+1, 3)
        image = mean_dn[labels[: height - case.crop, : width - case.crop]]  # (H, W, 3)
        if case.texture:
            image = image * shading[: image.shape[0], : image.shape[1], None]
        if case.cfa is not None:
            sites = np.tile(_cfa_index(case.cfa), (height // 2 + 1, width // 2 + 1))[: image.shape[0], : image.shape[1]]
            image = np.take_along_axis(image, sites[:, :, None], axis=2)[:, :, 0]
        electrons = image * electrons_per_dn / gain
        noisy = rng.poisson(np.maximum(electrons, 0)) * gain / electrons_per_dn
        noisy = noisy + rng.normal(0.0, READ_NOISE_DN, noisy.shape) + case.black
        if case.container.startswith("exr"):
            data = (np.clip(noisy, 0, code_max) / code_max).astype(np.float32)
        else:
            data = np.clip(np.rint(noisy), 0, code_max).astype(np.uint16)
        suffix = {"tiff": ".tif", "tiff-lzw": ".TIF", "png": ".png", "exr": ".exr", "exr-half": ".exr"}[case.container]
        file = f"img/{index:02d}_{role}{suffix}"
        entry: dict = {
            "file": file.replace("/", "\\") if "windows_paths" in case.quirks else file,
            "role": role,
            "led_levels": [float(v) for v in row],
            "exposure_us": exposure,
            "gain": gain,
        }
        if case.order == "unknown_keys":
            entry["vendor_timestamp"] = 1700000000 + index
        entries.append(entry)
        pixels_list.append((directory / file, data))  # on disk with '/' separators

    scale = 1.0 / code_max if case.container.startswith("exr") else 1.0
    unit_factor = photons if case.unit == "photons" else np.ones_like(nm)
    led_written = led_e * unit_factor[:, None]
    cam_written = cam_q if case.unit == "photons" else cam_q * photons[:, None]
    if "measured_spectra" in case.quirks:  # what the frames saw is the clean spectra; what is written is measured
        led_written = led_written + rng.normal(0, 0.003, led_written.shape) * led_written.max(axis=0)
        cam_written = cam_written + rng.normal(0, 0.003, cam_written.shape) * cam_written.max(axis=0)
    document: dict = {
        "format": "msflash-sequence",
        "version": 1,
        "complete": True,
        "wavelengths_nm": [float(w) for w in nm],
        "spectral_unit": case.unit,
        "camera": {
            "model": f"other-lab {case.camera}",
            "pixel_format": "BayerRG16" if case.cfa else "RGB16",
            "cfa": case.cfa,
            "black_level": case.black * scale,
            "white_level": white_dn * scale,
            "responsivity": {c: cam_written[:, i].tolist() for i, c in enumerate("RGB")},
        },
        "leds": [{"name": n, "spd": led_written[:, i].tolist()} for i, n in enumerate(led_names)],
        "frames": entries,
    }
    if case.order == "unknown_keys":
        document["lab"] = {"operator": "x", "temperature_c": 21.5}
        document["camera"]["lens"] = "50 mm f/4"
        document["leds"][0]["driver_current_ma"] = 700
    directory.mkdir(parents=True, exist_ok=True)
    for path, data in pixels_list:
        _write(path, data, case.container)
    (directory / "sequence.json").write_text(json.dumps(document, indent=2))
    led_levels = np.array([row for role, row in plan if role == "led"])
    return Rendered(
        directory,
        nm,
        truth_e * unit_factor,
        led_written,
        cam_written,
        light_energy("D65", nm) * unit_factor,
        led_levels,
        entries,
        case.black * scale,
        white_dn * scale,
    )


def _write(path: Path, data: np.ndarray, container: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    channels = 1 if data.ndim == 2 else data.shape[2]
    kind = {"exr": "float", "exr-half": "half"}.get(container, "uint16")
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], channels, kind)
    if container == "tiff-lzw":
        spec.attribute("compression", "lzw")
    output = oiio.ImageOutput.create(str(path))
    if output is None or not output.open(str(path), spec):
        raise OSError(f"cannot write {path}: {oiio.geterror()}")
    try:
        if not output.write_image(data.reshape(data.shape[0], data.shape[1], channels)):
            raise OSError(f"cannot write {path}: {output.geterror()}")
    finally:
        output.close()


def _read(path: Path) -> np.ndarray:
    image = oiio.ImageInput.open(str(path))
    try:
        spec = image.spec()
        data = image.read_image(0, 0, 0, spec.nchannels, spec.format)  # native: counts stay counts
    finally:
        image.close()
    return np.asarray(data, dtype=np.float64).reshape(spec.height, spec.width, spec.nchannels)


# -- checks ---------------------------------------------------------------------------------------
def rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """The paper's spectrum RMSE (estimate max-normalised, truth least-squares scaled onto it)."""
    estimate = np.asarray(estimate, float) / np.max(np.abs(estimate))
    scaled = truth * (truth @ estimate) / (truth @ truth)
    return float(np.sqrt(np.mean((estimate - scaled) ** 2)))


def led_bound(rendered: Rendered) -> float:
    """RMSE of the best non-negative fit of the truth by the LED spectra (what the LEDs allow)."""
    fit, _ = nnls(rendered.led_spd, rendered.truth)
    return rmse(rendered.led_spd @ fit, rendered.truth)


def run_cli(args: list[str]) -> tuple[int, str, str, list[str]]:
    """``msflash ARGS`` in-process: (status, stdout, stderr, Python warnings); a traceback is stderr."""
    from msflash.acquisition.app.cli import main

    out, err = io.StringIO(), io.StringIO()
    with (
        warnings.catch_warnings(record=True) as caught,
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
    ):
        warnings.simplefilter("always")
        try:
            status = main(args)
        except BaseException:  # noqa: BLE001 — a traceback is what the sweep is looking for
            status = -1
            err.write(traceback.format_exc())
    return status, out.getvalue(), err.getvalue(), [f"{w.category.__name__}: {w.message}" for w in caught]


def camera_angle_deg(rendered: Rendered, spd: np.ndarray, target: np.ndarray) -> float:
    """Angle between the camera's R, G, B responses to two lights (the flash solvers' camera-space goal)."""
    a, b = rendered.responsivity.T @ spd, rendered.responsivity.T @ target
    cosine = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(min(1.0, max(-1.0, cosine))))


ANGLE_REACHED_DEG = 1.0
"""A flash that says it reached its target must be this close to it in camera space (computed here)."""


def expected_synthesis(rendered: Rendered, weights: np.ndarray) -> np.ndarray:
    """``m_a + Σ_k w_k m_f,k`` computed here: LED-only images unmixed from the frames by the levels."""

    def linear(entry: dict) -> np.ndarray:
        pixels = _read(rendered.directory / entry["file"].replace("\\", "/"))
        return (pixels - rendered.black) / (entry["exposure_us"] * entry["gain"])

    ambient = linear(next(e for e in rendered.frames if e["role"] == "ambient"))
    differences = np.stack([linear(e) - ambient for e in rendered.frames if e["role"] == "led"])
    only = np.tensordot(np.linalg.pinv(rendered.levels), differences, axes=1)  # (k, H, W, C)
    image = ambient + np.tensordot(weights, only, axes=1)
    return image[:, :, 0] if image.shape[2] == 1 else image


@dataclass(frozen=True)
class Outcome:
    """What one case gave."""

    case: Case
    estimate_rmse: float = math.nan
    bound: float = math.nan
    warnings: tuple[str, ...] = ()
    defects: tuple[str, ...] = ()
    flash_error_deg: tuple[float, float] = (math.nan, math.nan)
    """Against the *true* ambient, in camera space: the matching flash's angle to it, and the complementary
    flash plus it to D65 (what a user sees; includes the estimate's error)."""

    @property
    def ratio(self) -> float:
        return self.estimate_rmse / self.bound if self.bound > 0 else math.inf


MARGIN = 0.1
"""How much worse than the LED bound an estimate may be without a warning (tests/processing/test_samples.py)."""


def check_case(case: Case, root: Path) -> Outcome:
    """Render ``case`` under ``root`` and run estimate, flash (both modes) and synthesize on it."""
    rendered = render_case(case, root / case.name)
    sequence = str(rendered.directory)
    defects: list[str] = []
    status, out, err, caught = run_cli(["estimate", sequence, "--json"])
    if status != 0 or caught or "Traceback" in err:
        return Outcome(case, defects=(f"estimate: status {status}: {err.strip()[-600:]} {caught}",))
    payload = json.loads(out)
    spectrum = np.asarray(payload["spectrum"], float)
    if spectrum.shape != rendered.truth.shape or not np.allclose(payload["wavelengths_nm"], rendered.wavelengths_nm):
        defects.append(f"estimate: spectrum shape {spectrum.shape} for {rendered.truth.shape}")
        return Outcome(case, defects=tuple(defects))
    if payload["spectral_unit"] != case.unit:
        defects.append(f"estimate: spectral_unit {payload['spectral_unit']} for {case.unit}")
    error, bound = rmse(spectrum, rendered.truth), led_bound(rendered)
    estimate_warnings = tuple(payload["warnings"])
    if error > bound + MARGIN and not estimate_warnings:
        defects.append(f"estimate: RMSE {error:.3f} vs LED bound {bound:.3f} without a warning")
    weights_by_mode, truth_angles = {}, {}
    for mode in ("complementary", "matching"):
        status, out, err, caught = run_cli(["flash", sequence, "--mode", mode, "--json"])
        if status == 2 and "expected a target covering the camera's range" in err and not caught:
            continue  # D65 is not defined where this camera still sees (an IR camera beyond 830 nm): refused, clearly
        if status != 0 or caught or "Traceback" in err:
            defects.append(f"flash {mode}: status {status}: {err.strip()[-600:]} {caught}")
            continue
        flash = json.loads(out)
        weights = np.asarray(flash["flash_weights"], float)
        if weights.shape != (rendered.led_spd.shape[1],) or not np.all((weights >= 0) & (weights <= 1)):
            defects.append(f"flash {mode}: weights {weights.round(4).tolist()} outside [0, 1]")
        if mode == "complementary" and not (isinstance(flash.get("scale"), float | int) and flash["scale"] >= 0):
            defects.append(f"flash {mode}: scale {flash.get('scale')!r}")
        # The solvers' goals recomputed here from the written spectra: matching, the flash looks like the
        # estimated ambient; complementary, ambient + flash looks like D65.
        estimated = rendered.led_spd @ np.asarray(flash["ambient_weights"], float)
        flash_spd = rendered.led_spd @ weights
        angle = (
            camera_angle_deg(rendered, flash_spd, estimated)
            if mode == "matching"
            else camera_angle_deg(rendered, estimated + flash_spd, rendered.d65)
        )
        truth_angles[mode] = (
            camera_angle_deg(rendered, flash_spd, rendered.truth)
            if mode == "matching"
            else camera_angle_deg(rendered, rendered.truth + flash_spd, rendered.d65)
        )
        if flash["target_reached"] and angle > ANGLE_REACHED_DEG:
            defects.append(f"flash {mode}: says the target is reached but is {angle:.2f}° from it in camera space")
        weights_by_mode[mode] = weights
    weights = weights_by_mode.get("matching", np.full(rendered.led_spd.shape[1], 0.5))
    output = rendered.directory.parent / f"{case.name}-synth.exr"
    status, out, err, caught = run_cli(
        ["synthesize", sequence, "--weights", ",".join(f"{w:.6g}" for w in weights), "--out", str(output)]
    )
    if status != 0 or caught or "Traceback" in err:
        defects.append(f"synthesize: status {status}: {err.strip()[-600:]} {caught}")
    else:
        written = _read(output)
        written = written[:, :, 0] if written.shape[2] == 1 else written
        expected = expected_synthesis(rendered, np.array([float(f"{w:.6g}") for w in weights]))
        if written.ndim == 3 and expected.ndim == 2 and case.cfa:
            # A mosaic's EXR is demosaicked RGB whose CFA channel at each pixel is the mosaic, exactly
            # (docs/decisions/exr-of-a-mosaic.md).
            height, width = expected.shape
            channel = np.tile(_cfa_index(case.cfa), ((height + 1) // 2, (width + 1) // 2))[:height, :width]
            written = np.take_along_axis(written, channel[..., None], axis=2)[..., 0]
        worst = float(np.max(np.abs(written - expected)) / np.max(np.abs(expected)))
        if worst > 1e-5:
            defects.append(f"synthesize: differs from ambient + Σ w·LED-only by {worst:.2g} of the peak")
    return Outcome(
        case,
        error,
        bound,
        estimate_warnings,
        tuple(defects),
        (truth_angles.get("matching", math.nan), truth_angles.get("complementary", math.nan)),
    )


def sweep_cases() -> list[Case]:
    """The sweep of what other labs would send (each a change from a plain paper-like case)."""
    base = Case("base")
    cases = [base]

    def add(name: str, **changes: object) -> None:
        cases.append(replace(base, name=name, seed=len(cases), **changes))

    for camera in (
        "Canon 5DMarkII",
        "Nikon D40",
        "isetcam:NikonD200IR",
        "isetcam:AptinaMT9M031",
        "AptinaMT9M131",
        "Pentax K-5",
        "Nokia N900",
        "Point Grey Grasshopper 50S5C",
        "gaussian",
        "isetcam:NikonD2xsNikon50mm",
    ):
        add(f"camera-{camera.replace(' ', '_').replace(':', '_')}", camera=camera)
    for container in ("png", "exr"):
        add(f"container-{container}", container=container)
    for cfa in ("RGGB", "BGGR", "GRBG", "GBRG"):
        add(f"bayer-{cfa}", cfa=cfa)
    for bits, black in ((10, 64), (12, 256), (14, 256)):
        add(f"bits{bits}-black{black}", bits=bits, black=black)
    add("bayer-12bit-exr", cfa="GRBG", bits=12, black=256, container="exr")
    add("bayer-10bit-png", cfa="BGGR", bits=10, black=64, container="png")
    for grid in ((400, 700, 10), (380, 780, 5), (400, 720, 4), (400, 700, 1)):
        for unit in ("energy", "photons"):
            add(f"grid{grid[0]}-{grid[1]}-{grid[2]}-{unit}", grid=grid, unit=unit)
    for leds in ("paper:0,3,5", "paper:0,2,4,6", "paper:0,1,3,4,5", "paper:0,1,2,3,5,6", "booth8", "luxeon8"):
        add(f"leds-{leds.replace(':', '').replace(',', '')}", leds=leds)
    add("levels-half", levels="half")
    add("levels-pairs", levels="pairs")
    add("levels-pairs-booth8", levels="pairs", leds="booth8")
    add("levels-shuffled", levels="shuffled", exposures="varying")
    add("levels-twice", levels="twice", cfa="RGGB")
    for light in ("A", "D50", "D65", "D75", "F2", "F7", "F11", "warmLED", "green", "orange", "underwater"):
        add(f"light-{light}", light=light)
        add(f"light-{light}-booth8", light=light, leds="booth8")
    for ratio in (0.05, 0.2, 5.0, 20.0):
        add(f"ratio-{ratio:g}", ratio=ratio)
    add("exposures-varying", exposures="varying")
    add("exposures-varying-bayer12", exposures="varying", cfa="RGGB", bits=12, black=256)
    add("specular", specular=True)
    add("specular-bayer", specular=True, cfa="RGGB")
    add("low-signal", peak=0.03)
    add("low-signal-12bit", peak=0.05, bits=12, black=256)
    for order in ("leds_first", "extra_dark", "extra_flash", "unknown_keys"):
        add(f"order-{order}", order=order)
    add("container-tiff-lzw", container="tiff-lzw")
    add("container-exr-half", container="exr-half", cfa="RGGB")
    add("odd-size-bayer", cfa="GBRG", crop=3)
    add("odd-size-rgb", crop=5, bits=12, black=256)
    add("grid380-1000-5-D200IR", grid=(380, 1000, 5), camera="isetcam:NikonD200IR")
    add("grid360-830-2-photons", grid=(360, 830, 2), unit="photons", camera="isetcam:NikonD200IR", light="D65")
    add("grid402-698-4", grid=(402, 698, 4))
    add("grid400-700-2.5", grid=(400, 700, 2.5))
    add("leds-gauss12", leds="gauss:12", light="D50")
    add("leds-gauss16-pairs", leds="gauss:16", levels="pairs", light="warmLED")
    add("windows-paths", quirks=("windows_paths",))
    add("measured-spectra", quirks=("measured_spectra",), leds="booth8", unit="photons")
    for texture in (0.1, 0.3):
        add(f"texture-{texture:g}", texture=texture)
        add(f"texture-{texture:g}-booth8-D65", texture=texture, leds="booth8", light="D65")
        add(f"texture-{texture:g}-bayer-7px", texture=texture, cfa="RGGB", patch_px=7)
    add("patches-7px", patch_px=7)
    for amplitude in (0.01, 0.03, 0.1):
        add(f"flicker-{amplitude:g}", quirks=(f"flicker:{amplitude:g}",), light="F2")
        add(f"flicker-{amplitude:g}-ratio5", quirks=(f"flicker:{amplitude:g}",), light="F2", ratio=5.0)
    return cases
