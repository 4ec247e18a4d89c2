"""Per-model camera profiles (``genicam/profiles.json``): feature names, lines, gain units, noise."""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

from msflash.acquisition.devices.aravis.camera_features import (
    CameraOptions,
    options_from_json,
)
from msflash.acquisition.devices.aravis.discovery import PROFILES_JSON
from msflash.acquisition.errors import CameraSettingError
from msflash.processing.json_input import parse_json_document
from msflash.processing.user_files import JSON_MAX_BYTES, printable, read_user_text, shown_path

log = logging.getLogger(__name__)


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
        for key, pattern in (("vendor", vendor), ("model", model)):
            try:  # matched as a regular expression on every camera opened (match_profile)
                re.compile(pattern)
            except (re.error, RecursionError, OverflowError) as err:
                raise CameraSettingError(
                    f"{where}.{key} is {printable(pattern[:60])!r}, not a regular expression ({err}); expected a "
                    "pattern such as 'Basler' or 'acA1920-.*'"
                ) from None
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
