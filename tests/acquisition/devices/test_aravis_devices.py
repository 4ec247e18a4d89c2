"""``msflash devices`` on the Fake interface and on the GigE Vision fake by address (no discovery)."""

from __future__ import annotations

import json
from types import ModuleType
from typing import Any

import pytest

from msflash.acquisition.app.cli import main

pytestmark = pytest.mark.aravis


def test_devices_json_lists_the_fake(aravis: ModuleType, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["devices", "--interfaces", "fake", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["interfaces"] == ["fake"]
    assert [c["device_id"] for c in report["cameras"]] == ["Fake_1"]
    assert report["cameras"][0]["model"] == "Fake"


def test_devices_human_output(aravis: ModuleType, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["devices", "--interfaces", "fake"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("Fake_1\tfake\tAravis Fake\tserial 1")


def test_devices_by_address_without_discovery(
    aravis: ModuleType, gv_fake: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["devices", "--interfaces", "fake", "--address", gv_fake.address, "--json"]) == 0
    cameras = json.loads(capsys.readouterr().out)["cameras"]
    assert [(c["interface"], c["serial"]) for c in cameras] == [("fake", "1"), ("gige", "MSFTEST1")]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["devices", "--interfaces", "fake,firewire"], "--interfaces: interfaces 'fake,firewire': unknown firewire"),
        (["devices", "--interfaces", "fake", "--address", "camera7"], "--address 'camera7': not an IPv4 address"),
    ],
)
def test_devices_bad_input_exits_2_with_one_line(
    aravis: ModuleType, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"msflash: error: {message}") and err.count("\n") == 1


def test_devices_lists_the_booths_among_the_serial_ports(
    aravis: ModuleType, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The system's serial port list is injected (no USB booth can be plugged in here: pyserial reads it
    from sysfs): the booth by its USB id is listed, the plain UART is not, and none found says so."""
    from msflash.led_controller import discovery
    from msflash.led_controller.discovery import SerialPortInfo

    ports = [
        SerialPortInfo("/dev/ttyS0", None, None, None, None, "ttyS0"),
        SerialPortInfo("/dev/ttyACM0", 0x1209, 0x4D53, "msflash booth", "B0042", "msflash booth"),
    ]
    monkeypatch.setattr(discovery, "list_serial_ports", lambda: ports)
    assert main(["devices", "--interfaces", "fake", "--json"]) == 0
    booths = json.loads(capsys.readouterr().out)["booths"]
    assert booths == [
        {
            "device": "/dev/ttyACM0",
            "usb_id": "1209:4d53",
            "product": "msflash booth",
            "serial_number": "B0042",
            "description": "msflash booth",
            "kind": "booth",
            "board": "msflash booth",
            "by_id": None,
        }
    ]
    assert main(["devices", "--interfaces", "fake"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == "booth\t/dev/ttyACM0\t1209:4d53\tmsflash booth\tserial B0042"
    monkeypatch.setattr(discovery, "list_serial_ports", lambda: ports[:1])
    assert main(["devices", "--interfaces", "fake"]) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines()[-1] == "no booth found among the serial ports"
    assert "'msflash doctor' says why" in captured.err
