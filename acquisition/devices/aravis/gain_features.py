"""An Aravis camera's gain: the feature chosen, written in its own unit and read back (docs/decisions/gain-units.md)."""

from __future__ import annotations

import logging
import math
from typing import Any

from msflash.acquisition.devices.aravis.gain import (
    GAIN_FEATURES,
    GainControl,
    GainRequest,
    choose_gain_control,
    choose_selector,
)
from msflash.acquisition.devices.aravis.image_settings import ImageSettings
from msflash.acquisition.devices.camera import NativeGain
from msflash.acquisition.errors import (
    CameraError,
    CameraSettingError,
)

log = logging.getLogger(__name__)


class GainFeatures(ImageSettings):
    """``--gain`` / ``--gain-raw`` and each step's gain, through the gain feature the camera names."""

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
