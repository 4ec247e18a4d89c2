"""What an EXR of a sequence's linear image holds: RGB, chromaticities, units and the LEDs.

Every EXR msflash writes from a sequence (``run``'s computational images, ``flash``/``synthesize
--out``, ``evaluate``'s images, ``export --to exr``) goes through :func:`exr_metadata`, so a viewer
knows what the RGB means (the camera's primaries in xy: the camera → XYZ fit of
:func:`processing.raw_colour.camera_matrix`, or sRGB's when the sequence has no responsivities,
said in ``msflash:chromaticities_source``), what a value is, and which LEDs made the image, with
their measured peaks (``msflash:led_peak_nm``, :meth:`Sequence.led_peaks_nm`, the one number).

A raw (Bayer) sequence's images are written demosaicked, ``R``, ``G``, ``B``, never as a one-channel
mosaic (which viewers take for luminance ``Y``): bilinear, which keeps each measured sample in its
own colour's channel, so the mosaic is every pixel's CFA channel of the file, exactly
(``msflash:cfa``, ``msflash:demosaic``; docs/decisions/exr-of-a-mosaic.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from msflash.acquisition.sequence.format import Sequence
from msflash.processing.errors import SpectralDataError
from msflash.processing.raw_colour import camera_matrix, rgb_chromaticities
from msflash.processing.render import demosaic_bilinear

LINEAR_UNITS = "camera counts above black per µs of exposure at gain 1 (linear camera RGB)"
"""``(value − black) / (exposure_us · gain)``, docs/architecture.md §6."""
DEMOSAIC_NOTE = (
    "bilinear: each pixel's CFA colour channel holds its measured value, the other two the mean of the "
    "nearest same-colour samples"
)
"""``msflash:demosaic`` of an EXR made from a raw mosaic."""


@dataclass(frozen=True)
class ExrMetadata:
    """Attributes of an EXR written from a sequence."""

    attributes: dict = field(default_factory=dict)
    """``msflash:units``, ``msflash:led_names``, ``msflash:led_peak_nm``, ``msflash:camera_model``,
    ``msflash:chromaticities_source``, and for a raw sequence ``msflash:cfa`` and ``msflash:demosaic``."""
    chromaticities: tuple[float, ...] | None = None
    """xy of R, G, B and white (8 values), or None for a one-channel (mosaic) image."""


def led_peaks_nm(sequence: Sequence) -> list[float]:
    """Each LED's peak wavelength, nm, in the sequence's LED order (:meth:`Sequence.led_peaks_nm`, the one number)."""
    return list(sequence.led_peaks_nm())


def exr_metadata(sequence: Sequence, units: str = LINEAR_UNITS) -> ExrMetadata:
    """The attributes of an RGB EXR holding a linear image of ``sequence``.

    ``msflash:led_names`` is the LED names joined by ", " (EXR viewers show strings; the JSON
    ``ImageDescription`` keeps them too) and ``msflash:led_peak_nm`` their measured peaks, nm. A camera
    → XYZ fit whose primaries leave the visible (X + Y + Z ≤ 0) gets no chromaticities, and
    ``msflash:chromaticities_source`` says so, as does a camera whose three responsivities are one curve (mono).
    """
    responsivities = sequence.camera_responsivities()
    attributes: dict = {
        "msflash:units": units,
        "msflash:led_names": ", ".join(led.name for led in sequence.leds),
        "msflash:led_peak_nm": led_peaks_nm(sequence),
        "msflash:camera_model": sequence.camera.model,
    }
    if sequence.camera.cfa is not None:
        attributes["msflash:cfa"] = sequence.camera.cfa
        attributes["msflash:demosaic"] = DEMOSAIC_NOTE
    try:
        matrix = camera_matrix(responsivities)
        chromaticities: tuple[float, ...] | None = rgb_chromaticities(matrix.camera_to_xyz)
        attributes["msflash:chromaticities_source"] = (
            "camera responsivities (camera to XYZ fitted on a Macbeth chart under D65)"
            if responsivities is not None
            else "assumed linear sRGB (no camera responsivities in the sequence)"
        )
    except SpectralDataError as err:
        chromaticities = None
        attributes["msflash:chromaticities_source"] = f"none ({err})"
    except np.linalg.LinAlgError:  # a mono camera's one curve in R, G and B: no colour to place
        chromaticities = None
        attributes["msflash:chromaticities_source"] = (
            "none (the camera's R, G and B responsivities are not independent, as a mono camera's one curve)"
        )
    return ExrMetadata(attributes, chromaticities)


def exr_image(sequence: Sequence, image: np.ndarray, units: str = LINEAR_UNITS) -> tuple[np.ndarray, ExrMetadata]:
    """A linear image of ``sequence`` as its EXR holds it — (H, W, 3) float32 RGB — and :func:`exr_metadata`.

    A raw mosaic ((H, W) with ``camera.cfa`` set) is demosaicked bilinearly (:data:`DEMOSAIC_NOTE`);
    an RGB image is kept as it is.

    Raises
    ------
    ValueError
        A one-channel image of a sequence without a CFA (format v1 records RGB or a mosaic).
    """
    pixels = np.asarray(image)
    if pixels.ndim == 2:
        if sequence.camera.cfa is None:
            raise ValueError(f"{sequence.path}: a one-channel image but camera.cfa is null; expected (H, W, 3) RGB")
        pixels = demosaic_bilinear(pixels, sequence.camera.cfa)
    return pixels.astype(np.float32), exr_metadata(sequence, units)
