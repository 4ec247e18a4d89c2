"""GenICam cameras through Aravis: :class:`AravisCamera`, device listing and the GigE Vision fake.

This is the one module of msflash that imports ``gi``. Everything Aravis returns is translated
here: pixels become owned numpy arrays, ``GLib.Error`` becomes :class:`~acquisition.errors.CameraError`
and its subclasses, and GenICam feature names with their per-model differences stay behind
:class:`AravisCamera`'s methods.

Public objects
--------------
- :data:`INTERFACES`, :func:`parse_interfaces`, :func:`use_interfaces`, :func:`list_devices`,
  :class:`DeviceEntry`: which transport layers Aravis may use and what they find.
- :class:`AravisCamera` with :class:`TriggerConfig`, :class:`StrobeConfig`,
  :class:`CameraSettings`, :class:`AcquisitionStats`: one opened camera.
- :func:`decode_pixels`, :data:`PIXEL_FORMATS`, :func:`frame_id_gap`: pure helpers.
- :class:`AravisGvFake`, :func:`gvcp_port_lock`, :data:`FAKE_SFNC_XML`: the Aravis GigE Vision
  fake camera served on 127.0.0.1 with msflash's SFNC GenICam description.
- :class:`FrameTiming` (:attr:`AravisCamera.last_frame_timing`), :func:`bare_aravis_run` with
  :class:`BareRun` and :class:`TriggerTiming`: stage times of frames, and the plain Aravis loop
  the camera bench compares against.

Network safety: Aravis discovers GigE Vision cameras by broadcasting on every network interface,
and opening a camera by a name that is not an IP address makes the GigE Vision interface resolve
the name and broadcast. Nothing here enables the GigE Vision interface unless the caller lists
``gige`` in ``interfaces``; an IP address opens that one device without discovery.
"""

from __future__ import annotations

import collections
import fcntl
import ipaddress
import logging
import math
import os
import queue
import random
import re
import socket
import tempfile
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from msflash.acquisition.devices.aravis.camera_features import (
    MSFLASH_FEATURES,
    CameraOptions,
    FeatureInfo,
    options_from_json,
)
from msflash.acquisition.devices.aravis.device_release import release_lost_device
from msflash.acquisition.devices.aravis.fake_models import FAKE_SFNC_XML as _FAKE_SFNC_XML
from msflash.acquisition.devices.aravis.gain import (
    GAIN_FEATURES,
    GainControl,
    GainRequest,
    choose_gain_control,
    choose_selector,
)
from msflash.acquisition.devices.aravis.gv_stream import create_gv_stream
from msflash.acquisition.devices.aravis.pixel_formats import PACKED_FORMATS, unpack_pixels
from msflash.acquisition.devices.camera import CameraInfo, NativeGain, RawFrame
from msflash.acquisition.errors import (
    CameraDisconnectedError,
    CameraError,
    CameraNotFoundError,
    CameraSettingError,
    FrameLostError,
    FrameTimeoutError,
)
from msflash.acquisition.plan import CapturePlan
from msflash.processing.json_input import parse_json_document
from msflash.processing.user_files import JSON_MAX_BYTES, read_user_text, shown_path

try:
    import gi

    gi.require_version("Aravis", "0.8")
    from gi.repository import Aravis, GLib  # noqa: E402
except (ImportError, ValueError) as _err:  # ValueError: gi present but typelib Aravis-0.8 missing
    raise ImportError(
        "msflash.acquisition.devices.aravis.camera: the Aravis 0.8 GObject typelib is not available "
        f"({_err}); expected PyGObject and the Debian package gir1.2-aravis-0.8 — run setup.sh"
    ) from _err

log = logging.getLogger(__name__)

GENICAM_DIR = Path(__file__).resolve().parent / "genicam"
"""Shipped GenICam data: the fake camera's SFNC description and the per-model profiles."""
FAKE_SFNC_XML = _FAKE_SFNC_XML
"""GenICam XML for the Aravis fake cameras adding SFNC ExposureTime, Gain, Line*, UserOutput*,
Counter* and Chunk* as registers (generated from the fake's own XML, Aravis 0.8.26)."""
PROFILES_JSON = GENICAM_DIR / "profiles.json"

INTERFACES: dict[str, str] = {"fake": "Fake", "gige": "GigEVision", "usb3": "USB3Vision"}
"""msflash interface names (``--interfaces``) and the Aravis interface ids they stand for."""

_GV_FRAME_ID_WRAP = 1 << 16
"""GigE Vision 1.x block ids are 16 bits and skip 0 when they wrap (65535 is followed by 1)."""
_GV_CCP_REGISTER = 0x0A00
"""GigE Vision bootstrap register Control Channel Privilege."""
_GV_CCP_CONTROL_BITS = 0b11
"""Its exclusive (bit 0) and control (bit 1) access bits, either of which Aravis's heartbeat accepts."""
_POP_POLL_US = 10_000
"""How long the pump thread waits in one ``timeout_pop_buffer`` call, so stop() is prompt (a frame
ends the wait at once; only stop() waits for the timeout)."""
_MAX_POOL_BYTES = 512 * 1024 * 1024
"""Upper bound on the buffer pool; a plan asking for more buffers gets fewer, with a warning."""
_MAX_SPARE_BYTES = 256 * 1024 * 1024
"""Upper bound on the spare arrays a zero-copy pool readies for a plan (beyond, the popping thread
allocates each replacement after queueing its frame)."""

_aravis_lock = threading.RLock()
"""Aravis's interface list and device list are process globals."""


# --------------------------------------------------------------------------------------------
# Interfaces and device listing
# --------------------------------------------------------------------------------------------


def parse_interfaces(spec: str | Iterable[str]) -> tuple[str, ...]:
    """Validate an interface list such as ``"fake,gige"`` and return it as a tuple.

    Parameters
    ----------
    spec
        Comma-separated text or an iterable of names from :data:`INTERFACES`.

    Returns
    -------
    tuple of str
        The names, lower case, without duplicates, in the given order.

    Raises
    ------
    ValueError
        An unknown or empty name; the message lists the valid names.
    """
    names = [s.strip().lower() for s in (spec.split(",") if isinstance(spec, str) else spec)]
    if not names or any(not n for n in names):
        raise ValueError(
            f"interfaces {spec!r}: empty name; expected a comma-separated subset of {', '.join(INTERFACES)}"
        )
    unknown = [n for n in names if n not in INTERFACES]
    if unknown:
        raise ValueError(
            f"interfaces {spec!r}: unknown {', '.join(unknown)}; expected a subset of {', '.join(INTERFACES)}"
        )
    return tuple(dict.fromkeys(names))


def use_interfaces(interfaces: str | Iterable[str]) -> tuple[str, ...]:
    """Enable exactly ``interfaces`` in Aravis and disable the others (process-wide).

    Returns the parsed names. Call it before any listing or opening: by default Aravis enables
    GigE Vision and USB3 Vision, and GigE Vision discovery broadcasts on every network interface.
    """
    names = parse_interfaces(interfaces)
    with _aravis_lock:
        for name, arv_id in INTERFACES.items():
            if name in names:
                Aravis.enable_interface(arv_id)
            else:
                Aravis.disable_interface(arv_id)
    return names


