"""An Aravis camera's state and its GenICam features: read, written, checked, described."""

from __future__ import annotations

import collections
import logging
import queue
import threading
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from msflash.acquisition.devices.aravis.buffers import (
    BufferPool,
    SpareStream,
)
from msflash.acquisition.devices.aravis.camera_features import FeatureInfo
from msflash.acquisition.devices.aravis.camera_records import (
    AcquisitionStats,
    FrameTiming,
    StrobeConfig,
    TriggerConfig,
)
from msflash.acquisition.devices.aravis.gain import (
    GainControl,
    GainRequest,
)
from msflash.acquisition.devices.aravis.gi_typelib import Aravis, GLib
from msflash.acquisition.devices.aravis.msflash_features import MSFLASH_FEATURES
from msflash.acquisition.devices.aravis.profiles import CameraProfile
from msflash.acquisition.devices.camera import NativeGain
from msflash.acquisition.errors import (
    CameraDisconnectedError,
    CameraError,
)
from msflash.acquisition.plan import CapturePlan

log = logging.getLogger(__name__)


class FeatureAccess:
    """The camera's state (declared for all its parts) and feature access by name; the base of
    :class:`~acquisition.devices.aravis.camera.AravisCamera`'s parts."""

    # The camera's state, set by AravisCamera.__init__ and _open (declared here for every part).
    _requested: str
    _interfaces: tuple[str, ...]
    _line_trigger: TriggerConfig
    _strobe_request: StrobeConfig | None
    _extra_buffers: int
    _zero_copy: bool
    _name: str
    _camera: Any
    _device: Any
    _pool: BufferPool | None
    _spare: SpareStream | None
    _stale_before_ns: int
    _control_lost_handler: int | None
    _control_lost: threading.Event
    _unreachable: bool
    _release_thread: threading.Thread | None
    _queue: queue.Queue[Any]
    _pump: threading.Thread | None
    _pump_stop: threading.Event
    _acquiring: bool
    _plan: CapturePlan | None
    _n_buffers: int
    _triggered_settings: collections.deque[tuple[float, float, NativeGain | None]]
    _n_triggered: int
    _n_consumed: int
    _last_frame_id: int | None
    _stats_lock: threading.Lock
    _stats: AcquisitionStats
    _trigger: TriggerConfig
    _strobe: StrobeConfig | None
    _step_request: tuple[float, float] | None
    _current: tuple[float, float, NativeGain | None]
    _gain_control: GainControl
    _gain_request: GainRequest | None
    _base_gain_db: float
    _native_gain: NativeGain | None
    _other_gains: dict[str, float]
    _warned_gains: set[tuple[str, float]]
    _last_timing: FrameTiming | None
    _vendor: str
    _model: str
    _serial: str
    _device_id: str
    _protocol: str
    _address: str
    _profile: CameraProfile
    _exposure_feature: str
    _layout_key: tuple[str, int, int]

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
