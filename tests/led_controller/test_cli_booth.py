"""``msflash booth-emulator`` and the bench function."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from msflash.acquisition.app.cli_booth import booth_emulator, register
from msflash.acquisition.app.cli_common import UsageError
from msflash.lab.bench.booth import run_bench
from msflash.led_controller import LedBooth
from tests.helpers import PipedLines

ROOT = Path(__file__).resolve().parents[2]


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="msflash")
    register(parser.add_subparsers())
    return parser.parse_args(list(argv))


def test_booth_emulator_handler_serves_until_stopped(capsys: pytest.CaptureFixture[str]) -> None:
    args = _parse("booth-emulator", "--names", "a,b", "--peaks-nm", "450,650")
    stop = threading.Event()
    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(booth_emulator(args, stop=stop)))
    thread.start()
    try:
        port = ""
        while not port and thread.is_alive():
            port = capsys.readouterr().out.strip()
            time.sleep(0.001)
        with LedBooth.open(port) as booth:
            assert booth.info.names == ("a", "b")
    finally:
        stop.set()
        thread.join(5)
    assert result == [0]


def test_booth_emulator_rejects_mismatched_peaks() -> None:
    with pytest.raises(UsageError, match="2 names but 1 peaks"):
        booth_emulator(_parse("booth-emulator", "--names", "a,b", "--peaks-nm", "450"))


@pytest.mark.parametrize("watchdog", ["0.01", "601"])
def test_booth_emulator_refuses_a_watchdog_its_firmware_would_refuse(watchdog: str) -> None:
    """The firmware's WDOG takes 0 or 50..600000 ms; a power-up period outside it could never be set back
    by a host (msflash raises the watchdog for long sequences and restores it)."""
    with pytest.raises(UsageError, match=rf"watchdog_s {watchdog}; expected 0 \(off\) or 0.05..600 s"):
        booth_emulator(_parse("booth-emulator", "--watchdog-s", watchdog))


def test_booth_emulator_process_prints_its_port_and_stops_on_ctrl_c() -> None:
    code = (
        "import argparse,sys; from msflash.acquisition.app.cli_booth import register; p=argparse.ArgumentParser(); "
        "register(p.add_subparsers()); a=p.parse_args(sys.argv[1:]); sys.exit(a.handler(a))"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "booth-emulator"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/pts/")
        with LedBooth.open(port) as booth:
            assert booth.info.channels == 7
        os.kill(proc.pid, signal.SIGINT)
        assert proc.wait(10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


def test_bench_reports_its_figures() -> None:
    figures = run_bench(round_trips=5, uploads=1, steps=16, channels=8)
    assert figures["booth_round_trip_ms_median"] > 0
    assert figures["booth_pattern_upload_ms_median"] > 0
    assert (figures["booth_pattern_steps"], figures["booth_pattern_channels"]) == (16, 8)


def test_booth_console_reads_commands_from_stdin_and_switches_off_at_the_end(
    booth_on_pty, monkeypatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``msflash booth console PORT`` with piped input: each line echoed, framed and explained; LEDs off
    at the end of input even though the last command switched them on."""
    from msflash.acquisition.app.cli import main

    monkeypatch.setattr(sys, "stdin", PipedLines("levels 1 0 0 0 0 0 0.5\nlevels 3\n"))
    assert main(["booth", "console", booth_on_pty.port]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[2].startswith("firmware msflash-emulator-0.1, protocol 1; 7 channels")
    start = out.index("booth> levels 1 0 0 0 0 0 0.5")
    shown = [line for line in out[:start] if line.startswith("  > ?")]  # the console's ID, after the opening's
    seq = int(shown[-1][5:7], 16) + 1  # a late boot banner has the opening ask ID twice (test_console.py)
    assert out[start + 1].startswith(f"  > ?{seq:02X}:026:SET FFFF 0000 0000 0000 0000 0000 8000*")
    assert out[start + 3].startswith("LEDs now: led440 1.0000 (FFFF)")
    assert out[start + 5].startswith("error: 1 levels for 7 channels")
    assert out[-1] == "LEDs off"
    assert booth_on_pty.emulator.levels == (0.0,) * 7


def test_booth_without_an_action_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    from msflash.acquisition.app.cli import main

    assert main(["booth"]) == 2
    assert (
        capsys.readouterr().err.strip()
        == "msflash: error: booth: no action given; expected 'msflash booth console PORT'"
    )
