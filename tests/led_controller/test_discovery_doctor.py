"""Booth discovery and the doctor checks over fake /sys, /dev and /proc trees."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from msflash.acquisition.app.cli_booth import register
from msflash.led_controller import BoothNotFoundError
from msflash.led_controller.discovery import SerialPortInfo, find_booth, find_booths
from msflash.led_controller.doctor import Identity, UsbDevice, run_doctor

USER = Identity(uid=1000, gids=frozenset({1000}))

BOOTH = SerialPortInfo("/dev/ttyACM0", 0x1209, 0x4D53, "booth", "A1", "ttyACM0")
GENERIC_BOOTH = SerialPortInfo("/dev/ttyUSB1", 0x0403, 0x6001, "msflash booth v2", None, "FT232R")
OTHER = SerialPortInfo("/dev/ttyS0", None, None, None, None, "n/a")


def test_find_booths_by_usb_id_and_product() -> None:
    assert find_booths([OTHER, GENERIC_BOOTH, BOOTH]) == [BOOTH, GENERIC_BOOTH]
    assert find_booth([OTHER, BOOTH]) == BOOTH


def test_find_booth_lists_what_was_found() -> None:
    with pytest.raises(BoothNotFoundError, match=r"no booth .*found: /dev/ttyS0 \(- n/a\)"):
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
