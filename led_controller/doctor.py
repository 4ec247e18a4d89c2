"""Host checks for cameras and booths (``msflash doctor``): each finding comes with its remedy.

The checks are functions over injectable roots (``/sys``, ``/dev``, ``/proc``) and injectable
device lists, so tests build a fake system in a temporary directory.
"""

from __future__ import annotations

import logging
import os
import stat
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

from msflash.led_controller.discovery import (
    FTDI_VENDOR,
    SerialPortInfo,
    describe_port,
    find_booths,
    find_megas,
    list_serial_ports,
    with_by_id_links,
)

log = logging.getLogger(__name__)

Status = Literal["ok", "info", "warn", "fail"]

U3V_CLASS = (0xEF, 0x05)
"""USB3 Vision interface class/subclass (miscellaneous / USB3 Vision)."""

SUPERSPEED_MBPS = 5000.0
USBFS_MEMORY_MB_MIN = 1000
RMEM_MAX_MIN = 16 * 1024 * 1024
JUMBO_MTU = 9000

_PYUSB_SPEED_MBPS = {1: 1.5, 2: 12.0, 3: 480.0, 4: 5000.0, 5: 10000.0}


@dataclass(frozen=True)
class Finding:
    """One result of a check."""

    check: str
    """Short name of the check, e.g. ``usb3vision.speed``."""
    status: Status
    """``ok``, ``info``, ``warn`` or ``fail``."""
    message: str
    """What was found."""
    remedy: str | None = None
    """What to do about it, when something is to be done."""

    def as_dict(self) -> dict[str, Any]:
        """The finding as a JSON-ready dict."""
        return asdict(self)


@dataclass(frozen=True)
class UsbDevice:
    """A USB device as far as the checks need it."""

    bus: int
    address: int
    vid: int
    pid: int
    product: str | None
    """Product string, if readable."""
    speed_mbps: float | None
    """Negotiated link speed in Mb/s, or None if unknown."""
    interfaces: tuple[tuple[int, int], ...]
    """(class, subclass) of every interface."""

    @property
    def is_usb3vision(self) -> bool:
        """Get whether the device has a USB3 Vision interface (bool)."""
        return U3V_CLASS in self.interfaces


@dataclass(frozen=True)
class Identity:
    """Whose permissions to check: user id and group ids."""

    uid: int
    gids: frozenset[int]

    @classmethod
    def current(cls) -> Identity:
        """The identity of this process."""
        return cls(os.geteuid(), frozenset([os.getegid(), *os.getgroups()]))


def can_read_write(path: Path, identity: Identity) -> bool:
    """Whether ``identity`` may open ``path`` for reading and writing (from its mode bits)."""
    info = path.stat()
    if identity.uid == 0:
        return True
    if info.st_uid == identity.uid:
        need = stat.S_IRUSR | stat.S_IWUSR
    elif info.st_gid in identity.gids:
        need = stat.S_IRGRP | stat.S_IWGRP
    else:
        need = stat.S_IROTH | stat.S_IWOTH
    return info.st_mode & need == need


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="ascii", errors="replace").strip()
    except OSError:
        return None


def list_usb_devices(
    find: Callable[..., Iterable[Any]] | None = None, sysfs_root: Path = Path("/sys")
) -> list[UsbDevice]:
    """USB devices through pyusb (raises ``usb.core.NoBackendError`` without libusb)."""
    if find is None:
        import usb.core

        find = usb.core.find
    devices = []
    for dev in find(find_all=True):
        interfaces: list[tuple[int, int]] = []
        try:
            for cfg in dev:
                interfaces.extend((intf.bInterfaceClass, intf.bInterfaceSubClass) for intf in cfg)
        except Exception as err:  # a device that refuses descriptors is listed without interfaces
            log.debug("usb %03d:%03d: no descriptors: %s", dev.bus, dev.address, err)
        speed = _PYUSB_SPEED_MBPS.get(getattr(dev, "speed", None) or 0)
        if speed is None:
            speed = _sysfs_speed(sysfs_root, dev.bus, dev.address)
        devices.append(UsbDevice(dev.bus, dev.address, dev.idVendor, dev.idProduct, None, speed, tuple(interfaces)))
    return devices


def _sysfs_speed(sysfs_root: Path, bus: int, address: int) -> float | None:
    for entry in (sysfs_root / "bus" / "usb" / "devices").glob("*"):
        if _read(entry / "busnum") == str(bus) and _read(entry / "devnum") == str(address):
            text = _read(entry / "speed")
            try:
                return float(text) if text else None
            except ValueError:
                return None
    return None


