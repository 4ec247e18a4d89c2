"""Camera options a user or a camera profile sets: lines, gain, ROI, binning, any GenICam feature.

:class:`CameraOptions` carries what ``--trigger-line``, ``--strobe-line``,
``--gain``, ``--roi``, ``--binning`` and ``--feature NAME=VALUE`` ask for (or a profile's
``"options"`` in ``genicam/profiles.json``; the command line wins), and
:func:`apply_camera_options` writes them to an opened camera and reads each one back.

A value the camera cannot take raises :class:`~acquisition.errors.CameraSettingError` (bad
input, exit 2) whose one line names the camera, the option or feature, and what the camera
allows: its enumeration entries, its range and increment, or its type. The checks use what the
camera reports at run time (:class:`FeatureInfo`, from ``AravisCamera.describe_feature``), never a
table of models.

No ``gi`` here: the camera object does the GenICam access (``describe_feature``, ``set_feature``,
``set_roi``), so everything but that access is testable without Aravis.

``--gain``/``--gain-raw`` is :mod:`acquisition.devices.aravis.gain`; every feature msflash touches,
:data:`~.msflash_features.MSFLASH_FEATURES`.
"""

from __future__ import annotations

import argparse
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

from msflash.acquisition.devices.aravis.gain import GainRequest
from msflash.acquisition.errors import CameraError, CameraSettingError
from msflash.processing.names import close_names
from msflash.processing.user_numbers import plain_number, plain_whole_number

log = logging.getLogger(__name__)

FeatureKind = Literal["enumeration", "boolean", "integer", "float", "string", "command", "other"]
FeatureValue = str | int | float | bool

_BINNING_FEATURES = ("BinningHorizontal", "BinningVertical")


@dataclass(frozen=True)
class FeatureInfo:
    """One GenICam feature as the camera describes it now."""

    name: str
    """Feature name (``Gain``, ``PixelFormat`` …)."""
    kind: FeatureKind
    """Its GenICam interface."""
    access: str
    """``RO``, ``RW`` or ``WO`` (``NA`` when the camera does not say)."""
    value: FeatureValue | None = None
    """Current value (None for commands, write-only or unreadable features)."""
    minimum: float | None = None
    """Lower bound of an integer or float feature, when the camera gives one."""
    maximum: float | None = None
    """Upper bound of an integer or float feature, when the camera gives one."""
    increment: float | None = None
    """Step of an integer feature (1 when unconstrained), when the camera gives one."""
    unit: str = ""
    """Unit of a float or integer feature (``us``, ``dB``), when the camera gives one."""
    entries: tuple[str, ...] = ()
    """Available entries of an enumeration."""
    category: str = ""
    """The GenICam category the feature was found under ("" when no category under ``Root`` lists it)."""
    visibility: str = ""
    """GenICam visibility (``Beginner``, ``Expert``, ``Guru``, ``Invisible``), when the camera says."""
    msflash: str = ""
    """What msflash does with it: ``reads``, ``writes``, ``executes`` (:mod:`.msflash_features`), else ""."""

    @property
    def writable(self) -> bool:
        """Whether the camera accepts writes to it now."""
        return self.access in ("RW", "WO") and self.kind != "command"

    def allowed(self) -> str:
        """What the feature accepts, for messages: entries, range and step, or type.

        Examples
        --------
        >>> FeatureInfo("Gain", "float", "RW", 0.0, 0.0, 24.0, unit="dB").allowed()
        'a number in 0 … 24 dB'
        >>> FeatureInfo("TriggerMode", "enumeration", "RW", "Off", entries=("Off", "On")).allowed()
        'one of Off, On'
        """
        if self.kind == "enumeration":
            return f"one of {', '.join(self.entries)}" if self.entries else "an entry (none available now)"
        if self.kind == "boolean":
            return "true or false"
        if self.kind in ("integer", "float"):
            what = "a whole number" if self.kind == "integer" else "a number"
            if self.minimum is None or self.maximum is None:
                return what
            step = (
                f" in steps of {self.increment:g}" if self.kind == "integer" and self.increment not in (None, 1) else ""
            )
            unit = f" {self.unit}" if self.unit else ""
            return f"{what} in {self.minimum:g} … {self.maximum:g}{unit}{step}"
        if self.kind == "string":
            return "text"
        return "nothing msflash can write (a command or an unsupported node type)"

    def to_dict(self) -> dict[str, Any]:
        """JSON form (``msflash devices --features --json``)."""
        out: dict[str, Any] = {"name": self.name, "type": self.kind, "access": self.access, "value": self.value}
        if self.kind in ("integer", "float"):
            out.update(minimum=self.minimum, maximum=self.maximum, increment=self.increment, unit=self.unit)
        if self.kind == "enumeration":
            out["entries"] = list(self.entries)
        if self.category:
            out["category"] = self.category
        out["under_root"] = bool(self.category)
        if self.visibility:
            out["visibility"] = self.visibility
        if self.msflash:
            out["msflash"] = self.msflash
        return out


