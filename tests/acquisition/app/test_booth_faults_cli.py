"""Link faults from the outside: ``msflash booth-emulator --fault`` on a pty, ``run``/``capture --booth-port``.

Every process is real: the emulator serves its pty from a process of its own, and msflash drives it
through the same ``LedBooth`` driver a real booth gets. The booth's state is read from the
emulator's ``--state-file``, written last when it stops, so "LEDs off" is what the booth holds, not
what the host believes.

Traffic of a fixed-exposure host-paced capture on 3 LEDs, request by request: ``ID``, ``STAT``
(leftovers of an earlier run), then per step ``SET`` and ``STAT`` (the simulated camera renders the
levels the booth reports). ``--fault-after 6`` lets steps 0 and 1 through, so a fault of
probability 1 hits step 2 (``led:2``), after two frames are on disk (one more request, ``WDOG``,
when the run raises a short watchdog for the sequence).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from msflash.led_controller import LedBooth

ROOT = Path(__file__).resolve().parents[3]
EMULATOR = ("booth-emulator", "--names", "led440,led520,led660", "--peaks-nm", "440,520,660")
SIM = ("--rig", "sim", "--leds", "3", "--exposure", "10000")
STEP_2 = "step 2 (led:2): "


def _msflash(*argv: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "msflash.acquisition.app.cli", *argv],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )


class Booth:
    """``msflash booth-emulator`` running in its own process."""

    def __init__(self, process: subprocess.Popen, port: str, state_file: Path) -> None:
        self.process = process
        self.port = port
        self.state_file = state_file

    def stop(self) -> dict:
        """Stop the emulator (Ctrl-C; a ``close`` fault has stopped it already) and return its last state."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        assert self.process.wait(15) == 0
        return json.loads(self.state_file.read_text())

    def state_when(self, key: str, value: object, deadline_s: float = 30.0) -> dict:
        """The state once ``key`` holds ``value`` (the booth's own watchdog acts on its own time)."""
        end = time.monotonic() + deadline_s
        while True:
            state = json.loads(self.state_file.read_text())
            if state[key] == value or time.monotonic() > end:
                return state
            time.sleep(0.05)


@contextmanager
def booth_process(tmp_path: Path, *options: str) -> Iterator[Booth]:
    state_file = tmp_path / "booth-state.json"
    process = subprocess.Popen(
        [sys.executable, "-m", "msflash.acquisition.app.cli", *EMULATOR, "--state-file", str(state_file), *options],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        port = process.stdout.readline().strip()
        assert port.startswith("/dev/pts/"), process.stderr.read() if process.poll() is not None else port
        yield Booth(process, port, state_file)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        process.stdout.close()
        process.stderr.close()


def _error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("msflash: error: ")]


def _sequence(out: Path) -> dict:
    return json.loads((out / "sequence" / "sequence.json").read_text())


def test_a_run_through_the_emulator_process_completes_with_the_leds_off(tmp_path: Path) -> None:
    with booth_process(tmp_path) as booth:
        done = _msflash("run", *SIM, "--booth-port", booth.port, "--out", str(tmp_path / "run"))
        state = booth.stop()
    assert done.returncode == 0, done.stderr
    assert _error_lines(done.stderr) == []
    sequence = _sequence(tmp_path / "run")
    assert sequence["complete"] is True
    assert [f["role"] for f in sequence["frames"]] == ["ambient", "led", "led", "led", "flash"]
    # The camera rendered what the booth held: the LED frames differ from the ambient's.
    assert state["leds_on"] is False and state["state"] == "IDLE" and state["link"] == "open"
    assert state["faults"] == {} and state["requests"] is None


@pytest.mark.parametrize(
    ("command", "fault", "says"),
    [
        ("run", "drop:1", "bad reply to SET"),
        ("capture", "flip:1", "bad reply to SET"),
        ("capture", "close:1", "serial link lost during SET"),
    ],
)
def test_a_link_fault_fails_the_step_it_hits_with_the_leds_off(
    tmp_path: Path, command: str, fault: str, says: str
) -> None:
    out = tmp_path / "out"
    with booth_process(tmp_path, "--fault", fault, "--seed", "3", "--fault-after", "6") as booth:
        done = _msflash(command, *SIM, "--booth-port", booth.port, "--out", str(out))
        state = booth.stop()
    assert done.returncode == 1, done.stderr
    errors = _error_lines(done.stderr)
    assert len(errors) == 1, done.stderr
    assert errors[0].startswith(f"msflash: error: {STEP_2}{booth.port}: "), errors
    assert says in errors[0] and "2 frame(s) already saved" in errors[0]
    assert "Traceback" not in done.stderr
    sequence = _sequence(out)
    assert sequence["complete"] is False
    assert [f["role"] for f in sequence["frames"]] == ["ambient", "led"]
    kind = fault.split(":")[0]
    assert state["faults"][kind] >= 1 and state["requests"] >= 7
    assert state["leds_on"] is False and state["levels"] == [0.0, 0.0, 0.0]
    assert state["link"] == ("closed" if kind == "close" else "open")


