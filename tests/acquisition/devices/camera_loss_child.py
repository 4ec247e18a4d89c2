"""Child process of the camera-loss tests: the camera side of a GigE camera that dies mid-sequence.

Run as ``python camera_loss_child.py SCENARIO OUT_DIR``. It opens the GigE Vision fake at 127.0.0.1
(no discovery), takes two frames, prints ``READY`` and waits for the parent to kill the fake
process and answer ``KILLED`` on stdin, then carries on and prints one JSON line with what it saw.

Why a child: Aravis 0.8.26 crashed (SIGTRAP, GLib's "Resource deadlock avoided") when the lost
device was finalised on its own heartbeat thread; ``AravisCamera.close`` now prevents that
(``devices/aravis/device_release.py``), and a child keeps any such crash from taking the pytest
worker down with it, reported as what it is.

Scenarios: ``camera`` (AravisCamera alone: the error names the step), ``silent`` (no frame after
the kill: the error says the camera no longer answers (CameraDisconnectedError), not to check the trigger wiring) and ``capture`` (through
``run_capture`` with a SequenceWriter and the booth emulator: frames so far on disk, the sequence
incomplete, the LEDs off).
"""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


def _wait_for_kill() -> None:
    print("READY", flush=True)
    if sys.stdin.readline().strip() != "KILLED":
        raise SystemExit("camera-loss child: the parent did not confirm the kill")


@contextlib.contextmanager
def _camera_after_kill() -> Iterator[Any]:
    """AravisCamera on the process fake at 127.0.0.1: two frames taken, then the fake killed by the parent."""
    from msflash.acquisition.devices.aravis import camera as aravis_camera
    from msflash.acquisition.plan import CapturePlan

    plan = CapturePlan.ambient_then_each_led(3, 1000.0)
    with aravis_camera.AravisCamera("127.0.0.1", interfaces="gige", roi=(0, 0, 32, 32)) as camera:
        camera.prepare(plan)
        camera.start()
        for _ in range(2):
            camera.trigger()
            camera.next_frame(plan.frame_timeout_s + 2.0)  # the process fake polls triggers slowly
        _wait_for_kill()
        yield camera


def camera_scenario() -> dict:
    from msflash.acquisition.errors import CameraDisconnectedError, FrameTimeoutError

    result: dict = {}
    with _camera_after_kill() as camera:
        try:
            camera.trigger()
            camera.next_frame(1.0)
        except (CameraDisconnectedError, FrameTimeoutError) as err:
            result = {"error": type(err).__name__, "message": str(err)}
    return result


def silent_scenario() -> dict:
    """No frame comes after the kill (nothing triggered): the timeout must say the camera is gone.

    The parent starts a fresh fake on the port (so releasing the device is quick) only once this
    side has asked the dead one and printed ``PROBED``.
    """
    from msflash.acquisition.errors import CameraDisconnectedError

    result: dict = {}
    with _camera_after_kill() as camera:
        try:
            camera.next_frame(0.3)
        except CameraDisconnectedError as err:
            result = {"error": type(err).__name__, "message": str(err)}
        print("PROBED", flush=True)
        if sys.stdin.readline().strip() != "ANSWERING":
            raise SystemExit("camera-loss child: the parent did not start the answering fake")
    return result


def capture_scenario(out_dir: Path) -> dict:
    from msflash.acquisition.devices.aravis import camera as aravis_camera
    from msflash.acquisition.errors import CameraError
    from msflash.acquisition.plan import CapturePlan
    from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
    from msflash.acquisition.sequence.writer import SequenceWriter
    from msflash.acquisition.session.capture import run_capture
    from msflash.led_controller import LedBooth, serve_on_pty

    peaks = (450.0, 550.0, 650.0)
    server = serve_on_pty(names=[f"led{i}" for i in range(3)], peaks_nm=list(peaks))
    wavelengths = np.arange(400.0, 701.0, 10.0)
    leds = [SequenceLed(f"led{i}", np.exp(-0.5 * ((wavelengths - peak) / 15) ** 2)) for i, peak in enumerate(peaks)]
    # One-channel frames need a CFA in format v1; the fake streams Mono16 test patterns.
    entry = SequenceCamera(
        model="Fake", serial="MSFLOSS", pixel_format="Mono16", cfa="RGGB", black_level=0, white_level=65535
    )
    plan = CapturePlan.ambient_then_each_led(3, 1000.0, timeout_margin_s=3.0)  # the process fake polls slowly

    class WaitAtStep1:
        """A frame handler: once step 1's frame is written, wait to be killed."""

        def frame_ready(self, event) -> None:  # noqa: ANN001 - a FrameEvent
            if event.step.index == 1:
                _wait_for_kill()

        def sequence_finished(self, result) -> None:  # noqa: ANN001 - a CaptureResult
            pass

    result: dict = {}
    try:
        with (
            LedBooth.open(server.port) as booth,
            aravis_camera.AravisCamera("127.0.0.1", interfaces="gige", roi=(0, 0, 32, 32)) as camera,
        ):
            writer = SequenceWriter(
                out_dir / "seq", wavelengths_nm=wavelengths, spectral_unit="energy", camera=entry, leds=leds
            )
            try:
                with writer:
                    run_capture(camera, booth, plan, writer, (WaitAtStep1(),))
            except CameraError as err:
                result = {"error": type(err).__name__, "message": str(err)}
            result["led_levels_after"] = list(server.emulator.levels)
    finally:
        server.close()
    return result


def main() -> int:
    scenario, out_dir = sys.argv[1], Path(sys.argv[2])
    scenarios = {"camera": camera_scenario, "silent": silent_scenario}
    result = scenarios[scenario]() if scenario in scenarios else capture_scenario(out_dir)
    print("RESULT " + json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