class FeatureCamera(Protocol):
    """What :func:`apply_camera_options` needs of a camera (``AravisCamera`` offers it)."""

    @property
    def name(self) -> str: ...  # noqa: D102

    def has_feature(self, feature: str) -> bool: ...  # noqa: D102

    def describe_feature(self, feature: str) -> FeatureInfo: ...  # noqa: D102

    def set_feature(self, feature: str, value: FeatureValue) -> FeatureValue: ...  # noqa: D102

    def set_roi(self, offset_x: int, offset_y: int, width: int, height: int) -> tuple[int, int, int, int]: ...  # noqa: D102

    def configure_gain(self, request: GainRequest | None, selector: str | None = None) -> Any: ...  # noqa: D102


@dataclass(frozen=True)
class CameraOptions:
    """Camera settings asked for by the user or a profile; None leaves the camera's own."""

    trigger_line: str | None = None
    """TriggerSource entry the booth's trigger wire is on (booth-paced plans); default Line0."""
    strobe_line: str | None = None
    """LineSelector entry driven by ExposureActive (camera-paced plans); default Line1."""
    gain_db: float | None = None
    """Analogue gain in dB applied to every frame (multiplies each plan step's own gain); ``--gain``."""
    gain_raw: float | None = None
    """Analogue gain in the camera's own units (``GainRaw``'s); ``--gain-raw``. At most one of the two."""
    roi: tuple[int, int, int, int] | None = None
    """(offset_x, offset_y, width, height) in pixels, after binning."""
    binning: tuple[int, int] | None = None
    """(horizontal, vertical) binning factors."""
    features: tuple[tuple[str, str], ...] = ()
    """Any other features, as (name, value text), applied in order after binning and ROI."""

    def overridden_by(self, other: CameraOptions) -> CameraOptions:
        """These options with every one ``other`` sets taken from ``other`` (features merged by name).

        Examples
        --------
        >>> profile = CameraOptions(trigger_line="Line2", features=(("BlackLevel", "64"), ("Gamma", "1")))
        >>> merged = profile.overridden_by(CameraOptions(gain_db=6.0, features=(("BlackLevel", "0"),)))
        >>> merged.trigger_line, merged.gain_db, merged.features
        ('Line2', 6.0, (('BlackLevel', '0'), ('Gamma', '1')))
        >>> CameraOptions(gain_db=6.0).overridden_by(CameraOptions(gain_raw=136)).gain_request
        GainRequest(value=136, unit='raw')
        """
        asked = dict(other.features)
        features = tuple((name, asked.pop(name, value)) for name, value in self.features) + tuple(asked.items())
        merged = {
            name: getattr(other, name) if getattr(other, name) is not None else getattr(self, name)
            for name in ("trigger_line", "strobe_line", "roi", "binning")
        }
        gain = other if other.gain_request is not None else self  # one gain, in the unit it was asked in
        return CameraOptions(**merged, gain_db=gain.gain_db, gain_raw=gain.gain_raw, features=features)

    @property
    def gain_request(self) -> GainRequest | None:
        """The gain asked for, in its unit (``--gain`` dB or ``--gain-raw``), None when none is."""
        if self.gain_db is not None:
            return GainRequest(self.gain_db, "dB")
        if self.gain_raw is not None:
            return GainRequest(self.gain_raw, "raw")
        return None

    @property
    def empty(self) -> bool:
        """Whether nothing is asked for."""
        return self == CameraOptions()

    def to_dict(self) -> dict[str, Any]:
        """JSON form, as a profile's ``"options"`` holds it (only what is set)."""
        out: dict[str, Any] = {}
        for name in ("trigger_line", "strobe_line", "gain_db", "gain_raw"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return _with_image_fields(out, self.roi, self.binning, self.features)


# -- parsing ----------------------------------------------------------------------------------


def parse_feature(text: str) -> tuple[str, str]:
    """argparse type of ``--feature NAME=VALUE``.

    Examples
    --------
    >>> parse_feature("BlackLevel=64"), parse_feature("DeviceUserID=a=b")
    (('BlackLevel', '64'), ('DeviceUserID', 'a=b'))
    """
    name, sep, value = text.partition("=")
    name = name.strip()
    if not sep or not name or not name.replace("_", "").isalnum() or not name[0].isalpha():
        raise argparse.ArgumentTypeError(
            f"'{text}': expected NAME=VALUE with a GenICam feature name (letters, digits, _), e.g. BlackLevel=64"
        )
    return name, value.strip()


def parse_roi(text: str) -> tuple[int, int, int, int]:
    """argparse type of ``--roi X,Y,W,H`` (offsets ≥ 0, sizes ≥ 1, pixels).

    Examples
    --------
    >>> parse_roi("0, 8, 640,480")
    (0, 8, 640, 480)
    """
    parts = [p.strip() for p in text.split(",")]
    try:
        x, y, w, h = (plain_whole_number(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"'{text}': expected X,Y,W,H as four whole numbers, e.g. 0,0,640,480"
        ) from None
    if x < 0 or y < 0 or w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"'{text}': expected offsets X,Y ≥ 0 and sizes W,H ≥ 1, e.g. 0,0,640,480")
    return x, y, w, h


def parse_binning(text: str) -> tuple[int, int]:
    """argparse type of ``--binning N`` or ``--binning HxV`` (factors ≥ 1).

    Examples
    --------
    >>> parse_binning("2"), parse_binning("2x1")
    ((2, 2), (2, 1))
    """
    parts = text.lower().split("x")
    try:
        factors = tuple(plain_whole_number(p) for p in parts)
    except ValueError:
        factors = ()
    if len(factors) not in (1, 2) or min(factors) < 1:
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a binning factor N or HxV (whole numbers ≥ 1), e.g. 2 or 2x2"
        )
    return (factors[0], factors[-1])