def test_a_booth_that_stalls_for_good_is_switched_off_by_its_watchdog(tmp_path: Path) -> None:
    """The host cannot reach a stalled booth (not even its OFF): the booth's own watchdog switches off."""
    out = tmp_path / "out"
    with booth_process(tmp_path, "--fault", "stall:1", "--fault-after", "7", "--watchdog-s", "0.5") as booth:
        done = _msflash("run", *SIM, "--booth-port", booth.port, "--out", str(out))
        booth.state_when("leds_on", False)
        state = booth.stop()
    assert done.returncode == 1, done.stderr
    errors = _error_lines(done.stderr)
    assert len(errors) == 1, done.stderr
    assert errors[0].startswith(f"msflash: error: {STEP_2}{booth.port}: no reply to SET within 1 s"), errors
    assert "LEDs not confirmed off" in done.stderr  # the host says it could not switch them off
    assert _sequence(out)["complete"] is False
    assert state["stalled"] is True and state["faults"]["stall"] == 1
    assert state["leds_on"] is False and state["watchdog_fired"] == 1


def test_the_next_run_resets_what_a_killed_run_left_on_the_booth(tmp_path: Path) -> None:
    """A killed run leaves its LEDs on and the watchdog it raised for a long exposure; on a board with
    auto-reset disabled (its open resets nothing) the next run says so and sets both back."""
    with booth_process(tmp_path, "--no-auto-reset") as booth:
        killed = LedBooth.open(booth.port, boot_s=0)
        killed.set_watchdog(120.0)
        killed.set_levels([1.0, 0.0, 0.5])
        killed.close()  # the port closed without OFF, as the kernel does for a killed process
        done = _msflash(
            "capture", *SIM, "--booth-port", booth.port, "--booth-boot-s", "0", "--out", str(tmp_path / "out")
        )
        state = booth.stop()
    assert done.returncode == 0, done.stderr
    assert f"{booth.port}: found the LEDs on (sequence IDLE)" in done.stderr
    assert f"{booth.port}: found the watchdog at 120 s" in done.stderr and "set back to 3 s" in done.stderr
    assert _sequence(tmp_path / "out")["complete"] is True
    assert state["watchdog_ms"] == 3000 and state["leds_on"] is False and state["boots"] == 1


def test_a_capture_through_a_port_that_resets_and_swallows_the_first_seconds(tmp_path: Path) -> None:
    """A stock Mega: each open resets it and its bootloader swallows what is sent for 1.6 s (the twin's
    default). What a killed run left on is gone with the reset, and the capture waits for the boot banner."""
    with booth_process(tmp_path, "--bootloader-s", "1.6") as booth:
        killed = LedBooth.open(booth.port)
        killed.set_watchdog(120.0)
        killed.set_levels([1.0, 0.0, 0.5])
        killed.close()
        done = _msflash("capture", *SIM, "--booth-port", booth.port, "--out", str(tmp_path / "out"))
        state = booth.stop()
    assert done.returncode == 0, done.stderr
    assert "found the LEDs on" not in done.stderr and "found the watchdog" not in done.stderr  # the reset did it
    assert _sequence(tmp_path / "out")["complete"] is True
    assert state["boots"] == 3  # power-up, then one reset per open
    assert state["watchdog_ms"] == 3000 and state["leds_on"] is False


def test_a_capture_that_does_not_wait_for_the_boot_fails_in_one_line_naming_auto_reset(tmp_path: Path) -> None:
    """--booth-boot-s 0 on a board that resets: ID goes to the bootloader; one line, the port, the wait, the cause."""
    with booth_process(tmp_path) as booth:
        done = _msflash(
            "capture", *SIM, "--booth-port", booth.port, "--booth-boot-s", "0", "--out", str(tmp_path / "out")
        )
        booth.stop()
    assert done.returncode == 1, done.stderr
    errors = _error_lines(done.stderr)
    assert len(errors) == 1 and "Traceback" not in done.stderr, done.stderr
    assert booth.port in errors[0] and "of opening the port" in errors[0]
    assert "auto-reset" in errors[0] and "--booth-boot-s 2.5" in errors[0]


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (("booth-emulator", "--fault", "drop:0.01,flip:2"), "--fault item 'flip:2': probability 2 outside [0, 1]"),
        (("booth-emulator", "--fault", "stall:0.1:x"), "--fault item 'stall:0.1:x': stall seconds 'x'"),
        (("booth-emulator", "--fault", "drop:0.1,,close:0.1"), "--fault item '': kind '' unknown"),
        (("booth-emulator", "--fault", "drop:0.1,drop:0.2"), "--fault item 'drop:0.2': drop given twice"),
        (("booth-emulator", "--fault-after", "-1"), "--fault-after -1: negative"),
        (
            ("run", "--rig", "sim", "--booth-port", "/dev/null", "--sync", "booth", "--out", "OUT"),
            "--booth-port with --sync booth",
        ),
        (
            ("capture", "--rig", "aravis-fake", "--booth-port", "/dev/null", "--out", "OUT"),
            "--booth-port: gives the simulated rig an outside booth, but the rig is 'aravis-fake'",
        ),
    ],
)
def test_bad_fault_and_port_options_exit_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: tuple[str, ...], names: str
) -> None:
    assert main([str(tmp_path / "out") if a == "OUT" else a for a in argv]) == 2
    err = capsys.readouterr().err
    assert [line[len("msflash: error: ") :][: len(names)] for line in _error_lines(err)] == [names], err
    assert "Traceback" not in err and len(err.splitlines()) <= 2, err  # 'run' says which rig it opens first
