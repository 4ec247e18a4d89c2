"""Baseline estimators run on the frames as written: a port of the authors' estimator and plain
least squares on the pixels.

Both read the sequence from disk with their own reader (sequence.json and
:func:`tests.processing.unseen_sequences._read`), not msflash's. Frames are linearised as
``(raw − black) / (exposure · gain)``; LED-only images are the LED frames minus the ambient frame,
unmixed by the frames' LED levels.

The authors' estimator (hblasins/compMultispFlash, MATLAB + CVX; eq. 4–6 as they solve it)::

    minimise   Σ_p ‖m_a(p) − Σ_k w_k m_f,k(p)‖₂  +  α ‖R I w‖₂     subject to  I w ≥ 0

a sum over pixels of the *unsquared* 3-channel residual norm, R the first difference over
wavelength, I the LED spectra in photons divided by their global maximum, the images divided by
their global maximum, LED-only images clipped at 0 (at full resolution, before downsampling), pixels
above 0.95 of full scale in any frame dropped, and the images downsampled by 4. Raw (Bayer) frames are demosaicked as 2 × 2 superpixels
(R, mean G, B) then downsampled by 2 more, so every case loses the same factor of 4 per side.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from tests.processing.unseen_sequences import _cfa_index, _read

AUTHORS_ALPHA = 100.0
"""The authors' roughness weight on full real frames (max-normalised data)."""
AUTHORS_DOWNSAMPLE = 4
AUTHORS_PIXELS = (1280 // 4) * (1024 // 4)
"""Pixels the authors' α = 100 was set for: their camera's full 1280 × 1024 frames downsampled by 4.
The data term is a sum over pixels, so :func:`authors_estimate_scaled` scales α by the pixel count
relative to this (the paper's own reason for α from 1 on 24 patches to 100 on full frames)."""
SATURATION = 0.95
"""Samples above this fraction of full scale (in any frame) are dropped."""


@dataclass(frozen=True)
class Frames:
    """A sequence's frames, linearised, and what is needed to estimate from them."""

    wavelengths_nm: np.ndarray
    unit: str
    led_spd: np.ndarray
    """LED spectra as written (sequence unit), (n, k)."""
    ambient: np.ndarray
    """Linear ambient image, (H, W) raw or (H, W, 3)."""
    led_only: np.ndarray
    """Linear LED-only images, (k, H, W[, 3])."""
    saturated: np.ndarray
    """Samples at or above :data:`SATURATION` of full scale in any frame, (H, W[, 3])."""
    cfa: str | None


def read_frames(directory: Path) -> Frames:
    """Read and linearise a format-v1 sequence written with one ambient frame and LED frames."""
    document = json.loads((directory / "sequence.json").read_text())
    camera = document["camera"]
    black, white = float(camera["black_level"]), float(camera["white_level"])
    raws, linear, levels = [], [], []
    for entry in document["frames"]:
        raw = _read(directory / entry["file"].replace("\\", "/"))
        raw = raw[:, :, 0] if camera["cfa"] is not None else raw
        raws.append(raw)
        linear.append((raw - black) / (float(entry["exposure_us"]) * float(entry["gain"])))
        levels.append(entry["led_levels"] if entry["role"] == "led" else None)
    roles = [entry["role"] for entry in document["frames"]]
    ambient = linear[roles.index("ambient")]
    led_rows = [i for i, role in enumerate(roles) if role == "led"]
    differences = np.stack([linear[i] - ambient for i in led_rows])
    mix = np.array([levels[i] for i in led_rows], float)
    led_only = np.tensordot(np.linalg.pinv(mix), differences, axes=1)
    saturated = np.any(np.stack(raws) >= black + SATURATION * (white - black), axis=0)
    led_spd = np.column_stack([led["spd"] for led in document["leds"]])
    return Frames(
        np.asarray(document["wavelengths_nm"], float),
        document["spectral_unit"],
        led_spd,
        ambient,
        led_only,
        saturated,
        camera["cfa"],
    )


def _superpixels(image: np.ndarray, cfa: str) -> np.ndarray:
    """(…, H, W) raw → (…, H/2, W/2, 3): R, mean of the two G, B of each 2 × 2 period."""
    height, width = (image.shape[-2] // 2) * 2, (image.shape[-1] // 2) * 2
    image = image[..., :height, :width]
    index = _cfa_index(cfa)
    out = np.zeros(image.shape[:-2] + (height // 2, width // 2, 3))
    count = np.zeros(3)
    for dy in range(2):
        for dx in range(2):
            channel = index[dy, dx]
            out[..., channel] += image[..., dy::2, dx::2]
            count[channel] += 1
    return out / count


def _block_mean(image: np.ndarray, factor: int) -> np.ndarray:
    """(…, H, W, C) → (…, H/f, W/f, C) by averaging f × f blocks (edges that do not fill a block dropped)."""
    height, width = (image.shape[-3] // factor) * factor, (image.shape[-2] // factor) * factor
    image = image[..., :height, :width, :]
    shape = image.shape[:-3] + (height // factor, factor, width // factor, factor, image.shape[-1])
    return image.reshape(shape).mean(axis=(-4, -2))


def downsampled(frames: Frames, factor: int = AUTHORS_DOWNSAMPLE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ambient (P, 3), LED-only (k, P, 3), valid (P,)) after demosaicking and downsampling by ``factor``.

    A downsampled pixel is invalid when any sample under it is saturated.
    """
    ambient, led_only, saturated = frames.ambient, frames.led_only, frames.saturated.astype(float)
    if frames.cfa is not None:
        ambient, led_only = _superpixels(ambient, frames.cfa), _superpixels(led_only, frames.cfa)
        saturated = _superpixels(saturated, frames.cfa).max(axis=-1, keepdims=True)
        factor //= 2
    else:
        saturated = saturated.max(axis=-1, keepdims=True)
    ambient, led_only = _block_mean(ambient, factor), _block_mean(led_only, factor)
    valid = _block_mean(saturated, factor)[..., 0] == 0
    k = led_only.shape[0]
    return ambient.reshape(-1, 3), led_only.reshape(k, -1, 3), valid.reshape(-1)


def to_photons(spd: np.ndarray, wavelengths_nm: np.ndarray, unit: str) -> np.ndarray:
    """Spectra (n, …) in photons (any constant) from the sequence's unit."""
    return spd * (wavelengths_nm / 550.0).reshape((-1,) + (1,) * (spd.ndim - 1)) if unit == "energy" else spd


def authors_weights(
    ambient: np.ndarray, led_only: np.ndarray, led_photons: np.ndarray, alpha: float = AUTHORS_ALPHA
) -> np.ndarray:
    """The authors' weights: min Σ_p ‖a_p − Σ_k w_k f_k,p‖₂ + α‖R I w‖₂ s.t. I w ≥ 0 (cvxpy).

    Parameters
    ----------
    ambient : (P, 3) ambient pixels; led_only : (k, P, 3) LED-only pixels, on one (max-normalised) scale.
    led_photons : (n, k) LED spectra in photons, divided by their global maximum.
    alpha : roughness weight.
    """
    import cvxpy as cp

    k, pixels = led_only.shape[0], ambient.shape[0]
    design = led_only.reshape(k, -1).T  # (P·3, k), pixel-major
    w = cp.Variable(k)
    residual = cp.reshape(design @ w - ambient.reshape(-1), (pixels, 3), order="C")
    roughness = np.diff(np.eye(led_photons.shape[0]), axis=0) @ led_photons
    objective = cp.sum(cp.norm(residual, 2, axis=1))
    if alpha:
        objective = objective + alpha * cp.norm(roughness @ w, 2)
    problem = cp.Problem(cp.Minimize(objective), [led_photons @ w >= 0])
    problem.solve(solver=cp.CLARABEL)
    if w.value is None:
        raise RuntimeError(f"cvxpy: {problem.status}")
    return np.asarray(w.value, float)


def authors_estimate(directory: Path, alpha: float = AUTHORS_ALPHA, scale_alpha: bool = False) -> np.ndarray:
    """The authors' ambient spectrum of a sequence on disk, in the sequence's unit.

    ``scale_alpha``: α times the used pixel count over :data:`AUTHORS_PIXELS`.
    """
    frames = read_frames(directory)
    frames = replace(frames, led_only=np.clip(frames.led_only, 0.0, None))  # clipped before downsampling, as theirs
    ambient, led_only, valid = downsampled(frames)
    if scale_alpha:
        alpha = alpha * int(valid.sum()) / AUTHORS_PIXELS
    ambient, led_only = ambient[valid], led_only[:, valid]
    scale = max(float(np.max(ambient)), float(np.max(led_only)))
    led_photons = to_photons(frames.led_spd, frames.wavelengths_nm, frames.unit)
    led_photons = led_photons / np.max(led_photons)
    w = authors_weights(ambient / scale, led_only / scale, led_photons, alpha)
    return _spectrum(frames, led_photons @ w)


def authors_estimate_scaled(directory: Path) -> np.ndarray:
    """:func:`authors_estimate` with α scaled to the pixel count (:data:`AUTHORS_PIXELS`)."""
    return authors_estimate(directory, scale_alpha=True)


def _spectrum(frames: Frames, photons: np.ndarray) -> np.ndarray:
    """A photon spectrum in the sequence's unit."""
    return photons / (frames.wavelengths_nm / 550.0) if frames.unit == "energy" else photons


def lstsq_estimate(directory: Path) -> np.ndarray:
    """Plain unregularised least squares on every unsaturated sample: min ‖m_a − Σ w_k m_f,k‖²."""
    frames = read_frames(directory)
    valid = ~frames.saturated.reshape(-1)
    design = frames.led_only.reshape(frames.led_only.shape[0], -1).T[valid]
    w, *_ = np.linalg.lstsq(design, frames.ambient.reshape(-1)[valid], rcond=None)
    return frames.led_spd @ w
