"""Booth discovery and the doctor checks over fake /sys, /dev and /proc trees."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from msflash.acquisition.app.cli_booth import register
from msflash.led_controller import BoothNotFoundError
from msflash.led_controller.discovery import (
    SerialPortInfo,
    by_id_links,
    describe_port,
    find_booth,
    find_booths,
    from_pyserial,
    with_by_id_links,
)
from msflash.led_controller.doctor import Identity, UsbDevice, run_doctor

USER = Identity(uid=1000, gids=frozenset({1000}))

BOOTH = SerialPortInfo("/dev/ttyACM0", 0x1209, 0x4D53, "booth", "A1", "ttyACM0")
GENERIC_BOOTH = SerialPortInfo("/dev/ttyUSB1", 0x0403, 0x6001, "msflash booth v2", None, "FT232R")
OTHER = SerialPortInfo("/dev/ttyS0", None, None, None, None, "n/a")


def test_find_booths_by_usb_id_and_product() -> None:
    assert find_booths([OTHER, GENERIC_BOOTH, BOOTH]) == [BOOTH, GENERIC_BOOTH]
    assert find_booth([OTHER, BOOTH]) == BOOTH


def test_find_booth_lists_what_was_found() -> None:
    with pytest.raises(BoothNotFoundError, match=r"no booth .*found: /dev/ttyS0 \(n/a, -\)"):
        find_booth([OTHER])
    with pytest.raises(BoothNotFoundError, match="2 booths .*pass --port"):
        find_booth([BOOTH, GENERIC_BOOTH])


def _node(path: Path, mode: int, text: str = "") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(mode)
    return path


@pytest.fixture
def fake_system(tmp_path: Path) -> dict[str, Path]:
    sysfs, dev, proc = tmp_path / "sys", tmp_path / "dev", tmp_path / "proc"
    _node(sysfs / "module/usbcore/parameters/usbfs_memory_mb", 0o644, "16\n")
    _node(sysfs / "class/net/eth0/mtu", 0o644, "1500\n")
    _node(sysfs / "class/net/eth0/operstate", 0o644, "up\n")
    _node(sysfs / "class/net/lo/mtu", 0o644, "65536\n")
    _node(proc / "sys/net/core/rmem_max", 0o644, "212992\n")
    _node(proc / "812/comm", 0o644, "ModemManager\n")
    _node(dev / "bus/usb/002/005", 0o600)  # root-only: the user cannot open the camera
    _node(dev / "ttyACM0", 0o660)  # owned by root's group: the user is not in dialout
    return {"sysfs_root": sysfs, "dev_root": dev, "proc_root": proc}


def _by_check(findings):
    return {f.check: f for f in findings}


def test_doctor_reports_each_problem_with_its_remedy(fake_system: dict[str, Path]) -> None:
    slow_camera = UsbDevice(2, 5, 0x1E10, 0x4000, None, 480.0, ((0xEF, 0x05), (0xEF, 0x05)))
    mouse = UsbDevice(1, 2, 0x046D, 0xC077, None, 12.0, ((0x03, 0x01),))
    findings = run_doctor(
        **fake_system, list_usb=lambda: [slow_camera, mouse], serial_ports=[BOOTH, OTHER], identity=USER
    )
    checks = _by_check(findings)
    assert checks["usb3vision.speed"].status == "warn" and "480 Mb/s" in checks["usb3vision.speed"].message
    assert checks["usb3vision.access"].status == "fail" and "udev rule" in checks["usb3vision.access"].remedy
    assert (
        checks["usb.usbfs_memory_mb"].status == "warn"
        and "usbfs_memory_mb=1000" in checks["usb.usbfs_memory_mb"].remedy
    )
    assert checks["booth.access"].status == "fail" and "dialout" in checks["booth.access"].remedy
    assert checks["booth.modemmanager"].status == "warn" and "pid 812" in checks["booth.modemmanager"].message
    assert checks["gige.rmem_max"].status == "warn" and "sysctl" in checks["gige.rmem_max"].remedy
    assert checks["gige.mtu"].status == "info" and "eth0: MTU 1500" in checks["gige.mtu"].message
    assert all(f.remedy for f in findings if f.status in ("warn", "fail"))


def test_doctor_all_good(fake_system: dict[str, Path]) -> None:
    (fake_system["sysfs_root"] / "module/usbcore/parameters/usbfs_memory_mb").write_text("1000\n")
    (fake_system["proc_root"] / "sys/net/core/rmem_max").write_text("33554432\n")
    (fake_system["proc_root"] / "812/comm").write_text("bash\n")
    (fake_system["dev_root"] / "bus/usb/002/005").chmod(0o666)
    (fake_system["dev_root"] / "ttyACM0").chmod(0o666)
    camera = UsbDevice(2, 5, 0x1E10, 0x4000, None, 5000.0, ((0xEF, 0x05),))
    findings = run_doctor(**fake_system, list_usb=lambda: [camera], serial_ports=[BOOTH], identity=USER)
    statuses = {f.check: f.status for f in findings}
    assert statuses == {
        "usb3vision.speed": "ok",
        "usb3vision.access": "ok",
        "usb.usbfs_memory_mb": "ok",
        "booth.access": "ok",
        "booth.modemmanager": "ok",
        "gige.rmem_max": "ok",
        "gige.mtu": "info",
    }


def test_doctor_says_when_pyusb_has_no_backend(fake_system: dict[str, Path]) -> None:
    class NoBackendError(Exception):
        pass

    def no_backend() -> list[UsbDevice]:
        raise NoBackendError("No backend available")

    findings = run_doctor(**fake_system, list_usb=no_backend, serial_ports=[], identity=USER)
    backend = _by_check(findings)["usb3vision.backend"]
    assert backend.status == "fail" and "libusb" in backend.remedy
    assert _by_check(findings)["booth.ports"].status == "warn"


def test_doctor_cli_json(fake_system: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser(prog="msflash")
    register(parser.add_subparsers())
    args = parser.parse_args(
        [
            "doctor",
            "--json",
            "--sysfs-root",
            str(fake_system["sysfs_root"]),
            "--dev-root",
            str(fake_system["dev_root"]),
            "--proc-root",
            str(fake_system["proc_root"]),
        ]
    )
    status = args.handler(args)
    payload = json.loads(capsys.readouterr().out)
    assert status in (0, 1) and payload["ok"] is (status == 0)
    checks = {f["check"] for f in payload["findings"]}
    assert {"gige.rmem_max", "gige.mtu", "booth.modemmanager", "usb.usbfs_memory_mb"} <= checks


# -- Arduino boards, USB-serial chips, /dev/serial/by-id (fake port lists: pyserial's own records) ---------


def _listed(device: str, vid: int | None, pid: int | None, serial: str | None, product: str | None) -> SerialPortInfo:
    """A port as pyserial lists it (its ListPortInfo filled in by hand), through discovery's conversion."""
    from serial.tools.list_ports_common import ListPortInfo

    info = ListPortInfo(device, skip_link_detection=True)
    info.vid, info.pid, info.serial_number, info.product = vid, pid, serial, product
    info.description = product or "n/a"
    return from_pyserial(info)


