"""Rendering camera images for people: demosaic, camera → XYZ, sRGB.

Public objects
--------------
- :func:`demosaic_superpixel` (half resolution, exact) and :func:`demosaic_bilinear` (full
  resolution, the paper's figures).
- :func:`reflectances_to_xyz`: CIE 1931 XYZ of surfaces under an illuminant (white Y = 1).
- :func:`camera_to_xyz_matrix`: the 3×3 camera → XYZ matrix fitted on a chart.
- :func:`camera_to_srgb_linear`: camera RGB → linear sRGB, with optional von Kries white balance.
- :func:`display_white`: the exposure of a preview (which linear luminance is display white).
- :func:`srgb_preview`: an 8-bit sRGB image.

The paper's figures are rendered without white balance: a 3×3 camera → XYZ matrix fitted on a
Macbeth chart under D65, then sRGB (the authors' code, hblasins/compMultispFlash). That keeps the ambient's colour cast visible,
which is the point of comparing ambient-only, matching and complementary images. Conversion to
colour-science objects happens here and in :mod:`processing.datasets` only.
"""

from __future__ import annotations

import warnings

import numpy as np

from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.image_formation import surface_responses
from msflash.processing.spectra import Spectra, require_same_grid

CFA_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")


def demosaic_superpixel(mosaic: np.ndarray, cfa: str, dtype: type = np.float64) -> np.ndarray:
    """Half-resolution RGB from a raw mosaic: each 2×2 cell gives one pixel (greens averaged), of ``dtype``.

    Exact (no interpolation) and fast; meant for previews and for per-patch colour, not for
    full-resolution output.

    Examples
    --------
    >>> demosaic_superpixel(np.array([[1.0, 2.0], [4.0, 3.0]]), "RGGB").tolist()
    [[[1.0, 3.0, 3.0]]]
    """
    if cfa not in CFA_PATTERNS:
        raise SpectralDataError(f"demosaic: CFA '{cfa}'; expected one of {', '.join(CFA_PATTERNS)}")
    if mosaic.ndim != 2:
        raise SpectralDataError(f"demosaic: mosaic has shape {mosaic.shape}; expected (H, W)")
    height, width = (mosaic.shape[0] // 2) * 2, (mosaic.shape[1] // 2) * 2
    cells = {
        (0, 0): mosaic[0:height:2, 0:width:2],
        (0, 1): mosaic[0:height:2, 1:width:2],
        (1, 0): mosaic[1:height:2, 0:width:2],
        (1, 1): mosaic[1:height:2, 1:width:2],
    }
    positions = {
        "RGGB": ((0, 0), ((0, 1), (1, 0)), (1, 1)),
        "BGGR": ((1, 1), ((0, 1), (1, 0)), (0, 0)),
        "GRBG": ((0, 1), ((0, 0), (1, 1)), (1, 0)),
        "GBRG": ((1, 0), ((0, 0), (1, 1)), (0, 1)),
    }[cfa]
    if dtype != np.float64:  # written in place, one pass a channel (the live flash preview, at video rate)
        out = np.empty((height // 2, width // 2, 3), dtype=dtype)
        out[..., 0] = cells[positions[0]]
        np.add(cells[positions[1][0]], cells[positions[1][1]], out=out[..., 1], dtype=dtype)
        out[..., 1] *= 0.5
        out[..., 2] = cells[positions[2]]
        return out
    red = cells[positions[0]].astype(np.float64)
    green = 0.5 * (cells[positions[1][0]].astype(np.float64) + cells[positions[1][1]])
    blue = cells[positions[2]].astype(np.float64)
    return np.stack([red, green, blue], axis=-1)


def _bilinear_kernels() -> tuple[np.ndarray, np.ndarray]:
    green = np.array([[0.0, 1.0, 0.0], [1.0, 4.0, 1.0], [0.0, 1.0, 0.0]]) / 4.0
    red_blue = np.array([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]]) / 4.0
    return green, red_blue


def demosaic_bilinear(mosaic: np.ndarray, cfa: str) -> np.ndarray:
    """Full-resolution RGB from a raw mosaic by bilinear interpolation (the paper's rendering).

    Each channel keeps its own samples and fills the others with the mean of the nearest
    same-colour neighbours (edges mirrored). Linear, so it commutes with the weighted sum of
    the computational flash.

    Examples
    --------
    >>> demosaic_bilinear(np.tile([[1.0, 2.0], [2.0, 3.0]], (2, 2)), "RGGB")[1, 1].tolist()
    [1.0, 2.0, 3.0]
    """
    from scipy.ndimage import convolve

    from msflash.processing.sensor import cfa_channel_map

    if cfa not in CFA_PATTERNS:
        raise SpectralDataError(f"demosaic: CFA '{cfa}'; expected one of {', '.join(CFA_PATTERNS)}")
    if mosaic.ndim != 2 or min(mosaic.shape) < 2:
        raise SpectralDataError(f"demosaic: mosaic has shape {mosaic.shape}; expected (H, W) with H, W ≥ 2")
    channels = cfa_channel_map(cfa, mosaic.shape)
    values = mosaic.astype(np.float64)
    green_kernel, red_blue_kernel = _bilinear_kernels()
    planes = []
    for channel in range(3):
        kernel = green_kernel if channel == 1 else red_blue_kernel
        present = (channels == channel).astype(np.float64)
        # Normalised convolution: exact at the borders (mirror) and for any layout.
        total = convolve(values * present, kernel, mode="mirror")
        weight = convolve(present, kernel, mode="mirror")
        planes.append(np.where(present > 0, values, total / np.maximum(weight, 1e-12)))
    return np.stack(planes, axis=-1)


def reflectances_to_xyz(reflectances: Spectra, illuminant: Spectra) -> np.ndarray:
    """CIE 1931 2° XYZ of each surface under an illuminant, shape (n_surfaces, 3), Y of a perfect white = 1.

    ``illuminant`` may be in energy or photons (converted to energy: the colour-matching
    functions are defined on radiance).

    Examples
    --------
    >>> from msflash.processing import datasets
    >>> white = Spectra(datasets.DEFAULT_GRID, np.ones(31), ("white",), kind="reflectance", unit="none")
    >>> xyz = reflectances_to_xyz(white, datasets.illuminant("D65"))
    >>> [round(float(v), 3) for v in xyz[0]]  # D65 white point on a 10 nm grid
    [0.949, 1.0, 1.087]
    """
    grid = require_same_grid(reflectances, illuminant)
    if illuminant.kind != "spd" or illuminant.count != 1:
        raise SpectralDataError(f"{illuminant.source or 'illuminant'}: expected one spectrum of kind 'spd'")
    observer = datasets.cie1931_cmfs(grid).values  # energy weights, (n_wavelengths, 3)
    light = illuminant.to_unit("energy").values[:, 0]
    white_y = float(observer[:, 1] @ light)
    if white_y <= 0:
        raise SpectralDataError(f"{illuminant.source or 'illuminant'}: no visible light; expected Y > 0")
    return (reflectances.values * light[:, None]).T @ observer / white_y


def camera_to_xyz_matrix(camera_responsivities: Spectra, chart: Spectra, illuminant: Spectra) -> np.ndarray:
    """3×3 matrix M with ``XYZ ≈ M · rgb``, fitted by least squares on a chart under an illuminant.

    ``camera_responsivities`` and ``illuminant`` in photons, ``chart`` reflectances, one grid.
    The camera responses are normalised so a perfect white has G = 1 under the illuminant.
    """
    rgb = surface_responses(chart, illuminant, camera_responsivities)
    white = camera_responsivities.values.T @ illuminant.values[:, 0]
    rgb = rgb / white[1]
    xyz = reflectances_to_xyz(chart, illuminant)
    matrix, *_ = np.linalg.lstsq(rgb, xyz, rcond=None)
    return matrix.T


def camera_to_srgb_linear(
    linear_rgb: np.ndarray, camera_to_xyz: np.ndarray | None = None, white_balance: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Linear camera RGB → (linear sRGB, luminance Y), both unclipped.

    Parameters
    ----------
    linear_rgb
        (H, W, 3) or (n, 3) linear camera values.
    camera_to_xyz
        The 3×3 camera → XYZ matrix; None treats camera RGB as linear sRGB.
    white_balance
        Optional per-channel von Kries gains applied to camera RGB first
        (:func:`processing.colour_metrics.von_kries_gains`); None renders as captured, as the paper does.
    """
    rgb = np.asarray(linear_rgb, dtype=np.float64)
    if rgb.shape[-1] != 3:
        raise SpectralDataError(f"render: image has shape {rgb.shape}; expected (..., 3)")
    if white_balance is not None:
        gains = np.asarray(white_balance, dtype=np.float64)
        if gains.shape != (3,) or not np.all(np.isfinite(gains)) or np.any(gains <= 0):
            raise SpectralDataError(f"render: white balance gains {gains}; expected three finite values > 0")
        rgb = rgb * gains
    if camera_to_xyz is None:
        return rgb, rgb @ np.array([0.2126, 0.7152, 0.0722])
    import colour

    xyz = rgb @ np.asarray(camera_to_xyz, dtype=np.float64).T
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour's domain-range notes; the conversion is a plain 3×3 product
        srgb_linear = colour.XYZ_to_RGB(xyz, "sRGB", apply_cctf_encoding=False)
    return srgb_linear, xyz[..., 1]


def encode_srgb(srgb_linear: np.ndarray, white_value: float) -> np.ndarray:
    """Linear sRGB scaled so ``white_value`` is display white, clipped and sRGB-encoded, float in [0, 1]."""
    import colour

    white_value = white_value if (np.isfinite(white_value) and white_value > 0) else 1.0
    return colour.cctf_encoding(np.clip(srgb_linear / white_value, 0.0, 1.0), function="sRGB")


MEDIAN_LEVEL = 0.25
"""The display level (linear, white = 1) a preview gives the median of the pixels' brightest channel."""


def display_white(srgb_linear: np.ndarray) -> float:
    """The linear value a preview shows as display white: its exposure.

    Measured on each pixel's brightest linear sRGB channel (so a strong cast, rendered without
    white balance, does not clip its dominant channel): the 99.5th percentile of it, unless that
    leaves the scene's median darker than :data:`MEDIAN_LEVEL` of white; then ``median / MEDIAN_LEVEL``,
    and the few pixels above white clip. A small bright area — a specular highlight, the sim rig's
    highlight strip below the chart (its size: docs/measurements.md) — then does not set the exposure
    and darken everything else.

    Examples
    --------
    >>> scene = np.full((1000, 3), 0.05); scene[:40] = 0.9  # a diffuse scene and 4 % highlights
    >>> round(display_white(scene), 3)  # median 0.05 → white 0.05 / 0.25
    0.2
    >>> round(display_white(np.linspace(0.0, 1.0, 101)[:, None] * [1.0, 0.5, 0.2]), 3)  # bright: the percentile
    0.995
    """
    values = np.asarray(srgb_linear, dtype=np.float64)
    brightest = (values.max(axis=-1) if values.ndim > 1 else values).ravel()
    brightest = brightest[np.isfinite(brightest)]
    if brightest.size == 0:
        return 1.0
    white = float(np.percentile(brightest, 99.5))
    median = float(np.median(brightest))
    if median > 0 and median / MEDIAN_LEVEL < white:
        white = median / MEDIAN_LEVEL
    return white if white > 0 else 1.0


def srgb_preview(
    linear_rgb: np.ndarray,
    camera_to_xyz: np.ndarray | None = None,
    white_value: float | None = None,
    white_balance: np.ndarray | None = None,
) -> np.ndarray:
    """An 8-bit sRGB preview of a linear camera RGB image (H, W, 3), rendered by :func:`camera_to_srgb_linear`.

    ``white_value``, the linear value shown as display white, is :func:`display_white` of the image by
    default: previews of images with different exposures are comparable only when given one.
    """
    if linear_rgb.ndim != 3 or linear_rgb.shape[2] != 3:
        raise SpectralDataError(f"preview: image has shape {linear_rgb.shape}; expected (H, W, 3)")
    srgb_linear, _ = camera_to_srgb_linear(linear_rgb, camera_to_xyz, white_balance)
    if white_value is None:
        white_value = display_white(srgb_linear)
    return np.round(encode_srgb(srgb_linear, white_value) * 255).astype(np.uint8)
