"""How ``--gain`` reaches a camera: which feature, which selector entry, which unit, which range.

Cameras name their analogue gain in three ways (docs/decisions/gain-units.md):

- SFNC ``Gain`` (or ``GainAbs``), a number in **dB** — the unit the camera states, or none (SFNC's
  unit is dB); a few state a linear factor (``x``), converted exactly;
- ``GainRaw``, a whole number in the **camera's own units**, whose relation to dB only the maker
  documents (``gain_raw_per_db`` in the model's profile, ``genicam/profiles.json``);
- either of them behind a ``GainSelector`` (``All``, ``AnalogAll``, …, one gain per entry) and a
  ``GainAuto`` that must be ``Off``.

The user asks in one of two units, never guessed from the other:

- ``--gain 6`` or ``--gain 6dB`` (:class:`GainRequest` in dB): a dB-scaled feature is written;
  ``GainRaw`` only when the profile gives its dB scale (``round(dB × gain_raw_per_db)``). A camera
  whose only gain is an unscaled ``GainRaw`` refuses it and names ``--gain-raw`` with the range.
- ``--gain-raw N`` (the camera's own unit): ``GainRaw`` (else the gain feature there is) is set to
  exactly N. When its dB scale is known the frames record the true linear gain; otherwise they
  record gain 1 — every frame has the same unknown gain, so the ratios processing uses are
  exact — and the sequence says so (``camera.gain.linear``).

Everything is checked against the range the camera reports (after the selector is set), before
any frame is taken: one :class:`~acquisition.errors.CameraSettingError` naming the option, the
feature and its range in the camera's units (exit 2).

No ``gi`` here: :class:`~acquisition.devices.aravis.camera.AravisCamera` reads the features and
calls :func:`choose_gain_control`; everything else is testable without Aravis.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from msflash.acquisition.errors import CameraSettingError
from msflash.processing.user_numbers import plain_number

if TYPE_CHECKING:  # camera_features imports this module
    from msflash.acquisition.devices.aravis.camera_features import FeatureInfo

GainUnit = Literal["dB", "raw"]
"""What a :class:`GainRequest` is in: decibels, or the camera's own units."""

GainScale = Literal["dB", "linear", "raw"]
"""What a gain feature's values are: dB, a linear factor, or camera units (dB scale known or not)."""

GAIN_FEATURES = ("Gain", "GainAbs", "GainRaw")
"""Gain features msflash knows, tried in this order after the profile's own list."""

SELECTOR_PREFERENCE = ("All", "AnalogAll")
"""``GainSelector`` entries that mean "the whole analogue gain", in order of preference."""

_LINEAR_UNITS = ("x", "times", "×", "factor")
"""Units (case-insensitive) that mark a gain feature as a linear factor."""


@dataclass(frozen=True)
class GainRequest:
    """A gain the user asked for, in the unit they asked in."""

    value: float
    """The number given."""
    unit: GainUnit
    """``dB`` (``--gain``) or ``raw`` (``--gain-raw``: the camera's own units)."""

    @property
    def option(self) -> str:
        """The option as the user would type it, for messages (``--gain 6 dB``, ``--gain-raw 6``).

        Examples
        --------
        >>> GainRequest(6.0, "dB").option, GainRequest(6.0, "raw").option
        ('--gain 6 dB', '--gain-raw 6')
        """
        return f"--gain {self.value:g} dB" if self.unit == "dB" else f"--gain-raw {self.value:g}"

    def to_dict(self) -> dict[str, Any]:
        """JSON form (recorded in the sequence's ``camera.gain.requested``)."""
        return {"value": self.value, "unit": self.unit}


_DB = re.compile(r"^\s*([-+]?[0-9.]+(?:[eE][-+]?[0-9]+)?)\s*(db)?\s*$", re.IGNORECASE)


def parse_gain_db(text: str) -> GainRequest:
    """argparse type of ``--gain``: a number of dB, ``6`` or ``6dB``.

    Examples
    --------
    >>> parse_gain_db("6"), parse_gain_db("4.5 dB"), parse_gain_db("-3db")
    (GainRequest(value=6.0, unit='dB'), GainRequest(value=4.5, unit='dB'), GainRequest(value=-3.0, unit='dB'))
    """
    match = _DB.match(text)
    value = float("nan")
    if match is not None:
        try:
            value = plain_number(match.group(1))
        except ValueError:
            pass
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a gain in dB, e.g. 6 or 6dB (a camera's own units: --gain-raw N)"
        )
    return GainRequest(value, "dB")


