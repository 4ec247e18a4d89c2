"""The plain-text booth adapter (``led_controller/adapters/text_booth.py``) against its emulator on a real pty."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from msflash.lab.text_booth_emulator import TextBoothServer, serve_text_booth
from msflash.led_controller.adapters import open_booth
from msflash.led_controller.adapters.text_booth import TextBooth
from msflash.led_controller.booth_interface import unsupported_sync
from msflash.led_controller.errors import BoothError, BoothNotFoundError, BoothTimeoutError


@pytest.fixture
def server() -> Iterator[TextBoothServer]:
    with serve_text_booth(3, ["red", "green", "blue"]) as served:
        yield served


def test_open_identifies_and_switches_leftovers_off(server: TextBoothServer) -> None:
    server.emulator.levels = (1.0, 0.5, 0.0)  # a run that did not finish
    with TextBooth.open(server.port) as booth:
        assert (booth.info.channels, booth.info.names) == (3, ("red", "green", "blue"))
        assert booth.info.firmware == server.emulator.firmware
        assert server.emulator.levels == (0.0, 0.0, 0.0)
        assert server.emulator.commands == ["ID?", "OFF"]


def test_levels_set_reported_and_off_at_close(server: TextBoothServer) -> None:
    booth = open_booth(server.port, "text")
    booth.set_levels([0.25, 0.0, 1.0])
    assert server.emulator.levels == (0.25, 0.0, 1.0)
    assert booth.reported_levels() == (0.25, 0.0, 1.0)
    booth.close()
    booth.close()
    assert server.emulator.levels == (0.0, 0.0, 0.0)
    assert server.emulator.commands[-2:] == ["L?", "OFF"]


@pytest.mark.parametrize(
    ("levels", "names"),
    [
        ([0.5, 0.5], "2 levels; expected one per channel (3)"),
        ([0.5, 1.5, 0.0], "level 1.5 of channel 2; expected a number in [0, 1]"),
        ([0.5, float("nan"), 0.0], "level nan of channel 2"),
    ],
)
def test_bad_levels_are_refused_with_the_leds_off(server: TextBoothServer, levels: list[float], names: str) -> None:
    with TextBooth.open(server.port) as booth:
        booth.set_levels([1.0, 1.0, 1.0])
        with pytest.raises(ValueError, match="booth .*: ") as refused:
            booth.set_levels(levels)
        assert names in str(refused.value)
        assert server.emulator.levels == (0.0, 0.0, 0.0)


def test_an_err_reply_is_a_booth_error_and_the_leds_go_off(server: TextBoothServer) -> None:
    with TextBooth.open(server.port) as booth:
        booth.set_levels([1.0, 1.0, 1.0])
        server.emulator.names = ("red", "green")  # the device now wants 2 levels: it answers ERR
        with pytest.raises(BoothError, match=rf"booth {server.port}: refused L: 3 levels; expected 2"):
            booth.set_levels([0.5, 0.5, 0.5])
        assert server.emulator.commands[-1] == "OFF" and server.emulator.levels == (0.0, 0.0)


def test_host_paced_only_and_the_refusal_names_booth_and_mode(server: TextBoothServer) -> None:
    with TextBooth.open(server.port) as booth:
        assert booth.capabilities.sync_modes == ("host",)
        assert unsupported_sync(booth, "host") is None
        why = unsupported_sync(booth, "camera")
    assert why is not None and why.startswith(
        f"booth {server.port} (msflash text-booth emulator 1) supports --sync host only; --sync camera needs"
    )


def test_a_silent_port_is_a_timeout_not_a_hang() -> None:
    master, slave = os.openpty()
    try:
        with pytest.raises(BoothTimeoutError, match=r"booth /dev/pts/\d+: no reply to ID\? within 1 s"):
            TextBooth.open(os.ttyname(slave))
    finally:
        os.close(master)
        os.close(slave)


def test_unknown_protocol_and_missing_port() -> None:
    with pytest.raises(ValueError, match="--booth-protocol 'acme': unknown; expected one of msflash, text"):
        open_booth("/dev/null", "acme")
    with pytest.raises(BoothNotFoundError, match="booth /nonexistent/tty: no such port"):
        TextBooth.open("/nonexistent/tty")


@pytest.mark.parametrize("driver", ["text", "msflash"])
def test_a_booth_that_does_not_identify_releases_its_port(monkeypatch: pytest.MonkeyPatch, driver: str) -> None:
    """Both drivers open through the one opener (``serial_port.open_driver``): a silent port times out, and the port
    it held exclusively is released, so the next open finds it free (not busy) and times out alike."""
    from msflash.led_controller import serial_port
    from msflash.led_controller.booth import LedBooth

    opened: list[str] = []
    real = serial_port.open_driver

    def counted(url, *args):  # noqa: ANN001, ANN202 — the module's own opener, counted
        opened.append(url)
        return real(url, *args)

    monkeypatch.setattr(
        f"msflash.led_controller.{'adapters.text_booth' if driver == 'text' else 'booth'}.open_driver", counted
    )
    cls = TextBooth if driver == "text" else LedBooth
    master, slave = os.openpty()
    try:
        for _ in range(2):
            with pytest.raises(BoothTimeoutError):
                cls.open(os.ttyname(slave), timeout_s=0.2, boot_s=0)
        assert opened == [os.ttyname(slave)] * 2
    finally:
        os.close(master)
        os.close(slave)