def options_from_json(data: Any, where: str) -> CameraOptions:
    """A profile's ``"options"`` object as :class:`CameraOptions`; ``where`` names it in errors.

    Keys: ``trigger_line``, ``strobe_line`` (strings), ``gain_db`` or ``gain_raw`` (a number of dB,
    or of the camera's own gain units), ``roi`` ([x, y, w, h]), ``binning`` (n or [h, v]),
    ``features`` ({name: value}).

    Raises
    ------
    CameraSettingError
        An unknown key or a value of the wrong form; names ``where`` and the key.
    """
    if not isinstance(data, Mapping):
        raise CameraSettingError(f"{where}: options is {type(data).__name__}; expected an object")
    known = ("trigger_line", "strobe_line", "gain_db", "gain_raw", "roi", "binning", "features")
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise CameraSettingError(
            f"{where}: options has unknown key {unknown[0]!r}; expected some of {', '.join(known)}"
        )

    def convert(key: str, parse: Any, text: str) -> Any:
        try:
            return parse(text)
        except argparse.ArgumentTypeError as err:
            raise CameraSettingError(f"{where}: options.{key} {err}") from None

    values: dict[str, Any] = {}
    for key in ("trigger_line", "strobe_line"):
        if key in data:
            if not isinstance(data[key], str) or not data[key]:
                raise CameraSettingError(f"{where}: options.{key} is {data[key]!r}; expected a line name such as Line0")
            values[key] = data[key]
    if "gain_db" in data and "gain_raw" in data:
        raise CameraSettingError(
            f"{where}: options has both gain_db and gain_raw; expected one (dB, or the camera's own units)"
        )
    for key, unit in (("gain_db", "a number of dB"), ("gain_raw", "a number in the camera's gain units")):
        if key in data:
            gain = data[key]
            if isinstance(gain, bool) or not isinstance(gain, int | float) or not math.isfinite(gain):
                raise CameraSettingError(f"{where}: options.{key} is {gain!r}; expected {unit}")
            values[key] = float(gain)
    if "roi" in data:
        roi = data["roi"]
        text = ",".join(str(v) for v in roi) if isinstance(roi, list) else str(roi)
        values["roi"] = convert("roi", parse_roi, text)
    if "binning" in data:
        binning = data["binning"]
        text = "x".join(str(v) for v in binning) if isinstance(binning, list) else str(binning)
        values["binning"] = convert("binning", parse_binning, text)
    if "features" in data:
        features = data["features"]
        if not isinstance(features, Mapping):
            raise CameraSettingError(
                f'{where}: options.features is {type(features).__name__}; expected an object {{"Name": value}}'
            )
        values["features"] = tuple(
            convert("features", parse_feature, f"{name}={_json_text(value)}") for name, value in features.items()
        )
    return CameraOptions(**values)