def parse_gain_raw(text: str) -> GainRequest:
    """argparse type of ``--gain-raw``: a number in the camera's own gain units (``GainRaw``'s).

    Examples
    --------
    >>> parse_gain_raw("136")
    GainRequest(value=136.0, unit='raw')
    """
    try:
        value = plain_number(text)
    except ValueError:
        value = float("nan")
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a number in the camera's own gain units (GainRaw), e.g. 136 — "
            "`msflash devices --features ID` shows its range"
        )
    return GainRequest(value, "raw")


def feature_scale(info: FeatureInfo, raw_per_db: float | None, profile: str) -> tuple[GainScale, float | None, str]:
    """What a gain feature's values are: (scale, dB per camera unit or None, how that is known).

    ``GainRaw`` is in camera units, with ``1 / raw_per_db`` dB per unit when the profile gives it;
    another gain feature is in dB when its unit says so or says nothing (SFNC's unit), a linear
    factor when its unit is ``x``/``times``, and otherwise in units of no known dB scale.

    Examples
    --------
    >>> from msflash.acquisition.devices.aravis.camera_features import FeatureInfo
    >>> gain = FeatureInfo("Gain", "float", "RW", 0.0, 0.0, 24.0, unit="dB")
    >>> feature_scale(gain, None, "generic")
    ('dB', 1.0, 'Gain in dB, as the camera states')
    >>> raw = FeatureInfo("GainRaw", "integer", "RW", 0, 0, 10)
    >>> feature_scale(raw, 2.0, "basler")
    ('raw', 0.5, "profile 'basler': gain_raw_per_db 2")
    >>> feature_scale(raw, None, "generic")[1] is None
    True
    """
    unit = info.unit.strip()
    if info.name == "GainRaw":
        if raw_per_db:
            return "raw", 1.0 / raw_per_db, f"profile '{profile}': gain_raw_per_db {raw_per_db:g}"
        return "raw", None, f"profile '{profile}' gives no gain_raw_per_db"
    if unit.lower() == "db":
        return "dB", 1.0, f"{info.name} in dB, as the camera states"
    if not unit:
        return "dB", 1.0, f"{info.name} in dB (SFNC's unit; the camera states none)"
    if unit.lower() in _LINEAR_UNITS:
        return "linear", None, f"{info.name} a linear factor ({unit}), as the camera states"
    return "raw", None, f"{info.name} in '{unit}', no dB scale known"


