"""GenICam cameras through Aravis: :class:`AravisCamera`, device listing and the GigE Vision fake.

This folder is the only one of msflash that imports ``gi`` (through :mod:`.gi_typelib`). Everything
Aravis returns is translated here: pixels become owned numpy arrays, ``GLib.Error`` becomes :class:`~acquisition.errors.CameraError`
and its subclasses, and GenICam feature names with their per-model differences stay behind
:class:`AravisCamera`'s methods.

The camera is made of parts, one module each, stacked as mixins over one shared state:
:class:`~.feature_access.FeatureAccess` (features by name) → :class:`~.image_settings.ImageSettings`
(pixel format, ROI, exposure) → :class:`~.gain_features.GainFeatures` → :class:`~.sync_lines.SyncLines`
(trigger and strobe lines) → :class:`~.streaming.Streaming` (the stream, its buffers in
:mod:`.buffers`, triggers and frames) → :class:`AravisCamera` (opening, closing, ``prepare``). The rest of
the folder is imported from where it is defined: device listing and interfaces (:mod:`.discovery`), the
records (:mod:`.camera_records`), profiles (:mod:`.profiles`), pixel decoding (:mod:`.pixel_layouts`) and
the GigE Vision fake on 127.0.0.1 (:mod:`.gv_fake`).

Network safety: Aravis discovers GigE Vision cameras by broadcasting on every network interface,
and opening a camera by a name that is not an IP address makes the GigE Vision interface resolve
the name and broadcast. Nothing here enables the GigE Vision interface unless the caller lists
``gige`` in ``interfaces``; an IP address opens that one device without discovery.
"""

from __future__ import annotations

import collections
import logging
import queue
import threading
from collections.abc import Iterable
from typing import Any

from msflash.acquisition.devices.aravis.buffers import CONTROL_LOST, BufferPool, SpareStream
from msflash.acquisition.devices.aravis.camera_records import (
    AcquisitionStats,
    CameraSettings,
    FrameTiming,
    StrobeConfig,
    TriggerConfig,
)
from msflash.acquisition.devices.aravis.device_release import release_lost_device
from msflash.acquisition.devices.aravis.discovery import (
    DeviceEntry,
    is_ipv4_address,
    list_devices,
    parse_interfaces,
    use_interfaces,
)
from msflash.acquisition.devices.aravis.gain import GainControl, GainRequest
from msflash.acquisition.devices.aravis.gi_typelib import Aravis, GLib, aravis_lock
from msflash.acquisition.devices.aravis.pixel_layouts import PIXEL_FORMATS
from msflash.acquisition.devices.aravis.profiles import match_profile
from msflash.acquisition.devices.aravis.streaming import Streaming
from msflash.acquisition.devices.camera import CameraInfo, NativeGain
from msflash.acquisition.errors import CameraError, CameraNotFoundError
from msflash.acquisition.plan import CapturePlan

log = logging.getLogger(__name__)

_GV_CCP_REGISTER = 0x0A00
"""GigE Vision bootstrap register Control Channel Privilege."""
_GV_CCP_CONTROL_BITS = 0b11
"""Its exclusive (bit 0) and control (bit 1) access bits, either of which Aravis's heartbeat accepts."""
_MAX_SPARE_BYTES = 256 * 1024 * 1024
"""Upper bound on the spare arrays a zero-copy pool readies for a plan (beyond, the popping thread
allocates each replacement after queueing its frame)."""


class AravisCamera(Streaming):
    """A GenICam camera (GigE Vision, USB3 Vision or the Aravis fake) behind the ``Camera`` protocol.

    Parameters
    ----------
    device
        Aravis device id (``Fake_1``), serial number, or the camera's IPv4 address.
    interfaces
        Transport layers to use, from :data:`~.discovery.INTERFACES` (``("fake",)``, ``"gige,usb3"``). Only
        these are enabled; ``gige`` with a name that is not an IP address broadcasts discovery.
    pixel_format, roi
        PixelFormat and (offset_x, offset_y, width, height) to set; ``None`` keeps the camera's.
    line_trigger
        Trigger used for plans paced by the booth (``plan.trigger == "booth"``).
    strobe
        Output line to drive from the exposure; set up by :meth:`prepare` for every plan when
        given, and required for camera-paced plans (``plan.trigger == "camera"``).
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

    Frames of formats stored as the frame itself (:func:`~.pixel_layouts.is_zero_copy_format`) on GigE Vision and
    the fake are not copied (:class:`~.buffers.BufferPool`): the array Aravis wrote into is the frame returned,
    read-only and the caller's; :meth:`prepare` readies one replacement per plan step.
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
        self._pool: BufferPool | None = None  # the stream and its buffers (see BufferPool's invariant)
        self._spare: SpareStream | None = None  # a stopped stream kept for the next prepare
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
                with aravis_lock:
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
                with aravis_lock:
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
        self._queue.put(CONTROL_LOST)

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

    # -- the Camera protocol ------------------------------------------------------------------

    @property
    def info(self) -> CameraInfo:
        """Identity and pixel encoding, read from the camera now: the mosaic layout and white level are what
        :data:`~acquisition.devices.aravis.pixel_layouts.PIXEL_FORMATS` says the format means (a format it lacks
        reads as ``cfa`` None and white level NaN, for listing; the rigs refuse it at open,
        :func:`~acquisition.devices.aravis.pixel_layouts.camera_pixel_layout`)."""
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
