"""Camera models the ``aravis-fake`` rig's GigE Vision fake can be: each names its gain its own way.

Real cameras set their analogue gain as SFNC ``Gain`` in dB, as ``GainRaw`` in units only their
maker documents, or behind a ``GainSelector`` without an ``All`` entry and with ``GainAuto`` on
at power-up (docs/decisions/gain-units.md); ``--fake-camera MODEL`` (``--rig aravis-fake``) picks one of:

=================  ==================================================================================
``sfnc``           msflash's SFNC XML as shipped (``genicam/fake_sfnc.xml``): ``Gain`` 0–24 dB
                   under a ``GainSelector`` whose one entry is ``All``; Aravis's own ``GainRaw``
                   0–10 outside the ``Root`` category. Model "Fake" (profile ``aravis-fake``).
``gain-db``        ``Gain`` in dB only (no selector, no ``GainRaw``). Model "Fake-GainDB".
``gain-raw``       ``GainRaw`` only: whole numbers 100–800, each 1/100 of a linear factor (100 = 0 dB,
                   800 = ×8), a scale no profile knows — ``--gain`` in dB is refused, ``--gain-raw`` taken.
                   Powers up at 100. Model "Fake-GainRaw".
``gain-selector``  ``GainSelector`` with ``AnalogAll`` (0–24 dB) and ``DigitalAll`` (0–12 dB, powers up
                   at 2 dB), no ``All``; ``Gain`` in dB for the selected one; ``GainAuto`` powers up
                   ``Continuous``. Model "Fake-GainSelector".
=================  ==================================================================================

Each model's :meth:`FakeModel.true_gain` is the twin's own truth: the linear gain its sensor
applies, read from the fake's registers (never from what msflash believes it set), so the
rendered frames are as bright as that camera's would be — a wrong unit, a selector left on the
wrong entry or an automatic gain left on shows in the pixels. The digital gain of
``gain-selector`` (2 dB unless changed) and its automatic gain while on (+12 dB) are applied too.

The XML of a model is msflash's SFNC XML with nodes removed or edited as text (the file is
GenICam's own layout, which an XML library would rewrite with namespace prefixes Aravis does not
read), written once per process to a temporary file (Aravis's fake reads a file name).
"""

from __future__ import annotations

import atexit
import os
import re
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

FAKE_SFNC_XML = Path(__file__).resolve().parent / "genicam" / "fake_sfnc.xml"
"""msflash's SFNC description of the Aravis fake (the ``sfnc`` model's, and every other model's base)."""

GAIN_RAW_REGISTER = 0x110
"""The fake's own ``GainRaw`` register (Aravis's fake XML)."""
GAIN_AUTO_REGISTER = 0x114
"""The fake's ``GainAuto`` register: 1 Off, 2 Continuous, 3 Once."""
SFNC_GAIN_REGISTER = 0x4004
"""msflash's ``Gain`` register: hundredths of a dB."""
SELECTED_GAIN_REGISTER = 0x4800
"""``gain-selector``: one ``Gain`` register (hundredths of a dB) per ``GainSelector`` entry, 4 bytes apart."""
AUTO_GAIN_DB = 12.0
"""The gain the ``gain-selector`` twin's automatic gain adds while it is on (dB)."""

Registers = Callable[[int], int]
"""Reads one 32-bit register of the fake."""


def _drop_node(xml: str, name: str) -> str:
    """``xml`` without the node named ``name`` and without every ``<pFeature>`` naming it."""
    node = re.compile(rf'\t<(\w+) Name="{name}" [^>]*>.*?</\1>\n', re.S)
    if not node.search(xml):
        raise ValueError(f"fake_models: no node {name!r} in {FAKE_SFNC_XML.name}")
    xml = node.sub("", xml, count=1)
    return re.sub(rf"\s*<pFeature>{name}</pFeature>", "", xml)


def _edit_node(xml: str, name: str, edit: Callable[[str], str]) -> str:
    node = re.compile(rf'\t<(\w+) Name="{name}" [^>]*>.*?</\1>\n', re.S)
    match = node.search(xml)
    if match is None:
        raise ValueError(f"fake_models: no node {name!r} in {FAKE_SFNC_XML.name}")
    return xml[: match.start()] + edit(match.group(0)) + xml[match.end() :]


def _gain_db_xml(xml: str) -> str:
    return _drop_node(_drop_node(xml, "GainSelector"), "GainRaw")


def _gain_raw_xml(xml: str) -> str:
    xml = _drop_node(_drop_node(xml, "GainSelector"), "Gain")
    return _edit_node(
        xml,
        "GainRaw",
        lambda node: node.replace("<Min>0</Min>", "<Min>100</Min>").replace("<Max>10</Max>", "<Max>800</Max>"),
    )