def _json_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:g}" if value == float(f"{value:g}") else repr(value)
    return str(value)


# -- applying -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class AppliedOptions:
    """What the camera reports after :func:`apply_camera_options`."""

    roi: tuple[int, int, int, int] | None = None
    """ROI read back, when one was asked for."""
    binning: tuple[int, int] | None = None
    """Binning read back, when asked for."""
    features: dict[str, FeatureValue] = field(default_factory=dict)
    """Each ``--feature`` read back, by name."""
    gain: dict[str, Any] | None = None
    """The gain feature as read back after ``--gain``/``--gain-raw`` (``NativeGain.to_dict``), when asked."""

    def to_dict(self) -> dict[str, Any]:
        """JSON form (recorded in the sequence's ``camera.extra``)."""
        out: dict[str, Any] = {}
        if self.gain is not None:
            out["gain"] = dict(self.gain)
        return _with_image_fields(out, self.roi, self.binning, self.features)


def _with_image_fields(
    out: dict[str, Any],
    roi: tuple[int, int, int, int] | None,
    binning: tuple[int, int] | None,
    features: tuple[tuple[str, str], ...] | dict[str, FeatureValue],
) -> dict[str, Any]:
    """``out`` with the region, binning and raw features that are set, as JSON (the options' and the record's)."""
    if roi is not None:
        out["roi"] = list(roi)
    if binning is not None:
        out["binning"] = list(binning)
    if features:
        out["features"] = dict(features)
    return out


def _describe(camera: FeatureCamera, feature: str, option: str) -> FeatureInfo:
    if not camera.has_feature(feature):
        listing = getattr(camera, "feature_names", None)  # AravisCamera's; a twin without it gets no suggestion
        near = close_names(feature, [name for name, _ in listing()] if callable(listing) else [])
        raise CameraSettingError(
            f"{camera.name}: {option}: no feature {feature}"
            + (f"; did you mean {' or '.join(map(repr, near))}?" if near else "")
            + "; expected one the camera offers — `msflash devices --features ID` lists them"
        )
    return camera.describe_feature(feature)


