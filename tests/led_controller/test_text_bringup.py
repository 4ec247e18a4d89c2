"""Bringing up a plain-text booth by hand: ``booth console PORT --booth-protocol text``, ``doctor --port P
--booth-protocol …`` and the serial ports ``devices`` lists, against the emulators on real ptys."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from msflash.lab.text_booth_emulator import TextBoothServer, serve_text_booth
from msflash.led_controller import discovery
from msflash.led_controller.adapters.text_booth import TextBooth
from msflash.led_controller.booth_probe import probe_booth
from msflash.led_controller.console import BoothConsole
from msflash.led_controller.discovery import SerialPortInfo
from msflash.led_controller.emulator import BoothEmulator
from msflash.led_controller.emulator_pty import serve_on_pty
from msflash.led_controller.errors import BoothError
from tests.helpers import PipedLines

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def server() -> Iterator[TextBoothServer]:
    with serve_text_booth(3, ["red", "green", "blue"]) as served:
        yield served


# -- the console --------------------------------------------------------------------------------


def test_console_session_levels_status_err_and_off_at_end_of_input(
    server: TextBoothServer, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each line is checked against the booth's 3 channels, sent as a text line and explained; an ERR reply
    is one line and switches the LEDs off (a raw ``send`` too); end of input switches the LEDs off although
    the last command switched them on."""
    typed = "levels 0.5 0 1\nstatus\nlevels 0.5\nsend L 2 0 0\nlevels 0.25 1 0\n"
    monkeypatch.setattr(sys, "stdin", PipedLines(typed))
    assert main(["booth", "console", server.port, "--booth-protocol", "text"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[:3] == [
        "  > ID?",
        f"  < {server.emulator.firmware},channels=3,names=red green blue",
        f"firmware {server.emulator.firmware!r}, plain-text protocol; 3 channels: red green blue",
    ]
    at = out.index("booth> levels 0.5 0 1")
    assert out[at + 1 : at + 4] == [
        "  > L 0.50000 0.00000 1.00000",
        "  < OK",
        "LEDs now: red 0.5000, green 0.0000, blue 1.0000",
    ]
    at = out.index("booth> status")
    assert out[at + 1 : at + 4] == ["  > L?", "  < L 0.5 0 1", "LEDs: red 0.5000, green 0.0000, blue 1.0000"]
    at = out.index("booth> levels 0.5")
    assert out[at + 1] == ("error: 1 levels for 3 channels; expected levels L0 L1 … (one per channel) (nothing sent)")
    assert out[at + 2] == "booth> send L 2 0 0"  # nothing went out for the refused line
    refused = out[out.index("booth> send L 2 0 0") + 1 : out.index("booth> levels 0.25 1 0")]
    assert refused == [
        "  > L 2 0 0",
        "  < ERR level 2 of channel 1 outside [0, 1]",
        "  > OFF",  # a refused line switches the LEDs off, as every failed command does
        "  < OK",
        f"booth: booth {server.port}: refused L: level 2 of channel 1 outside [0, 1]",
    ]
    assert out[-1] == "LEDs off"
    assert server.emulator.levels == (0.0, 0.0, 0.0)
    assert server.emulator.commands[-2:] == ["L 0.25000 1.00000 0.00000", "OFF"]
    assert "L 0.50000" not in server.emulator.commands  # the refused one-level line was never sent


def test_console_help_and_commands_the_text_booth_lacks(server: TextBoothServer, tmp_path: Path) -> None:
    transcript = tmp_path / "transcript.txt"
    with TextBooth.open(server.port, log_serial=transcript) as booth:
        console = BoothConsole(booth, transcript)
        try:
            assert "send LINE" in "\n".join(console.execute("help"))
            assert console.execute("table 1,0,0") == [
                "error: table needs a booth that runs a pattern table (--booth-protocol msflash); this text "
                "booth takes id, levels, off, status, send, help, quit (nothing sent)"
            ]
            assert console.execute("frobnicate")[0].startswith("error: unknown command 'frobnicate'")
            assert console.execute("send") == ["error: a line to send; expected send LINE (nothing sent)"]
            assert console.execute("levels 0 x 1") == [
                "error: levels '0 x 1' are not numbers; expected levels L0 L1 … (one per channel) (nothing sent)"
            ]
            assert console.execute("send L?")[-1] == "booth answered 'L 0 0 0'"
            assert console.execute("off") == ["  > OFF", "  < OK", "all LEDs off"]
        finally:
            console.close()


def test_console_process_ctrl_c_switches_the_leds_off(server: TextBoothServer) -> None:
    """A real ``msflash booth console`` process, interrupted (SIGINT) right after it lit the LEDs."""
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "msflash.acquisition.app.cli",
            "booth",
            "console",
            server.port,
            "--booth-protocol",
            "text",
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    try:
        assert process.stdin is not None and process.stdout is not None
        process.stdin.write("levels 1 0.5 0\n")
        process.stdin.flush()
        for line in process.stdout:
            if line.startswith("LEDs now:"):
                break
        assert server.emulator.levels == (1.0, 0.5, 0.0)
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 130
    assert err.strip().splitlines()[-1].startswith("msflash: interrupted; LEDs off")
    assert server.emulator.levels == (0.0, 0.0, 0.0)
    assert server.emulator.commands[-1] == "OFF"


# -- doctor --port ------------------------------------------------------------------------------


def test_doctor_on_a_text_booth(server: TextBoothServer, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["doctor", "--port", server.port, "--booth-protocol", "text"]) == 0
    assert capsys.readouterr().out == (
        f"OK    booth.identity: booth {server.port} answers --booth-protocol text: "
        f"firmware {server.emulator.firmware!r}; 3 channels: red green blue\n"
    )
    assert server.emulator.commands == ["ID?"]  # asked who it is, nothing else
    assert main(["doctor", "--port", server.port, "--booth-protocol", "text", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["booth"] == {
        "port": server.port,
        "protocol": "text",
        "firmware": server.emulator.firmware,
        "channels": 3,
        "names": ["red", "green", "blue"],
        "serial": None,
    }


def test_doctor_asking_a_text_booth_in_binary_says_err_in_one_line(
    server: TextBoothServer, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["doctor", "--port", server.port, "--booth-protocol", "msflash"]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1
    assert captured.err.startswith(f'msflash: error: booth {server.port}: answered an ERR line "ERR unknown command')
    assert "(a text booth? try --booth-protocol text); expected an msflash ID reply frame" in captured.err


def test_doctor_asking_our_emulator_as_text_says_it_is_an_msflash_frame(capsys: pytest.CaptureFixture[str]) -> None:
    with serve_on_pty(BoothEmulator()) as served:
        assert main(["doctor", "--port", served.port, "--booth-protocol", "text"]) == 1
        assert served.emulator.levels == (0.0,) * 7
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"msflash: error: booth {served.port}: answered an msflash frame '=00:")
    assert "(an msflash booth? try --booth-protocol msflash); expected '<firmware>,channels=<n>" in err


def test_doctor_on_our_emulator_in_its_protocol(capsys: pytest.CaptureFixture[str]) -> None:
    with serve_on_pty(BoothEmulator()) as served:
        assert main(["doctor", "--port", served.port]) == 0
    assert capsys.readouterr().out.startswith(
        f"OK    booth.identity: booth {served.port} answers --booth-protocol msflash: firmware 'msflash-emulator-"
    )


def test_doctor_on_a_silent_port(capsys: pytest.CaptureFixture[str]) -> None:
    """A pty nobody answers on: nothing within the timeout, in one line."""
    master, slave = os.openpty()
    try:
        import tty

        tty.setraw(slave)
        port = os.ttyname(slave)
        command = ["doctor", "--port", port, "--booth-protocol", "text", "--timeout-s", "0.2", "--booth-boot-s", "0.3"]
        assert main(command) == 1  # a device that is there but silent: the device's failure
        err = capsys.readouterr().err
        assert err == (
            f"msflash: error: booth {port}: nothing answered ID? within 0.2 s (after 0.3 s waiting for it to "
            "boot; a board that resets when its port opens may need a longer --booth-boot-s); expected "
            "'<firmware>,channels=<n>[,names=…]' (a text booth) (--booth-protocol text)\n"
        )
        assert os.read(master, 64) == b"ID?\n"  # the one request, and only to the named port
    finally:
        os.close(master)
        os.close(slave)


def test_probe_reads_binary_noise_as_noise() -> None:
    """A device answering in bytes, served like a booth on a pty: the probe names the bytes."""
    import threading
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    port = os.ttyname(slave)

    def answer() -> None:
        os.read(master, 64)
        os.write(master, b"\xff\x00\x13\x80\n")

    thread = threading.Thread(target=answer)
    thread.start()
    try:
        with pytest.raises(BoothError, match=r"answered binary noise ff 00 13 80 \(another device"):
            probe_booth(port, "msflash", timeout_s=5.0)
    finally:
        thread.join()
        os.close(master)
        os.close(slave)


def test_doctor_on_a_missing_port(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["doctor", "--port", str(tmp_path / "ttyNONE"), "--booth-protocol", "text"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such port" in err


# -- devices ------------------------------------------------------------------------------------


def test_devices_lists_other_serial_ports_with_the_text_booth_hint(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The system's port list is injected (pyserial reads it from sysfs; a pty is not listed): our booth is
    a booth, the USB serial adapter is a serial port with the doctor command that asks it — and nothing
    is opened."""
    pytest.importorskip("gi")
    ports = [
        SerialPortInfo("/dev/ttyUSB0", 0x0403, 0x6001, "FT232R USB UART", "A10K", "FT232R USB UART"),
        SerialPortInfo("/dev/ttyACM0", 0x1209, 0x4D53, "msflash booth", "B0042", "msflash booth"),
    ]
    monkeypatch.setattr(discovery, "list_serial_ports", lambda: ports)
    assert main(["devices", "--interfaces", "fake"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[-2:] == [
        "serial\t/dev/ttyUSB0\t0403:6001\tFTDI FT232R USB-serial\t-\t"
        "'msflash doctor --port /dev/ttyUSB0 --booth-protocol text' to check a text booth",
        "booth\t/dev/ttyACM0\t1209:4d53\tmsflash booth\tserial B0042",
    ]
    assert main(["devices", "--interfaces", "fake", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [b["device"] for b in listed["booths"]] == ["/dev/ttyACM0"]
    assert listed["serial_ports"] == [
        {
            "device": "/dev/ttyUSB0",
            "usb_id": "0403:6001",
            "product": "FT232R USB UART",
            "serial_number": "A10K",
            "description": "FT232R USB UART",
            "kind": "usb-serial",
            "board": "FTDI FT232R USB-serial",
            "by_id": None,
            "hint": "'msflash doctor --port /dev/ttyUSB0 --booth-protocol text' to check a text booth",
        }
    ]