MEGA = _listed("/dev/ttyACM0", 0x2341, 0x0042, "75833353035351A0C1E1", "Arduino Mega 2560")
MEGA_ORG = _listed("/dev/ttyACM1", 0x2A03, 0x0042, "8553130343935170D0A0", "Arduino Mega 2560")
CLONE = _listed("/dev/ttyUSB0", 0x1A86, 0x7523, None, "USB2.0-Serial")
FTDI = _listed("/dev/ttyUSB1", 0x0403, 0x6001, "A50285BI", "FT232R USB UART")
UNO = _listed("/dev/ttyACM2", 0x2341, 0x0043, "95530343", "Arduino Uno")


def test_ports_are_told_apart_by_usb_id() -> None:
    assert [p.kind for p in (BOOTH, MEGA, MEGA_ORG, UNO, CLONE, FTDI, OTHER)] == [
        "booth",
        "arduino-mega",
        "arduino-mega",
        "arduino",
        "usb-serial",
        "usb-serial",
        "serial",
    ]
    assert MEGA.board == "Arduino Mega 2560 R3" and CLONE.board == "WCH CH340 USB-serial"
    assert _listed("/dev/ttyUSB2", 0x10C4, 0xEA60, None, None).board == "Silicon Labs CP210x USB-serial"
    assert _listed("/dev/ttyUSB3", 0x0403, 0x6015, None, None).kind == "usb-serial"