@dataclass(frozen=True)
class DeviceEntry:
    """One device as Aravis lists it."""

    device_id: str
    """Aravis device id (``Fake_1``, ``Aravis-Fake-GV01``, ``<vendor>-<serial>``); opens the device."""
    interface: str
    """msflash interface name: ``fake``, ``gige`` or ``usb3``."""
    vendor: str
    """Vendor name."""
    model: str
    """Model name."""
    serial: str
    """Serial number."""
    address: str
    """IP address for GigE Vision devices, else empty."""
    physical_id: str
    """MAC address (GigE) or bus id (USB)."""

    def to_dict(self) -> dict[str, str]:
        """The entry as a JSON-ready mapping."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


_PROTOCOL_TO_INTERFACE = {"Fake": "fake", "GigEVision": "gige", "USB3Vision": "usb3"}


def list_devices(interfaces: str | Iterable[str]) -> tuple[DeviceEntry, ...]:
    """List the devices found on ``interfaces`` (only those are enabled; see :func:`use_interfaces`).

    With ``gige`` in ``interfaces`` this broadcasts GigE Vision discovery on every network
    interface of the machine; leave it out where that is not allowed.
    """
    use_interfaces(interfaces)
    with _aravis_lock:
        Aravis.update_device_list()
        entries = []
        for i in range(Aravis.get_n_devices()):
            protocol = Aravis.get_device_protocol(i) or ""
            entries.append(
                DeviceEntry(
                    device_id=Aravis.get_device_id(i) or "",
                    interface=_PROTOCOL_TO_INTERFACE.get(protocol, protocol.lower()),
                    vendor=Aravis.get_device_vendor(i) or "",
                    model=Aravis.get_device_model(i) or "",
                    serial=Aravis.get_device_serial_nbr(i) or "",
                    address=(Aravis.get_device_address(i) or "") if protocol == "GigEVision" else "",
                    physical_id=Aravis.get_device_physical_id(i) or "",
                )
            )
    return tuple(entries)


def is_ipv4_address(text: str) -> bool:
    """Whether ``text`` is a dotted IPv4 address (such a device id opens without discovery)."""
    try:
        ipaddress.IPv4Address(text)
    except ValueError:
        return False
    return True


_builtin_fake_xml: str | None = None


def _builtin_fake_xml_path() -> str:
    # Aravis 0.8.26 has no way to unset the fake's GenICam file name (None is refused, "" fails to
    # load), so the built-in description is saved once, before msflash first replaces it.
    global _builtin_fake_xml
    with _aravis_lock:
        if _builtin_fake_xml is None:
            xml, size = Aravis.FakeDevice.new("builtin").get_genicam_xml()
            handle, path = tempfile.mkstemp(prefix="msflash-fake-builtin-", suffix=".xml")
            with os.fdopen(handle, "w", encoding="utf-8") as out:
                out.write(xml[:size])
            _builtin_fake_xml = path
        return _builtin_fake_xml


def use_fake_genicam(path: str | os.PathLike[str] | None = FAKE_SFNC_XML) -> None:
    """Make the in-process ``Fake`` interface camera load ``path`` as its GenICam XML.

    Takes effect for fake cameras opened afterwards (Aravis reads the file when the fake device
    is created). ``None`` restores the fake's built-in description.
    """
    builtin = _builtin_fake_xml_path()
    Aravis.set_fake_camera_genicam_filename(str(path) if path is not None else builtin)


# --------------------------------------------------------------------------------------------
# Pixel formats and frame ids
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PixelLayout:
    """How a GenICam pixel format is laid out in a payload."""

    dtype: str
    """numpy dtype of one sample (little endian, as PFNC specifies for GigE Vision and USB3)."""
    channels: int
    """1 for mono and raw mosaics, 3 for RGB."""
    bits: int
    """Significant bits per sample: the white level is ``2**bits - 1``."""
    cfa: str | None = None
    """Mosaic layout for Bayer formats."""
    bgr: bool = False
    """Channels are stored B, G, R (reversed to R, G, B on decoding)."""
    packed: bool = False
    """Samples are bit-packed (:mod:`acquisition.devices.aravis.pixel_formats` decodes them to ``uint16``)."""


def _pixel_formats() -> dict[str, PixelLayout]:
    table = {
        "Mono8": PixelLayout("u1", 1, 8),
        "Mono10": PixelLayout("<u2", 1, 10),
        "Mono12": PixelLayout("<u2", 1, 12),
        "Mono14": PixelLayout("<u2", 1, 14),
        "Mono16": PixelLayout("<u2", 1, 16),
        "RGB8": PixelLayout("u1", 3, 8),
        "BGR8": PixelLayout("u1", 3, 8, bgr=True),
        "RGB16": PixelLayout("<u2", 3, 16),
    }
    for cfa in ("RG", "GR", "GB", "BG"):
        pattern = {"RG": "RGGB", "GR": "GRBG", "GB": "GBRG", "BG": "BGGR"}[cfa]
        table[f"Bayer{cfa}8"] = PixelLayout("u1", 1, 8, pattern)
        for bits in (10, 12, 16):
            table[f"Bayer{cfa}{bits}"] = PixelLayout("<u2", 1, bits, pattern)
    for name, packed in PACKED_FORMATS.items():
        table[name] = PixelLayout("<u2", 1, packed.bits, packed.cfa, packed=True)
    return table


PIXEL_FORMATS: dict[str, PixelLayout] = _pixel_formats()
"""Pixel formats msflash decodes: unpacked ones, and the packed 10/12-bit formats of
:data:`acquisition.devices.aravis.pixel_formats.PACKED_FORMATS` (decoded to ``uint16``)."""


def _frame_shape(
    pixel_format: str, width: int, height: int, n_bytes: int, where: str
) -> tuple[PixelLayout, int, tuple[int, ...]]:
    """The layout of ``pixel_format``, the sample count of one image and the frame's shape.

    Raises :class:`CameraError` for an unknown format or a payload of ``n_bytes`` too short.
    """
    layout = PIXEL_FORMATS.get(pixel_format)
    if layout is None:
        raise CameraError(
            f"{where}: pixel format {pixel_format!r} is not supported; expected one of {', '.join(PIXEL_FORMATS)}"
        )
    n = width * height * layout.channels
    itemsize = np.dtype(layout.dtype).itemsize
    if n_bytes < n * itemsize:
        raise CameraError(
            f"{where}: payload of {n_bytes} bytes is too short for {width}x{height} "
            f"{pixel_format}; expected {n * itemsize} bytes"
        )
    shape = (height, width) if layout.channels == 1 else (height, width, layout.channels)
    return layout, n, shape


def decode_pixels(
    data: bytes | memoryview, pixel_format: str, width: int, height: int, where: str = "decode_pixels"
) -> np.ndarray:
    """Turn an image payload into an owned, read-only array of raw linear values.

    Parameters
    ----------
    data
        The image bytes, at least ``width * height * channels * itemsize`` long.
    pixel_format
        A key of :data:`PIXEL_FORMATS`.
    width, height
        Image size in pixels.
    where
        Prefix of error messages (the camera's name).

    Returns
    -------
    numpy.ndarray
        (height, width) for mono and mosaics, (height, width, 3) in R, G, B order for colour;
        ``uint8`` or ``uint16`` values as the sensor delivered them.

    Raises
    ------
    CameraError
        Unknown pixel format or a payload shorter than the image.
    """
    if pixel_format in PACKED_FORMATS:
        return unpack_pixels(data, pixel_format, width, height, where=where)
    layout, n, shape = _frame_shape(pixel_format, width, height, len(data), where)
    flat = np.frombuffer(data, dtype=layout.dtype, count=n)
    native = np.dtype(layout.dtype).newbyteorder("=")
    # An array over immutable ``bytes`` (what PyGObject's Buffer.get_data returns, already a copy
    # of the Aravis buffer) is safe to keep without another 2.6 MB copy per frame.
    owned = isinstance(data, bytes) and flat.dtype == native
    pixels = flat.reshape(shape) if owned else flat.reshape(shape).astype(native, copy=True)
    if layout.bgr:
        pixels = np.ascontiguousarray(pixels[..., ::-1])
    pixels.flags.writeable = False
    return pixels


def is_zero_copy_format(pixel_format: str) -> bool:
    """Whether a payload of ``pixel_format`` already is its frame, so :func:`view_pixels` applies.

    True for the formats of :data:`PIXEL_FORMATS` stored in this host's byte order and in R, G, B
    order (mono, Bayer, RGB8, RGB16); False for BGR8 (reordered), packed and unknown formats.

    Examples
    --------
    >>> is_zero_copy_format("Mono16"), is_zero_copy_format("BayerRG8"), is_zero_copy_format("BGR8")
    (True, True, False)
    >>> is_zero_copy_format("Mono12p")
    False
    """
    layout = PIXEL_FORMATS.get(pixel_format)
    return layout is not None and not layout.bgr and not layout.packed and np.dtype(layout.dtype).isnative


def view_pixels(
    payload: np.ndarray, pixel_format: str, width: int, height: int, where: str = "view_pixels"
) -> np.ndarray:
    """The frame inside ``payload`` (a byte array), as a read-only view: no copy.

    The result has the shape and dtype :func:`decode_pixels` gives and keeps ``payload`` alive.

    Raises
    ------
    CameraError
        A format :func:`is_zero_copy_format` refuses, or a payload shorter than the image.
    """
    if not is_zero_copy_format(pixel_format):
        raise CameraError(
            f"{where}: pixel format {pixel_format!r} needs decoding; expected one is_zero_copy_format accepts"
        )
    layout, n, shape = _frame_shape(pixel_format, width, height, payload.nbytes, where)
    dtype = np.dtype(layout.dtype)
    pixels = payload[: n * dtype.itemsize].view(dtype).reshape(shape)
    pixels.flags.writeable = False
    return pixels


def frame_id_gap(previous: int, current: int, wrap: int | None = _GV_FRAME_ID_WRAP, skip_zero: bool = True) -> int:
    """Number of frame ids missing between two consecutive frames.

    Parameters
    ----------
    previous, current
        Frame ids of two frames delivered one after the other.
    wrap
        Modulus of the counter (``1 << 16`` for GigE Vision 1.x block ids), or ``None`` for a
        counter that does not wrap.
    skip_zero
        The counter skips 0 when it wraps (GigE Vision block ids run 1..65535).

    Returns
    -------
    int
        0 when ``current`` follows ``previous``; the number of skipped ids otherwise. A counter
        that went backwards without wrapping (a restarted camera) counts as ``-1``.

    Examples
    --------
    >>> frame_id_gap(65534, 65535), frame_id_gap(65535, 1), frame_id_gap(10, 13)
    (0, 0, 2)
    """
    if wrap is None:
        return current - previous - 1 if current > previous else -1
    step = (current - previous) % wrap
    if skip_zero and current < previous and step > 0:
        step -= 1  # id 0 is never sent after a wrap
    return step - 1 if step > 0 else -1


# --------------------------------------------------------------------------------------------
# Profiles, configuration and records
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CameraProfile:
    """Per-model differences, kept as data in ``genicam/profiles.json``."""

    name: str
    """Profile name."""
    exposure_features: tuple[str, ...] = ("ExposureTime", "ExposureTimeAbs")
    """Exposure features to try, in order (microseconds)."""
    gain_features: tuple[str, ...] = ("Gain",)
    """Gain features to try first, in order (then ``Gain``, ``GainAbs``, ``GainRaw``): ``Gain`` is in dB
    (SFNC), ``GainRaw`` in camera units (:mod:`acquisition.devices.aravis.gain`)."""
    gain_raw_per_db: float | None = None
    """GainRaw units per dB, when the model documents it (then ``--gain`` in dB may use GainRaw)."""
    integer_exposure: bool = False
    """The camera rounds exposure to whole microseconds (the read-back value is recorded anyway)."""
    user_outputs: tuple[str, ...] = ()
    """Names of the user outputs in order, when known; otherwise read from the camera."""
    electrons_per_dn: float | None = None
    """Conversion gain at 0 dB (electrons per digital number of the pixel format), when known."""
    read_noise_e: float | None = None
    """Read noise in electrons, when known (with ``electrons_per_dn`` it lets exposure planning predict SNR)."""
    notes: str = ""
    """Where the quirks come from."""
    options: CameraOptions = CameraOptions()
    """Settings applied whenever this model is opened by the hardware rig (trigger/strobe lines, gain,
    ROI, binning, features); command-line options override them (:mod:`acquisition.devices.aravis.camera_features`)."""


PROFILE_LISTS = ("exposure_features", "gain_features", "user_outputs")
"""A profile's fields holding lists of names (tuples in :class:`CameraProfile`)."""

PROFILE_NUMBERS = ("gain_raw_per_db", "electrons_per_dn", "read_noise_e")
"""A profile's fields holding a positive number, or null when unknown."""


def load_profiles(path: Path = PROFILES_JSON) -> tuple[tuple[str, str, CameraProfile], ...]:
    """The profiles as ``(vendor_regex, model_regex, profile)``, in matching order.

    Read as every user-editable JSON file is (:func:`processing.json_input.parse_json_document`: line and
    column of a syntax error, duplicate keys, non-finite numbers refused); a wrong field is named.

    Raises
    ------
    CameraSettingError
        One line naming ``path``, the profile and the field, and what was expected.
    """
    shown = shown_path(path)
    text = read_user_text(path, "camera profiles JSON", JSON_MAX_BYTES, CameraSettingError)
    data = parse_json_document(text, shown, CameraSettingError)
    items = data.get("profiles") if isinstance(data, dict) else None
    if not isinstance(items, list):
        raise CameraSettingError(f"{shown}: field 'profiles' is missing or not a list; expected a list of profiles")
    known = {name for name in CameraProfile.__dataclass_fields__} | {"vendor", "model"}
    profiles = []
    for index, raw in enumerate(items):
        where = f"{shown}: profiles[{index}]"
        if not isinstance(raw, dict):
            raise CameraSettingError(f"{where} is {type(raw).__name__}; expected an object")
        item = dict(raw)
        unknown = sorted(set(item) - known)
        missing = [key for key in ("name", "vendor", "model") if not isinstance(item.get(key), str)]
        if unknown or missing:
            field_name = (unknown or missing)[0]
            raise CameraSettingError(
                f"{where}.{field_name} is {'unknown' if unknown else 'missing or not a string'}; expected the fields "
                f"of a profile ({', '.join(sorted(known))}), with name, vendor and model strings"
            )
        vendor, model = item.pop("vendor"), item.pop("model")
        for key in PROFILE_LISTS:
            if key in item:
                if not isinstance(item[key], list) or not all(isinstance(name, str) for name in item[key]):
                    raise CameraSettingError(f"{where}.{key} is {item[key]!r}; expected a list of feature names")
                item[key] = tuple(item[key])
        for key in PROFILE_NUMBERS:
            value = item.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int | float) or value <= 0):
                raise CameraSettingError(f"{where}.{key} is {value!r}; expected a positive number or null")
        if not isinstance(item.get("integer_exposure", False), bool) or not isinstance(item.get("notes", ""), str):
            key = "notes" if isinstance(item.get("integer_exposure", False), bool) else "integer_exposure"
            raise CameraSettingError(
                f"{where}.{key} is {item[key]!r}; expected {'text' if key == 'notes' else 'true or false'}"
            )
        if "options" in item:
            item["options"] = options_from_json(item["options"], f"{path} profile {item.get('name', '?')!r}")
        profiles.append((vendor, model, CameraProfile(**item)))
    return tuple(profiles)


def match_profile(vendor: str, model: str) -> CameraProfile:
    """The first profile whose vendor and model patterns match (the last is the default)."""
    for vendor_re, model_re, profile in load_profiles():
        if re.fullmatch(vendor_re, vendor, re.IGNORECASE) and re.fullmatch(model_re, model, re.IGNORECASE):
            return profile
    return CameraProfile("generic")


TriggerMode = Literal["software", "line", "free"]


@dataclass(frozen=True)
class TriggerConfig:
    """How frames are started."""

    mode: TriggerMode = "software"
    """``software`` (TriggerSoftware), ``line`` (a hardware input) or ``free`` (the camera's clock)."""
    line: str = "Line0"
    """Input line for ``line`` mode (a TriggerSource entry)."""
    activation: str = "RisingEdge"
    """TriggerActivation entry for ``line`` mode."""
    delay_us: float = 0.0
    """TriggerDelay in microseconds (``line`` mode); needs the feature when non-zero."""
    frame_rate_hz: float | None = None
    """AcquisitionFrameRate for ``free`` mode, when given."""


@dataclass(frozen=True)
class StrobeConfig:
    """An output line that follows the exposure (camera-master synchronisation)."""

    line: str = "Line1"
    """LineSelector entry of the output."""
    source: str = "ExposureActive"
    """LineSource entry driving it: ``ExposureActive``, or a user output such as ``UserOutput1``."""
    inverted: bool = False
    """LineInverter, when the booth expects an active-low signal."""


@dataclass(frozen=True)
class CameraSettings:
    """Settings as read back from the camera after writing them."""

    exposure_us: float
    """Exposure time actually set, microseconds."""
    gain: float
    """Linear gain actually set (1.0 = 0 dB)."""
    gain_db: float
    """The same gain in dB."""
    roi: tuple[int, int, int, int]
    """(offset_x, offset_y, width, height) in pixels."""
    pixel_format: str
    """GenICam pixel format."""
    trigger: TriggerConfig
    """Trigger configuration in effect."""
    strobe: StrobeConfig | None
    """Strobe output in effect, if any."""
    exposure_feature: str
    """Feature used for exposure."""
    gain_feature: str | None
    """Feature used for gain (None when the camera has none and gain stays 1)."""


@dataclass(frozen=True)
class AcquisitionStats:
    """What happened to the frames of one acquisition."""

    frames_good: int = 0
    """Complete frames delivered."""
    frames_incomplete: int = 0
    """Buffers that arrived with a status other than success (never delivered as data)."""
    frames_missing: int = 0
    """Frame ids skipped by the counter (frames that never reached the host)."""
    statuses: dict[str, int] = field(default_factory=dict)
    """Count of each non-success buffer status (``missing-packets``, ``timeout``, …)."""
    n_buffers: int = 0
    """Size of the buffer pool."""
    buffers_unfilled: int = 0
    """Buffers Aravis returned never filled (status ``cleared``): no frame, pushed back unseen."""


