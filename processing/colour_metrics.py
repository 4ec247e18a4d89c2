"""Colour accuracy and noise of rendered charts: per-patch CIEDE2000, von Kries, SNR, chroma noise.

Public objects
--------------
- :func:`usable_labels`: a label image with the pixels near patch edges dropped.
- :func:`patch_means`, :func:`patch_pixels`: per-patch statistics of an image from a label map.
- :func:`reference_chart`: XYZ and CIELAB of the ideal chart under a reference illuminant (D65).
- :func:`xyz_to_lab`, :func:`delta_e_2000`: thin wrappers on colour-science (warnings contained).
- :func:`luminance_scale`: the exposure normalisation before ΔE.
- :func:`chart_delta_e`: Fig. 9's per-patch ΔE00 of a camera image against the ideal chart.
- :func:`von_kries_gains`, :func:`von_kries_balance`: diagonal white balance in camera space.
- :func:`channel_snr`, :func:`chroma_noise`: the noise measures of Fig. 3.

How Fig. 9's ΔE is computed here
--------------------------------
The paper renders every image the same way — a 3×3 camera → XYZ matrix fitted on a Macbeth
chart under D65, **no white balance** — and compares chart patches with the ideal chart under
D65. An image's absolute level depends on exposure and flash power, which ΔE should not
punish, so the patch XYZ are first scaled by one number, the least-squares fit of their Y to
the reference Y (:func:`luminance_scale`). The colour cast of the illuminant is left intact,
which is what the figure measures. Lab uses the reference illuminant's white (Y = 1).

Noise (Fig. 3)
--------------
A von Kries balance multiplies each camera channel by a gain: the per-channel SNR of a patch
(mean / std) does not change, but a weak channel (red under water) is amplified to full
brightness with its noise, which shows as chroma noise — the spread of a*, b* within uniform
patches, ``sqrt(σ_a*² + σ_b*²)``. A complementary flash instead adds the missing light, so the
weak channel's SNR itself rises. Both are measured at equal exposure.

References
----------
Blasinski H., Farrell J. "Computational multispectral flash", ICCP 2017, Fig. 3 and Fig. 9.
Sharma G., Wu W., Dalal E. N. (2005), "The CIEDE2000 color-difference formula", Color Res.
Appl. 30(1), 21–30.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from msflash.processing.errors import SpectralDataError
from msflash.processing.render import reflectances_to_xyz
from msflash.processing.sensor import cfa_channel_map
from msflash.processing.spectra import Spectra


def _colour():  # noqa: ANN202 - colour-science takes a second to import; only these helpers need it
    import colour

    return colour


# -- patches ----------------------------------------------------------------------------------
def usable_labels(labels: np.ndarray, margin_px: int = 1, excluded: np.ndarray | None = None) -> np.ndarray:
    """Labels with every pixel within ``margin_px`` of another label (or an excluded pixel) set to −1.

    Edges mix two surfaces after demosaicking, optics or misregistration; patch statistics use
    the interior only.

    Examples
    --------
    >>> labels = np.zeros((5, 5), dtype=int); labels[:, 3:] = 1
    >>> usable_labels(labels, 1)[2].tolist()
    [0, 0, -1, -1, 1]
    """
    from scipy.ndimage import maximum_filter, minimum_filter

    labels = np.asarray(labels)
    if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer):
        raise SpectralDataError(
            f"patch labels: shape {labels.shape}, type {labels.dtype}; expected an integer (H, W) array"
        )
    result = labels.astype(np.int64, copy=True)
    if excluded is not None:
        result[np.asarray(excluded, dtype=bool)] = -1
    if margin_px > 0:
        size = 2 * margin_px + 1
        low = minimum_filter(result, size=size, mode="nearest")
        high = maximum_filter(result, size=size, mode="nearest")
        result[low != high] = -1
    return result


def _labels_for(image: np.ndarray, labels: np.ndarray) -> np.ndarray:
    if image.shape[:2] != labels.shape:
        raise SpectralDataError(
            f"patch statistics: image {image.shape[:2]} and labels {labels.shape} differ in size; "
            "expected the label map of this image"
        )
    return labels


def patch_pixels(image: np.ndarray, labels: np.ndarray, patch: int, cfa: str | None = None) -> list[np.ndarray]:
    """The samples of one patch, per channel: a list of 1-D arrays (R, G, B; or one for mono).

    For a raw mosaic (``image`` 2-D and ``cfa`` given) each channel gets the samples of its
    colour, so no demosaicking is needed for patch statistics.
    """
    labels = _labels_for(image, labels)
    inside = labels == patch
    if image.ndim == 2:
        if cfa is None:
            return [image[inside].astype(np.float64)]
        channels = cfa_channel_map(cfa, image.shape)
        return [image[inside & (channels == c)].astype(np.float64) for c in range(3)]
    return [image[..., c][inside].astype(np.float64) for c in range(image.shape[2])]


def patch_means(
    image: np.ndarray, labels: np.ndarray, n_patches: int, cfa: str | None = None, min_pixels: int = 1
) -> np.ndarray:
    """Mean of every channel over every patch ``0 … n_patches − 1``, shape (n_patches, n_channels).

    Raises
    ------
    SpectralDataError
        If a patch has fewer than ``min_pixels`` usable samples in some channel.

    Examples
    --------
    >>> image = np.dstack([np.arange(4.0).reshape(2, 2)] * 3)
    >>> patch_means(image, np.array([[0, 0], [1, 1]]), 2)[:, 0].tolist()
    [0.5, 2.5]
    """
    means = []
    for patch in range(n_patches):
        samples = patch_pixels(image, labels, patch, cfa)
        counts = [s.size for s in samples]
        if min(counts) < min_pixels:
            raise SpectralDataError(
                f"patch {patch}: {min(counts)} usable pixels; expected at least {min_pixels} "
                "(check the chart layout: --patch-px/--border-px)"
            )
        means.append([float(s.mean()) for s in samples])
    return np.asarray(means)


# -- colorimetry ------------------------------------------------------------------------------
def xyz_to_lab(xyz: np.ndarray, white_xyz: np.ndarray) -> np.ndarray:
    """CIELAB of XYZ values relative to a white ``white_xyz`` (same scale as ``xyz``), shape (..., 3)."""
    colour = _colour()
    white_xyz = np.asarray(white_xyz, dtype=np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", colour.utilities.ColourWarning)
        return colour.XYZ_to_Lab(np.asarray(xyz, dtype=np.float64) / white_xyz[1], colour.XYZ_to_xy(white_xyz))


def delta_e_2000(lab_a: np.ndarray, lab_b: np.ndarray) -> np.ndarray:
    """CIEDE2000 between two sets of Lab colours (colour-science's ``delta_E(method="CIE 2000")``).

    Examples
    --------
    >>> round(float(delta_e_2000(np.array([50.0, 2.6772, -79.7751]), np.array([50.0, 0.0, -82.7485]))), 4)
    2.0425
    """
    colour = _colour()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", colour.utilities.ColourWarning)
        return np.asarray(colour.delta_E(lab_a, lab_b, method="CIE 2000"), dtype=np.float64)


@dataclass(frozen=True)
class ReferenceChart:
    """The ideal chart under a reference illuminant."""

    xyz: np.ndarray
    """XYZ of every patch, (n_patches, 3), Y of a perfect white = 1."""
    lab: np.ndarray
    """CIELAB of every patch, (n_patches, 3)."""
    white_xyz: np.ndarray
    """XYZ of the perfect white, (3,)."""
    illuminant: str
    """Name or source of the illuminant."""


def reference_chart(reflectances: Spectra, illuminant: Spectra) -> ReferenceChart:
    """XYZ and Lab of surfaces under ``illuminant`` (D65 for Fig. 9), relative to a perfect white."""
    xyz = reflectances_to_xyz(reflectances, illuminant)
    white = reflectances_to_xyz(
        reflectances.replace(values=np.ones((reflectances.grid.size, 1)), names=("white",)), illuminant
    )[0]
    return ReferenceChart(xyz, xyz_to_lab(xyz, white), white, illuminant.source or illuminant.names[0])


def luminance_scale(xyz: np.ndarray, reference_xyz: np.ndarray) -> float:
    """The factor ``s`` minimising ``Σ (s·Y − Y_ref)²`` over patches: exposure normalisation before ΔE.

    Examples
    --------
    >>> luminance_scale(np.array([[0, 1.0, 0], [0, 2.0, 0]]), np.array([[0, 0.5, 0], [0, 1.0, 0]]))
    0.5
    """
    y, reference = np.asarray(xyz)[:, 1], np.asarray(reference_xyz)[:, 1]
    denominator = float(y @ y)
    if not denominator > 0:
        raise SpectralDataError("luminance scale: the image patches have no luminance; expected a lit chart")
    return float(y @ reference) / denominator


@dataclass(frozen=True)
class ChartDeltaE:
    """Per-patch CIEDE2000 of an image of a chart against the ideal chart."""

    delta_e: np.ndarray
    """ΔE00 of every patch, (n_patches,)."""
    lab: np.ndarray
    """The image's patch colours in CIELAB after exposure normalisation, (n_patches, 3)."""
    xyz: np.ndarray
    """The image's patch XYZ after exposure normalisation, (n_patches, 3)."""
    scale: float
    """The exposure normalisation applied to camera → XYZ values (:func:`luminance_scale`)."""

    @property
    def mean(self) -> float:
        """Mean ΔE00 over patches (Fig. 9's number)."""
        return float(np.mean(self.delta_e))

    @property
    def max(self) -> float:
        """Largest ΔE00 over patches."""
        return float(np.max(self.delta_e))


def chart_delta_e(
    camera_means: np.ndarray,
    camera_to_xyz: np.ndarray,
    reference: ReferenceChart,
    white_balance: np.ndarray | None = None,
) -> ChartDeltaE:
    """Fig. 9: per-patch ΔE00 of an image's patch means against the ideal chart.

    Parameters
    ----------
    camera_means
        Linear camera RGB of every patch, (n_patches, 3) (:func:`patch_means`), any scale.
    camera_to_xyz
        The 3×3 matrix of :func:`processing.render.camera_to_xyz_matrix` (fitted under D65).
    reference
        The ideal chart (:func:`reference_chart`), same patches in the same order.
    white_balance
        Optional von Kries gains applied to camera RGB first (None: the paper's rendering).
    """
    camera_means = np.asarray(camera_means, dtype=np.float64)
    if camera_means.shape != reference.xyz.shape:
        raise SpectralDataError(
            f"chart ΔE: {camera_means.shape} patch means for a {reference.xyz.shape} reference; "
            "expected one RGB triple per reference patch"
        )
    rgb = camera_means * (np.asarray(white_balance, dtype=np.float64) if white_balance is not None else 1.0)
    xyz = rgb @ np.asarray(camera_to_xyz, dtype=np.float64).T
    scale = luminance_scale(xyz, reference.xyz)
    xyz = xyz * scale
    lab = xyz_to_lab(xyz, reference.white_xyz)
    return ChartDeltaE(delta_e_2000(lab, reference.lab), lab, xyz, scale)


# -- white balance ----------------------------------------------------------------------------
def von_kries_gains(ambient_white: np.ndarray, target_white: np.ndarray) -> np.ndarray:
    """Per-channel gains taking the camera's white under the ambient to its white under the target.

    Gains are normalised so the green gain is 1 (the image keeps its green level, as cameras do).

    Parameters
    ----------
    ambient_white, target_white
        Camera RGB of a white surface under the ambient and under the target (e.g.
        ``Cᵀ I w_a`` and ``Cᵀ i_D65``), shape (3,).

    Examples
    --------
    >>> von_kries_gains(np.array([2.0, 1.0, 0.5]), np.array([1.0, 1.0, 1.0])).tolist()
    [0.5, 1.0, 2.0]
    """
    ambient_white = np.asarray(ambient_white, dtype=np.float64)
    target_white = np.asarray(target_white, dtype=np.float64)
    if (
        ambient_white.shape != (3,)
        or target_white.shape != (3,)
        or np.any(ambient_white <= 0)
        or np.any(target_white <= 0)
    ):
        raise SpectralDataError(f"von Kries: whites {ambient_white} and {target_white}; expected two RGB triples > 0")
    gains = target_white / ambient_white
    return gains / gains[1]


def von_kries_balance(image: np.ndarray, gains: np.ndarray, cfa: str | None = None) -> np.ndarray:
    """The image with each channel multiplied by its gain (a mosaic by each sample's channel)."""
    gains = np.asarray(gains, dtype=np.float64)
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 2:
        if cfa is None:
            raise SpectralDataError("von Kries: a one-channel image needs its CFA layout; expected cfa")
        return image * gains[cfa_channel_map(cfa, image.shape)]
    return image * gains


# -- noise ------------------------------------------------------------------------------------
def channel_snr(
    image: np.ndarray, labels: np.ndarray, patches: list[int] | np.ndarray, cfa: str | None = None
) -> np.ndarray:
    """Per-patch, per-channel SNR ``mean / std`` over uniform patches, shape (n_patches, n_channels).

    ``image`` is linear with its black level removed; for a raw mosaic give ``cfa``. The SNR of
    a channel does not change under a per-channel gain (von Kries).
    """
    result = []
    for patch in patches:
        samples = patch_pixels(image, labels, int(patch), cfa)
        if min(s.size for s in samples) < 2:
            raise SpectralDataError(f"SNR: patch {patch} has fewer than 2 usable pixels; expected a larger patch")
        result.append([float(s.mean() / s.std(ddof=1)) if s.std(ddof=1) > 0 else np.inf for s in samples])
    return np.asarray(result)


def chroma_noise(
    camera_rgb: np.ndarray,
    labels: np.ndarray,
    patches: list[int] | np.ndarray,
    camera_to_xyz: np.ndarray,
    reference: ReferenceChart,
    n_patches: int,
    white_balance: np.ndarray | None = None,
) -> np.ndarray:
    """Chroma noise ``sqrt(σ_a*² + σ_b*²)`` within each of ``patches``, shape (len(patches),).

    The image (H, W, 3, demosaicked, linear) is rendered like :func:`chart_delta_e` — optional
    von Kries gains, camera → XYZ, one exposure normalisation fitted on the patch means of all
    ``n_patches`` patches — then every pixel goes to CIELAB.
    """
    rgb = np.asarray(camera_rgb, dtype=np.float64)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise SpectralDataError(f"chroma noise: image has shape {rgb.shape}; expected (H, W, 3)")
    if white_balance is not None:
        rgb = rgb * np.asarray(white_balance, dtype=np.float64)
    matrix = np.asarray(camera_to_xyz, dtype=np.float64)
    means = patch_means(rgb, labels, n_patches)
    scale = luminance_scale(means @ matrix.T, reference.xyz)
    result = []
    for patch in patches:
        inside = _labels_for(rgb, labels) == int(patch)
        lab = xyz_to_lab(rgb[inside] @ matrix.T * scale, reference.white_xyz)
        if lab.shape[0] < 2:
            raise SpectralDataError(f"chroma noise: patch {patch} has fewer than 2 usable pixels")
        result.append(float(np.sqrt(lab[:, 1].var(ddof=1) + lab[:, 2].var(ddof=1))))
    return np.asarray(result)
