"""The booth console's logic against both far ends: typed commands become checked frames, and
the console explains replies and refusals without stopping."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from msflash.led_controller import LedBooth, serve_on_pty
from msflash.led_controller.console import BoothConsole, ConsoleQuit
from msflash.led_controller.protocol import encode_request
from tests.helpers import levels_close

from .conftest import FarEnd


@pytest.fixture
def console(far_end: FarEnd, tmp_path: Path) -> Iterator[BoothConsole]:
    transcript = tmp_path / "transcript.txt"
    with LedBooth.open(far_end.port, timeout_s=2.0, log_serial=transcript) as booth:
        shell = BoothConsole(booth, transcript)
        try:
            yield shell
        finally:
            shell.close()


@pytest.fixture
def first_seq(console: BoothConsole, tmp_path: Path) -> int:
    """The sequence number of a test's first request: the one after the opening's last request (a booth whose
    boot banner comes after ``boot_s`` is asked ``ID`` twice; docs/decisions/firmware-tests-under-load.md)."""
    requests = [line for line in (tmp_path / "transcript.txt").read_text().splitlines() if line.startswith("> ?")]
    return int(requests[-1][3:5], 16) % 255 + 1


def test_levels_are_framed_sent_and_explained(console: BoothConsole, far_end: FarEnd, first_seq: int) -> None:
    out = console.execute("levels 0.5 0 1 0 0 0 0.25")
    frame = encode_request(first_seq, "SET", "8000", "0000", "FFFF", "0000", "0000", "0000", "4000")
    assert out[0] == "  > " + frame.decode().rstrip("\n")
    assert out[1].startswith(f"  < ={first_seq:02X}:006:OK SET*")
    assert out[2].startswith("LEDs now: led440 0.5000 (8000), led480 0.0000 (0000), led500 1.0000 (FFFF)")
    assert levels_close(far_end.levels, [0.5, 0, 1, 0, 0, 0, 0.25])


def test_bad_input_is_explained_and_nothing_is_sent(console: BoothConsole, far_end: FarEnd, first_seq: int) -> None:
    assert console.execute("levels 2 0 0 0 0 0 0") == [
        "error: level 0 (led440) is 2, outside 0..1; expected levels L0 L1 … (one per channel) (nothing sent)"
    ]
    assert console.execute("levels 0.5")[0].startswith("error: 1 levels for 7 channels")
    assert console.execute("frobnicate")[0].startswith("error: unknown command 'frobnicate'")
    assert console.execute("arm camera x")[0].startswith("error: times 'x' are not whole microseconds")
    status = console.execute("status")
    assert status[0].startswith(
        f"  > ?{first_seq:02X}:004:STAT*"
    )  # the first frame since opening: nothing else was sent
    assert status[2].startswith("state IDLE, mode -, step -1 of 0, 0 triggers, watchdog 3 s, last error -")
    assert far_end.levels == (0.0,) * 7


def test_a_held_table_in_host_mode_with_a_refusal_on_the_way(
    console: BoothConsole, far_end: FarEnd, first_seq: int
) -> None:
    loaded = console.execute("table 0.1,0,0,0,0,0,0 hold:0,0,0,0,0,0,0")
    pclr, padd, held = (f"{first_seq + i:02X}" for i in range(3))
    assert [line[:10] for line in loaded[:6]] == [
        f"  > ?{pclr}:00",
        f"  < ={pclr}:00",
        f"  > ?{padd}:02",
        f"  < ={padd}:00",
        f"  > ?{held}:02",
        f"  < ={held}:00",
    ]
    assert "HOLD" in loaded[4] and loaded[6] == "table loaded: 2 steps (PCLR, then one PADD each)"
    console.execute("arm host 0")
    console.execute("start")
    assert console.execute("next")[-1] == "step 0 applied and settled: trigger the camera now"
    refused = console.execute("next")
    assert refused[-1].endswith("booth refused NEXT (E_STATE: next step held; expected PSET first); expected 'OK NEXT'")
    console.execute("pset 1 0.2 0 0 0 0 0 0")
    assert console.execute("next")[-1] == "step 1 applied and settled: trigger the camera now"
    assert levels_close(far_end.levels, [0.2, 0, 0, 0, 0, 0, 0])
    done = console.execute("next")
    assert any(line.startswith("  ! !") and "DONE 2" in line for line in done)
    assert done[-1] == "no more steps: LEDs off, sequence DONE"
    assert console.execute("events") == ["event DONE 2"]
    assert far_end.levels == (0.0,) * 7


def test_a_booth_whose_banner_comes_after_the_wait_is_asked_id_twice(tmp_path: Path) -> None:
    """A loaded machine can start the firmware after ``boot_s`` (the simavr harness starved): the first ``ID``
    goes to the bootloader and the driver asks again once the banner comes, so a console's first request is
    not always ``?02`` (the ``first_seq`` fixture). A bootloader window longer than the wait makes it certain."""
    transcript = tmp_path / "transcript.txt"
    with (
        serve_on_pty(bootloader_s=0.5) as server,
        LedBooth.open(server.port, timeout_s=5.0, boot_s=0.3, log_serial=transcript) as booth,
    ):
        shell = BoothConsole(booth, transcript)
        status = shell.execute("status")
        shell.close()
    asked = [line[:5] for line in transcript.read_text().splitlines() if line.startswith("> ") and ":ID*" in line]
    assert asked == ["> ?01", "> ?02"] and status[0].startswith("  > ?03:004:STAT*")


def test_identify_and_quit(console: BoothConsole) -> None:
    out = console.execute("id")
    assert out[2].startswith("firmware msflash-") and "7 channels: led440 (440 nm)" in out[2]
    assert console.execute("") == [] and console.execute("# a comment") == []
    with pytest.raises(ConsoleQuit):
        console.execute("quit")
