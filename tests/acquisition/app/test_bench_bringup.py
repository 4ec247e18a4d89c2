"""The README's hardware section, step by step, against the unkind twins (docs/booth-firmware.md §4).

1. **flash**: ``make -C led_controller/firmware flash PORT=…`` runs the real avrdude (``-c wiring``, STK500v2)
   against the emulator's board, which resets on the open and answers in its bootloader window
   (``led_controller/stk500v2.py``); the flash it holds afterwards is ``booth.hex`` byte for byte.
2. **wire**: ``docs/booth-wiring.svg`` is what the firmware's pin table draws.
3. **find**: discovery over a port list with an Arduino Mega's USB id (pyserial's own ``ListPortInfo``
   records filled in by hand, the device being the resetting emulator's pty) takes the Mega, and
   ``run --rig hw`` opens it without ``--port``.
4. **run**: ``msflash run --rig sim --booth-port`` against ``msflash booth-emulator`` (1.6 s bootloader)
   and against the firmware in simavr behind a resetting port, host paced.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.rigs.emulated_booth import emulator_for
from msflash.lab.wiring import read_pins, wiring_svg
from msflash.led_controller import LedBooth, discovery, firmware_sim, serve_on_pty
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID
from tests.acquisition.support.intel_hex import read_intel_hex

REPO = Path(__file__).resolve().parents[3]
MSFLASH = [sys.executable, "-m", "msflash.acquisition.app.cli"]


@pytest.fixture(scope="module")
def firmware() -> Path:
    reason = firmware_sim.toolchain_missing()
    if reason:
        pytest.skip(reason)
    firmware_sim.build()
    return firmware_sim.ELF


def test_flash_the_image_through_the_bootloader_with_avrdude(firmware: Path) -> None:
    if shutil.which("avrdude") is None:
        pytest.skip("avrdude not installed; expected the Debian package avrdude (setup.sh installs it)")
    with serve_on_pty() as server:
        done = subprocess.run(
            [
                "make",
                "-s",
                "-C",
                str(firmware_sim.FIRMWARE_DIR),
                f"BUILD={firmware_sim.BUILD_DIR}",
                "flash",
                f"PORT={server.port}",
            ],
            capture_output=True,
            text=True,
            check=False,
            timeout=300,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        assert "device signature = 0x1e9801" in done.stderr and "bytes of flash verified" in done.stderr
        image = read_intel_hex((firmware_sim.BUILD_DIR / "booth.hex").read_text())
        assert image and all(server.programmer.flash[address] == byte for address, byte in image.items())
        assert server.resets == 1  # avrdude's open reset the board into its bootloader
        with LedBooth.open(server.port) as booth:  # the board left its bootloader and booted
            assert booth.boots_seen == 1


def test_the_wiring_diagram_is_the_firmwares_pin_table() -> None:
    pins = read_pins()
    assert [(led.arduino, led.output) for led in pins.leds] == [
        (5, "OC3A"),
        (2, "OC3B"),
        (3, "OC3C"),
        (6, "OC4A"),
        (7, "OC4B"),
        (8, "OC4C"),
        (46, "OC5A"),
    ]
    assert pins.trigger_out == ("A", 0, 22) and pins.exposure_in == ("D", 0, 21, "INT0")
    shipped = (REPO / "docs" / "booth-wiring.svg").read_text(encoding="utf-8")
    assert shipped == wiring_svg(pins), (
        "docs/booth-wiring.svg is stale: python -m msflash.lab.wiring --out docs/booth-wiring.svg"
    )


def _mega_port(device: str) -> discovery.SerialPortInfo:
    from serial.tools.list_ports_common import ListPortInfo

    info = ListPortInfo(device, skip_link_detection=True)
    info.vid, info.pid, info.serial_number = 0x2341, 0x0042, "75833353035351A0C1E1"
    info.product = info.description = "Arduino Mega 2560"
    return discovery.from_pyserial(info)


def _serial_port(device: str) -> discovery.SerialPortInfo:
    from serial.tools.list_ports_common import ListPortInfo

    info = ListPortInfo(device, skip_link_detection=True)
    info.description = "ttyS0"
    return discovery.from_pyserial(info)


@pytest.mark.aravis
def test_run_on_the_hardware_rig_finds_the_mega_without_port(
    aravis: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The one Arduino Mega among the ports is the booth: run opens it (resetting it) with no --port."""
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero")
    (tmp_path / "led_spectra.csv").write_text(
        "wavelength_nm,"
        + ",".join(leds.names)
        + "\n"
        + "\n".join(f"{w:g}," + ",".join(f"{v:.6g}" for v in row) for w, row in zip(leds.wavelengths_nm, leds.values))
        + "\n"
    )
    with serve_on_pty(emulator_for(leds)) as server:
        ports = [_serial_port("/dev/ttyS0"), _mega_port(server.port)]
        monkeypatch.setattr(discovery, "list_serial_ports", lambda dev_root=Path("/dev"): ports)
        assert discovery.find_booth().device == server.port
        out = tmp_path / "capture"
        argv = ["capture", "--rig", "hw", "--camera", "Fake_1", "--interfaces", "fake"]
        argv += ["--led-spectra", str(tmp_path / "led_spectra.csv"), "--exposure", "10000", "--out", str(out)]
        assert main(argv) == 0
        assert server.resets == 1
    assert read_sequence(out / "sequence").complete


def test_run_against_the_resetting_emulator_process(tmp_path: Path) -> None:
    """``msflash booth-emulator`` (a stock Mega's link: 1.6 s bootloader, 16 ms latency), then ``run --booth-port``."""
    emulator = subprocess.Popen(
        [*MSFLASH, "booth-emulator", "--serial", "bench-A"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert emulator.stdout is not None
        port = emulator.stdout.readline().strip()
        done = subprocess.run(
            [*MSFLASH, "run", "--rig", "sim", "--booth-port", port, "--out", str(tmp_path / "run")],
            capture_output=True,
            text=True,
            check=False,
            timeout=600,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        probe = subprocess.run([*MSFLASH, "doctor", "--port", port], capture_output=True, text=True, check=False)
        assert probe.returncode == 0 and "serial bench-A" in probe.stdout, probe.stdout + probe.stderr
    finally:
        emulator.terminate()
        emulator.wait(timeout=10)
        if emulator.stdout is not None:
            emulator.stdout.close()
    assert (tmp_path / "run" / "run.json").exists()


def test_run_against_the_firmware_in_simavr_behind_a_resetting_port(firmware: Path, tmp_path: Path) -> None:
    """The whole run, host paced, against the AVR image; the port resets the MCU when run opens it."""
    with firmware_sim.SimulatedBooth(firmware) as sim:
        done = subprocess.run(
            [*MSFLASH, "run", "--rig", "sim", "--booth-port", sim.port, "--out", str(tmp_path / "run")],
            capture_output=True,
            text=True,
            check=False,
            timeout=900,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        assert sim.link()["resets"] == 1
        assert sim.levels == (0.0,) * 7
    assert read_sequence(tmp_path / "run" / "sequence").complete
    recorded = json.loads((tmp_path / "run" / "sequence" / "sequence.json").read_text())
    assert recorded["msflash"]["booth"] == "msflash-avr-0.1"  # the firmware's own ID, through the reset
