"""Frame image files: the only module of msflash that uses OpenImageIO.

Frames describe themselves: :func:`write_image` stores its ``attributes`` (``msflash:role``,
``msflash:exposure_us``, ``msflash:led_levels``…) as a JSON object in the standard
``ImageDescription`` tag, because OpenImageIO's TIFF writer drops arbitrary attributes; EXR files
also get them as native header attributes. :func:`read_image_header` reads both back.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.frame_digest import FileDigest, digest_open_file
from msflash.acquisition.sequence.memory_budget import check_decode
from msflash.calibration.file_modes import replacing
from msflash.processing.json_input import parse_json_document
from msflash.processing.user_files import IMAGE_MAX_BYTES, check_user_file, shown_path

INTEGER_SUFFIX = ".tiff"
"""Suffix of integer frames (16-bit TIFF, uncompressed)."""
FLOAT_SUFFIX = ".exr"
"""Suffix of float frames (32-bit float EXR)."""

_ATTRIBUTE_PREFIX = "msflash:"
_INTEGER_SUFFIXES = (".tif", ".tiff")
_FLOAT_SUFFIXES = (".exr",)

# Native integer types are kept as they are (they are camera counts); every float type is
# returned as float32 so callers see one float type whatever the file stored (half, float, double).
_NATIVE_TYPES = {
    oiio.UINT8: ("uint8", np.uint8),
    oiio.UINT16: ("uint16", np.uint16),
    oiio.HALF: ("float", np.float32),
    oiio.FLOAT: ("float", np.float32),
    oiio.DOUBLE: ("float", np.float32),
}

_TYPE_NAMES = {
    oiio.INT8: "int8",
    oiio.INT16: "int16",
    oiio.UINT32: "uint32",
    oiio.INT32: "int32",
    oiio.UINT64: "uint64",
    oiio.INT64: "int64",
}
"""Names of the refused pixel types, as numpy calls them (OpenImageIO prints uint32 as 'uint')."""


@dataclass(frozen=True)
class ImageHeader:
    """What a frame file holds, read without decoding its pixels."""

    path: Path
    """The file."""
    width: int
    """Width in pixels."""
    height: int
    """Height in pixels."""
    channels: int
    """Number of channels: 1 (raw mosaic or mono) or 3 (RGB)."""
    dtype: np.dtype
    """The type :func:`read_image` returns: uint8, uint16 or float32."""
    attributes: dict = field(default_factory=dict, compare=False)
    """The msflash attributes stored by :func:`write_image` (empty for other files)."""

    @property
    def shape(self) -> tuple[int, ...]:
        """The shape :func:`read_image` returns: (H, W) or (H, W, 3)."""
        return (self.height, self.width) if self.channels == 1 else (self.height, self.width, self.channels)


def _oiio_error() -> str:
    # OpenImageIO keeps a per-thread error string; reading it also clears it, so a stale message
    # never leaks into the next failure.
    message = oiio.geterror()
    return message.strip() or "unknown OpenImageIO error"


@contextlib.contextmanager
def _open_input(path: Path):
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:  # OpenImageIO takes UTF-8 names only
        raise RecordingError(
            f"{shown_path(path)}: is not a UTF-8 file name; expected a file name in UTF-8 (rename the file)"
        ) from None
    if not os.path.lexists(path):
        raise RecordingError(f"{shown_path(path)}: image file is missing; expected a frame image")
    # Before OpenImageIO opens it: a FIFO would block it, a device or a directory has no image.
    check_user_file(path, "a frame image", IMAGE_MAX_BYTES, RecordingError)
    image = oiio.ImageInput.open(str(path))
    if image is None:
        raise RecordingError(f"{path}: cannot be read as an image ({_oiio_error()}); expected a TIFF, PNG or EXR")
    try:
        yield image
    finally:
        image.close()


def _header(path: Path, image: oiio.ImageInput) -> tuple[ImageHeader, str]:
    spec = image.spec()
    if spec.nchannels not in (1, 3):
        raise RecordingError(f"{path}: image has {spec.nchannels} channels; expected 1 (raw mosaic or mono) or 3 (RGB)")
    if spec.depth > 1:
        raise RecordingError(f"{path}: image is a volume (depth {spec.depth}); expected a 2-D image")
    basetype = spec.format.basetype
    if basetype not in _NATIVE_TYPES:
        name = _TYPE_NAMES.get(basetype, str(spec.format))
        raise RecordingError(
            f"{path}: pixel type '{name}' is not supported; expected uint8 or uint16 counts, or floats "
            "(16-, 32- or 64-bit)"
        )
    if image.seek_subimage(1, 0):
        # A multi-page TIFF (or multi-part file): which page is the frame is not for msflash to guess.
        raise RecordingError(
            f"{path}: holds more than one image (a multi-page TIFF?); expected one image per frame file"
        )
    image.seek_subimage(0, 0)
    request, dtype = _NATIVE_TYPES[basetype]
    header = ImageHeader(path, spec.width, spec.height, spec.nchannels, np.dtype(dtype), _attributes(spec))
    return header, request


def _attributes(spec: oiio.ImageSpec) -> dict:
    attributes: dict = {}
    description = spec.getattribute("ImageDescription")
    if isinstance(description, str) and description.startswith("{"):
        with contextlib.suppress(ValueError):  # someone else's description: ours or nothing
            decoded = parse_json_document(description, str(spec), ValueError)
            if isinstance(decoded, dict):
                attributes.update({k: v for k, v in decoded.items() if k.startswith(_ATTRIBUTE_PREFIX)})
    for attribute in spec.extra_attribs:
        if attribute.name.startswith(_ATTRIBUTE_PREFIX) and attribute.name not in attributes:
            value = attribute.value
            attributes[attribute.name] = list(value) if isinstance(value, tuple) else value
    return attributes


def read_image_header(path: str | os.PathLike) -> ImageHeader:
    """Size, channel count, pixel type and msflash attributes of an image file, without its pixels; refused as
    :func:`read_image` refuses."""
    path = Path(path)
    with _open_input(path) as image:
        return _header(path, image)[0]


def read_image(path: str | os.PathLike) -> np.ndarray:
    """The pixels of an image file OpenImageIO reads (16-bit TIFF or PNG, float EXR…).

    Returns
    -------
    numpy.ndarray
        Shape (H, W) for one channel, (H, W, 3) for three. Integer files keep their type
        (uint8, uint16) and values; float files (half, float, double) come back as float32.

    Raises
    ------
    RecordingError
        Naming the file, if it is missing, unreadable, of an unsupported pixel type (uint32,
        signed integers), holds more than one image (a multi-page TIFF), or has a channel count
        other than 1 or 3. The encodings read and refused: docs/architecture.md §6.
    """
    return read_image_and_header(path)[1]


def read_image_and_header(
    path: str | os.PathLike, before_decoding: Callable[[ImageHeader], None] | None = None
) -> tuple[ImageHeader, np.ndarray]:
    """The header (:func:`read_image_header`) and the pixels (:func:`read_image`) of an image file, opened once.

    The pixels are decoded only if the size the header declares fits the memory budget
    (:func:`~acquisition.sequence.memory_budget.check_decode`) and ``before_decoding(header)`` (a caller's
    check of the declared header, e.g. against another frame's size) raises nothing.

    Raises
    ------
    RecordingError
        As :func:`read_image`; or the decoded pixels would exceed the memory budget.
    """
    path = Path(path)
    with _open_input(path) as image:
        header, request = _header(path, image)
        if before_decoding is not None:
            before_decoding(header)
        check_decode(
            shown_path(path),
            header.width * header.height * header.channels * header.dtype.itemsize,
            f"its {header.width}×{header.height}×{header.channels} {header.dtype} pixels",
        )
        pixels = image.read_image(0, 0, 0, header.channels, request)
        if pixels is None:
            raise RecordingError(f"{path}: pixels cannot be decoded ({_oiio_error()}); expected a readable image")
    pixels = np.asarray(pixels, dtype=header.dtype).reshape(header.height, header.width, header.channels)
    return header, (pixels[:, :, 0] if header.channels == 1 else pixels)


def image_suffix(pixels: np.ndarray) -> str:
    """The file suffix :func:`write_image` requires for ``pixels``: ``.tiff`` (integer) or ``.exr`` (float)."""
    return FLOAT_SUFFIX if np.issubdtype(np.asarray(pixels).dtype, np.floating) else INTEGER_SUFFIX


def _prepare_pixels(path: Path, pixels: np.ndarray) -> tuple[np.ndarray, str]:
    pixels = np.asarray(pixels)
    if pixels.ndim == 3 and pixels.shape[2] == 1:
        pixels = pixels[:, :, 0]
    if pixels.ndim not in (2, 3) or (pixels.ndim == 3 and pixels.shape[2] != 3) or pixels.size == 0:
        raise RecordingError(f"{path}: pixels have shape {pixels.shape}; expected (H, W), (H, W, 1) or (H, W, 3)")
    if np.issubdtype(pixels.dtype, np.floating):
        if path.suffix.lower() not in _FLOAT_SUFFIXES:
            raise RecordingError(f"{path}: float pixels need a float format; expected a {FLOAT_SUFFIX} file")
        return np.ascontiguousarray(pixels, dtype=np.float32), "float"
    if np.issubdtype(pixels.dtype, np.integer) and pixels.dtype != np.bool_:
        if path.suffix.lower() not in _INTEGER_SUFFIXES:
            raise RecordingError(f"{path}: integer pixels are stored as 16-bit TIFF; expected a {INTEGER_SUFFIX} file")
        low, high = int(pixels.min()), int(pixels.max())
        if low < 0 or high > 65535:
            raise RecordingError(f"{path}: integer pixels span {low}…{high}; expected counts in 0…65535 (16-bit TIFF)")
        # Cast in numpy rather than letting OpenImageIO convert: its conversion rescales
        # normalised integers (uint8 255 would become 65535), and counts must stay counts.
        return np.ascontiguousarray(pixels, dtype=np.uint16), "uint16"
    raise RecordingError(f"{path}: pixel type {pixels.dtype} is not supported; expected integer counts or floats")


def _attribute_json(path: Path, attributes: dict) -> str:
    for name in attributes:
        if not isinstance(name, str) or not name.startswith(_ATTRIBUTE_PREFIX):
            raise RecordingError(
                f"{path}: attribute name {name!r}; expected a name starting with '{_ATTRIBUTE_PREFIX}'"
            )
    try:
        return json.dumps(attributes, allow_nan=False, default=json_default)
    except (TypeError, ValueError) as err:
        raise RecordingError(f"{path}: attributes cannot be stored ({err}); expected JSON-compatible values") from err


def json_default(value: object) -> object:
    """``json.dumps`` fallback for numpy arrays and scalars (the one such converter in msflash)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _set_native_attribute(spec: oiio.ImageSpec, name: str, value: object) -> None:
    # Native header attributes are a convenience for EXR viewers; the JSON description is what
    # read_image_header relies on, so values without a simple OpenImageIO type are skipped here.
    value = json_default(value) if isinstance(value, np.ndarray | np.generic) else value
    if isinstance(value, bool):
        spec.attribute(name, int(value))
    elif isinstance(value, str | int | float):
        spec.attribute(name, value)
    elif (
        isinstance(value, list | tuple)
        and value
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        spec.attribute(name, oiio.TypeDesc(f"float[{len(value)}]"), tuple(float(v) for v in value))


def write_image(
    path: str | os.PathLike,
    pixels: np.ndarray,
    attributes: dict | None = None,
    chromaticities: tuple[float, ...] | None = None,
) -> Path:
    """Write a frame image atomically: a temporary file in the same directory, then ``os.replace``.

    As :func:`write_image_digest`, returning the written file's path.
    """
    path = Path(path)
    write_image_digest(path, pixels, attributes, chromaticities)
    return path


def write_image_digest(
    path: str | os.PathLike,
    pixels: np.ndarray,
    attributes: dict | None = None,
    chromaticities: tuple[float, ...] | None = None,
) -> FileDigest:
    """Write a frame image atomically and return the SHA-256 and length of the bytes written.

    The file is written to a temporary file in the same directory, then moved into place with
    ``os.replace``; the digest is read back in the ``fsync`` pass before the rename (OpenImageIO cannot
    write to memory and libtiff seeks back, so the bytes cannot be hashed as produced).

    Parameters
    ----------
    path
        Target file: ``.tif``/``.tiff`` for integer pixels (written as 16-bit TIFF, zip
        no compression, values unchanged), ``.exr`` for float pixels (written as 32-bit float).
    pixels
        Shape (H, W), (H, W, 1) or (H, W, 3). Integer values must lie in 0…65535.
    attributes
        ``msflash:``-prefixed metadata (``msflash:role``, ``msflash:exposure_us``,
        ``msflash:led_levels``…) with JSON-compatible values, so the file describes itself.
    chromaticities
        EXR only: xy of the R, G, B primaries and of white (8 values), the standard
        ``chromaticities`` attribute viewers use to interpret the RGB
        (:func:`processing.raw_colour.rgb_chromaticities`); ignored for TIFF.

    Raises
    ------
    RecordingError
        If the pixels, suffix or attributes cannot be stored as described.
    OSError
        If the file cannot be written (permissions, disk full).
    """
    path = Path(path)
    data, type_name = _prepare_pixels(path, pixels)
    channels = 1 if data.ndim == 2 else 3
    spec, format_name = _image_spec(path, data, channels, type_name, dict(attributes or {}), chromaticities)
    path.parent.mkdir(parents=True, exist_ok=True)
    with replacing(path, suffix=f".tmp{path.suffix}") as temporary:
        output = oiio.ImageOutput.create(format_name)
        if output is None:
            raise OSError(f"{path}: no OpenImageIO writer for {format_name} ({_oiio_error()})")
        try:
            # Always hand OpenImageIO an (H, W, C) array: a 2-D array is read as (pixels, channels)
            # and would come out transposed.
            planes = data.reshape(data.shape[0], data.shape[1], channels)
            if not output.open(temporary, spec) or not output.write_image(planes):
                raise OSError(f"{path}: cannot write image ({output.geterror() or _oiio_error()})")
        finally:
            output.close()
        with open(temporary, "rb+") as written:
            digest = digest_open_file(written)
            os.fsync(written.fileno())
    return digest


def _image_spec(
    path: Path,
    data: np.ndarray,
    channels: int,
    type_name: str,
    attributes: dict,
    chromaticities: tuple[float, ...] | None,
) -> tuple[oiio.ImageSpec, str]:
    """The OpenImageIO spec of a frame file and its format: an uncompressed TIFF, or a zip EXR with its attributes."""
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], channels, type_name)
    if attributes:
        spec.attribute("ImageDescription", _attribute_json(path, attributes))
    if type_name == "uint16":
        # Uncompressed: capture writes every frame as it arrives, and zip costs many times the write
        # itself for a 2× size gain on real data (docs/architecture.md §10).
        spec.attribute("compression", "none")
        return spec, "tiff"
    spec.attribute("compression", "zip")  # EXR: derived float images, not on the capture path
    for name, value in attributes.items():
        _set_native_attribute(spec, name, value)
    if chromaticities is not None:
        if len(chromaticities) != 8:
            raise RecordingError(f"{path}: {len(chromaticities)} chromaticities; expected 8 (x, y of R, G, B, white)")
        spec.attribute("chromaticities", oiio.TypeDesc("float[8]"), tuple(float(v) for v in chromaticities))
    return spec, "openexr"