def test_the_one_mega_is_the_booth_when_no_port_has_the_booth_id() -> None:
    assert find_booth([OTHER, CLONE, MEGA, UNO]) == MEGA
    assert find_booth([MEGA, BOOTH]) == BOOTH  # the booth's own id wins
    with pytest.raises(BoothNotFoundError, match="2 Arduino Megas .*pass --port") as caught:
        find_booth([MEGA, MEGA_ORG])
    assert "USB serial 75833353035351A0C1E1" in str(caught.value)
    with pytest.raises(BoothNotFoundError, match="WCH CH340 USB-serial.*found only by --port"):
        find_booth([CLONE, OTHER])


def test_by_id_links_are_read_from_dev(tmp_path: Path) -> None:
    by_id = tmp_path / "serial" / "by-id"
    by_id.mkdir(parents=True)
    link = "usb-Arduino__www.arduino.cc__0042_75833353035351A0C1E1-if00"
    (by_id / link).symlink_to("../../ttyACM0")
    (by_id / "usb-1a86_USB2.0-Serial-if00-port0").symlink_to("../../ttyUSB0")
    assert by_id_links(tmp_path) == {
        "/dev/ttyACM0": f"/dev/serial/by-id/{link}",
        "/dev/ttyUSB0": "/dev/serial/by-id/usb-1a86_USB2.0-Serial-if00-port0",
    }
    mega, clone, other = with_by_id_links([MEGA, CLONE, OTHER], tmp_path)
    assert mega.path == f"/dev/serial/by-id/{link}" and other.by_id is None
    assert (
        describe_port(clone)
        == "/dev/ttyUSB0 (WCH CH340 USB-serial, 1a86:7523, /dev/serial/by-id/usb-1a86_USB2.0-Serial-if00-port0)"
    )
    assert by_id_links(tmp_path / "none") == {}


def test_doctor_takes_the_mega_names_the_others_and_reads_the_ftdi_latency(fake_system: dict[str, Path]) -> None:
    by_id = fake_system["dev_root"] / "serial" / "by-id"
    by_id.mkdir(parents=True)
    (by_id / "usb-Arduino_Mega-if00").symlink_to("../../ttyACM0")
    (fake_system["dev_root"] / "ttyACM0").chmod(0o666)
    _node(fake_system["sysfs_root"] / "bus/usb-serial/devices/ttyUSB1/latency_timer", 0o644, "16\n")
    findings = run_doctor(**fake_system, list_usb=lambda: [], serial_ports=[MEGA, FTDI, OTHER], identity=USER)
    by_check = {f.check: [x for x in findings if x.check == f.check] for f in findings}
    ports = by_check["booth.ports"][0]
    assert ports.status == "info" and "Arduino Mega 2560 R3" in ports.message
    assert "msflash doctor --port /dev/serial/by-id/usb-Arduino_Mega-if00" in ports.message
    assert by_check["booth.access"][0].status == "ok"
    boards = by_check["serial.boards"]
    assert len(boards) == 1 and "FT232R" in boards[0].message and "--port /dev/ttyUSB1" in boards[0].message
    latency = by_check["serial.latency"][0]
    assert latency.status == "info" and "16 ms" in latency.message and "latency_timer" in latency.remedy


def test_doctor_exits_1_on_a_warning_and_checks_the_aravis_typelib(
    fake_system: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from msflash.acquisition.app.cli_booth import aravis_finding

    assert aravis_finding().status in ("ok", "fail")  # the real import, whatever this machine has

    def missing() -> None:
        raise ImportError("Namespace Aravis not available")

    finding = aravis_finding(missing)
    assert finding.status == "fail" and "gir1.2-aravis-0.8" in finding.remedy
    parser = argparse.ArgumentParser(prog="msflash")
    register(parser.add_subparsers())
    roots = ["--sysfs-root", str(fake_system["sysfs_root"]), "--dev-root", str(fake_system["dev_root"])]
    args = parser.parse_args(["doctor", *roots, "--proc-root", str(fake_system["proc_root"])])
    status = args.handler(args)
    out = capsys.readouterr().out
    assert "aravis.typelib" in out
    assert ("WARN" in out or "FAIL" in out) and status == 1  # the fake system has warnings (usbfs 16 MB …)