def _gain_selector_xml(xml: str) -> str:
    xml = _drop_node(xml, "GainRaw")
    xml = _edit_node(
        xml,
        "GainSelector",
        lambda node: re.sub(
            r"<EnumEntry Name=\"All\".*?</EnumEntry>",
            '<EnumEntry Name="AnalogAll" NameSpace="Standard">\n\t\t\t<Value>0</Value>\n\t\t</EnumEntry>\n'
            '\t\t<EnumEntry Name="DigitalAll" NameSpace="Standard">\n\t\t\t<Value>1</Value>\n\t\t</EnumEntry>',
            node,
            flags=re.S,
        ),
    )
    xml = _edit_node(
        xml,
        "Gain",
        lambda node: (
            node.replace("<Max>24.0</Max>", "<pMax>SelectedGainMax</pMax>")
            + '\t<SwissKnife Name="SelectedGainMax" NameSpace="Custom">\n'
            '\t\t<pVariable Name="SEL">GainSelectorRegister</pVariable>\n'
            "\t\t<Formula>(SEL = 1) ? 12.0 : 24.0</Formula>\n"
            "\t</SwissKnife>\n"
        ),
    )
    return _edit_node(
        xml,
        "GainRegister",
        lambda node: node.replace(
            f"<Address>0x{SFNC_GAIN_REGISTER:x}</Address>",
            f'<Address>0x{SELECTED_GAIN_REGISTER:x}</Address>\n\t\t<pIndex Offset="4">GainSelectorRegister</pIndex>',
        ),
    )


def _db(value: float) -> float:
    return float(10.0 ** (value / 20.0))


def _sfnc_truth(read: Registers) -> float:
    return _db(read(SFNC_GAIN_REGISTER) / 100.0)


def _gain_raw_truth(read: Registers) -> float:
    return read(GAIN_RAW_REGISTER) / 100.0


def _gain_selector_truth(read: Registers) -> float:
    analog, digital = (read(SELECTED_GAIN_REGISTER + 4 * i) / 100.0 for i in (0, 1))
    auto = AUTO_GAIN_DB if read(GAIN_AUTO_REGISTER) != 1 else 0.0
    return _db(analog + digital + auto)


@dataclass(frozen=True)
class FakeModel:
    """One camera model of the GigE Vision fake: its GenICam XML, its name, its power-up state, its truth."""

    name: str
    """What ``--fake-camera`` takes."""
    model: str
    """The model name the fake reports (profiles in ``genicam/profiles.json`` are matched on it)."""
    summary: str
    """One line for ``--help`` and the record."""
    xml: Callable[[str], str] | None = None
    """Edit of msflash's SFNC XML, None to serve it as shipped."""
    registers: dict[int, int] = field(default_factory=dict)
    """Registers written at power-up (address → value)."""
    true_gain: Callable[[Registers], float] = _sfnc_truth
    """The linear gain the twin's sensor applies, from its registers."""

    def xml_path(self) -> Path:
        """The model's GenICam XML file (written once per process for an edited model)."""
        if self.xml is None:
            return FAKE_SFNC_XML
        path = _written.get(self.name)
        if path is None or not path.exists():
            handle, name = tempfile.mkstemp(prefix=f"msflash-fake-{self.name}-", suffix=".xml")
            with os.fdopen(handle, "w", encoding="utf-8") as out:
                out.write(self.xml(FAKE_SFNC_XML.read_text(encoding="utf-8")))
            path = _written[self.name] = Path(name)
        return path


_written: dict[str, Path] = {}


@atexit.register
def _remove_written() -> None:  # pragma: no cover - at interpreter exit
    for path in _written.values():
        path.unlink(missing_ok=True)


FAKE_MODELS: dict[str, FakeModel] = {
    model.name: model
    for model in (
        FakeModel("sfnc", "Fake", "Gain 0-24 dB (GainSelector All), Aravis's GainRaw hidden"),
        FakeModel("gain-db", "Fake-GainDB", "Gain 0-24 dB only", _gain_db_xml),
        FakeModel(
            "gain-raw",
            "Fake-GainRaw",
            "GainRaw 100-800 only (1/100 of a linear factor, no dB scale in any profile)",
            _gain_raw_xml,
            {GAIN_RAW_REGISTER: 100},
            _gain_raw_truth,
        ),
        FakeModel(
            "gain-selector",
            "Fake-GainSelector",
            "GainSelector AnalogAll 0-24 dB / DigitalAll 0-12 dB (at 2 dB), no All; GainAuto on at power-up",
            _gain_selector_xml,
            {GAIN_AUTO_REGISTER: 2, SELECTED_GAIN_REGISTER + 4: 200},
            _gain_selector_truth,
        ),
    )
}
"""The fake's camera models by ``--fake-camera`` name; ``sfnc`` is the default."""

DEFAULT_FAKE_MODEL = "sfnc"
"""The ``aravis-fake`` rig's model without ``--fake-camera``."""