@dataclass(frozen=True)
class GainControl:
    """How one camera's gain is set: the feature, its selector entry, unit and range, and how dB maps.

    ``feature`` None: the camera has no gain msflash can set (``why`` says why); every frame then
    records gain 1.
    """

    feature: str | None
    """``Gain``, ``GainAbs``, ``GainRaw`` (or another the profile names); None when none is usable."""
    kind: str = "float"
    """The feature's GenICam type: ``float`` or ``integer``."""
    scale: GainScale = "dB"
    """What its values are (:func:`feature_scale`)."""
    db_per_unit: float | None = 1.0
    """dB per camera unit (``dB`` scale: 1); None when unknown (then the linear gain is unknown)."""
    camera_unit: str = ""
    """The unit the camera states for the feature ("" when none)."""
    minimum: float | None = None
    """Lower bound in camera units, as the camera reports it with the selector set."""
    maximum: float | None = None
    """Upper bound in camera units."""
    increment: float | None = None
    """Step of an integer feature (None or 1: any whole number)."""
    selector: str | None = None
    """The ``GainSelector`` entry the feature is written under, None without a selector."""
    source: str = ""
    """How the dB scale is known (or that it is not), for the record and messages."""
    why: str = ""
    """Why the gain cannot be set (no feature, a stuck ``GainAuto``, no selector entry), else ""."""

    @property
    def settable(self) -> bool:
        """Whether msflash can write the gain at all."""
        return self.feature is not None and not self.why

    @property
    def db_known(self) -> bool:
        """Whether the feature's values convert to dB (then frames record the true linear gain)."""
        return self.settable and (self.scale == "linear" or self.db_per_unit is not None)

    @property
    def unit(self) -> str:
        """The unit recorded with values: ``dB``, ``x`` (linear factor) or ``raw`` (camera units)."""
        return {"dB": "dB", "linear": "x", "raw": "raw"}[self.scale]

    def db_of(self, value: float) -> float | None:
        """The gain in dB of a value of the feature, None when its scale is unknown.

        Examples
        --------
        >>> GainControl("GainRaw", "integer", "raw", 0.5).db_of(12)
        6.0
        >>> round(GainControl("Gain", "float", "linear", None).db_of(2.0), 3)
        6.021
        """
        if self.scale == "linear":
            return 20.0 * math.log10(value) if value > 0 else None
        if self.db_per_unit is None:
            return None
        return float(value) * self.db_per_unit

    def value_of_db(self, gain_db: float) -> float:
        """The value of the feature for ``gain_db`` (whole units for an integer feature).

        Raises
        ------
        ValueError
            The scale is unknown (no dB ↔ camera-unit relation).

        Examples
        --------
        >>> GainControl("GainRaw", "integer", "raw", 0.5).value_of_db(6.2)
        12
        """
        if self.scale == "linear":
            value = 10.0 ** (gain_db / 20.0)
        elif self.db_per_unit is None:
            raise ValueError(f"{self.feature}: no dB scale known")
        else:
            value = gain_db / self.db_per_unit
        return int(round(value)) if self.kind == "integer" else float(value)

    def allows(self, value: float) -> bool:
        """Whether ``value`` (camera units) is within the range and on the increment.

        Examples
        --------
        >>> control = GainControl("GainRaw", "integer", "raw", None, minimum=100, maximum=800, increment=4)
        >>> control.allows(100), control.allows(102), control.allows(804), control.allows(100.5)
        (True, False, False, False)
        """
        if not math.isfinite(value):
            return False
        if self.kind == "integer" and value != int(value):
            return False
        if self.minimum is not None and value < self.minimum - 1e-9:
            return False
        if self.maximum is not None and value > self.maximum + 1e-9:
            return False
        if self.kind == "integer" and self.increment and self.increment > 1 and self.minimum is not None:
            return (value - self.minimum) % self.increment == 0
        return True

    def range_text(self) -> str:
        """The range in camera units, with its dB equivalent when known.

        Examples
        --------
        >>> GainControl("Gain", "float", "dB", 1.0, "dB", 0.0, 24.0).range_text()
        'a number in 0 … 24 dB'
        >>> GainControl("GainRaw", "integer", "raw", 1.0, "", 0, 10).range_text()
        'a whole number in 0 … 10 (camera units; 0 … 10 dB)'
        >>> GainControl("GainRaw", "integer", "raw", None, "", 100, 800, 4).range_text()
        'a whole number in 100 … 800 in steps of 4 (camera units, no known dB scale)'
        """
        what = "a whole number" if self.kind == "integer" else "a number"
        if self.minimum is None or self.maximum is None:
            span = what
        else:
            step = (
                f" in steps of {self.increment:g}" if self.kind == "integer" and self.increment not in (None, 1) else ""
            )
            span = f"{what} in {self.minimum:g} … {self.maximum:g}{step}"
        if self.scale == "dB":
            return f"{span} dB"
        low_high = self.db_range()
        if self.scale == "linear":
            return f"{span} x" + (f" ({low_high[0]:.3g} … {low_high[1]:.3g} dB)" if low_high else "")
        if low_high is not None:
            return f"{span} (camera units; {low_high[0]:g} … {low_high[1]:g} dB)"
        return f"{span} (camera units, no known dB scale)"

    def db_range(self) -> tuple[float, float] | None:
        """(lowest, highest) gain in dB the camera allows, None when unknown."""
        if self.minimum is None or self.maximum is None:
            return None
        low, high = self.db_of(self.minimum), self.db_of(self.maximum)
        if low is None or high is None:
            return None
        return (low, high)

    def where(self) -> str:
        """The feature with its selector, for messages (``Gain (GainSelector AnalogAll)``)."""
        return f"{self.feature} (GainSelector {self.selector})" if self.selector else str(self.feature)

    def value_for(self, request: GainRequest, camera: str) -> float:
        """The value (camera units) ``request`` writes, checked against the range.

        Raises
        ------
        CameraSettingError
            The gain cannot be set, the request has no meaning for this feature (dB asked of an
            unscaled ``GainRaw``), or the value is outside the range or off the increment: one line
            naming ``camera``, the option, the feature and its range in the camera's units.
        """
        option = request.option
        if not self.settable:
            raise CameraSettingError(f"{camera}: {option}: {self.why}")
        if request.unit == "raw":
            value = request.value
            if not self.allows(value):
                raise CameraSettingError(
                    f"{camera}: {option}: {self.where()} cannot be {value:g}; expected {self.range_text()}"
                )
            return int(value) if self.kind == "integer" else float(value)
        if not self.db_known:
            raise CameraSettingError(
                f"{camera}: {option}: this camera's gain is {self.where()}, {self.range_text()[:-1]}: "
                f"{self.source}); expected --gain-raw N in that range, or gain_raw_per_db in its profile "
                "(genicam/profiles.json) to use dB"
            )
        value = self.value_of_db(request.value)
        if not self.allows(value):
            if self.scale == "dB":
                shown = f"{request.value:g} dB"
            elif self.scale == "linear":
                shown = f"{value:.4g} x ({request.value:g} dB)"
            else:
                shown = f"{value:g} ({request.value:g} dB at {1 / self.db_per_unit:g} per dB, {self.source})"  # type: ignore[operator]
            raise CameraSettingError(
                f"{camera}: {option}: {self.where()} cannot be {shown}; expected {self.range_text()}"
            )
        return value

    def to_dict(self) -> dict[str, Any]:
        """JSON form (the sequence's ``camera.gain``, ``devices --features``)."""
        return {
            "feature": self.feature,
            "selector": self.selector,
            "unit": self.unit if self.feature is not None else None,
            "camera_unit": self.camera_unit,
            "range": [self.minimum, self.maximum] if self.minimum is not None and self.maximum is not None else None,
            "increment": self.increment if self.kind == "integer" else None,
            "db_per_unit": self.db_per_unit if self.scale != "linear" else None,
            "scale": self.source,
            **({"why_not": self.why} if self.why else {}),
        }


