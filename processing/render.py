"""Rendering camera images for people: demosaic, camera → XYZ, sRGB.

The paper's figures are rendered without white balance: a 3×3 camera → XYZ matrix fitted on a
Macbeth chart under D65, then sRGB (PAPER.md). That keeps the ambient's colour cast visible,
which is the point of comparing ambient-only, matching and complementary images. Conversion to
colour-science objects happens here and in :mod:`processing.datasets` only.
"""

from __future__ import annotations

import warnings

import colour
import numpy as np

from processing.errors import SpectralDataError
from processing.image_formation import surface_responses
from processing.spectra import Spectra, require_same_grid

CFA_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")


def demosaic_superpixel(mosaic: np.ndarray, cfa: str) -> np.ndarray:
    """Half-resolution RGB from a raw mosaic: each 2×2 cell gives one pixel (greens averaged).

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
    cells = {(0, 0): mosaic[0:height:2, 0:width:2], (0, 1): mosaic[0:height:2, 1:width:2],
             (1, 0): mosaic[1:height:2, 0:width:2], (1, 1): mosaic[1:height:2, 1:width:2]}
    positions = {"RGGB": ((0, 0), ((0, 1), (1, 0)), (1, 1)), "BGGR": ((1, 1), ((0, 1), (1, 0)), (0, 0)),
                 "GRBG": ((0, 1), ((0, 0), (1, 1)), (1, 0)), "GBRG": ((1, 0), ((0, 0), (1, 1)), (0, 1))}[cfa]
    red = cells[positions[0]].astype(np.float64)
    green = 0.5 * (cells[positions[1][0]].astype(np.float64) + cells[positions[1][1]])
    blue = cells[positions[2]].astype(np.float64)
    return np.stack([red, green, blue], axis=-1)


def _xyz_of_reflectances(reflectances: Spectra, illuminant_energy: Spectra) -> np.ndarray:
    """CIE 1931 XYZ of each surface under an illuminant (energy units), shape (n, 3), Y of white = 1."""
    grid = require_same_grid(reflectances, illuminant_energy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
        observer = np.stack([np.interp(grid.wavelengths_nm, cmfs.wavelengths, cmfs.values[:, i]) for i in range(3)], 1)
    light = illuminant_energy.values[:, 0]
    white_y = float(observer[:, 1] @ light)
    return (reflectances.values * light[:, None]).T @ observer / white_y


def camera_to_xyz_matrix(camera_responsivities: Spectra, chart: Spectra, illuminant: Spectra) -> np.ndarray:
    """3×3 matrix M with ``XYZ ≈ M · rgb``, fitted by least squares on a chart under an illuminant.

    ``camera_responsivities`` and ``illuminant`` in photons, ``chart`` reflectances, one grid.
    The camera responses are normalised so a perfect white has G = 1 under the illuminant.
    """
    rgb = surface_responses(chart, illuminant, camera_responsivities)
    white = camera_responsivities.values.T @ illuminant.values[:, 0]
    rgb = rgb / white[1]
    xyz = _xyz_of_reflectances(chart, illuminant.to_unit("energy"))
    matrix, *_ = np.linalg.lstsq(rgb, xyz, rcond=None)
    return matrix.T


def srgb_preview(linear_rgb: np.ndarray, camera_to_xyz: np.ndarray | None = None, white_value: float | None = None,
                 percentile: float = 99.5) -> np.ndarray:
    """An 8-bit sRGB preview of a linear camera RGB image (no white balance).

    Parameters
    ----------
    linear_rgb
        (H, W, 3) linear camera values.
    camera_to_xyz
        The 3×3 camera → XYZ matrix; None treats camera RGB as linear sRGB.
    white_value
        The linear Y that maps to display white; default: the ``percentile`` of Y, so previews
        of images with different exposures are comparable only when given one ``white_value``.
    """
    if linear_rgb.ndim != 3 or linear_rgb.shape[2] != 3:
        raise SpectralDataError(f"preview: image has shape {linear_rgb.shape}; expected (H, W, 3)")
    if camera_to_xyz is None:
        srgb_linear = linear_rgb.astype(np.float64)
        luminance = srgb_linear @ np.array([0.2126, 0.7152, 0.0722])
    else:
        xyz = linear_rgb.astype(np.float64) @ camera_to_xyz.T
        luminance = xyz[..., 1]
        srgb_linear = colour.XYZ_to_RGB(xyz, "sRGB", apply_cctf_encoding=False)
    if white_value is None:
        white_value = float(np.percentile(luminance, percentile)) if luminance.size else 1.0
    white_value = white_value if white_value > 0 else 1.0
    encoded = colour.cctf_encoding(np.clip(srgb_linear / white_value, 0.0, 1.0), function="sRGB")
    return np.round(encoded * 255).astype(np.uint8)
