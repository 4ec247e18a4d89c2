"""``msflash devices``: the cameras Aravis finds on the interfaces the user names, and the booths.

GigE Vision discovery broadcasts on every network interface, so it runs only when ``gige`` is in
``--interfaces``. ``--address IP`` queries one GigE Vision camera directly, without discovery.
``--features ID`` lists what one camera offers (each feature's type, access, value, range or
entries; :meth:`AravisCamera.describe_feature`) — the names ``--feature NAME=VALUE`` takes.
Booths are the serial ports that look like one (:func:`led_controller.discovery.find_booths`), listed with
every other serial port from the system's list: nothing is opened (docs/cli.md).
"""

from __future__ import annotations

import argparse
from typing import Any

from msflash.acquisition.app.cli_common import UsageError, print_json, progress
from msflash.acquisition.errors import CameraError
from msflash.led_controller import discovery
from msflash.led_controller.discovery import SerialPortInfo, find_booths, other_serial_ports, text_booth_hint

DEFAULT_INTERFACES = "usb3"
"""What ``devices`` searches without ``--interfaces``: never GigE Vision discovery by default."""


def _camera_at(address: str) -> dict[str, Any]:
    from msflash.acquisition.devices.aravis.camera import AravisCamera

    with AravisCamera(address, interfaces="gige") as camera:
        info = camera.info
        return {
            "device_id": info.extra.get("device_id", ""),
            "interface": "gige",
            "vendor": info.vendor,
            "model": info.model,
            "serial": info.serial,
            "address": address,
            "physical_id": "",
            "pixel_format": info.pixel_format,
            "width": info.width,
            "height": info.height,
        }


def _devices(args: argparse.Namespace) -> int:
    try:
        from msflash.acquisition.devices.aravis.discovery import is_ipv4_address, list_devices, parse_interfaces
        from msflash.acquisition.devices.aravis.gi_typelib import Aravis
    except ImportError as err:
        raise CameraError(f"devices: {err}") from err
    try:
        interfaces = parse_interfaces(args.interfaces)
    except ValueError as err:
        raise UsageError(f"--interfaces: {err}") from err
    if args.features is not None:
        return _features(args.features, interfaces, args.json)
    if "gige" in interfaces:
        progress("devices: GigE Vision discovery broadcasts on every network interface")
    cameras = [entry.to_dict() for entry in list_devices(interfaces)]
    for address in args.address or ():
        if not is_ipv4_address(address):
            raise UsageError(f"--address {address!r}: not an IPv4 address; expected e.g. 192.168.1.20")
        cameras.append(_camera_at(address))
    ports = discovery.list_serial_ports()  # looked up on the module: tests stand in their own port list
    booths = [_booth_entry(port) for port in find_booths(ports)]
    serial_ports = [{**_booth_entry(port), "hint": text_booth_hint(port.device)} for port in other_serial_ports(ports)]
    if args.json:
        print_json(
            {
                "interfaces": list(interfaces),
                "aravis": Aravis._version,
                "cameras": cameras,
                "booths": booths,
                "serial_ports": serial_ports,
            }
        )
        return 0
    if not cameras:
        print(f"no camera found on {','.join(interfaces)}")
        if "gige" not in interfaces:
            progress(
                "devices: GigE Vision not searched; add --interfaces gige (broadcasts) "
                "or --address IP (one camera, no broadcast)"
            )
    for camera in cameras:
        where = camera["address"] or camera["physical_id"]
        print(
            f"{camera['device_id']}\t{camera['interface']}\t{camera['vendor']} {camera['model']}\t"
            f"serial {camera['serial']}\t{where}"
        )
    for port in serial_ports:  # not our USB id: maybe another booth; never opened unless named
        print(f"serial\t{port['device']}\t{port['usb_id']}\t{port['board']}\t{port['by_id'] or '-'}\t{port['hint']}")
    if not booths:
        print("no booth found among the serial ports")
        progress("devices: 'msflash doctor' says why a booth is not found (USB id, permissions, ModemManager)")
    for booth in booths:
        print(
            f"booth\t{booth['device']}\t{booth['usb_id']}\t{booth['product'] or booth['description']}\t"
            f"serial {booth['serial_number'] or '-'}"
        )
    return 0


