"""What a spectrometer export's header says about how it was taken: instrument, integration time,
averaging, smoothing, the unit of its values.

Public objects
--------------
- :class:`AcquisitionSettings`: the settings found, each with the line it came from.
- :func:`acquisition_settings`: read them from an export's header lines.
- :func:`header_number`: a number as instrument software writes it (decimal comma or point,
  ``1.2E+002``).

The header spellings of each program (OceanView, SpectraSuite/OOIBase32, AvaSoft, SpectraWiz,
Thorlabs, plain files) are listed in ``docs/calibration.md`` (*Header spellings*).

Numbers in headers are read with a decimal comma or point (instrument software writes no
thousands separators). An integration time that is not a positive finite number is refused naming
the file, line and key.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Literal

from msflash.calibration.errors import CalibrationError
from msflash.processing.user_numbers import plain_number

ValueUnit = Literal["counts", "energy", "photons"]

SECONDS_PER = {"s": 1.0, "sec": 1.0, "secs": 1.0, "ms": 1e-3, "msec": 1e-3, "us": 1e-6, "µs": 1e-6, "usec": 1e-6}
"""Seconds per unit of time as spectrometer programs spell it (``µs`` also as the micro sign U+00B5)."""

_NUMBER = r"[-+]?(?:[0-9]+(?:[.,][0-9]*)?|[.,][0-9]+)(?:[eE][-+]?[0-9]+)?"
_UNIT = r"(?:secs?|s|msec|ms|usec|us|µs|μs)"


@dataclass(frozen=True)
class AcquisitionSettings:
    """How an export was taken, as far as its header says (``None``: the header does not say)."""

    instrument: str = "plain"
    """``OceanView``, ``SpectraSuite``, ``OOIBase32``, ``AvaSoft``, ``SpectraWiz``, ``Thorlabs`` or ``plain``."""
    integration_time_s: float | None = None
    """Integration time of one scan, seconds."""
    averages: int | None = None
    """Scans averaged (the programs average, they do not sum: the level does not change, the noise does)."""
    boxcar: int | None = None
    """Smoothing width, pixels (neighbouring samples' noise is then correlated)."""
    value_unit: ValueUnit | None = None
    """What the values are, when the header says: raw ``counts`` or a calibrated ``energy``/``photons``."""
    electric_dark: bool | None = None
    """The program subtracted the electrical dark (optically masked pixels): the fixed offset is gone."""
    lines: dict[str, int] = field(default_factory=dict, compare=False)
    """Line of the header each setting came from, for messages."""

    def as_dict(self) -> dict[str, object]:
        """For the calibration file and JSON output."""
        return {
            "instrument": self.instrument,
            "integration_time_s": self.integration_time_s,
            "averages": self.averages,
            "boxcar": self.boxcar,
            "value_unit": self.value_unit,
            "electric_dark": self.electric_dark,
        }


def header_number(text: str) -> float | None:
    """A number as instrument software writes it, or None.

    Examples
    --------
    >>> header_number("1.000000E-1"), header_number("35,000"), header_number(" 1,2112E+002 "), header_number("x")
    (0.1, 35.0, 121.12, None)
    """
    if not re.fullmatch(_NUMBER, text.strip()):
        return None
    try:  # the one reading of a user's number, its decimal comma made a point
        return plain_number(text.replace(",", "."))
    except ValueError:
        return None


def _flag(text: str) -> bool | None:
    word = text.strip().split()[0].lower() if text.strip() else ""
    if word in ("true", "yes", "enabled", "on", "1", "はい"):
        return True
    if word in ("false", "no", "disabled", "off", "0", "いいえ"):
        return False
    return None


# (regex, field, how the value is read). The regex is matched against the line with any leading
# comment marks ('#', '"', '%', '//', ';') and blanks removed; group "v" is the value, "u" a unit.
_OCEAN_TIME = re.compile(rf"^integration time \((?P<u>{_UNIT})\)\s*:\s*(?P<v>{_NUMBER})", re.IGNORECASE)
_AVANTES_TIME = re.compile(rf"^integration time \[(?P<u>{_UNIT})\]\s*:\s*(?P<v>{_NUMBER})", re.IGNORECASE)
_THORLABS_TIME = re.compile(rf"^integrationtime\s*[;,\t=:]\s*(?P<v>{_NUMBER})\s*$", re.IGNORECASE)
_SPECTRAWIZ = re.compile(r"\bTime:\s*(?P<v>[0-9.,]+)\s*(?P<u>ms|us|µs|s)?\b", re.IGNORECASE)
_PLAIN_TIME = re.compile(
    rf"^(?:integration|exposure)[ _-]?time(?:[ _-]?\(?\[?(?P<ku>{_UNIT})\]?\)?)?\s*[:=;,\t]\s*"
    rf"(?P<v>{_NUMBER})\s*(?P<u>{_UNIT})?\s*$",
    re.IGNORECASE,
)
_AVERAGES = re.compile(
    r"^(?:scans to average|spectra averaged|averaging nr\. \[scans\]|average|averages|averaging|scans)\s*[:;,\t=]\s*"
    r"(?P<v>\d+)",
    re.IGNORECASE | re.ASCII,
)
_BOXCAR = re.compile(
    r"^(?:boxcar width|boxcar smoothing|smoothing nr\. \[pixels\]|spectrumsmooth|smoothing)\s*[:;,\t=]\s*(?P<v>\d+)",
    re.IGNORECASE | re.ASCII,
)
_ELECTRIC_DARK = re.compile(
    r"^(?:electric dark correction enabled|correct for electrical dark)\s*:\s*(?P<v>\S+)", re.IGNORECASE
)
_THORLABS_UNIT = re.compile(r"^yaxisunit\s*[;,\t=]\s*(?P<v>.+)$", re.IGNORECASE)


def _instrument(lines: list[str]) -> str:
    joined = "\n".join(lines).lower()
    if "spectrasuite" in joined:
        return "SpectraSuite"
    if "ooibase32" in joined:
        return "OOIBase32"
    if "begin spectral data" in joined or "begin processed spectral data" in joined:
        return "OceanView"
    if "data measured with spectrometer" in joined or "averaging nr." in joined or "integration time [ms]" in joined:
        return "AvaSoft"
    if "[spectrumheader]" in joined or re.search(r"^#?\s*integrationtime\s*[;,]", joined, re.MULTILINE):
        return "Thorlabs"
    if any(line.startswith('"') for line in lines) and re.search(r"\btime:\s*[0-9]", joined):
        return "SpectraWiz"
    return "plain"


def _stripped(line: str) -> str:
    return re.sub(r'^(?:#|%|//|;|")+\s*', "", line.strip()).strip()


def _unit_of_values(instrument: str, lines: list[str], column_units: tuple[str, ...]) -> ValueUnit | None:
    """What the values are, where the export says so."""
    if column_units:
        unit = column_units[0].strip("[] ").lower()
        if unit in ("counts", "count", "adc", "dn"):
            return "counts"
        if re.search(r"w/|w /|watt|µw|uw|mw|j/", unit):
            return "energy"
        if re.search(r"photon|µmol|umol|quanta", unit):
            return "photons"
    if instrument == "SpectraWiz":
        first = next((line for line in lines if "->" in line), "")
        if "SCOPE" in first.upper():
            return "counts"
    if instrument == "Thorlabs":
        for line in lines:
            match = _THORLABS_UNIT.match(_stripped(line))
            if match:
                unit = match.group("v").strip().lower()
                if unit in ("intensity", "counts", "a.u.", "au", "arb"):
                    return "counts"
                if re.search(r"w|watt", unit):
                    return "energy"
    return None


def acquisition_settings(
    header_lines: tuple[tuple[int, str], ...] | list[tuple[int, str]],
    source: str,
    column_units: tuple[str, ...] = (),
) -> AcquisitionSettings:
    """The settings an export's header states (see the module notes for the formats).

    Parameters
    ----------
    header_lines
        ``(line number, text)`` of every header and comment line, in file order.
    column_units
        The units of the value column(s), where the export has a unit row (AvaSoft ``[counts]``).

    Raises
    ------
    CalibrationError
        ``<file>:<line>: <key> is …; expected …``: an integration time that is not a positive
        finite number, or a plain-file time without a unit.

    Examples
    --------
    >>> lines = ["SpectraSuite Data File", "Integration Time (usec): 60000 (USB4F06998)", "Spectra Averaged: 5 (USB4F06998)"]
    >>> s = acquisition_settings(list(enumerate(lines, start=1)), "x.txt")
    >>> s.instrument, s.integration_time_s, s.averages
    ('SpectraSuite', 0.06, 5)
    >>> acquisition_settings([(1, '" SCOPE->  Wave:632.47nm  Pix:1050  Time:30ms  Avg:10  Sm:1')], "d.SSM").integration_time_s
    0.03
    """
    texts = [text.strip().lstrip("\ufeff") for _, text in header_lines]
    instrument = _instrument(texts)
    found = _Found()
    for (number, _), raw in zip(header_lines, texts, strict=True):
        _read_setting_line(found, instrument, raw, number, source)
    seconds = _integration_seconds(found, source)
    averages = found.values.get("averages")
    if averages is not None and int(averages) == 0:  # type: ignore[call-overload]
        averages = 1  # Thorlabs writes 0 for "no averaging"
    return AcquisitionSettings(
        instrument=instrument,
        integration_time_s=seconds,
        averages=averages,  # type: ignore[arg-type]
        boxcar=found.values.get("boxcar"),  # type: ignore[arg-type]
        value_unit=_unit_of_values(instrument, texts, column_units),
        electric_dark=found.values.get("electric_dark"),  # type: ignore[arg-type]
        lines=found.lines,
    )


class _Found:
    """The settings found so far and the line each came from; the first statement of a key wins."""

    def __init__(self) -> None:
        self.values: dict[str, object] = {}
        self.lines: dict[str, int] = {}

    def put(self, key: str, value: object, number: int) -> None:
        if key not in self.values:
            self.values[key] = value
            self.lines[key] = number


def _read_setting_line(found: _Found, instrument: str, raw: str, number: int, source: str) -> None:
    """The settings one header line states: integration time (as text, unit, line), averages, boxcar, dark."""
    line = _stripped(raw)
    time_match = _OCEAN_TIME.match(line) or _AVANTES_TIME.match(line)
    if time_match:
        found.put("integration_time_s", (time_match.group("v"), time_match.group("u"), line), number)
    elif instrument == "Thorlabs" and (match := _THORLABS_TIME.match(line)):
        found.put("integration_time_s", (match.group("v"), "s", line), number)  # ThorSpectra writes seconds
    elif instrument == "SpectraWiz" and raw.startswith('"') and (match := _SPECTRAWIZ.search(line)):
        found.put("integration_time_s", (match.group("v"), match.group("u") or "ms", line), number)
        if avg := re.search(r"\bAvg:\s*(\d+)", line, re.IGNORECASE | re.ASCII):
            found.put("averages", int(avg.group(1)), number)
        if smooth := re.search(r"\bSm:\s*(\d+)", line, re.IGNORECASE | re.ASCII):
            found.put("boxcar", int(smooth.group(1)), number)
    elif match := _PLAIN_TIME.match(line):
        unit = match.group("ku") or match.group("u")
        if unit is None:
            raise CalibrationError(
                f"{source}:{number}: '{line[:60]}' states an integration time without a unit; expected e.g. "
                "'integration_time_ms: 10' or 'integration time: 10 ms'"
            )
        found.put("integration_time_s", (match.group("v"), unit, line), number)
    if match := _AVERAGES.match(line):
        found.put("averages", int(match.group("v")), number)
    if match := _BOXCAR.match(line):
        found.put("boxcar", int(match.group("v")), number)
    if match := _ELECTRIC_DARK.match(line):
        flag = _flag(match.group("v"))
        if flag is not None:
            found.put("electric_dark", flag, number)


def _integration_seconds(found: _Found, source: str) -> float | None:
    """The stated integration time in seconds (None if not stated); refused unless positive and finite."""
    if "integration_time_s" not in found.values:
        return None
    stated: tuple[str, str, str] = found.values["integration_time_s"]  # type: ignore[assignment]
    text, unit, line = stated
    value = header_number(str(text))
    seconds = value * SECONDS_PER[str(unit).lower().replace("μ", "µ")] if value is not None else None
    if seconds is None or not math.isfinite(seconds) or seconds <= 0:
        raise CalibrationError(
            f"{source}:{found.lines['integration_time_s']}: '{str(line)[:60]}': integration time '{text}'; expected a "
            "positive number"
        )
    return seconds