# --------------------------------------------------------------------------------------------
# The camera
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FrameTiming:
    """When one frame passed each stage on its way to :meth:`AravisCamera.next_frame`.

    ``received_ns``, ``popped_ns`` and ``delivered_ns`` are host ``CLOCK_REALTIME`` nanoseconds
    (what ``time.time_ns`` and Aravis's ``g_get_real_time`` read); ``device_ns`` is the camera's
    clock, which for the in-process GigE Vision fake is that same host clock.
    """

    device_ns: int
    """The buffer's timestamp: frame start on the camera's clock (the fake stamps it as it fills the image)."""
    received_ns: int
    """Aravis's system timestamp: when its stream thread received the frame's leader packet."""
    popped_ns: int
    """When the buffer thread got the completed buffer from the stream."""
    delivered_ns: int
    """When :meth:`AravisCamera.next_frame` returned the frame."""


@dataclass(frozen=True)
class _Good:
    pixels: np.ndarray
    frame_id: int
    timestamp_ns: int
    received_ns: int
    popped_ns: int


@dataclass(frozen=True)
class _Bad:
    frame_id: int
    status: str


@dataclass(frozen=True)
class _Failure:
    error: BaseException


_CONTROL_LOST = object()

ZERO_COPY_PROTOCOLS = ("gige", "fake")
"""Transports whose streams can hand buffers out as frames. USB3 Vision keeps copying: Aravis's
asynchronous USB3 stream (0.8.26, ``arvuvstream.c``) sets up one set of USB transfers per buffer
*address*, pointing at that buffer's memory, and reuses it for any later buffer at the same
address, so a buffer replaced by a new one would be filled through the old one's pointer."""


def _prefaulted(n_bytes: int) -> np.ndarray:
    """A new byte array with every page written once, so the first write by Aravis's receive
    thread takes no page fault (``np.zeros`` would map untouched zero pages)."""
    array = np.empty(n_bytes, dtype=np.uint8)
    array.fill(0)
    return array


class _BufferPool:
    """One Aravis stream with its buffers and, when frames are delivered without a copy, the numpy
    arrays whose memory those buffers use.

    A copying pool lets Aravis allocate each buffer; frames are copied out (:func:`decode_pixels`)
    and buffers are pushed back. A zero-copy pool builds every buffer over a pre-faulted array it
    allocates (``Aravis.Buffer.new(size, address)``); a complete frame is handed to the caller as a
    view of its array (:func:`view_pixels`) and its buffer is never pushed again: a replacement over
    a fresh array (a spare readied beforehand, else a new one) takes its place in the stream.

    Memory-safety invariant (zero-copy): Aravis's stream thread writes into the memory of every
    buffer the stream holds — queued for input, being filled, or complete and not yet popped —
    and never frees memory it did not allocate. So every array backing a buffer the stream may
    hold is referenced from ``_in_stream``: registered *before* its buffer is pushed, removed only
    by :meth:`hand_out` (its buffer popped, complete, and never to be pushed again) or by
    :meth:`release`, which first stops the stream's thread (joined) and deletes every buffer the
    stream still holds. A buffer popped and pushed back (incomplete, stale, refused) keeps its
    array registered throughout. Call :meth:`release` after acquisition stopped and after the thread
    popping the stream exited; if that thread cannot be stopped, :meth:`abandon` keeps the arrays
    for the life of the process instead. A pool dropped unreleased releases itself first.
    """

    def __init__(self, stream: Any, payload: int, zero_copy: bool) -> None:
        self.stream: Any = stream
        """The Aravis stream (None once released)."""
        self.payload = payload
        """Bytes per buffer."""
        self.zero_copy = zero_copy
        """Frames are views of the buffers' arrays (else copies)."""
        self._in_stream: dict[Any, np.ndarray] = {}  # Aravis.Buffer wrapper -> the array it writes into
        self._spares: list[tuple[Any, np.ndarray]] = []
        self._abandoned = False

    @property
    def counts(self) -> tuple[int, int]:
        """(arrays backing buffers in the stream, spare arrays ready to replace handed-out ones)."""
        return len(self._in_stream), len(self._spares)

    def _new_buffer(self) -> tuple[Any, np.ndarray]:
        array = _prefaulted(self.payload)
        return Aravis.Buffer.new(self.payload, array.ctypes.data), array

    def _push(self, buffer: Any, array: np.ndarray) -> None:
        self._in_stream[buffer] = array  # referenced before Aravis can write into it
        self.stream.push_buffer(buffer)

    def fill(self, n_buffers: int) -> None:
        """Push ``n_buffers`` new buffers into the stream."""
        for _ in range(n_buffers):
            if self.zero_copy:
                self._push(*self._new_buffer())
            else:
                self.stream.push_buffer(Aravis.Buffer.new_allocate(self.payload))

    def reserve(self, n_spares: int) -> None:
        """Have at least ``n_spares`` spare buffers ready (zero-copy pools only)."""
        while self.zero_copy and len(self._spares) < n_spares:
            self._spares.append(self._new_buffer())

    def array_of(self, buffer: Any) -> np.ndarray | None:
        """The array behind a popped buffer, or None when its memory is Aravis's (copy it out)."""
        return self._in_stream.get(buffer)

    def hand_out(self, buffer: Any) -> None:
        """Give up a popped buffer's array to the caller; the buffer must never be pushed again."""
        del self._in_stream[buffer]

    def replace(self) -> None:
        """Push a buffer in place of one handed out: a spare, else a new one allocated now."""
        buffer, array = self._spares.pop() if self._spares else self._new_buffer()
        self._push(buffer, array)

    def release(self) -> None:
        """Stop the stream's thread, delete the buffers it holds, drop the stream, then the arrays.

        Call it after acquisition stopped and the popping thread exited. The stream's thread is
        started again, with no buffer left to write into, so that Aravis's finalisation (which
        stops it) finds it running. Idempotent.
        """
        stream, self.stream = self.stream, None
        if stream is not None and self._in_stream:
            stream.stop_thread(True)  # joins the thread, then unrefs every buffer in its queues
            stream.start_thread()
        stream = None  # noqa: F841 - the stream goes before the arrays
        self._in_stream.clear()
        self._spares.clear()

    def abandon(self) -> None:
        """Keep the stream and the arrays for the life of the process: the stream may still write
        into them, and its buffers may still be pushed back by a thread that did not stop."""
        self._abandoned = True
        _ABANDONED.append(self)
        self._spares.clear()

    def __del__(self) -> None:
        if self.stream is not None and self._in_stream and not self._abandoned:
            self.release()


@dataclass(frozen=True)
class _SpareStream:
    """A stopped stream kept, with its buffers, for the next :meth:`AravisCamera.prepare`."""

    pool: _BufferPool
    n_buffers: int
    layout: tuple[str, int, int]


_ABANDONED: list[_BufferPool] = []
"""Pools whose stream may still write into their arrays (its popping thread did not stop):
leaked on purpose, since freeing them could let Aravis write into freed memory."""


