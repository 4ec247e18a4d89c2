"""The GenICam features msflash uses (``msflash devices --features``)."""

from __future__ import annotations

MSFLASH_FEATURES: dict[str, str] = {
    **dict.fromkeys(("DeviceVendorName", "DeviceModelName", "DeviceSerialNumber", "DeviceVersion"), "reads"),
    **dict.fromkeys(("PayloadSize",), "reads"),
    **dict.fromkeys(
        (
            "PixelFormat",
            "Width",
            "Height",
            "OffsetX",
            "OffsetY",
            "BinningHorizontal",
            "BinningVertical",
            "AcquisitionMode",
            "AcquisitionFrameRate",
            "AcquisitionFrameRateAbs",
            "AcquisitionFrameRateEnable",
            "AcquisitionFrameRateEnabled",
            "ExposureTime",
            "ExposureTimeAbs",
            "ExposureAuto",
            "Gain",
            "GainAbs",
            "GainRaw",
            "GainSelector",
            "GainAuto",
            "BlackLevel",
            "BlackLevelAuto",
            "GammaEnable",
            "TriggerSelector",
            "TriggerMode",
            "TriggerSource",
            "TriggerActivation",
            "TriggerDelay",
            "TriggerDelayAbs",
            "LineSelector",
            "LineMode",
            "LineSource",
            "LineInverter",
            "UserOutputSelector",
            "UserOutputValue",
        ),
        "writes",
    ),
    **dict.fromkeys(("AcquisitionStart", "AcquisitionStop", "TriggerSoftware"), "executes"),
}
"""Every GenICam feature msflash reads, writes or executes, by name (a camera profile's
``exposure_features`` and ``gain_features`` add theirs). ``msflash devices --features`` lists each the
camera has, even when its ``Root`` category does not (Aravis's fake hides ``GainRaw`` so)."""
