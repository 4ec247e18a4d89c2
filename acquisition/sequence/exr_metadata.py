"""What an EXR of a sequence's linear image carries: chromaticities, units and the LED names.

Public objects
--------------
- :data:`LINEAR_UNITS`: the unit of msflash's linear images.
- :class:`ExrMetadata` and :func:`exr_metadata`: the ``msflash:*`` attributes and the standard
  ``chromaticities`` for :func:`acquisition.sequence.image_files.write_image`.

Every EXR msflash writes from a sequence (``run``'s computational images, ``flash``/``synthesize
--out``, ``evaluate``'s images, ``export --to exr``) goes through :func:`exr_metadata`, so a viewer
knows what the RGB means (the camera's primaries in xy: the camera → XYZ fit of
:func:`processing.raw_colour.camera_matrix`, or sRGB's when the sequence has no responsivities,
said in ``msflash:chromaticities_source``), what a value is, and which LEDs made the image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from msflash.acquisition.sequence.format import Sequence
from msflash.processing.errors import SpectralDataError
from msflash.processing.raw_colour import camera_matrix, rgb_chromaticities

LINEAR_UNITS = "camera counts above black per µs of exposure at gain 1 (linear camera RGB)"
"""``(value − black) / (exposure_us · gain)``, docs/architecture.md §6."""


@dataclass(frozen=True)
class ExrMetadata:
    """Attributes of an EXR written from a sequence."""

    attributes: dict = field(default_factory=dict)
    """``msflash:units``, ``msflash:led_names``, ``msflash:led_peak_nm``, ``msflash:camera_model``,
    ``msflash:chromaticities_source``."""
    chromaticities: tuple[float, ...] | None = None
    """xy of R, G, B and white (8 values), or None for a one-channel (mosaic) image."""


def led_peaks_nm(sequence: Sequence) -> list[float]:
    """Wavelength of each LED spectrum's maximum, nm, in the sequence's LED order."""
    return [float(sequence.wavelengths_nm[int(np.argmax(led.spd))]) for led in sequence.leds]


def exr_metadata(sequence: Sequence, channels: int = 3, units: str = LINEAR_UNITS) -> ExrMetadata:
    """The attributes of an EXR of ``channels`` channels holding a linear image of ``sequence``.

    ``msflash:led_names`` is the LED names joined by ", " (EXR viewers show strings; the JSON
    ``ImageDescription`` keeps them too). A camera → XYZ fit whose primaries leave the visible
    (X + Y + Z ≤ 0) gets no chromaticities, and ``msflash:chromaticities_source`` says so.
    """
    responsivities = sequence.camera_responsivities()
    attributes: dict = {
        "msflash:units": units,
        "msflash:led_names": ", ".join(led.name for led in sequence.leds),
        "msflash:led_peak_nm": led_peaks_nm(sequence),
        "msflash:camera_model": sequence.camera.model,
    }
    if channels != 3:
        attributes["msflash:cfa"] = sequence.camera.cfa or "mono"
        attributes["msflash:chromaticities_source"] = "none (one-channel image)"
        return ExrMetadata(attributes, None)
    matrix = camera_matrix(responsivities)
    try:
        chromaticities: tuple[float, ...] | None = rgb_chromaticities(matrix.camera_to_xyz)
        attributes["msflash:chromaticities_source"] = (
            "camera responsivities (camera to XYZ fitted on a Macbeth chart under D65)"
            if responsivities is not None
            else "assumed linear sRGB (no camera responsivities in the sequence)"
        )
    except SpectralDataError as err:
        chromaticities = None
        attributes["msflash:chromaticities_source"] = f"none ({err})"
    return ExrMetadata(attributes, chromaticities)
