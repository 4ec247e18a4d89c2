"""A GigE camera whose process dies mid-sequence (issue 3): a clear error naming the step; through the
capture path, the frames so far on disk, the sequence marked incomplete and the LEDs off.

The camera side runs in a child process (``camera_loss_child.py``, see its docstring for why).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from msflash.acquisition.sequence.reader import read_sequence

pytestmark = pytest.mark.aravis

CHILD = Path(__file__).with_name("camera_loss_child.py")
REPO = Path(__file__).resolve().parents[3]


def _run_scenario(
    scenario: str, out_dir: Path, gv_fake_process: Callable[..., Any], serial: str, probe_dead: bool = False
) -> dict:
    """Run the child once: a child killed by a signal fails the test with its stderr.

    It used to be retried once: Aravis finalised the lost device on its own heartbeat thread,
    which then joined itself (GLib's "Resource deadlock avoided", SIGTRAP). AravisCamera.close
    now hands a lost device to devices/aravis/device_release.py instead.
    """
    work = out_dir / "run"
    work.mkdir()
    fake = gv_fake_process(serial=serial)
    child = subprocess.Popen(
        [sys.executable, "-X", "faulthandler", str(CHILD), scenario, str(work)],
        cwd=REPO,
        text=True,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert child.stdout is not None and child.stdin is not None
    line = child.stdout.readline().strip()
    assert line == "READY", (
        f"child did not reach the kill point: {line!r} {child.stderr.read() if child.stderr else ''}"
    )
    fake.send_signal(signal.SIGKILL)
    fake.wait(timeout=10)
    if probe_dead:  # the child asks the dead device first, then carries on with the answering fake
        child.stdin.write("KILLED\n")
        child.stdin.flush()
        probed = child.stdout.readline().strip()
        assert probed == "PROBED", f"child did not probe: {probed!r}"
    # Releasing the dead device waits out GVCP retries (5 × 500 ms per write); a fresh fake on
    # the port answers them at once, which keeps the test short.
    answering = gv_fake_process(serial=f"{serial}R")
    child.stdin.write("ANSWERING\n" if probe_dead else "KILLED\n")
    child.stdin.flush()
    out, err = child.communicate(timeout=120)
    answering.send_signal(signal.SIGKILL)
    answering.wait(timeout=10)
    assert child.returncode == 0, f"child exit status {child.returncode}; stderr tail: {err[-2000:]}"
    result_lines = [line for line in out.splitlines() if line.startswith("RESULT ")]
    assert result_lines, out
    return {**json.loads(result_lines[-1][len("RESULT ") :]), "work": str(work), "stderr": err}


def test_killed_camera_process_gives_a_clear_error_naming_the_step(
    aravis: ModuleType, gv_fake_process: Callable[..., Any], tmp_path: Path
) -> None:
    result = _run_scenario("camera", tmp_path, gv_fake_process, "MSFKILL")
    assert result["error"] in ("CameraDisconnectedError", "FrameTimeoutError")
    assert "camera Fake (serial MSFKILL" in result["message"]
    assert "step 2 'led:2'" in result["message"]


def test_killed_camera_mid_capture_keeps_the_frames_and_marks_the_sequence_incomplete(
    aravis: ModuleType, gv_fake_process: Callable[..., Any], tmp_path: Path
) -> None:
    result = _run_scenario("capture", tmp_path, gv_fake_process, "MSFLOSS")
    assert result["error"] in ("CameraDisconnectedError", "FrameTimeoutError")
    assert "step 2" in result["message"]
    assert result["led_levels_after"] == [0.0, 0.0, 0.0]  # LEDs off on the failure path
    sequence = read_sequence(Path(result["work"]) / "seq")
    assert not sequence.complete
    assert [frame.role for frame in sequence.frames] == ["ambient", "led"]
    assert all(sequence.load_frame(i).shape[:2] == (32, 32) for i in range(2))


def test_a_frame_timeout_after_the_camera_died_says_it_no_longer_answers(
    aravis: ModuleType, gv_fake_process: Callable[..., Any], tmp_path: Path
) -> None:
    """The camera dies between frames and control-lost has not come yet: the timeout says the camera no
    longer answers (one bootstrap-register read, ~4 s of Aravis retries), not to check the trigger wiring."""
    result = _run_scenario("silent", tmp_path, gv_fake_process, "MSFSILENT", probe_dead=True)
    assert result["error"] == "CameraDisconnectedError"  # not a timeout: no retry or trigger check can help
    message = result["message"]
    assert message.startswith("camera Fake (serial MSFSILENT") and "step 2 'led:2'" in message
    assert "the camera no longer answers" in message and "check its power and cable" in message
    assert "trigger source and wiring" not in message
    # Releasing it then waits out Aravis's retries: the user is told, rather than left at a silent pause.
    assert "releasing a camera that no longer answers" in result["stderr"]


def test_a_frame_timeout_from_a_live_camera_still_points_at_the_trigger(gv_camera: Any) -> None:
    """The counterpart: a camera that answers but was never triggered keeps the wiring advice."""
    from msflash.acquisition.errors import FrameTimeoutError
    from msflash.acquisition.plan import CapturePlan

    gv_camera.prepare(CapturePlan.ambient_then_each_led(2, 1000.0))
    gv_camera.start()
    with pytest.raises(FrameTimeoutError) as caught:
        gv_camera.next_frame(0.2)  # nothing triggered
    assert "check the trigger source and wiring" in str(caught.value)
    assert "no longer answers" not in str(caught.value)