def _convert(info: FeatureInfo, text: str) -> FeatureValue | None:
    """``text`` as a value of ``info``'s type within what it allows, or None when it is not."""
    if info.kind == "enumeration":
        return text if text in info.entries else None
    if info.kind == "boolean":
        return {"true": True, "1": True, "on": True, "false": False, "0": False, "off": False}.get(text.lower())
    if info.kind == "string":
        return text
    if info.kind == "integer":
        if "_" in text or not text.isascii():  # int() reads 1_0 as 10 and ١٢ as 12: no register value a user means
            return None
        try:
            value: float = int(text, 0)  # 64, 0x40, 0b1000000
        except ValueError:
            try:
                value = int(text, 10)  # 064: a leading zero base 0 refuses
            except ValueError:
                return None
    elif info.kind == "float":
        try:
            value = plain_number(text)
        except ValueError:
            return None
    else:
        return None
    if info.minimum is not None and value < info.minimum or info.maximum is not None and value > info.maximum:
        return None
    if info.kind == "integer" and info.increment and info.increment > 1 and info.minimum is not None:
        if (value - info.minimum) % info.increment:
            return None
    return value


def apply_feature(camera: FeatureCamera, feature: str, text: str, option: str | None = None) -> FeatureValue:
    """Write ``feature`` from its text value, checked against what the camera allows; returns the read-back.

    Raises
    ------
    CameraSettingError
        No such feature, not writable, or a value outside its entries/range/type: the message names
        the camera, ``option`` (``--feature NAME=VALUE`` by default) and what the feature allows.
    """
    option = option or f"--feature {feature}={text}"
    info = _describe(camera, feature, option)
    if not info.writable:
        raise CameraSettingError(
            f"{camera.name}: {option}: {feature} is {info.kind}, access {info.access}; expected a writable feature"
        )
    value = _convert(info, text)
    if value is None:
        current = "" if info.value is None else f" (now {_json_text(info.value)})"
        raise CameraSettingError(
            f"{camera.name}: {option}: {feature} cannot be {text!r}{current}; expected {info.allowed()}"
        )
    try:
        read_back = camera.set_feature(feature, value)
    except CameraSettingError:
        raise
    except CameraError as err:
        raise CameraSettingError(
            f"{camera.name}: {option}: the camera refused it "
            f"({str(err).removeprefix(camera.name + ': ')}); expected {info.allowed()}"
        ) from err
    if read_back != value:  # the camera rounded it (a register of whole units, an increment): keep its value
        log.warning("%s: %s: %s reads back %s", camera.name, option, feature, _json_text(read_back))
    return read_back


def _check_entry(camera: FeatureCamera, feature: str, entry: str, option: str) -> None:
    info = _describe(camera, feature, option)
    if entry not in info.entries:
        raise CameraSettingError(
            f"{camera.name}: {option}: {feature} has no entry {entry!r}; expected {info.allowed()}"
        )