def check_usb3vision(
    list_devices: Callable[[], Sequence[UsbDevice]], dev_root: Path, identity: Identity
) -> list[Finding]:
    """USB3 Vision cameras: pyusb backend present, SuperSpeed link, device node access."""
    try:
        devices = list_devices()
    except Exception as err:
        if type(err).__name__ == "NoBackendError":
            return [
                Finding(
                    "usb3vision.backend",
                    "fail",
                    f"pyusb has no backend ({err}); USB3 Vision cameras cannot be listed",
                    "install libusb 1.0 (Debian: sudo apt install libusb-1.0-0)",
                )
            ]
        raise
    cameras = [d for d in devices if d.is_usb3vision]
    if not cameras:
        return [Finding("usb3vision.devices", "info", f"no USB3 Vision device among {len(devices)} USB devices")]
    findings = []
    for cam in cameras:
        where = f"USB3 Vision {cam.vid:04x}:{cam.pid:04x} on bus {cam.bus} address {cam.address}"
        if cam.speed_mbps is None:
            findings.append(Finding("usb3vision.speed", "warn", f"{where}: link speed unknown"))
        elif cam.speed_mbps < SUPERSPEED_MBPS:
            findings.append(
                Finding(
                    "usb3vision.speed",
                    "warn",
                    f"{where}: link runs at {cam.speed_mbps:g} Mb/s; expected SuperSpeed ({SUPERSPEED_MBPS:g} Mb/s or more)",
                    "plug the camera into a USB 3 port with a USB 3 cable, without a USB 2 hub in between",
                )
            )
        else:
            findings.append(Finding("usb3vision.speed", "ok", f"{where}: {cam.speed_mbps:g} Mb/s"))
        node = dev_root / "bus" / "usb" / f"{cam.bus:03d}" / f"{cam.address:03d}"
        if not node.exists():
            findings.append(Finding("usb3vision.access", "warn", f"{where}: device node {node} missing"))
        elif not can_read_write(node, identity):
            findings.append(
                Finding(
                    "usb3vision.access",
                    "fail",
                    f"{where}: no read/write access to {node}",
                    f'add a udev rule: SUBSYSTEM=="usb", ATTR{{idVendor}}=="{cam.vid:04x}", MODE="0660", '
                    'GROUP="plugdev" (then add yourself to plugdev and replug)',
                )
            )
        else:
            findings.append(Finding("usb3vision.access", "ok", f"{where}: {node} is readable and writable"))
    return findings


def check_usbfs_memory(sysfs_root: Path) -> list[Finding]:
    """The kernel's usbfs buffer limit, which caps USB3 Vision streaming."""
    path = sysfs_root / "module" / "usbcore" / "parameters" / "usbfs_memory_mb"
    text = _read(path)
    if text is None or not text.isdigit():
        return [Finding("usb.usbfs_memory_mb", "info", f"{path} not readable; usbfs limit unknown")]
    value = int(text)
    if value != 0 and value < USBFS_MEMORY_MB_MIN:
        return [
            Finding(
                "usb.usbfs_memory_mb",
                "warn",
                f"usbfs_memory_mb is {value}; expected {USBFS_MEMORY_MB_MIN} or more for USB3 Vision streaming",
                f"echo {USBFS_MEMORY_MB_MIN} | sudo tee {path} (persist with the kernel parameter "
                f"usbcore.usbfs_memory_mb={USBFS_MEMORY_MB_MIN})",
            )
        ]
    return [Finding("usb.usbfs_memory_mb", "ok", f"usbfs_memory_mb is {value} (0 means unlimited)")]


def _dev_path(device: str, dev_root: Path) -> Path:
    return dev_root / device[len("/dev/") :] if device.startswith("/dev/") else Path(device)


def check_serial_ports(ports: Sequence[SerialPortInfo], dev_root: Path, identity: Identity) -> list[Finding]:
    """Booth ports found (by the booth's USB id, else the one Arduino Mega) and accessible; other boards named.

    Nothing is opened: ``msflash doctor --port P`` asks one port who it is (its firmware and ``SERIAL=``).
    """
    ports = with_by_id_links(ports, dev_root)
    booths = find_booths(ports)
    megas = find_megas(ports)
    findings: list[Finding] = []
    if not booths and len(megas) == 1:
        mega = megas[0]
        findings.append(
            Finding(
                "booth.ports",
                "info",
                f"no port with the booth's USB id; the Arduino Mega {describe_port(mega)} is taken as the booth "
                f"('msflash doctor --port {mega.path}' asks it whether it runs the booth firmware)",
            )
        )
        booths = megas
    elif not booths:
        listing = "; ".join(describe_port(p) for p in ports) or "none"
        several = f"{len(megas)} Arduino Megas, " if megas else ""
        findings.append(
            Finding(
                "booth.ports",
                "warn",
                f"no booth among the serial ports ({several}found: {listing})",
                "plug the booth in; a Mega clone (CH340, FTDI) or another USB id: pass --port (a /dev/serial/by-id "
                "path stays the same across re-plugging); 'msflash doctor --port P' asks port P who it is "
                "(--booth-protocol text for a plain-text booth)",
            )
        )
    for port in booths:
        path = _dev_path(port.device, dev_root)
        where = describe_port(port)
        if not path.exists():
            findings.append(Finding("booth.access", "fail", f"booth {where}: {path} missing"))
        elif not can_read_write(path, identity):
            findings.append(
                Finding(
                    "booth.access",
                    "fail",
                    f"booth {where}: no read/write access",
                    "sudo usermod -aG dialout $USER, then log out and in again",
                )
            )
        else:
            findings.append(Finding("booth.access", "ok", f"booth {where} is accessible"))
    for port in ports:
        if port not in booths and port.kind != "serial":
            findings.append(
                Finding(
                    "serial.boards",
                    "info",
                    f"{port.kind} {describe_port(port)}: not taken as the booth; pass --port {port.path} to use it",
                )
            )
    return findings


