"""Which transport layers Aravis may use, what they find, and the GenICam description the fakes use.

Network safety: Aravis discovers GigE Vision cameras by broadcasting on every network interface;
nothing here enables the GigE Vision interface unless the caller lists ``gige``.
"""

from __future__ import annotations

import ipaddress
import logging
import os
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from msflash.acquisition.devices.aravis.fake_models import FAKE_SFNC_XML as _FAKE_SFNC_XML
from msflash.acquisition.devices.aravis.gi_typelib import Aravis, aravis_lock

log = logging.getLogger(__name__)


GENICAM_DIR = Path(__file__).resolve().parent / "genicam"
"""Shipped GenICam data: the fake camera's SFNC description and the per-model profiles."""
FAKE_SFNC_XML = _FAKE_SFNC_XML
"""GenICam XML for the Aravis fake cameras adding SFNC ExposureTime, Gain, Line*, UserOutput*,
Counter* and Chunk* as registers (generated from the fake's own XML, Aravis 0.8.26)."""
PROFILES_JSON = GENICAM_DIR / "profiles.json"

INTERFACES: dict[str, str] = {"fake": "Fake", "gige": "GigEVision", "usb3": "USB3Vision"}
"""msflash interface names (``--interfaces``) and the Aravis interface ids they stand for."""


def parse_interfaces(spec: str | Iterable[str]) -> tuple[str, ...]:
    """An interface list (``"fake,gige"`` or an iterable of names from :data:`INTERFACES`) as a tuple of
    names, lower case, without duplicates, in the given order.

    Raises
    ------
    ValueError
        An unknown or empty name; the message lists the valid names.
    """
    names = [s.strip().lower() for s in (spec.split(",") if isinstance(spec, str) else spec)]
    if not names or any(not n for n in names):
        raise ValueError(
            f"interfaces {spec!r}: empty name; expected a comma-separated subset of {', '.join(INTERFACES)}"
        )
    unknown = [n for n in names if n not in INTERFACES]
    if unknown:
        raise ValueError(
            f"interfaces {spec!r}: unknown {', '.join(unknown)}; expected a subset of {', '.join(INTERFACES)}"
        )
    return tuple(dict.fromkeys(names))


def use_interfaces(interfaces: str | Iterable[str]) -> tuple[str, ...]:
    """Enable exactly ``interfaces`` in Aravis and disable the others (process-wide).

    Returns the parsed names. Call it before any listing or opening: by default Aravis enables
    GigE Vision and USB3 Vision, and GigE Vision discovery broadcasts on every network interface.
    """
    names = parse_interfaces(interfaces)
    with aravis_lock:
        for name, arv_id in INTERFACES.items():
            if name in names:
                Aravis.enable_interface(arv_id)
            else:
                Aravis.disable_interface(arv_id)
    return names


@dataclass(frozen=True)
class DeviceEntry:
    """One device as Aravis lists it."""

    device_id: str
    """Aravis device id (``Fake_1``, ``Aravis-Fake-GV01``, ``<vendor>-<serial>``); opens the device."""
    interface: str
    """msflash interface name: ``fake``, ``gige`` or ``usb3``."""
    vendor: str
    """Vendor name."""
    model: str
    """Model name."""
    serial: str
    """Serial number."""
    address: str
    """IP address for GigE Vision devices, else empty."""
    physical_id: str
    """MAC address (GigE) or bus id (USB)."""

    def to_dict(self) -> dict[str, str]:
        """The entry as a JSON-ready mapping."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


_PROTOCOL_TO_INTERFACE = {"Fake": "fake", "GigEVision": "gige", "USB3Vision": "usb3"}


def list_devices(interfaces: str | Iterable[str]) -> tuple[DeviceEntry, ...]:
    """List the devices found on ``interfaces`` (only those are enabled; see :func:`use_interfaces`).

    With ``gige`` in ``interfaces`` this broadcasts GigE Vision discovery on every network
    interface of the machine; leave it out where that is not allowed.
    """
    use_interfaces(interfaces)
    with aravis_lock:
        Aravis.update_device_list()
        entries = []
        for i in range(Aravis.get_n_devices()):
            protocol = Aravis.get_device_protocol(i) or ""
            entries.append(
                DeviceEntry(
                    device_id=Aravis.get_device_id(i) or "",
                    interface=_PROTOCOL_TO_INTERFACE.get(protocol, protocol.lower()),
                    vendor=Aravis.get_device_vendor(i) or "",
                    model=Aravis.get_device_model(i) or "",
                    serial=Aravis.get_device_serial_nbr(i) or "",
                    address=(Aravis.get_device_address(i) or "") if protocol == "GigEVision" else "",
                    physical_id=Aravis.get_device_physical_id(i) or "",
                )
            )
    return tuple(entries)


def is_ipv4_address(text: str) -> bool:
    """Whether ``text`` is a dotted IPv4 address (such a device id opens without discovery)."""
    try:
        ipaddress.IPv4Address(text)
    except ValueError:
        return False
    return True


_builtin_fake_xml: str | None = None


def _builtin_fake_xml_path() -> str:
    # Aravis 0.8.26 has no way to unset the fake's GenICam file name (None is refused, "" fails to
    # load), so the built-in description is saved once, before it is first replaced
    # (tests/acquisition/support/fake_genicam.py).
    global _builtin_fake_xml
    with aravis_lock:
        if _builtin_fake_xml is None:
            xml, size = Aravis.FakeDevice.new("builtin").get_genicam_xml()
            handle, path = tempfile.mkstemp(prefix="msflash-fake-builtin-", suffix=".xml")
            with os.fdopen(handle, "w", encoding="utf-8") as out:
                out.write(xml[:size])
            _builtin_fake_xml = path
        return _builtin_fake_xml