def apply_camera_options(camera: FeatureCamera, options: CameraOptions) -> AppliedOptions:
    """Write binning, then the ROI, then each feature in order, then the gain; check the lines.

    Binning comes first because it changes the sensor size the ROI is checked against; the gain
    last, under the ``GainSelector`` a ``--feature`` may have named. Lines are only checked here:
    the camera sets them per plan (trigger source, strobe output). The gain is resolved, checked
    against its range in the camera's units and written (``camera.configure_gain``,
    :mod:`acquisition.devices.aravis.gain`); each plan step's own gain multiplies it.

    Raises
    ------
    CameraSettingError
        The first option the camera cannot take, named with what it allows.
    """
    if options.trigger_line is not None:
        _check_entry(camera, "TriggerSource", options.trigger_line, f"--trigger-line {options.trigger_line}")
    if options.strobe_line is not None:
        _check_entry(camera, "LineSelector", options.strobe_line, f"--strobe-line {options.strobe_line}")
    if options.gain_db is not None and options.gain_raw is not None:
        raise CameraSettingError(
            f"{camera.name}: --gain {options.gain_db:g} and --gain-raw {options.gain_raw:g}: expected one of them "
            "(dB, or the camera's own units)"
        )
    binning = None
    if options.binning is not None:
        text = "x".join(str(v) for v in options.binning)
        read = [
            apply_feature(camera, feature, str(factor), option=f"--binning {text}")
            for feature, factor in zip(_BINNING_FEATURES, options.binning)
        ]
        binning = (int(read[0]), int(read[1]))
    roi = None
    if options.roi is not None:
        roi = _apply_roi(camera, options.roi)
    features = {name: apply_feature(camera, name, text) for name, text in options.features}
    request = options.gain_request
    camera.configure_gain(request, selector=dict(options.features).get("GainSelector"))
    native = getattr(camera, "native_gain", None)
    gain = native.to_dict() if request is not None and native is not None else None
    return AppliedOptions(roi=roi, binning=binning, features=features, gain=gain)


def _apply_roi(camera: FeatureCamera, roi: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
    option = f"--roi {','.join(str(v) for v in roi)}"
    limits = []
    for feature, _value in zip(("OffsetX", "OffsetY", "Width", "Height"), roi):
        if camera.has_feature(feature):
            info = camera.describe_feature(feature)
            limits.append(f"{feature} {info.allowed().removeprefix('a whole number in ')}")
    x, y, width, height = roi
    try:
        read = camera.set_roi(x, y, width, height)
    except CameraError as err:
        raise CameraSettingError(
            f"{camera.name}: {option}: the camera refused it "
            f"({str(err).removeprefix(camera.name + ': ')}); expected "
            f"{'; '.join(limits) or 'a region inside the sensor'} (offset + size within "
            "the sensor, after binning)"
        ) from err
    return read


class ConfigurableCamera(FeatureCamera, Protocol):
    """A :class:`FeatureCamera` with a profile and sync lines (``AravisCamera``)."""

    @property
    def profile(self) -> Any: ...  # noqa: D102

    def set_sync_lines(self, trigger_line: str | None = None, strobe_line: str | None = None) -> None: ...  # noqa: D102


@dataclass(frozen=True)
class CameraSetup:
    """Options in effect on an opened camera: as merged, and as read back."""

    options: CameraOptions
    """The profile's options overridden by the command line's."""
    applied: AppliedOptions
    """What the camera read back."""

    def to_dict(self) -> dict[str, Any]:
        """JSON form recorded in the sequence (``camera.extra.camera_options``)."""
        return {"requested": self.options.to_dict(), "read_back": self.applied.to_dict()}


def configure_camera(
    camera: ConfigurableCamera, asked: CameraOptions, strobe: bool, profile_options: CameraOptions | None = None
) -> CameraSetup:
    """Apply the camera profile's options overridden by ``asked`` to an opened camera.

    Parameters
    ----------
    strobe
        Whether plans drive a strobe output (camera-paced sync): then the strobe line is set up,
        Line1 unless an option names another.
    profile_options
        The options ``asked`` overrides; the camera profile's (``camera.profile.options``) when None.

    Raises
    ------
    CameraSettingError
        The first option the camera cannot take, named with what it allows.
    """
    if profile_options is None:
        profile_options = getattr(camera.profile, "options", CameraOptions())
    options = profile_options.overridden_by(asked)
    applied = apply_camera_options(camera, options)
    strobe_line = (options.strobe_line or "Line1") if strobe else None
    camera.set_sync_lines(trigger_line=options.trigger_line, strobe_line=strobe_line)
    return CameraSetup(options, applied)