class AravisCamera:
    """A GenICam camera (GigE Vision, USB3 Vision or the Aravis fake) behind the ``Camera`` protocol.

    Parameters
    ----------
    device
        Aravis device id (``Fake_1``), serial number, or the camera's IPv4 address.
    interfaces
        Transport layers to use, from :data:`INTERFACES` (``("fake",)``, ``"gige,usb3"``). Only
        these are enabled; ``gige`` with a name that is not an IP address broadcasts discovery.
    pixel_format
        PixelFormat to set; ``None`` keeps the camera's.
    roi
        (offset_x, offset_y, width, height) to set; ``None`` keeps the camera's.
    line_trigger
        Trigger used for plans paced by the booth (``plan.trigger == "booth"``).
    strobe
        Output line to drive from the exposure; set up by :meth:`prepare` for every plan when
        given, and required for camera-paced plans (``plan.trigger == "camera"``).
    extra_buffers
        Buffers in the pool beyond one per plan step.
    zero_copy
        Deliver frames without copying them where possible (see Notes); False always copies.

    Raises
    ------
    CameraNotFoundError
        No device matched; the message lists what was found.
    CameraError
        The device refused a setting; the message names the camera and the feature.

    Notes
    -----
    Release the camera with :meth:`close` (or use it as a context manager): Aravis keeps control
    of a GigE Vision device as long as any reference to it lives.

    Frames of formats stored as the frame itself (:func:`is_zero_copy_format`) on GigE Vision and
    the fake (:data:`ZERO_COPY_PROTOCOLS`) are not copied: Aravis writes each frame into a numpy
    array msflash allocated, and that array, once the frame is complete, is the frame returned
    (read-only, owned by the caller from then on). A new buffer replaces it in the stream after
    the frame is queued; :meth:`prepare` readies one per plan step so that a sequence allocates
    nothing while it runs. :attr:`pool_arrays` counts the arrays the camera holds.
    """

    def __init__(
        self,
        device: str,
        *,
        interfaces: str | Iterable[str] = ("fake",),
        pixel_format: str | None = None,
        roi: tuple[int, int, int, int] | None = None,
        line_trigger: TriggerConfig | None = None,
        strobe: StrobeConfig | None = None,
        extra_buffers: int = 4,
        zero_copy: bool = True,
    ) -> None:
        self._requested = device
        self._interfaces = parse_interfaces(interfaces)
        self._line_trigger = line_trigger or TriggerConfig(mode="line")
        self._strobe_request = strobe
        self._extra_buffers = max(1, int(extra_buffers))
        self._zero_copy = bool(zero_copy)
        self._name = f"camera {device!r}"
        self._camera: Any = None
        self._device: Any = None
        self._pool: _BufferPool | None = None  # the stream and its buffers (see _BufferPool's invariant)
        self._spare: _SpareStream | None = None  # a stopped stream kept for the next prepare
        self._stale_before_ns = 0
        self._control_lost_handler: int | None = None
        self._control_lost = threading.Event()
        self._unreachable = False
        self._release_thread: threading.Thread | None = None
        """Releases a lost device after its control-lost emission (device_release.py)."""
        self._queue: queue.Queue[Any] = queue.Queue()
        self._pump: threading.Thread | None = None
        self._pump_stop = threading.Event()
        self._acquiring = False
        self._plan: CapturePlan | None = None
        self._n_buffers = 0
        self._triggered_settings: collections.deque[tuple[float, float, NativeGain | None]] = collections.deque()
        self._n_triggered = 0
        self._n_consumed = 0
        self._last_frame_id: int | None = None
        self._stats_lock = threading.Lock()
        self._stats = AcquisitionStats()
        self._trigger = TriggerConfig(mode="free")
        self._strobe: StrobeConfig | None = None
        self._step_request: tuple[float, float] | None = None
        self._current: tuple[float, float, NativeGain | None] = (float("nan"), float("nan"), None)
        self._gain_control = GainControl(None, why="not resolved yet")
        """How the gain is set (:meth:`configure_gain`)."""
        self._gain_request: GainRequest | None = None
        self._base_gain_db = 0.0
        """The gain a plan step of gain 1 gets, in dB (``--gain``; 0 without)."""
        self._native_gain: NativeGain | None = None
        self._other_gains: dict[str, float] = {}
        self._warned_gains: set[tuple[str, float]] = set()
        """The gain feature under the other ``GainSelector`` entries, as found (not set by msflash)."""
        self._last_timing: FrameTiming | None = None
        self._open()
        try:
            self._setup(pixel_format, roi)
        except BaseException:
            self.close()
            raise

    # -- opening and closing -----------------------------------------------------------------

    def _open(self) -> None:
        device = self._requested
        use_interfaces(self._interfaces)
        entry: DeviceEntry | None = None
        try:
            if is_ipv4_address(device):
                if "gige" not in self._interfaces:
                    raise CameraNotFoundError(
                        f"camera {device!r}: an IP address needs the GigE Vision interface; expected "
                        f"'gige' in the interfaces (got {','.join(self._interfaces)})"
                    )
                # By address Aravis talks to that device alone (no discovery broadcast).
                with _aravis_lock:
                    self._camera = Aravis.Camera.new(device)
            else:
                found = list_devices(self._interfaces)
                matches = [e for e in found if device in (e.device_id, e.serial, e.physical_id)]
                if not matches:
                    listing = ", ".join(f"{e.device_id} (serial {e.serial})" for e in found) or "nothing"
                    raise CameraNotFoundError(
                        f"camera {device!r}: not found on {','.join(self._interfaces)} (found: {listing}); "
                        "expected a device id, serial number or IP address — check the cable and "
                        "`msflash devices --interfaces …`"
                    )
                if len(matches) > 1:
                    raise CameraNotFoundError(
                        f"camera {device!r}: matches {len(matches)} devices "
                        f"({', '.join(e.device_id for e in matches)}); expected one — give the device id"
                    )
                entry = matches[0]
                with _aravis_lock:
                    self._camera = Aravis.Camera.new(entry.device_id)
        except GLib.Error as err:
            raise CameraNotFoundError(
                f"camera {device!r}: cannot open on {','.join(self._interfaces)} ({err.message}); "
                "expected a reachable device — is another program controlling it?"
            ) from err
        if self._camera is None:
            raise CameraNotFoundError(f"camera {device!r}: Aravis returned no camera; expected a device")
        self._device = self._camera.get_device()
        # Aravis checks neither access modes nor Min/Max unless told to.
        self._device.set_access_check_policy(Aravis.AccessCheckPolicy.ENABLE)
        self._device.set_range_check_policy(Aravis.RangeCheckPolicy.ENABLE)
        self._control_lost_handler = self._device.connect("control-lost", self._on_control_lost)
        self._vendor = self._read_string("DeviceVendorName", default=self._camera.get_vendor_name() or "")
        self._model = self._read_string("DeviceModelName", default=self._camera.get_model_name() or "")
        self._serial = self._camera.get_device_serial_number() or (entry.serial if entry else device)
        if entry is not None and entry.serial and self._serial != entry.serial:
            reached = self._serial
            self._camera = self._device = None
            raise CameraNotFoundError(
                f"camera {device!r}: opening {entry.device_id} reached a camera with serial {reached!r}, not the "
                f"{entry.serial!r} discovery listed; expected that camera — is another device answering at its "
                "address?"
            )
        self._device_id = entry.device_id if entry else (self._camera.get_device_id() or device)
        self._protocol = "gige" if self._camera.is_gv_device() else ("usb3" if self._camera.is_uv_device() else "fake")
        self._address = device if is_ipv4_address(device) else (entry.address if entry else "")
        self._name = f"camera {self._model or '?'} (serial {self._serial})"
        self._profile = match_profile(self._vendor, self._model)
        log.info(
            "%s: opened as %s over %s, profile %s", self._name, self._device_id, self._protocol, self._profile.name
        )

    def _on_control_lost(self, _device: Any) -> None:
        # Emitted from Aravis's heartbeat thread: only flag it and wake a waiting next_frame.
        log.error("%s: control lost", self._name)
        self._control_lost.set()
        self._queue.put(_CONTROL_LOST)

    def _setup(self, pixel_format: str | None, roi: tuple[int, int, int, int] | None) -> None:
        if self._has("AcquisitionMode"):
            self._set_enum("AcquisitionMode", "Continuous")
        for auto in ("ExposureAuto", "GainAuto", "BlackLevelAuto"):
            if self._has(auto) and self._is_writable(auto) and "Off" in self.enum_entries(auto):
                self._set_enum(auto, "Off")
        if self._has("GammaEnable") and self._is_writable("GammaEnable"):
            self._set_bool("GammaEnable", False)  # frames must stay linear
        if pixel_format is not None:
            self.set_pixel_format(pixel_format)
        if roi is not None:
            self.set_roi(*roi)
        self._exposure_feature = self._first_feature(self._profile.exposure_features, "exposure")
        self.configure_gain(None)

    def close(self) -> None:
        """Stop, then release the stream and the device; idempotent."""
        try:
            self.stop()
        finally:
            device, camera = self._device, self._camera
            self._device = self._camera = None
            if device is not None and self._protocol == "gige" and not self._still_in_control(device):
                # Its control-lost emission may be under way: never drop the last reference here.
                self._release_thread = release_lost_device(device, (camera,), self._control_lost, self._name)
                device = camera = None
            if device is not None and self._control_lost_handler is not None:
                try:
                    device.disconnect(self._control_lost_handler)
                except (TypeError, GLib.Error):  # pragma: no cover - already gone
                    pass
            self._control_lost_handler = None
            # Drop every reference: Aravis keeps control of the device while one lives. stop() left
            # no stream but a spare: its thread is stopped and its buffers deleted before the arrays
            # behind them go.
            spare, self._spare = self._spare, None
            if spare is not None:
                spare.pool.release()
            device = camera = None  # a camera that answers: released here, no emission in flight

    def _still_in_control(self, device: Any) -> bool:
        """Whether this host still holds the GigE device's control channel (one read of CCP, 0x0A00).

        Aravis's heartbeat thread emits ``control-lost`` when the same read shows no privilege or
        fails; a device that answers with the privilege set cannot be in that emission now, so
        :meth:`close` may finalise it on this thread (``device_release.py``).
        """
        if self._control_lost.is_set() or self._unreachable:
            return False
        try:
            privilege = int(device.read_register(_GV_CCP_REGISTER))
        except GLib.Error:
            return False
        return privilege & _GV_CCP_CONTROL_BITS != 0

    def __enter__(self) -> AravisCamera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<AravisCamera {self._name} {'open' if self._camera is not None else 'closed'}>"

    # -- feature access -----------------------------------------------------------------------

    @property
    def name(self) -> str:
        """``camera <model> (serial <serial>)``, the prefix of every message about this camera."""
        return self._name

    def _live(self) -> Any:
        if self._device is None:
            raise CameraError(f"{self._name}: camera is closed; expected an open camera")
        if self._control_lost.is_set():
            raise CameraDisconnectedError(
                f"{self._name}: control of the device was lost; expected a connected camera — check "
                "power and cable, then reopen it"
            )
        return self._device

    def _fail(self, action: str, feature: str, err: GLib.Error) -> CameraError:
        if self._control_lost.is_set():
            return CameraDisconnectedError(
                f"{self._name}: {action} {feature} failed, control of the "
                f"device was lost ({err.message}); expected a connected camera"
            )
        if err.matches(Aravis.DeviceError.quark(), Aravis.DeviceError.FEATURE_NOT_FOUND):
            return CameraError(
                f"{self._name}: has no feature {feature}; expected it for {action} — "
                "this model lacks it (see genicam/profiles.json)"
            )
        if err.matches(Aravis.DeviceError.quark(), Aravis.DeviceError.TIMEOUT) or (
            err.matches(Aravis.DeviceError.quark(), Aravis.DeviceError.TRANSFER_ERROR)
        ):
            self._unreachable = True  # skip further control writes (each would wait out its retries)
            return CameraDisconnectedError(
                f"{self._name}: {action} {feature}: no answer from the "
                f"device ({err.message}); expected a connected camera — check "
                "power and cable, and that no other program controls it"
            )
        return CameraError(f"{self._name}: {action} {feature} failed: {err.message}")

    def has_feature(self, feature: str) -> bool:
        """Whether the camera implements ``feature`` and it is available now."""
        return self._has(feature)

    def _has(self, feature: str) -> bool:
        device = self._live()
        try:
            node = device.get_feature(feature)
            return node is not None and bool(node.is_implemented()) and bool(node.is_available())
        except GLib.Error:
            return False

    def _is_writable(self, feature: str) -> bool:
        node = self._live().get_feature(feature)
        try:
            return node.get_actual_access_mode() in (Aravis.GcAccessMode.RW, Aravis.GcAccessMode.WO)
        except (AttributeError, GLib.Error):
            return True

    def _first_feature(self, candidates: Sequence[str], what: str) -> str:
        for feature in candidates:
            if self._has(feature):
                return feature
        raise CameraError(f"{self._name}: no feature for {what}; expected one of {', '.join(candidates)}")

    def enum_entries(self, feature: str) -> tuple[str, ...]:
        """Available entries of an enumeration feature, as the camera reports them now."""
        try:
            return tuple(self._live().dup_available_enumeration_feature_values_as_strings(feature) or ())
        except GLib.Error as err:
            raise self._fail("listing", feature, err) from err

    def get_feature(self, feature: str) -> str | int | float | bool:
        """Read any feature, typed by its GenICam node (enumerations and strings as text)."""
        device = self._live()
        node = device.get_feature(feature)
        if node is None:
            raise CameraError(f"{self._name}: has no feature {feature}; expected it to read it")
        try:
            if isinstance(node, Aravis.GcEnumeration):
                return device.get_string_feature_value(feature)
            if isinstance(node, Aravis.GcBoolean):
                return bool(device.get_boolean_feature_value(feature))
            if isinstance(node, Aravis.GcFloat):
                return float(device.get_float_feature_value(feature))
            if isinstance(node, Aravis.GcInteger):
                return int(device.get_integer_feature_value(feature))
            return device.get_string_feature_value(feature)
        except GLib.Error as err:
            raise self._fail("reading", feature, err) from err

    def set_feature(self, feature: str, value: str | int | float | bool) -> str | int | float | bool:
        """Write any feature (checked against its access mode, range and entries); returns the read-back."""
        device = self._live()
        node = device.get_feature(feature)
        if node is None:
            raise CameraError(f"{self._name}: has no feature {feature}; expected it to set {value!r}")
        if isinstance(node, Aravis.GcEnumeration):
            self._set_enum(feature, str(value))
        elif isinstance(node, Aravis.GcBoolean):
            self._set_bool(feature, bool(value))
        elif isinstance(node, Aravis.GcFloat):
            self._set_float(feature, float(value))
        elif isinstance(node, Aravis.GcInteger):
            self._set_int(feature, int(value))
        else:
            try:
                device.set_string_feature_value(feature, str(value))
            except GLib.Error as err:
                raise self._fail("setting", feature, err) from err
        return self.get_feature(feature)

    _KINDS = (
        ("enumeration", Aravis.GcEnumeration),
        ("boolean", Aravis.GcBoolean),
        ("float", Aravis.GcFloat),
        ("integer", Aravis.GcInteger),
        ("string", Aravis.GcString),
        ("command", Aravis.GcCommand),
    )
    _ACCESS = {Aravis.GcAccessMode.RO: "RO", Aravis.GcAccessMode.RW: "RW", Aravis.GcAccessMode.WO: "WO"}

    def feature_names(self) -> tuple[tuple[str, str], ...]:
        """Every implemented, available feature under the GenICam ``Root`` category, with its category,
        then every one msflash uses (:meth:`used_features`) that no category under ``Root`` lists
        (category "": Aravis's fake keeps ``GainRaw`` so)."""
        genicam = self._live().get_genicam()
        found: dict[str, str] = {}

        def walk(name: str, category: str) -> None:
            node = genicam.get_node(name)
            if isinstance(node, Aravis.GcCategory):
                for child in node.get_features() or ():
                    walk(child, name)
            elif node is not None and name not in found and self._has(name):
                found[name] = category

        walk("Root", "Root")
        for name in self.used_features():
            if name not in found and self._has(name):
                found[name] = ""
        return tuple(found.items())

    def used_features(self) -> dict[str, str]:
        """Every feature msflash reads, writes or executes on this camera, by name: :data:`MSFLASH_FEATURES`
        and the profile's exposure and gain features."""
        used = dict(MSFLASH_FEATURES)
        for name in (*self._profile.exposure_features, *self._profile.gain_features):
            used.setdefault(name, "writes")
        return used

    def describe_feature(self, feature: str, category: str = "") -> FeatureInfo:
        """One feature as the camera describes it now: type, access, value, range or entries."""
        device = self._live()
        node = device.get_feature(feature)
        if node is None:
            raise CameraError(f"{self._name}: has no feature {feature}; expected it to describe it")
        kind = next((name for name, cls in self._KINDS if isinstance(node, cls)), "other")
        try:
            access = self._ACCESS.get(node.get_actual_access_mode(), "NA")
        except (AttributeError, GLib.Error):
            access = "NA"
        value = None
        if kind not in ("command", "other") and access != "WO":
            try:
                value = self.get_feature(feature)
            except CameraError:
                value = None
        try:
            visibility = str(node.get_visibility().value_nick).capitalize()
        except (AttributeError, GLib.Error):
            visibility = ""
        info = FeatureInfo(
            feature,
            kind,  # type: ignore[arg-type]
            access,
            value,
            category=category,
            visibility="" if visibility == "Undefined" else visibility,
            msflash=self.used_features().get(feature, ""),
        )
        if kind == "enumeration":
            return replace(info, entries=self.enum_entries(feature))
        if kind in ("integer", "float"):
            interface = Aravis.GcInteger if kind == "integer" else Aravis.GcFloat
            limits: dict[str, Any] = {}
            for key, getter in (
                ("minimum", "get_min"),
                ("maximum", "get_max"),
                ("increment", "get_inc"),
                ("unit", "get_unit"),
            ):
                try:
                    limits[key] = getattr(interface, getter)(node)
                except (AttributeError, GLib.Error, TypeError):
                    pass
            limits["unit"] = limits.get("unit") or ""
            if kind == "float" and "increment" in limits:
                limits.pop("increment")  # a float increment is optional and often absent
            return replace(info, **limits)
        return info

    def _read_string(self, feature: str, default: str = "") -> str:
        try:
            return str(self.get_feature(feature)) if self._has(feature) else default
        except CameraError:
            return default

    def _set_enum(self, feature: str, value: str) -> None:
        entries = self.enum_entries(feature)
        if value not in entries:
            raise CameraError(f"{self._name}: {feature} has no entry {value!r}; expected one of {', '.join(entries)}")
        try:
            self._live().set_string_feature_value(feature, value)
        except GLib.Error as err:
            raise self._fail("setting", f"{feature}={value}", err) from err

    def _set_bool(self, feature: str, value: bool) -> None:
        try:
            self._live().set_boolean_feature_value(feature, value)
        except GLib.Error as err:
            raise self._fail("setting", f"{feature}={value}", err) from err

    def _set_float(self, feature: str, value: float) -> None:
        try:
            self._live().set_float_feature_value(feature, value)
        except GLib.Error as err:
            raise self._fail("setting", f"{feature}={value}", err) from err

    def _set_int(self, feature: str, value: int) -> None:
        try:
            self._live().set_integer_feature_value(feature, value)
        except GLib.Error as err:
            raise self._fail("setting", f"{feature}={value}", err) from err

    def _number(self, feature: str) -> float:
        value = self.get_feature(feature)
        if isinstance(value, (int, float)):
            return float(value)
        raise CameraError(f"{self._name}: {feature} is {value!r}; expected a number")

    def _execute(self, feature: str) -> None:
        try:
            self._live().execute_command(feature)
        except GLib.Error as err:
            raise self._fail("executing", feature, err) from err

    # -- image format, exposure, gain ----------------------------------------------------------

    def set_pixel_format(self, pixel_format: str) -> str:
        """Set PixelFormat; refuses formats the camera lacks or msflash cannot decode (``CameraSettingError``)."""
        if pixel_format not in PIXEL_FORMATS:
            raise CameraSettingError(
                f"{self._name}: pixel format {pixel_format!r} cannot be decoded by msflash; "
                f"expected one of {', '.join(PIXEL_FORMATS)}"
            )
        offered = self.enum_entries("PixelFormat")
        if pixel_format not in offered:
            raise CameraSettingError(
                f"{self._name}: PixelFormat {pixel_format!r} is not offered by this camera; "
                f"expected one of {', '.join(offered)}"
            )
        self._set_enum("PixelFormat", pixel_format)
        return str(self.get_feature("PixelFormat"))

    def set_roi(self, offset_x: int, offset_y: int, width: int, height: int) -> tuple[int, int, int, int]:
        """Set the region of interest; returns it as read back (x, y, width, height)."""
        has_offsets = self._has("OffsetX") and self._has("OffsetY")
        if has_offsets:  # shrink offsets first so the new size fits
            self._set_int("OffsetX", 0)
            self._set_int("OffsetY", 0)
        elif (offset_x, offset_y) != (0, 0):
            raise CameraError(f"{self._name}: has no feature OffsetX/OffsetY; expected offsets (0, 0)")
        self._set_int("Width", int(width))
        self._set_int("Height", int(height))
        if has_offsets:
            self._set_int("OffsetX", int(offset_x))
            self._set_int("OffsetY", int(offset_y))
        return self.roi

    @property
    def roi(self) -> tuple[int, int, int, int]:
        """(offset_x, offset_y, width, height) as the camera reports them."""
        x = int(self._number("OffsetX")) if self._has("OffsetX") else 0
        y = int(self._number("OffsetY")) if self._has("OffsetY") else 0
        return x, y, int(self._number("Width")), int(self._number("Height"))

    def set_exposure_us(self, exposure_us: float) -> float:
        """Set the exposure time; returns the value read back (microseconds)."""
        feature = self._exposure_feature
        if self._is_integer(feature) or self._profile.integer_exposure:
            exposure_us = float(round(exposure_us))
        if isinstance(self._live().get_feature(feature), Aravis.GcInteger):
            self._set_int(feature, int(exposure_us))
        else:
            self._set_float(feature, float(exposure_us))
        return self.exposure_us

    def _is_integer(self, feature: str) -> bool:
        return isinstance(self._live().get_feature(feature), Aravis.GcInteger)

    @property
    def exposure_us(self) -> float:
        """Exposure time read back from the camera, microseconds."""
        return self._number(self._exposure_feature)

    @property
    def exposure_range_us(self) -> tuple[float, float] | None:
        """(min, max) of the exposure feature in microseconds, or None when the camera does not say."""
        try:
            node = self._live().get_feature(self._exposure_feature)
            low, high = float(node.get_min()), float(node.get_max())
        except (GLib.Error, AttributeError, TypeError):
            return None
        return (low, high) if 0 <= low < high and math.isfinite(high) else None

    @property
    def profile(self) -> CameraProfile:
        """The per-model profile in use."""
        return self._profile

    @property
    def noise_model(self) -> tuple[float, float] | None:
        """(electrons per DN at 0 dB, read noise in electrons) from the profile, or None when unknown."""
        if self._profile.electrons_per_dn is None or self._profile.read_noise_e is None:
            return None
        return float(self._profile.electrons_per_dn), float(self._profile.read_noise_e)

    def _resolve_gain(self, request: GainRequest | None, selector: str | None) -> GainControl:
        """The gain feature for ``request``: selector entry set, ``GainAuto`` checked, range read now."""
        why = ""
        chosen = None
        if self._has("GainSelector"):
            entries = self.enum_entries("GainSelector")
            chosen, why = choose_selector(entries, selector)
            if chosen is not None and str(self.get_feature("GainSelector")) != chosen:
                if not self._is_writable("GainSelector"):
                    why = f"GainSelector is {self.get_feature('GainSelector')} and read-only; expected {chosen}"
                else:
                    self._set_enum("GainSelector", chosen)
        elif selector is not None:
            why = f"has no feature GainSelector; expected it for --feature GainSelector={selector}"
        if not why and self._has("GainAuto"):
            auto = str(self.get_feature("GainAuto"))
            if auto != "Off":
                why = (
                    f"GainAuto is {auto} and could not be switched Off (access "
                    f"{self.describe_feature('GainAuto').access}); expected automatic gain off, so frames are linear"
                )
        order = self._profile.gain_features
        features = {
            name: self.describe_feature(name) for name in dict.fromkeys((*order, *GAIN_FEATURES)) if self._has(name)
        }
        return choose_gain_control(
            features, order, request, self._profile.gain_raw_per_db, self._profile.name, chosen, why
        )

    def configure_gain(self, request: GainRequest | None, selector: str | None = None) -> GainControl:
        """Choose the gain feature for ``request``, check it against the camera's range, and set it.

        ``request`` None keeps plan steps' own gains in dB on the first dB-scaled gain feature (a
        step of gain 1 is 0 dB), or, on a camera without one, leaves the gain as it is (frames then
        record gain 1). A request in dB becomes the gain of a plan step of gain 1 (each step's own
        gain multiplies it); a request in camera units (``--gain-raw``) is written as given — on a
        feature of no known dB scale it stays fixed, and only steps of gain 1 can be taken.
        ``selector`` is the ``GainSelector`` entry asked for (``--feature GainSelector=NAME``).

        Raises
        ------
        CameraSettingError
            The request cannot be set, or is outside the range (named with it, in the camera's units).
        """
        control = self._resolve_gain(request, selector)
        base_db = 0.0
        if request is not None:
            value = control.value_for(request, self._name)  # CameraSettingError: one line, exit 2
            if control.db_known:
                base_db = control.db_of(value) or 0.0  # what is written: an integer feature rounds
            self._write_gain(control, value)
        if request is not None and request.unit == "dB" and control.scale == "dB" and not control.camera_unit:
            log.warning(
                "%s: %s: %s states no unit; taken as dB (SFNC's unit)", self._name, request.option, control.feature
            )
        if control.settable:
            self._native_gain = self._read_native_gain(control)
            self._other_gains = self._other_selected_gains(control)
        else:
            if control.feature is not None:  # a gain it cannot set: a stuck GainAuto, no selector entry
                log.warning("%s: the gain is left as the camera has it: %s", self._name, control.why)
            self._native_gain = None
        self._gain_control, self._gain_request, self._base_gain_db = control, request, base_db
        return control

    def _other_selected_gains(self, control: GainControl) -> dict[str, float]:
        """The gain feature's value under every other ``GainSelector`` entry (msflash leaves them as they
        are; a digital gain there multiplies every frame), with a warning for each that is not zero."""
        if control.selector is None or control.feature is None or not self._is_writable("GainSelector"):
            return {}
        others: dict[str, float] = {}
        try:
            for entry in self.enum_entries("GainSelector"):
                if entry != control.selector:
                    self._set_enum("GainSelector", entry)
                    if self._has(control.feature):
                        others[entry] = self._number(control.feature)
        except CameraError as err:
            log.info("%s: reading the gain under each GainSelector entry: %s", self._name, err)
        finally:
            self._set_enum("GainSelector", control.selector)
        for entry, value in others.items():
            gain_db = control.db_of(value)
            if (gain_db is None or abs(gain_db) > 1e-6) and (entry, value) not in self._warned_gains:
                self._warned_gains.add((entry, value))
                shown = f"{gain_db:g} dB" if gain_db is not None else f"{value:g} ({control.unit})"
                log.warning(
                    "%s: GainSelector %s: %s is %s, left as the camera has it (msflash sets %s); frames record "
                    "the %s gain only",
                    self._name,
                    entry,
                    control.feature,
                    shown,
                    control.selector,
                    control.selector,
                )
        return others

    def _write_gain(self, control: GainControl, value: float) -> None:
        if control.selector is not None and self._is_writable("GainSelector"):
            self._set_enum("GainSelector", control.selector)
        assert control.feature is not None
        if control.kind == "integer":
            self._set_int(control.feature, int(value))
        else:
            self._set_float(control.feature, float(value))

    def _read_native_gain(self, control: GainControl) -> NativeGain:
        assert control.feature is not None
        return NativeGain(control.feature, self._number(control.feature), control.unit, control.selector)

    def _step_gain_value(self, gain: float) -> float | None:
        """The feature's value for a plan step of linear ``gain`` (None: nothing to write), checked."""
        if gain <= 0 or not math.isfinite(gain):
            raise CameraError(f"{self._name}: gain {gain!r} is invalid; expected a finite linear gain > 0")
        control = self._gain_control
        step_db = 20.0 * math.log10(gain)
        if not control.db_known:
            if abs(step_db) > 1e-6:
                how = control.why or f"{control.where()} is {control.range_text()} ({control.source})"
                raise CameraSettingError(
                    f"{self._name}: a gain of {gain:.4g}x ({step_db:+.3g} dB) cannot be set: {how}; expected "
                    "gain 1 (on this camera the gain is the one --gain-raw set, or the camera's own)"
                )
            return None
        total_db = self._base_gain_db + step_db
        value = control.value_of_db(total_db)
        if not control.allows(value):
            asked = f" on --gain {self._base_gain_db:g} dB" if self._gain_request is not None else ""
            raise CameraSettingError(
                f"{self._name}: a gain of {gain:.4g}x{asked} is {total_db:.4g} dB, {control.where()} {value:g}; "
                f"expected {control.range_text()}"
            )
        return value

    def check_step_gain(self, gain: float) -> None:
        """Raise what :meth:`set_gain` would for a plan step of linear ``gain``, writing nothing.

        Raises
        ------
        CameraSettingError
            Outside the camera's range (with ``--gain``'s), or not 1 on a gain of no known dB scale.
        """
        self._step_gain_value(gain)

    def set_gain(self, gain: float) -> float:
        """Set a plan step's analogue gain (linear, 1.0 = the ``--gain`` asked, else 0 dB); returns the
        linear gain read back (1 when the camera's gain has no known dB scale)."""
        value = self._step_gain_value(gain)
        if value is None:
            return 1.0
        self._write_gain(self._gain_control, value)
        return self.gain

    @property
    def gain_control(self) -> GainControl:
        """How the gain is set: feature, selector, unit, range, dB scale (:meth:`configure_gain`)."""
        return self._gain_control

    @property
    def gain_feature(self) -> str | None:
        """The feature :meth:`set_gain` writes (``Gain``, ``GainRaw``…), None when there is none."""
        return self._gain_control.feature if self._gain_control.settable else None

    @property
    def native_gain(self) -> NativeGain | None:
        """The gain feature's value as last read back, in the camera's unit (None without one)."""
        return self._native_gain

    @property
    def gain_db(self) -> float:
        """Gain read back from the camera, dB (0 when its dB scale is unknown: frames record gain 1)."""
        control = self._gain_control
        if not control.db_known:
            return 0.0
        native = self._read_native_gain(control)
        self._native_gain = native
        return control.db_of(native.value) or 0.0

    @property
    def gain(self) -> float:
        """Linear gain read back from the camera (1 when its dB scale is unknown)."""
        return float(10.0 ** (self.gain_db / 20.0))

    def gain_record(self) -> dict[str, Any]:
        """What the sequence records of the gain (``camera.gain``): feature, selector, unit, range,
        dB scale, what was asked and read back, and whether ``frames[].gain`` is the true linear gain."""
        control = self._gain_control
        native = self._native_gain
        if control.db_known:
            linear = "true: frames[].gain is the linear gain the camera read back"
        elif native is not None:
            linear = (
                f"relative: frames[].gain is 1 at {control.where()} {native.value:g} ({control.source}); every "
                "frame has that same gain"
            )
        else:
            linear = f"relative: frames[].gain is 1 ({control.why or 'no gain feature'})"
        return {
            **control.to_dict(),
            "requested": self._gain_request.to_dict() if self._gain_request is not None else None,
            "value": native.to_dict()["value"] if native is not None else None,
            "linear": linear,
            **({"other_selectors": dict(self._other_gains)} if self._other_gains else {}),
        }

    # -- triggers and lines -------------------------------------------------------------------

    def configure_trigger(self, trigger: TriggerConfig) -> TriggerConfig:
        """Set up FrameStart triggering; returns the configuration as read back."""
        if trigger.mode not in ("software", "line", "free"):
            raise CameraError(f"{self._name}: trigger mode {trigger.mode!r}; expected software, line or free")
        has_selector = self._has("TriggerSelector")
        if has_selector:
            selectors = self.enum_entries("TriggerSelector")
            # Only FrameStart may trigger: an armed AcquisitionStart trigger would swallow the first one.
            for other in ("AcquisitionStart", "FrameBurstStart"):
                if other in selectors:
                    self._set_enum("TriggerSelector", other)
                    self._set_enum("TriggerMode", "Off")
            if "FrameStart" not in selectors:
                raise CameraError(
                    f"{self._name}: TriggerSelector has no entry 'FrameStart'; expected one of {', '.join(selectors)}"
                )
            self._set_enum("TriggerSelector", "FrameStart")
        if trigger.mode == "free":
            self._set_enum("TriggerMode", "Off")
            if trigger.frame_rate_hz is not None:
                for enable in ("AcquisitionFrameRateEnable", "AcquisitionFrameRateEnabled"):
                    if self._has(enable):
                        self._set_bool(enable, True)
                self._set_float(
                    self._first_feature(("AcquisitionFrameRate", "AcquisitionFrameRateAbs"), "frame rate"),
                    trigger.frame_rate_hz,
                )
            self._trigger = trigger
            return trigger
        # The trigger source must be chosen before TriggerMode On on some cameras.
        source = "Software" if trigger.mode == "software" else trigger.line
        self._set_enum("TriggerSource", source)
        if trigger.mode == "line":
            if self._has("TriggerActivation"):
                self._set_enum("TriggerActivation", trigger.activation)
            elif trigger.activation != "RisingEdge":
                raise CameraError(
                    f"{self._name}: has no feature TriggerActivation; expected it for {trigger.activation}"
                )
            delay_feature = next((f for f in ("TriggerDelay", "TriggerDelayAbs") if self._has(f)), None)
            if delay_feature is not None:
                self._set_float(delay_feature, float(trigger.delay_us))
            elif trigger.delay_us:
                raise CameraError(
                    f"{self._name}: has no feature TriggerDelay; expected it for a "
                    f"{trigger.delay_us:g} us trigger delay — set the delay in the booth instead"
                )
        self._set_enum("TriggerMode", "On")
        actual = trigger
        if trigger.mode == "line":
            delay = next((self._number(f) for f in ("TriggerDelay", "TriggerDelayAbs") if self._has(f)), 0.0)
            activation = str(self.get_feature("TriggerActivation")) if self._has("TriggerActivation") else "RisingEdge"
            actual = replace(
                trigger, line=str(self.get_feature("TriggerSource")), activation=activation, delay_us=delay
            )
        self._trigger = actual
        return actual

    def configure_strobe(self, strobe: StrobeConfig) -> StrobeConfig:
        """Drive an output line from ``strobe.source`` (ExposureActive or a user output)."""
        for feature in ("LineSelector", "LineSource"):
            if not self._has(feature):
                raise CameraError(
                    f"{self._name}: has no feature {feature}; expected it for a strobe "
                    f"output on {strobe.line} — use a host-paced or booth-paced plan"
                )
        self._set_enum("LineSelector", strobe.line)
        if self._has("LineMode") and self._is_writable("LineMode"):
            self._set_enum("LineMode", "Output")
        self._set_enum("LineSource", strobe.source)
        if self._has("LineInverter"):
            self._set_bool("LineInverter", strobe.inverted)
        elif strobe.inverted:
            raise CameraError(f"{self._name}: has no feature LineInverter; expected it to invert {strobe.line}")
        self._strobe = replace(strobe, source=str(self.get_feature("LineSource")))
        return self._strobe

    def set_sync_lines(self, trigger_line: str | None = None, strobe_line: str | None = None) -> None:
        """Use ``trigger_line`` for booth-paced plans and drive ``strobe_line`` in later :meth:`prepare` calls.

        None keeps the line in use. A strobe line given when none was configured sets one up (source
        ExposureActive); entries are checked when :meth:`prepare` writes them.
        """
        if trigger_line is not None:
            self._line_trigger = replace(self._line_trigger, line=trigger_line)
        if strobe_line is not None:
            self._strobe_request = replace(self._strobe_request or StrobeConfig(), line=strobe_line)

    def user_outputs(self) -> tuple[str, ...]:
        """The camera's user outputs (UserOutputSelector entries; FLIR counts from 1, others from 0)."""
        if not self._has("UserOutputSelector"):
            return ()
        return self.enum_entries("UserOutputSelector")

    def set_user_output(self, output: int | str, value: bool) -> None:
        """Set a user output by position in :meth:`user_outputs` or by name."""
        outputs = self.user_outputs()
        if not outputs or not self._has("UserOutputValue"):
            raise CameraError(f"{self._name}: has no feature UserOutputSelector/UserOutputValue; expected user outputs")
        if isinstance(output, int):
            if not 0 <= output < len(outputs):
                raise CameraError(
                    f"{self._name}: user output {output} out of range; expected 0..{len(outputs) - 1} "
                    f"({', '.join(outputs)})"
                )
            output = outputs[output]
        self._set_enum("UserOutputSelector", output)
        self._set_bool("UserOutputValue", bool(value))

    # -- the Camera protocol ------------------------------------------------------------------

    @property
    def info(self) -> CameraInfo:
        """Identity and pixel encoding, read from the camera now."""
        pixel_format = str(self.get_feature("PixelFormat"))
        layout = PIXEL_FORMATS.get(pixel_format)
        _, _, width, height = self.roi
        black = self._number("BlackLevel") if self._has("BlackLevel") else 0.0
        extra = {
            "device_id": self._device_id,
            "interface": self._protocol,
            "address": self._address,
            "profile": self._profile.name,
            "exposure_feature": self._exposure_feature,
            "gain_feature": self.gain_feature,
            "firmware": self._read_string("DeviceVersion"),
        }
        return CameraInfo(
            vendor=self._vendor,
            model=self._model,
            serial=self._serial,
            pixel_format=pixel_format,
            cfa=layout.cfa if layout else None,
            black_level=black,
            white_level=float(2**layout.bits - 1) if layout else float("nan"),
            width=width,
            height=height,
            extra=extra,
        )

    @property
    def settings(self) -> CameraSettings:
        """The settings in effect, read back from the camera."""
        return CameraSettings(
            exposure_us=self.exposure_us,
            gain=self.gain,
            gain_db=self.gain_db,
            roi=self.roi,
            pixel_format=str(self.get_feature("PixelFormat")),
            trigger=self._trigger,
            strobe=self._strobe,
            exposure_feature=self._exposure_feature,
            gain_feature=self.gain_feature,
        )

    @property
    def stats(self) -> AcquisitionStats:
        """Frame accounting of the current (or last) acquisition."""
        with self._stats_lock:
            return replace(self._stats, statuses=dict(self._stats.statuses))

    def prepare(self, plan: CapturePlan) -> None:
        """Configure trigger, strobe, the first step's exposure and gain, and a buffer pool for ``plan``."""
        if not plan.steps:
            raise CameraError(f"{self._name}: plan has no steps; expected at least one")
        self.stop()
        if plan.trigger == "software":
            self.configure_trigger(TriggerConfig(mode="software"))
        elif plan.trigger == "booth":
            self.configure_trigger(self._line_trigger)
        elif plan.trigger == "camera":
            if self._strobe_request is None:
                raise CameraError(
                    f"{self._name}: a camera-paced plan needs a strobe output; expected "
                    "AravisCamera(strobe=StrobeConfig(line=…))"
                )
            self.configure_trigger(TriggerConfig(mode="free"))
        else:
            raise CameraError(f"{self._name}: plan trigger {plan.trigger!r}; expected software, booth or camera")
        if self._strobe_request is not None:
            self.configure_strobe(self._strobe_request)
        self._step_request = None
        self._current = (self.exposure_us, self.gain, self._native_gain)
        self._apply_step(0, plan)
        self._plan = plan
        self._build_stream(len(plan.steps) + self._extra_buffers)
        # One spare buffer per step: a sequence hands out one buffer per frame and allocates none.
        assert self._pool is not None
        self._pool.reserve(min(len(plan.steps), _MAX_SPARE_BYTES // self._pool.payload))

    def update_plan(self, plan: CapturePlan, index: int) -> None:
        """Take ``plan``, whose step ``index`` changed (before its trigger): software triggered, the
        step is applied when triggered; on a trigger line it was set up after the previous frame, so
        it is applied again now."""
        self._plan = plan
        if self._trigger.mode != "software" and self._n_consumed == index:
            self._apply_step(index, plan)

    @property
    def readout_skew_us(self) -> float:
        """0: the camera's rolling-shutter skew is not read (taken as a global shutter)."""
        return 0.0

    def _apply_step(self, index: int, plan: CapturePlan) -> tuple[float, float, NativeGain | None]:
        # Write only what changes: each write and read-back is a GVCP round trip on the trigger path.
        step = plan.steps[index]
        requested = self._step_request
        exposure, gain, native = self._current
        if requested is None or requested[0] != step.exposure_us:
            exposure = self.set_exposure_us(step.exposure_us)
        if requested is None or requested[1] != step.gain:
            gain = self.set_gain(step.gain)
            native = self._native_gain
        self._step_request = (step.exposure_us, step.gain)
        log.debug("%s: step %d exposure %.1f us gain %.3f", self._name, index, exposure, gain)
        self._current = (exposure, gain, native)
        return exposure, gain, native

    def _build_stream(self, n_buffers: int) -> None:
        # Creating (and destroying) a stream costs tens of ms on GigE Vision (socket, thread, stream
        # channel registers): the stream of the previous capture is reused, with its buffers, when
        # the frame layout, the payload and the pool still fit. Buffers it still holds are stale:
        # start() drains them.
        spare, self._spare = self._spare, None
        fits = False
        try:
            try:
                payload = int(self._camera.get_payload())
            except GLib.Error as err:
                raise self._fail("reading", "PayloadSize", err) from err
            layout = (str(self.get_feature("PixelFormat")),) + self.roi[2:]
            fits = (
                spare is not None
                and (spare.pool.payload, spare.layout) == (payload, layout)
                and (spare.n_buffers >= n_buffers)
            )
        finally:
            if spare is not None and not fits:
                spare.pool.release()
        if spare is not None and fits:
            self._pool, self._n_buffers, self._layout_key = spare.pool, spare.n_buffers, layout
            self._stale_before_ns = 1  # start() sets the acquisition's start time
            return
        try:
            if self._protocol == "gige":
                stream = create_gv_stream(self._camera, payload)  # the UDP socket, sized for frames
            else:
                stream = self._camera.create_stream(None, None)
        except GLib.Error as err:
            raise self._fail("creating the stream for", "PayloadSize", err) from err
        if stream is None:
            raise CameraError(f"{self._name}: no stream channel; expected the camera to stream images")
        if n_buffers * payload > _MAX_POOL_BYTES:
            reduced = max(2, _MAX_POOL_BYTES // payload)
            log.warning(
                "%s: %d buffers of %d bytes exceed %d MiB; using %d",
                self._name,
                n_buffers,
                payload,
                _MAX_POOL_BYTES >> 20,
                reduced,
            )
            n_buffers = reduced
        zero_copy = self._zero_copy and self._protocol in ZERO_COPY_PROTOCOLS and is_zero_copy_format(layout[0])
        pool = _BufferPool(stream, payload, zero_copy)
        try:
            pool.fill(n_buffers)
        except BaseException:
            pool.release()
            raise
        self._pool = pool
        self._n_buffers = n_buffers
        self._layout_key = layout
        self._stale_before_ns = 0

    @property
    def pool_arrays(self) -> tuple[int, int]:
        """Arrays the camera holds for zero-copy frames: (behind buffers in the stream, spares).

        The first stays at the pool size and the second only shrinks during an acquisition
        (:meth:`prepare` tops it up): frames handed out are the caller's, not the camera's.
        Both are 0 for a copying camera and after :meth:`close`.
        """
        pool = self._pool if self._pool is not None else (self._spare.pool if self._spare is not None else None)
        return pool.counts if pool is not None else (0, 0)

    def start(self) -> None:
        """Start acquisition and the thread that pops buffers."""
        if self._acquiring:
            return
        pool = self._pool
        if pool is None:
            raise CameraError(f"{self._name}: start() before prepare(); expected a prepared camera")
        self._queue = queue.Queue()
        self._triggered_settings.clear()
        self._n_triggered = self._n_consumed = 0
        self._last_frame_id = None
        with self._stats_lock:
            self._stats = AcquisitionStats(n_buffers=self._n_buffers)
        self._pump_stop.clear()
        if self._stale_before_ns:  # a reused stream: drop what the previous acquisition left in it
            while (buffer := pool.stream.try_pop_buffer()) is not None:
                pool.stream.push_buffer(buffer)
            self._stale_before_ns = time.time_ns()
        self._pump = threading.Thread(
            target=self._pump_buffers, args=(pool,), name=f"aravis-pump-{self._serial}", daemon=True
        )
        self._pump.start()
        try:
            self._camera.start_acquisition()
        except GLib.Error as err:
            self._stop_pump()
            raise self._fail("starting", "AcquisitionStart", err) from err
        self._acquiring = True

    def _pump_buffers(self, pool: _BufferPool) -> None:
        # A dedicated thread popping with a timeout: stream callbacks lost most frames under load.
        stream = pool.stream
        stale_before_ns = self._stale_before_ns
        while not self._pump_stop.is_set():
            buffer = stream.timeout_pop_buffer(_POP_POLL_US)
            if buffer is None:
                continue
            popped_ns = time.time_ns()
            handed_out = False
            try:
                if 0 < int(buffer.get_system_timestamp()) < stale_before_ns:
                    continue  # a frame of the previous acquisition still in flight when it stopped
                if buffer.get_status() == Aravis.BufferStatus.CLEARED:
                    # Never filled: Aravis hands a buffer back untouched when the packet that took
                    # it could not start a frame (a stray datagram; gv_stream.py). Not a frame.
                    with self._stats_lock:
                        self._stats = replace(self._stats, buffers_unfilled=self._stats.buffers_unfilled + 1)
                    continue
                item, handed_out = self._take(buffer, pool, popped_ns)
            except Exception as exc:  # noqa: BLE001 - handed to the consumer, never lost
                item = _Failure(exc)
            finally:
                if not handed_out:
                    stream.push_buffer(buffer)  # its array (if any) stays registered in the pool
            # The caller's thread, woken by the queue, need not wait for this one: a copy is already
            # made, and a handed-out buffer's replacement is pushed only now.
            self._queue.put(item)
            if handed_out:
                try:
                    pool.replace()
                except Exception as exc:  # noqa: BLE001 - the pool is one buffer short, frames still flow
                    log.warning(
                        "%s: no buffer to replace one handed out (%s); the pool shrinks by one", self._name, exc
                    )

    def _take(self, buffer: Any, pool: _BufferPool, popped_ns: int) -> tuple[_Good | _Bad | _Failure, bool]:
        """What the consumer gets for one popped buffer, and whether the buffer's own array went
        with it (then the buffer must never be pushed again); otherwise the pixels are copied."""
        pixel_format, width, height = self._layout_key
        status = buffer.get_status()
        frame_id = int(buffer.get_frame_id())
        if status != Aravis.BufferStatus.SUCCESS:
            return _Bad(frame_id, status.value_nick), False
        w, h = buffer.get_image_width(), buffer.get_image_height()
        if (w, h) != (width, height):
            return _Failure(CameraError(f"{self._name}: frame {frame_id} is {w}x{h}; expected {width}x{height}")), False
        received = int(buffer.get_system_timestamp())
        timestamp = int(buffer.get_timestamp()) or received
        array = pool.array_of(buffer)
        if array is None:
            pixels = decode_pixels(buffer.get_data(), pixel_format, w, h, where=self._name)
            return _Good(pixels, frame_id, timestamp, received, popped_ns), False
        pixels = view_pixels(array, pixel_format, w, h, where=self._name)
        pool.hand_out(buffer)  # last: nothing after it can fail and push the buffer back
        return _Good(pixels, frame_id, timestamp, received, popped_ns), True

    def _step_label(self, index: int) -> str:
        plan = self._plan
        if plan is not None and index < len(plan.steps):
            step = plan.steps[index]
            # A sequence's steps are named by their index (a retake's plan holds the steps left,
            # from the lost one); a plan repeating one step (the bench, live view) counts frames.
            distinct = len({s.index for s in plan.steps}) == len(plan.steps)
            return f"step {step.index if distinct else index} '{step.label}'"
        return f"frame {index} (beyond the plan)"

    def trigger(self) -> None:
        """Apply the next step's exposure and gain, then issue a software trigger (no-op otherwise)."""
        if self._trigger.mode != "software":
            return
        if not self._acquiring:
            raise CameraError(f"{self._name}: trigger() before start(); expected a started acquisition")
        index = self._n_triggered
        settings = self._current
        if self._plan is not None and index < len(self._plan.steps):
            try:
                settings = self._apply_step(index, self._plan)
            except CameraError as err:
                raise type(err)(f"{err} (while setting up {self._step_label(index)})") from err
        try:
            self._live().execute_command("TriggerSoftware")
        except GLib.Error as err:
            raise self._fail(f"triggering {self._step_label(index)}:", "TriggerSoftware", err) from err
        self._triggered_settings.append(settings)
        self._n_triggered += 1

    def next_frame(self, timeout_s: float) -> RawFrame:
        """The next complete frame.

        Raises
        ------
        FrameTimeoutError
            Nothing arrived within ``timeout_s``; names the step.
        FrameLostError
            The frame arrived incomplete or frame ids were skipped; names the step and frame id.
            Incomplete frames are counted in :attr:`stats` and never returned.
        CameraDisconnectedError
            Aravis reported ``control-lost``, or nothing arrived within ``timeout_s`` and the camera
            no longer answers a register read (:meth:`_silence`): a camera switched off or
            unplugged, told apart from a trigger problem before its heartbeat fails.
        """
        if not self._acquiring:
            raise CameraError(f"{self._name}: next_frame() before start(); expected a started acquisition")
        index = self._n_consumed
        where = self._step_label(index)
        if self._control_lost.is_set():
            raise CameraDisconnectedError(
                f"{self._name}: control lost before {where}; expected a "
                "connected camera — check power and cable, then reopen it"
            )
        try:
            item = self._queue.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            stats = self.stats
            silent = self._silence()
            if silent is not None:
                raise CameraDisconnectedError(
                    f"{self._name}: no frame for {where} within {timeout_s:.3g} s, and the camera no longer "
                    f"answers ({silent}); expected a connected camera — check its power and cable, then "
                    f"reopen it ({stats.frames_good} good frame(s) before)"
                ) from None
            raise FrameTimeoutError(
                f"{self._name}: no frame for {where} within {timeout_s:.3g} s; expected one frame per "
                f"{'trigger' if self._trigger.mode != 'free' else 'frame period'} "
                f"({stats.frames_good} good, {stats.frames_incomplete} incomplete so far) — check the "
                "trigger source and wiring"
            ) from None
        if item is _CONTROL_LOST:
            raise CameraDisconnectedError(
                f"{self._name}: control lost while waiting for {where}; expected a "
                "connected camera — check power and cable, then reopen it"
            )
        settings = self._triggered_settings.popleft() if self._triggered_settings else self._current
        self._n_consumed += 1
        if isinstance(item, _Failure):
            raise CameraError(f"{self._name}: {where}: {item.error}") from item.error
        if isinstance(item, _Bad) and item.frame_id == 0 and self._protocol == "gige":
            # Aravis names no block id (0, never sent on GigE Vision) for a frame it could not
            # identify: it is taken as the next frame, so neither it nor the frame after it counts
            # the whole 16-bit range as missing.
            missing = 0
            previous = self._last_frame_id
            if previous is not None:  # 65535 is followed by 1 (16-bit block ids), beyond by +1 (64-bit)
                self._last_frame_id = 1 if previous == _GV_FRAME_ID_WRAP - 1 else previous + 1
        else:
            missing = self._check_continuity(item.frame_id)
        if isinstance(item, _Bad):
            with self._stats_lock:
                statuses = dict(self._stats.statuses)
                statuses[item.status] = statuses.get(item.status, 0) + 1
                self._stats = replace(
                    self._stats, frames_incomplete=self._stats.frames_incomplete + 1, statuses=statuses
                )
            raise FrameLostError(
                f"{self._name}: frame {item.frame_id} for {where} arrived incomplete "
                f"(buffer status {item.status}); expected a complete frame — check the "
                "link (packet size, MTU, cable, bandwidth)"
            )
        if missing:
            raise FrameLostError(
                f"{self._name}: {missing} frame(s) lost before frame {item.frame_id} "
                f"({where}); expected consecutive frame ids — enlarge the buffer pool "
                "or lower the frame rate"
            )
        with self._stats_lock:
            self._stats = replace(self._stats, frames_good=self._stats.frames_good + 1)
        if self._trigger.mode != "software" and self._plan is not None and self._n_consumed < len(self._plan.steps):
            # Without software triggers the next exposure is set between frames: the plan's
            # deadtime must cover these writes.
            self._apply_step(self._n_consumed, self._plan)
        exposure_us, gain, native = settings
        frame = RawFrame(item.pixels, item.frame_id, item.timestamp_ns, exposure_us, gain, native)
        self._last_timing = FrameTiming(item.timestamp_ns, item.received_ns, item.popped_ns, time.time_ns())
        return frame

    def _silence(self) -> str | None:
        """Why the camera no longer answers, or None when it does (asked after a frame timeout).

        A GigE Vision camera that is switched off or unplugged raises ``control-lost`` only when its
        heartbeat fails, seconds later: a frame timeout then read as a trigger problem. One read of
        a bootstrap register (GigE Vision ``Version``, 0x0000, which every device has) tells them
        apart: an answer in milliseconds, or a timeout after Aravis's retries (about 4 s) — after
        which the control writes of stopping are skipped (each would wait its retries again).
        Other transports report a lost device themselves.
        """
        if self._control_lost.is_set():
            return "control lost"
        if self._protocol != "gige" or self._device is None:
            return None
        try:
            self._device.read_register(0x0000)
        except GLib.Error as err:
            self._unreachable = True
            return "control lost" if self._control_lost.is_set() else err.message
        return None

    @property
    def last_frame_timing(self) -> FrameTiming | None:
        """Stage times of the frame :meth:`next_frame` returned last (None before the first)."""
        return self._last_timing

    def _check_continuity(self, frame_id: int) -> int:
        previous, self._last_frame_id = self._last_frame_id, frame_id
        if previous is None:
            return 0
        wrap = _GV_FRAME_ID_WRAP if self._protocol == "gige" and max(previous, frame_id) < _GV_FRAME_ID_WRAP else None
        gap = frame_id_gap(previous, frame_id, wrap=wrap, skip_zero=self._protocol == "gige")
        if gap > 0:
            with self._stats_lock:
                self._stats = replace(self._stats, frames_missing=self._stats.frames_missing + gap)
            return gap
        return 0

    def _stop_pump(self) -> bool:
        """Stop the popping thread; False when it did not exit (it may still touch the stream)."""
        self._pump_stop.set()
        if self._pump is not None:
            self._pump.join(timeout=5.0)
            if self._pump.is_alive():  # pragma: no cover - Aravis stuck in pop
                log.error("%s: buffer thread did not stop", self._name)
                return False
        self._pump = None
        return True

    def stop(self) -> None:
        """Stop acquisition, stop the buffer thread and drop the stream; idempotent.

        The order keeps Aravis from writing into freed memory: acquisition stops first, then the
        popping thread, then the stream is kept for the next :meth:`prepare` with its buffers and
        their arrays, or — control lost — released (its thread stopped, its buffers deleted)
        before the arrays go (see :class:`_BufferPool`).
        """
        if self._acquiring and self._camera is not None:
            try:
                if not (self._control_lost.is_set() or self._unreachable):
                    self._camera.stop_acquisition()
            except GLib.Error as err:
                log.warning("%s: AcquisitionStop failed: %s", self._name, err.message)
        self._acquiring = False
        stopped = self._stop_pump()
        pool, self._pool = self._pool, None
        if pool is None:
            return
        if not stopped:  # pragma: no cover - the thread may still push a buffer back
            pool.abandon()
        elif self._control_lost.is_set() or self._unreachable:
            # Measured on the GigE fake killed mid-stream: 5 s here and 5 s more at close, in Aravis.
            log.warning(
                "%s: releasing a camera that no longer answers; Aravis waits out its control "
                "retries first (about 10 s)",
                self._name,
            )
            pool.release()
        elif self._stats.frames_incomplete or self._stats.frames_missing:
            # A stream that lost frames is not reused: Aravis may still hold a partial frame of
            # it, which the next acquisition received in place of its first frame (seen on the
            # lossy fake when a capture took a lost frame again: the new first frame never came).
            pool.release()
        else:
            self._spare = _SpareStream(pool, self._n_buffers, self._layout_key)


# --------------------------------------------------------------------------------------------
# The GigE Vision fake camera on 127.0.0.1
# --------------------------------------------------------------------------------------------

GVCP_LOCK_PATH = Path(tempfile.gettempdir()) / "msflash-gvcp-127.0.0.1-3956.lock"
"""One GigE Vision fake can listen on 127.0.0.1:3956 at a time on this machine."""
GVCP_PORT = 3956
"""The GigE Vision control port (UDP)."""
_GV_MODEL_NAME_REGISTER = 0x68
"""GigE Vision bootstrap register of the model name (32 bytes), which the fake fills with "Fake"."""


def gvcp_port_holder(address: str = "127.0.0.1", port: int = GVCP_PORT) -> str | None:
    """Why ``address:port`` cannot be bound by itself (another program holds it), or None when it is free.

    The probe binds without ``SO_REUSEADDR``: the Aravis GigE Vision fake binds its control port
    *with* address reuse, so a second fake on the same address starts without error and the
    kernel then hands each control request to one of the two — a camera opened at the address may
    be the other program's (seen: ``arv-fake-gv-camera-0.8 -i 127.0.0.1`` running, the
    ``aravis-fake`` rig's own fake started, and the rig talked to the other one). Only an
    exclusive bind tells.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind((address, port))
        except OSError as err:
            return err.strerror or str(err)
    return None


_gvcp_hold: dict[str, Any] = {"count": 0, "fd": None}
"""This process's hold of :func:`gvcp_port_lock`: how many holders, and the locked file's descriptor."""
_gvcp_hold_lock = threading.Lock()


@contextmanager
def gvcp_port_lock(timeout_s: float = 120.0) -> Iterator[None]:
    """Hold the machine-wide lock on the GigE Vision control port 3956 of 127.0.0.1.

    The Aravis GigE Vision fake binds 127.0.0.1:3956 and only the loopback address exists, so
    fakes in parallel test workers, benches and rigs must take turns. An ``flock`` is released by
    the kernel if the holder dies. A process that holds it already holds it again at once (it
    never waits for itself): a second fake it starts then finds the port bound and is refused
    (:meth:`AravisGvFake.start`), as one of another program is. The ``flock`` goes with the last
    holder of the process.

    Raises
    ------
    CameraError
        The lock was not obtained within ``timeout_s``.
    """
    with _gvcp_hold_lock:
        if _gvcp_hold["count"]:
            _gvcp_hold["count"] += 1
            fd = None
        else:
            fd = os.open(GVCP_LOCK_PATH, os.O_CREAT | os.O_RDWR, 0o666)
    if fd is not None:
        try:
            deadline = time.monotonic() + timeout_s
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() > deadline:
                        raise CameraError(
                            f"GigE Vision fake: port 127.0.0.1:3956 busy for {timeout_s:g} s "
                            f"(lock {GVCP_LOCK_PATH}); expected it free — another fake is running"
                        ) from None
                    time.sleep(0.02)
        except BaseException:
            os.close(fd)
            raise
        with _gvcp_hold_lock:
            _gvcp_hold["count"] += 1
            _gvcp_hold["fd"] = fd
    try:
        yield
    finally:
        with _gvcp_hold_lock:
            _gvcp_hold["count"] -= 1
            if not _gvcp_hold["count"]:
                held, _gvcp_hold["fd"] = _gvcp_hold["fd"], None
                fcntl.flock(held, fcntl.LOCK_UN)
                os.close(held)


class AravisGvFake:
    """The Aravis GigE Vision fake camera served on 127.0.0.1 by this process.

    It speaks real GVCP/GVSP, honours software triggers and exposes its registers, so
    :class:`AravisCamera` opened on ``address`` with ``interfaces=("gige",)`` exercises the whole
    GigE Vision path without a network. Use as a context manager; it holds :func:`gvcp_port_lock`.

    Parameters
    ----------
    serial
        Serial number the fake reports.
    genicam_xml
        GenICam description (defaults to msflash's SFNC XML); ``None`` for the fake's built-in one.
    trigger_frequency_hz
        How often the fake checks for a software trigger (its trigger-to-frame latency).
    lost_packet_ratio
        Fraction of GVSP packets the fake drops (a lossy link).
    model
        Model name the fake reports (its bootstrap register; the XML's ``DeviceModelName`` reads it),
        None for Aravis's "Fake". Camera profiles are matched on it.
    registers
        Registers written when the fake starts (address → 32-bit value): a camera's power-on state
        (``GainAuto`` on, a gain register's first value).

    Examples
    --------
    A rig on the fake (no network beyond loopback, no discovery)::

        with AravisGvFake(serial="RIG01") as fake, \
                AravisCamera(fake.address, interfaces="gige", pixel_format="Mono16") as camera:
            camera.prepare(plan)
            camera.start()
            ...
    """

    address = "127.0.0.1"

    def __init__(
        self,
        serial: str = "MSF0001",
        genicam_xml: str | os.PathLike[str] | None = FAKE_SFNC_XML,
        trigger_frequency_hz: float = 1000.0,
        lost_packet_ratio: float = 0.0,
        lock_timeout_s: float = 120.0,
        model: str | None = None,
        registers: dict[int, int] | None = None,
    ) -> None:
        self.serial = serial
        self.model = model
        self._registers = dict(registers or {})
        # None: the fake's built-in description, named explicitly — given no file, Aravis's fake
        # reads the process-wide one use_fake_genicam last set for the in-process fake.
        self._xml = str(genicam_xml) if genicam_xml is not None else _builtin_fake_xml_path()
        self._frequency = trigger_frequency_hz
        self._lost = lost_packet_ratio
        self._lock_timeout_s = lock_timeout_s
        self._lock: Any = None
        self._fake: Any = None

    def __enter__(self) -> AravisGvFake:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        """Take the port lock and start serving.

        Raises
        ------
        CameraError
            The port is held by another program (not an msflash fake: those take the lock), whose
            camera would answer in place of this one (:func:`gvcp_port_holder`).
        """
        self._lock = gvcp_port_lock(self._lock_timeout_s)
        self._lock.__enter__()
        try:
            held = gvcp_port_holder(self.address)
            if held is not None:
                raise CameraError(
                    f"GigE Vision fake {self.serial}: {self.address}:{GVCP_PORT} is already bound by another "
                    f"program ({held}) — another GigE Vision fake such as arv-fake-gv-camera-0.8?; expected it "
                    "free: both would share the port and msflash could open the other camera — stop it, or use "
                    "it with --rig hw --camera 127.0.0.1 --interfaces gige"
                )
            fake = Aravis.GvFakeCamera.new_full(self.address, self.serial, self._xml)
            if not fake.is_running():
                raise CameraError(
                    f"GigE Vision fake {self.serial}: cannot listen on {self.address}:3956; "
                    "expected the port free — is an arv-fake-gv-camera running?"
                )
            fake.set_property("gvsp-lost-ratio", float(self._lost))
            fake.get_fake_camera().set_trigger_frequency(self._frequency)
            self._fake = fake
            if self.model is not None:
                self._write_model_name(self.model)
            for address, value in self._registers.items():
                self.write_register(address, value)
        except BaseException:
            self._lock.__exit__(None, None, None)
            self._lock = None
            raise

    def close(self) -> None:
        """Stop serving and release the port; idempotent."""
        self._fake = None  # finalising the GObject stops its thread and closes its sockets
        if self._lock is not None:
            self._lock.__exit__(None, None, None)
            self._lock = None

    def _write_model_name(self, model: str) -> None:
        data = model.encode("ascii")[:31].ljust(32, b"\0")
        for offset in range(0, 32, 4):
            self.write_register(_GV_MODEL_NAME_REGISTER + offset, int.from_bytes(data[offset : offset + 4], "big"))

    def read_register(self, address: int) -> int:
        """A 32-bit register of the fake, as the camera side sees it."""
        ok, value = self._fake.get_fake_camera().read_register(address)
        if not ok:
            raise CameraError(
                f"GigE Vision fake {self.serial}: register 0x{address:x} unreadable; expected an address below 0x10000"
            )
        return int(value)

    def write_register(self, address: int, value: int) -> None:
        """Write a 32-bit register of the fake (simulates the camera changing state)."""
        self._fake.get_fake_camera().write_register(address, value)


# --------------------------------------------------------------------------------------------
# Reference loops for the bench: plain Aravis, no msflash layer
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TriggerTiming:
    """One software trigger and its frame, as a latency run times them (``CLOCK_REALTIME`` ns)."""

    sent_ns: int
    """Just before the trigger call."""
    triggered_ns: int
    """When the trigger call returned (the device acknowledged the TriggerSoftware write)."""
    frame: FrameTiming
    """The frame's stage times; ``delivered_ns`` is when the caller had it in hand."""


@dataclass(frozen=True)
class BareRun:
    """What a bare Aravis loop measured."""

    frames: int
    """Complete frames received (warm-up frames excluded)."""
    bad: int
    """Buffers with a status other than success."""
    missing: int
    """Frame ids skipped."""
    seconds: float
    """Wall time from the first to the last frame received."""
    timings: tuple[TriggerTiming, ...] = ()
    """Per trigger, its stage times (software-trigger runs only; warm-up frames excluded)."""


def bare_aravis_run(
    address: str,
    *,
    width: int,
    height: int,
    pixel_format: str,
    n_frames: int,
    software_trigger: bool,
    frame_rate_hz: float | None = None,
    n_buffers: int = 16,
    timeout_s: float = 2.0,
    dither_s: float = 0.0,
    warm_up_frames: int = 0,
) -> BareRun:
    """The smallest correct Aravis loop on the GigE Vision camera at ``address``: pop, check, push.

    With ``software_trigger`` each frame is triggered and waited for (latency); otherwise the
    camera free-runs at ``frame_rate_hz`` and the loop measures throughput. It is the baseline
    the bench compares :class:`AravisCamera` against; it never copies pixels, and its buffers,
    like AravisCamera's, use pre-faulted memory. ``dither_s`` waits a random time up to that long
    before each trigger, and the first ``warm_up_frames`` frames are received but not counted or
    timed (see ``bench_camera`` for why both matter on the fake).
    """
    use_interfaces(("gige",))
    camera = Aravis.Camera.new(address)
    pool: _BufferPool | None = None
    try:
        device = camera.get_device()
        camera.set_acquisition_mode(Aravis.AcquisitionMode.CONTINUOUS)
        camera.set_region(0, 0, width, height)
        camera.set_pixel_format_from_string(pixel_format)
        if software_trigger:
            camera.set_trigger("Software")
        else:
            device.set_string_feature_value("TriggerSelector", "FrameStart")
            device.set_string_feature_value("TriggerMode", "Off")
            if frame_rate_hz is not None:
                camera.set_frame_rate(frame_rate_hz)
        payload = int(camera.get_payload())
        stream = create_gv_stream(camera, payload)  # as AravisCamera's
        pool = _BufferPool(stream, payload, zero_copy=True)  # buffers only pushed back
        pool.fill(n_buffers)
        camera.start_acquisition()
        frames = bad = missing = 0
        previous: int | None = None
        timings: list[TriggerTiming] = []
        first = last = time.perf_counter()
        try:
            for index in range(-warm_up_frames, n_frames):
                if dither_s > 0:
                    time.sleep(random.uniform(0.0, dither_s))
                sent = triggered = time.time_ns()
                if software_trigger:
                    camera.software_trigger()
                    triggered = time.time_ns()
                buffer = stream.timeout_pop_buffer(int(timeout_s * 1e6))
                popped = time.time_ns()
                now = time.perf_counter()
                if buffer is None:
                    raise CameraError(
                        f"bare Aravis loop on {address}: no frame within {timeout_s} s; expected a streaming camera"
                    )
                try:
                    good = buffer.get_status() == Aravis.BufferStatus.SUCCESS
                    frame_id = int(buffer.get_frame_id())
                    stamps = int(buffer.get_timestamp()), int(buffer.get_system_timestamp())
                finally:
                    stream.push_buffer(buffer)
                delivered = time.time_ns()
                if index < 0:
                    previous = frame_id
                    continue
                frames, bad = frames + good, bad + (not good)
                if previous is not None:
                    missing += max(0, frame_id_gap(previous, frame_id))
                if index == 0:
                    first = now
                previous = frame_id
                last = now
                if software_trigger:
                    timings.append(TriggerTiming(sent, triggered, FrameTiming(*stamps, popped, delivered)))
        finally:
            camera.stop_acquisition()
        return BareRun(frames, bad, missing, last - first, tuple(timings))
    finally:
        if pool is not None:
            pool.release()  # the stream and its buffers go before their arrays
        stream = None  # noqa: F841 - release the stream before the camera
        camera = None  # noqa: F841