def _features(device: str, interfaces: tuple[str, ...], as_json: bool) -> int:
    """``devices --features ID``: every feature the camera offers, with type, value and what it accepts.

    The features under the camera's ``Root`` category first, then every one msflash reads, writes or
    executes that no category under ``Root`` lists (Aravis's fake hides ``GainRaw`` so), and how
    ``--gain``/``--gain-raw`` map on this camera (feature, selector, unit, range).
    """
    from msflash.acquisition.devices.aravis.camera import AravisCamera
    from msflash.acquisition.devices.aravis.discovery import is_ipv4_address

    if is_ipv4_address(device) and "gige" not in interfaces:
        interfaces = (*interfaces, "gige")  # by address: that one camera, no discovery broadcast
    with AravisCamera(device, interfaces=interfaces) as camera:
        features = [camera.describe_feature(name, category) for name, category in camera.feature_names()]
        gain = camera.gain_record()
        if as_json:
            print_json({"camera": camera.name, "features": [info.to_dict() for info in features], "gain": gain})
            return 0
        listed = [info for info in features if info.category]
        hidden = [info for info in features if not info.category]
        print(f"# {camera.name}: {len(features)} features (name, type, access, value, accepts, msflash's use)")
        for info in listed:
            print(_feature_line(info))
        if hidden:
            print("# not under the camera's Root category, but read or written by msflash:")
            for info in hidden:
                print(_feature_line(info))
        print(f"# --gain/--gain-raw: {_gain_line(gain)}")
    return 0


def _feature_line(info: Any) -> str:
    value = "-" if info.value is None else str(info.value)
    accepts = info.allowed() if info.writable else ""
    use = f"msflash {info.msflash}" if info.msflash else ""
    if info.visibility and info.visibility != "Beginner":
        use = f"{use} ({info.visibility})".strip()
    return f"{info.name}\t{info.kind}\t{info.access}\t{value}\t{accepts}\t{use}".rstrip("\t")


def _gain_line(gain: dict[str, Any]) -> str:
    if gain["feature"] is None or gain.get("why_not"):
        return f"the gain cannot be set: {gain.get('why_not', 'no gain feature')}"
    where = gain["feature"] + (f" under GainSelector {gain['selector']}" if gain["selector"] else "")
    low_high = gain["range"]
    span = f" {low_high[0]:g} … {low_high[1]:g}" if low_high else ""
    if gain["unit"] == "raw" and gain["db_per_unit"] is None:
        return f"{where},{span} in camera units ({gain['scale']}): --gain-raw N only"
    return f"{where},{span} {gain['unit']} ({gain['scale']}): --gain in dB or --gain-raw in these units"


def _booth_entry(port: SerialPortInfo) -> dict[str, Any]:
    return {
        "device": port.device,
        "usb_id": port.usb_id,
        "product": port.product,
        "serial_number": port.serial_number,
        "description": port.description,
        "kind": port.kind,  # booth, arduino-mega, arduino, usb-serial, serial
        "board": port.board,
        "by_id": port.by_id,  # /dev/serial/by-id/…: stable across re-plugging
    }


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``devices``."""
    devices = subparsers.add_parser(
        "devices",
        help="list cameras (Aravis) on the given interfaces, and booths among the serial ports",
        description="List cameras found by Aravis, the serial ports that are msflash booths (by USB "
        "id or product string), and the other serial ports (not opened; 'msflash doctor --port P "
        "--booth-protocol text' asks one whether it is a text booth). GigE Vision discovery broadcasts on every network "
        "interface and runs only with --interfaces gige.",
    )
    devices.add_argument(
        "--interfaces",
        default=DEFAULT_INTERFACES,
        help="comma-separated subset of fake,gige,usb3 (default: %(default)s)",
    )
    devices.add_argument(
        "--address",
        action="append",
        metavar="IP",
        help="also query the GigE Vision camera at IP directly, without discovery (repeatable)",
    )
    devices.add_argument(
        "--features",
        default=None,
        metavar="ID",
        help="list every GenICam feature of camera ID (device id, serial or IP on --interfaces): "
        "type, access, value, and its range or entries; no booth search",
    )
    devices.add_argument("--json", action="store_true", help="print one JSON object")
    devices.set_defaults(handler=_devices)
