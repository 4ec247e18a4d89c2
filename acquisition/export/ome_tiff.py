"""A sequence's frames as one OME-TIFF: one plane per frame, what lit it and how it was exposed.

Layout. One OME ``Image`` whose channels are the frames (``DimensionOrder`` XYCZT, one TIFF page per
frame, ``TiffData`` naming it): an RGB frame is a channel of ``SamplesPerPixel`` 3, a raw mosaic one
of 1. The instrument lists the LEDs as ``LightEmittingDiode`` light sources and the camera as the
``Detector``; a frame lit by one LED names it in ``LightSourceSettings`` with its peak wavelength,
which is also the channel's ``ExcitationWavelength`` (nm); ``DetectorSettings.Gain`` is the frame's
gain and ``Plane.ExposureTime`` its exposure (µs). ``Image.AcquisitionDate`` is the first frame's time
and each ``Plane.DeltaT`` the frame's time after it (s), when known. Everything else (role, LED levels,
black and white levels) is in a ``MapAnnotation`` per channel and one for the image.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np
import tifffile
from ome_types import model as ome

_PIXEL_TYPES = {
    np.dtype(np.uint8): ome.PixelType.UINT8,
    np.dtype(np.uint16): ome.PixelType.UINT16,
    np.dtype(np.float32): ome.PixelType.FLOAT,
}
_DETECTOR = "Detector:0"
_NAMESPACE = "msflash.sequence"


@dataclass(frozen=True)
class OmeLight:
    """One LED of the booth."""

    name: str
    """The LED's name in the sequence."""
    peak_nm: float
    """Its measured peak wavelength, nm (:func:`processing.led_wavelength.led_peaks_nm`)."""


@dataclass(frozen=True)
class OmePlane:
    """What one frame is."""

    name: str
    """Channel name (unique in the file)."""
    exposure_us: float
    """Exposure time, µs."""
    gain: float
    """Linear gain."""
    light: int | None = None
    """Index in the lights of the one LED lighting the frame (besides the ambient), or None."""
    notes: Mapping[str, str] = field(default_factory=dict)
    """Key–value notes (role, LED levels…), written as the channel's ``MapAnnotation``."""
    delta_t_s: float | None = None
    """Seconds after the image's acquisition date (the first frame) the frame was taken, or None if unknown."""


def _map_annotation(identifier: str, notes: Mapping[str, str]) -> ome.MapAnnotation:
    pairs = [ome.Map.M(k=str(key), value=str(value)) for key, value in notes.items()]
    return ome.MapAnnotation(id=identifier, namespace=_NAMESPACE, value=ome.Map(ms=pairs))


def ome_document(
    planes: SequenceOf[OmePlane],
    lights: SequenceOf[OmeLight],
    shape: tuple[int, ...],
    dtype: np.dtype,
    camera_model: str,
    image_name: str,
    notes: Mapping[str, str],
    acquired: datetime | None = None,
) -> ome.OME:
    """The OME model of :func:`write_ome_tiff`'s file (frames of ``shape`` and ``dtype``)."""
    samples = 3 if len(shape) == 3 else 1
    annotations = [_map_annotation("Annotation:image", notes)]
    for index, plane in enumerate(planes):
        annotations.append(_map_annotation(f"Annotation:{index}", plane.notes))
    channels = [_channel(index, plane, lights, samples) for index, plane in enumerate(planes)]
    ome_planes = [
        ome.Plane(
            the_c=index,
            the_z=0,
            the_t=0,
            exposure_time=plane.exposure_us,
            exposure_time_unit=ome.UnitsTime.MICROSECOND,
            delta_t=plane.delta_t_s,
            delta_t_unit=ome.UnitsTime.SECOND,
        )
        for index, plane in enumerate(planes)
    ]
    blocks = [ome.TiffData(ifd=i, first_c=i, first_z=0, first_t=0, plane_count=1) for i in range(len(planes))]
    instrument = ome.Instrument(
        id="Instrument:0",
        detectors=[ome.Detector(id=_DETECTOR, model=camera_model)],
        light_emitting_diodes=[
            ome.LightEmittingDiode(id=f"LightSource:{k}", model=light.name) for k, light in enumerate(lights)
        ],
    )
    pixels = ome.Pixels(
        id="Pixels:0",
        dimension_order=ome.Pixels_DimensionOrder.XYCZT,
        type=_PIXEL_TYPES[np.dtype(dtype)],
        size_x=shape[1],
        size_y=shape[0],
        size_c=len(planes) * samples,
        size_z=1,
        size_t=1,
        interleaved=samples > 1,
        big_endian=False,
        channels=channels,
        planes=ome_planes,
        tiff_data_blocks=blocks,
    )
    image = ome.Image(
        id="Image:0",
        name=image_name,
        acquisition_date=acquired,
        pixels=pixels,
        instrument_ref=ome.InstrumentRef(id="Instrument:0"),
        annotation_refs=[ome.AnnotationRef(id="Annotation:image")],
    )
    return ome.OME(
        creator="msflash",
        images=[image],
        instruments=[instrument],
        structured_annotations=ome.StructuredAnnotations(map_annotations=annotations),
    )


