"""An Aravis camera's trigger and strobe lines and user outputs (the sync modes' wiring)."""

from __future__ import annotations

import logging
from dataclasses import replace

from msflash.acquisition.devices.aravis.camera_records import (
    StrobeConfig,
    TriggerConfig,
)
from msflash.acquisition.devices.aravis.gain_features import GainFeatures
from msflash.acquisition.errors import CameraError

log = logging.getLogger(__name__)


class SyncLines(GainFeatures):
    """Trigger source, strobe output (ExposureActive) and user outputs, checked against the camera."""

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