def choose_selector(
    entries: Sequence[str], asked: str | None, preference: Sequence[str] = SELECTOR_PREFERENCE
) -> tuple[str | None, str]:
    """The ``GainSelector`` entry to write the gain under, or (None, why not).

    The entry the user named (``--feature GainSelector=NAME``) wins; otherwise the first of
    ``preference`` the camera offers; otherwise the only entry.

    Examples
    --------
    >>> choose_selector(("DigitalAll", "AnalogAll"), None)
    ('AnalogAll', '')
    >>> choose_selector(("Red", "Blue"), None)[1]
    'GainSelector offers Red, Blue and none of All, AnalogAll; expected --feature GainSelector=ENTRY naming the gain to set'
    """
    if asked is not None:
        if asked in entries:
            return asked, ""
        return None, f"GainSelector has no entry {asked!r}; expected one of {', '.join(entries)}"
    for entry in preference:
        if entry in entries:
            return entry, ""
    if len(entries) == 1:
        return entries[0], ""
    return None, (
        f"GainSelector offers {', '.join(entries) or 'no entry'} and none of {', '.join(preference)}; "
        "expected --feature GainSelector=ENTRY naming the gain to set"
    )


def choose_gain_control(
    features: Mapping[str, FeatureInfo],
    order: Sequence[str],
    request: GainRequest | None,
    raw_per_db: float | None = None,
    profile: str = "generic",
    selector: str | None = None,
    why: str = "",
) -> GainControl:
    """The gain feature ``request`` is written to, with its scale and range.

    Parameters
    ----------
    features
        The gain features the camera has, described now (after the selector was set).
    order
        Names to try, in order (the profile's ``gain_features``, then :data:`GAIN_FEATURES`).
    request
        What the user asked; None picks the feature for plan steps' own gains (dB-scaled first).
    raw_per_db
        ``GainRaw`` units per dB from the model's profile.
    why
        Why the gain cannot be set whatever the feature (a ``GainAuto`` that stays on, a selector
        with no usable entry), or "".

    Examples
    --------
    >>> from msflash.acquisition.devices.aravis.camera_features import FeatureInfo
    >>> raw = FeatureInfo("GainRaw", "integer", "RW", 0, 0, 10)
    >>> choose_gain_control({"GainRaw": raw}, GAIN_FEATURES, GainRequest(6, "dB")).db_known
    False
    >>> choose_gain_control({"GainRaw": raw}, GAIN_FEATURES, GainRequest(6, "dB"), 1.0, "aravis-fake").feature
    'GainRaw'
    """
    present = [name for name in dict.fromkeys((*order, *GAIN_FEATURES)) if name in features]
    usable = [name for name in present if features[name].writable and features[name].kind in ("float", "integer")]

    def control(name: str) -> GainControl:
        info = features[name]
        scale, per_unit, source = feature_scale(info, raw_per_db, profile)
        return GainControl(
            name,
            info.kind,
            scale,
            per_unit,
            info.unit,
            info.minimum,
            info.maximum,
            info.increment if info.kind == "integer" else None,
            selector,
            source,
            why,
        )

    if not usable:
        listed = ", ".join(f"{name} ({features[name].kind}, access {features[name].access})" for name in present)
        reason = (
            f"no writable gain feature ({listed}); expected one of {', '.join(dict.fromkeys((*order, *GAIN_FEATURES)))}"
            if present
            else f"no gain feature; expected one of {', '.join(dict.fromkeys((*order, *GAIN_FEATURES)))}"
        )
        return GainControl(None, why=why or reason, selector=selector)
    controls = [control(name) for name in usable]
    if request is not None and request.unit == "raw":
        return next((c for c in controls if c.feature == "GainRaw"), controls[0])
    return next((c for c in controls if c.scale == "linear" or c.db_per_unit is not None), controls[0])