def _channel(index: int, plane: OmePlane, lights: SequenceOf[OmeLight], samples: int) -> ome.Channel:
    """Plane ``index``'s channel: its name, the LED lighting it (wavelength, light source) and the detector's gain."""
    light = lights[plane.light] if plane.light is not None else None
    return ome.Channel(
        id=f"Channel:0:{index}",
        name=plane.name,
        samples_per_pixel=samples,
        excitation_wavelength=light.peak_nm if light is not None else None,
        excitation_wavelength_unit=ome.UnitsLength.NANOMETER,
        light_source_settings=(
            ome.LightSourceSettings(id=f"LightSource:{plane.light}", wavelength=light.peak_nm)
            if light is not None
            else None
        ),
        detector_settings=ome.DetectorSettings(id=_DETECTOR, gain=plane.gain),
        annotation_refs=[ome.AnnotationRef(id=f"Annotation:{index}")],
    )


def write_ome_tiff(
    path: str | os.PathLike,
    frames: Iterable[np.ndarray],
    planes: SequenceOf[OmePlane],
    lights: SequenceOf[OmeLight],
    camera_model: str,
    image_name: str,
    notes: Mapping[str, str] | None = None,
    acquired: datetime | None = None,
) -> Path:
    """Write frames as one OME-TIFF, a page per frame, the OME-XML in the first page's description.

    Parameters
    ----------
    frames
        One (H, W) or (H, W, 3) array per plane, all of one shape and type (uint8, uint16 or
        float32); taken one at a time, so a long sequence is never all in memory.
    lights
        The LEDs, in the order :attr:`OmePlane.light` indexes.
    notes
        Key–value notes for the image (``MapAnnotation``).
    acquired
        When the first frame was taken (an aware time): ``Image.AcquisitionDate``; None writes none.

    Raises
    ------
    ValueError
        If the frames' count, shape or type do not fit (the file is then incomplete: the caller removes it).
    """
    path = Path(path)
    count = 0
    with tifffile.TiffWriter(path, bigtiff=True, ome=False) as writer:
        first: np.ndarray | None = None
        for count, frame in enumerate(frames, start=1):
            pixels = np.asarray(frame)
            if first is None:
                if pixels.dtype not in _PIXEL_TYPES or pixels.ndim not in (2, 3):
                    raise ValueError(
                        f"{path}: frames of type {pixels.dtype}, shape {pixels.shape}; expected "
                        "(H, W) or (H, W, 3) uint8, uint16 or float32"
                    )
                first = pixels
                document = ome_document(
                    planes, lights, pixels.shape, pixels.dtype, camera_model, image_name, notes or {}, acquired
                )
                # TIFF strings are 7-bit ASCII: anything else (µs, a name) as an XML character reference.
                description: str | None = document.to_xml().encode("ascii", "xmlcharrefreplace").decode("ascii")
            elif pixels.shape != first.shape or pixels.dtype != first.dtype:
                raise ValueError(
                    f"{path}: frame {count - 1} is {pixels.shape} {pixels.dtype}; expected "
                    f"{first.shape} {first.dtype} as frame 0"
                )
            else:
                description = None
            if count > len(planes):
                raise ValueError(f"{path}: more frames than the {len(planes)} planes described")
            writer.write(
                pixels,
                photometric="rgb" if pixels.ndim == 3 else "minisblack",
                description=description,
                metadata=None,
                software="msflash",
                contiguous=False,
            )
    if count != len(planes):
        raise ValueError(f"{path}: {count} frames for {len(planes)} planes; expected one frame per plane")
    return path
