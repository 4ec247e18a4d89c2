"""Capture through a booth adapter: ``--booth-protocol text`` against the text booth emulator on a pty.

msflash runs in its own process and opens the pty the emulator serves in the test's process, so the
booth's levels and every command it received are read from the emulator itself.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import UsageError
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.capture import SYNC_OF_TRIGGER, check_booth_runs
from msflash.lab.text_booth_emulator import TextBoothServer, serve_text_booth
from msflash.led_controller.adapters.text_booth import TextBooth
from tests.acquisition.support.hw_rig import fake_camera_capture

ROOT = Path(__file__).resolve().parents[3]
SIM = ("--rig", "sim", "--leds", "3", "--exposure", "10000")


@pytest.fixture
def text_booth() -> Iterator[TextBoothServer]:
    with serve_text_booth(3, ["led440", "led520", "led660"]) as server:
        yield server


def _error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("msflash: error: ")]


def test_a_host_paced_capture_through_the_text_booth_completes_with_the_leds_off(
    text_booth: TextBoothServer, tmp_path: Path
) -> None:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "msflash.acquisition.app.cli",
            "capture",
            *SIM,
            "--booth-port",
            text_booth.port,
            "--booth-protocol",
            "text",
            "--sync",
            "host",
            "--out",
            str(tmp_path / "c"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    sequence = read_sequence(tmp_path / "c" / "sequence")
    assert sequence.complete
    assert [f.role for f in sequence.frames] == ["ambient", "led", "led", "led"]
    assert sequence.extra["msflash"]["booth"] == "msflash text-booth emulator 1"
    commands = text_booth.emulator.commands
    assert commands[:2] == ["ID?", "OFF"] and commands[-1] == "OFF"
    # each step's levels were set, then read back for the simulated camera to render with
    sets = [c for c in commands if c.startswith("L ")]
    assert sets == [
        "L 0.00000 0.00000 0.00000",
        "L 1.00000 0.00000 0.00000",
        "L 0.00000 1.00000 0.00000",
        "L 0.00000 0.00000 1.00000",
    ]
    assert commands.count("L?") == len(sets)
    assert text_booth.emulator.levels == (0.0, 0.0, 0.0)
    # the LED frames saw the LED the booth held: each is brighter than the ambient frame
    ambient = sequence.load_frame(0).mean()
    assert all(sequence.load_frame(i).mean() > ambient for i in (1, 2, 3))


def test_booth_master_through_the_sim_booth_port_is_refused(
    text_booth: TextBoothServer, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert (
        main(
            [
                "capture",
                *SIM,
                "--booth-port",
                text_booth.port,
                "--booth-protocol",
                "text",
                "--sync",
                "booth",
                "--out",
                str(tmp_path / "c"),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert [line.split(":")[2] for line in _error_lines(err)] == [" --booth-port with --sync booth"], err
    assert not (tmp_path / "c" / "sequence").exists()


@pytest.mark.aravis
def test_booth_master_on_a_host_paced_adapter_is_refused_naming_booth_and_mode(
    aravis: ModuleType,
    hw_calibration: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    with serve_text_booth(7) as server:
        assert (
            main(
                fake_camera_capture(
                    server.port,
                    "--booth-protocol",
                    "text",
                    "--calibration",
                    str(hw_calibration),
                    "--sync",
                    "booth",
                    "--exposure",
                    "10000",
                    "--out",
                    str(tmp_path / "c"),
                )
            )
            == 2
        )
        err = capsys.readouterr().err
        assert _error_lines(err) == [
            f"msflash: error: booth {server.port} (msflash text-booth emulator 1) supports --sync host only; "
            "--sync booth needs a booth that runs a pattern table and pulses the camera's trigger (booth master); "
            "expected --sync host"
        ], err
        assert "Traceback" not in err
        assert server.emulator.commands[-1] == "OFF" and server.emulator.levels == (0.0,) * 7
    assert not (tmp_path / "c" / "sequence").exists()


def test_booth_protocol_without_a_port_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["capture", *SIM, "--booth-protocol", "text", "--out", str(tmp_path / "c")]) == 2
    assert _error_lines(capsys.readouterr().err) == [
        "msflash: error: --booth-protocol text: says what the booth at --port or --booth-port speaks, but neither "
        "is given (discovery and the emulators speak msflash); expected --port PATH or --booth-port PATH"
    ]


@pytest.mark.parametrize(("trigger", "refused"), [("software", False), ("booth", True), ("camera", True)])
def test_the_session_checks_the_booth_capabilities(text_booth: TextBoothServer, trigger: str, refused: bool) -> None:
    plan = CapturePlan.ambient_then_each_led(3, 10_000.0, trigger=trigger)  # type: ignore[arg-type]
    with TextBooth.open(text_booth.port) as booth:
        if not refused:
            check_booth_runs(booth, plan)
            return
        sync = SYNC_OF_TRIGGER[trigger]
        with pytest.raises(
            UsageError,
            match=rf"^booth {text_booth.port} \(.*\) supports --sync host only; "
            rf"--sync {sync} needs .*; expected --sync host$",
        ):
            check_booth_runs(booth, plan)
