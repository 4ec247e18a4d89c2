"""What a raw developer needs to know about a camera's colour: the neutral and the colour matrix.

Public objects
--------------
- :func:`camera_neutral`: a camera's RGB of white under an illuminant (DNG ``AsShotNeutral``).
- :class:`CameraMatrix` and :func:`camera_matrix`: its XYZ ↔ camera matrices (DNG ``ColorMatrix1``),
  from the camera's responsivities or, without them, from the assumption msflash's previews
  make (camera RGB taken as linear sRGB).
- :func:`rgb_chromaticities`: the xy of the R, G, B primaries and of white of a camera → XYZ matrix.
- :data:`XYZ_TO_LINEAR_SRGB`: IEC 61966-2-1's matrix (D65 white).

The neutral is the camera's RGB response to the illuminant reflected by a perfect white,
``Cᵀ i`` (eq. 1 with r = 1), normalised so its largest channel is 1: DNG's ``AsShotNeutral``,
which a raw developer divides by to white-balance. The colour matrix is the inverse of the
3×3 camera → XYZ fit on a Macbeth chart under D65 (:func:`processing.render.camera_to_xyz_matrix`,
the fit msflash's previews use), scaled as DNG's ``ColorMatrix1`` is: D65's white (Y = 1) maps
to a camera RGB whose largest channel is 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.render import camera_to_xyz_matrix, reflectances_to_xyz
from msflash.processing.spectra import Spectra

XYZ_TO_LINEAR_SRGB = np.array(
    [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ]
)
"""XYZ → linear sRGB (IEC 61966-2-1, D65 white): what msflash assumes of a camera with no recorded
responsivities."""

CALIBRATION_ILLUMINANT = "D65"
"""The illuminant the colour matrix is fitted under (DNG ``CalibrationIlluminant1`` 21)."""


@dataclass(frozen=True)
class CameraMatrix:
    """A camera's colour matrix, both ways."""

    xyz_to_camera: np.ndarray
    """3×3, camera RGB ≈ M · XYZ under D65, D65 white → largest channel 1 (DNG ``ColorMatrix1``)."""
    camera_to_xyz: np.ndarray
    """3×3, XYZ ≈ M · camera RGB (the fit; G of D65 white = 1)."""
    source: str
    """``"camera responsivities"``, or ``"assumed linear sRGB"`` when none were recorded."""


def _xyz_of_light(illuminant: Spectra) -> np.ndarray:
    observer = datasets.cie1931_cmfs(illuminant.grid).values  # energy weights
    return observer.T @ illuminant.to_unit("energy").values[:, 0]


def camera_neutral(illuminant: Spectra, camera_responsivities: Spectra | None) -> np.ndarray:
    """Camera R, G, B of a perfect white under ``illuminant``, ``Cᵀ i`` (eq. 1, r = 1), largest channel 1.

    DNG's ``AsShotNeutral``: what a raw developer white-balances to.

    Without ``camera_responsivities`` camera RGB is taken as linear sRGB (as msflash's previews take
    it) and the neutral is the sRGB of the illuminant's XYZ.

    Raises
    ------
    SpectralDataError
        If the camera does not see the illuminant in every channel (a neutral must be > 0).

    Examples
    --------
    >>> from msflash.processing import datasets
    >>> [round(float(v), 2) for v in camera_neutral(datasets.illuminant("D65"), None)]  # sRGB's white
    [1.0, 1.0, 1.0]
    >>> [round(float(v), 2) for v in camera_neutral(datasets.illuminant("A"), None)]  # tungsten: red
    [1.0, 0.45, 0.13]
    """
    if camera_responsivities is None:
        neutral = XYZ_TO_LINEAR_SRGB @ _xyz_of_light(illuminant)
    else:
        neutral = camera_responsivities.to_unit("photons").values.T @ illuminant.to_unit("photons").values[:, 0]
    if not np.all(np.isfinite(neutral)) or np.any(neutral <= 0):
        raise SpectralDataError(
            f"{illuminant.source or 'illuminant'}: camera response {np.round(neutral, 6).tolist()} to it; expected "
            "three values > 0 (an illuminant the camera sees in every channel)"
        )
    return neutral / neutral.max()


def camera_matrix(camera_responsivities: Spectra | None) -> CameraMatrix:
    """The camera → XYZ fit on a Macbeth chart under D65 and its inverse scaled as DNG's ``ColorMatrix1``.

    Without responsivities, camera RGB is taken as linear sRGB (:data:`XYZ_TO_LINEAR_SRGB`).

    Examples
    --------
    >>> matrix = camera_matrix(None)
    >>> matrix.source, [round(float(v), 4) for v in matrix.xyz_to_camera[0]]
    ('assumed linear sRGB', [3.2405, -1.5371, -0.4985])
    """
    if camera_responsivities is None:
        return CameraMatrix(XYZ_TO_LINEAR_SRGB.copy(), np.linalg.inv(XYZ_TO_LINEAR_SRGB), "assumed linear sRGB")
    responsivities = camera_responsivities.to_unit("photons")
    grid = responsivities.grid
    d65 = datasets.illuminant(CALIBRATION_ILLUMINANT, grid).to_unit("photons")
    chart = datasets.macbeth().resample(grid, outside="edge")
    camera_to_xyz = camera_to_xyz_matrix(responsivities, chart, d65)
    xyz_to_camera = np.linalg.inv(camera_to_xyz)
    white = Spectra(grid, np.ones((grid.size, 1)), ("white",), kind="reflectance", unit="none")
    d65_white = xyz_to_camera @ reflectances_to_xyz(white, d65)[0]
    return CameraMatrix(xyz_to_camera / d65_white.max(), camera_to_xyz, "camera responsivities")


def rgb_chromaticities(camera_to_xyz: np.ndarray) -> tuple[float, ...]:
    """xy of the R, G, B primaries and of white (R = G = B) of a camera → XYZ matrix, 8 values.

    The order of OpenEXR's ``chromaticities`` attribute: red x, y, green x, y, blue x, y, white x, y.

    Raises
    ------
    SpectralDataError
        If a primary's X + Y + Z is not positive (a fit that puts a channel outside the visible).

    Examples
    --------
    >>> xy = rgb_chromaticities(np.linalg.inv(XYZ_TO_LINEAR_SRGB))
    >>> [round(v, 4) for v in xy]  # Rec. 709 primaries, D65 white
    [0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3127, 0.329]
    """
    matrix = np.asarray(camera_to_xyz, dtype=float)
    columns = [matrix[:, 0], matrix[:, 1], matrix[:, 2], matrix.sum(axis=1)]
    values: list[float] = []
    for name, xyz in zip(("red", "green", "blue", "white"), columns, strict=True):
        total = float(xyz.sum())
        if not np.isfinite(total) or total <= 0:
            raise SpectralDataError(f"camera → XYZ matrix: the {name} primary has X + Y + Z = {total:g}; expected > 0")
        values += [float(xyz[0] / total), float(xyz[1] / total)]
    return tuple(values)