def check_ftdi_latency(ports: Sequence[SerialPortInfo], sysfs_root: Path) -> list[Finding]:
    """The latency timer of FTDI ports: a reply shorter than a USB packet waits for it (16 ms by default)."""
    findings = []
    for port in ports:
        if port.vid != FTDI_VENDOR:
            continue
        name = port.device.rsplit("/", 1)[-1]
        path = sysfs_root / "bus" / "usb-serial" / "devices" / name / "latency_timer"
        text = _read(path)
        if text is None or not text.isdigit():
            continue
        findings.append(
            Finding(
                "serial.latency",
                "info",
                f"{port.device}: FTDI latency timer {int(text)} ms (each short reply waits up to that long; "
                "msflash's timing allows it)",
                f"echo 1 | sudo tee {path} for 1 ms (persist with a udev rule)" if int(text) > 1 else None,
            )
        )
    return findings


def check_modemmanager(proc_root: Path) -> list[Finding]:
    """ModemManager probes new serial ports with AT commands, which a booth must not receive."""
    for comm in proc_root.glob("[0-9]*/comm"):
        if _read(comm) == "ModemManager":
            return [
                Finding(
                    "booth.modemmanager",
                    "warn",
                    f"ModemManager is running (pid {comm.parent.name}); it probes new serial ports and "
                    "can hold the booth's port or send it AT commands",
                    "sudo systemctl disable --now ModemManager, or a udev rule setting "
                    'ENV{ID_MM_DEVICE_IGNORE}="1" for the booth',
                )
            ]
    return [Finding("booth.modemmanager", "ok", "ModemManager is not running")]


def check_rmem_max(proc_root: Path) -> list[Finding]:
    """The socket receive buffer limit, which GigE Vision streams need raised."""
    path = proc_root / "sys" / "net" / "core" / "rmem_max"
    text = _read(path)
    if text is None or not text.isdigit():
        return [Finding("gige.rmem_max", "info", f"{path} not readable")]
    value = int(text)
    if value < RMEM_MAX_MIN:
        return [
            Finding(
                "gige.rmem_max",
                "warn",
                f"net.core.rmem_max is {value} bytes; expected {RMEM_MAX_MIN} or more for GigE Vision streams",
                f"sudo sysctl -w net.core.rmem_max={RMEM_MAX_MIN} (persist in /etc/sysctl.d/)",
            )
        ]
    return [Finding("gige.rmem_max", "ok", f"net.core.rmem_max is {value} bytes")]


def check_mtu(sysfs_root: Path) -> list[Finding]:
    """MTU of the wired interfaces that are up (jumbo frames help GigE Vision)."""
    findings = []
    for iface in sorted((sysfs_root / "class" / "net").glob("*")):
        if iface.name == "lo" or (iface / "wireless").exists() or _read(iface / "operstate") != "up":
            continue
        text = _read(iface / "mtu")
        if text is None or not text.isdigit():
            continue
        mtu = int(text)
        if mtu < JUMBO_MTU:
            findings.append(
                Finding(
                    "gige.mtu",
                    "info",
                    f"{iface.name}: MTU {mtu}; expected {JUMBO_MTU} if a GigE camera is on this interface",
                    f"sudo ip link set {iface.name} mtu {JUMBO_MTU} (and enable jumbo frames on the camera)",
                )
            )
        else:
            findings.append(Finding("gige.mtu", "ok", f"{iface.name}: MTU {mtu}"))
    return findings or [Finding("gige.mtu", "info", "no wired network interface is up")]


def run_doctor(
    *,
    sysfs_root: Path = Path("/sys"),
    dev_root: Path = Path("/dev"),
    proc_root: Path = Path("/proc"),
    list_usb: Callable[[], Sequence[UsbDevice]] | None = None,
    serial_ports: Sequence[SerialPortInfo] | None = None,
    identity: Identity | None = None,
) -> list[Finding]:
    """Run every check and return the findings in a stable order.

    The roots stand for ``/sys``, ``/dev`` and ``/proc``; by default the USB devices come through
    pyusb, the serial ports through pyserial, and the access checked is this process's.
    """
    who = identity or Identity.current()
    usb_lister = list_usb or (lambda: list_usb_devices(sysfs_root=sysfs_root))
    ports = list_serial_ports(dev_root) if serial_ports is None else serial_ports
    return [
        *check_usb3vision(usb_lister, dev_root, who),
        *check_usbfs_memory(sysfs_root),
        *check_serial_ports(ports, dev_root, who),
        *check_ftdi_latency(ports, sysfs_root),
        *check_modemmanager(proc_root),
        *check_rmem_max(proc_root),
        *check_mtu(sysfs_root),
    ]
