"""A GigE camera process killed mid-sequence: a clear error naming the step, the frames so far on
disk, the sequence marked incomplete, the LEDs off (issue 3's test, through the real capture path)."""

from __future__ import annotations

import signal
from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from acquisition.capture import run_capture
from acquisition.errors import CameraError
from acquisition.plan import CapturePlan
from acquisition.sequence_format import SequenceCamera, SequenceLed, SequenceWriter, read_sequence
from led_controller import LedBooth, serve_on_pty

pytestmark = pytest.mark.aravis

N_LEDS = 3


def test_killed_camera_mid_sequence_keeps_the_frames_and_marks_the_sequence_incomplete(
        aravis: ModuleType, gv_fake_process: Callable[..., Any], tmp_path) -> None:
    process = gv_fake_process(serial="MSFLOSS")
    server = serve_on_pty(names=[f"led{i}" for i in range(N_LEDS)], peaks_nm=[450.0, 550.0, 650.0])
    wavelengths = np.arange(400.0, 701.0, 10.0)
    leds = [SequenceLed(f"led{i}", np.exp(-0.5 * ((wavelengths - peak) / 15) ** 2))
            for i, peak in enumerate((450.0, 550.0, 650.0))]
    # One-channel frames need a CFA in format v1; the fake streams Mono16 test patterns.
    camera_entry = SequenceCamera(model="Fake", serial="MSFLOSS", pixel_format="Mono16", cfa="RGGB",
                                  black_level=0, white_level=65535)
    plan = CapturePlan.ambient_then_each_led(N_LEDS, 1000.0, timeout_margin_s=3.0)  # the process fake polls slowly

    def kill_after_second_frame(step, frame, entry) -> None:  # noqa: ANN001 - capture callback
        if step.index == 1:
            process.send_signal(signal.SIGKILL)
            process.wait(timeout=10)

    try:
        with LedBooth.open(server.port) as booth, \
                aravis.AravisCamera("127.0.0.1", interfaces="gige", roi=(0, 0, 32, 32)) as camera:
            writer = SequenceWriter(tmp_path / "seq", wavelengths_nm=wavelengths, spectral_unit="energy",
                                    camera=camera_entry, leds=leds)
            with pytest.raises(CameraError) as failure, writer:
                run_capture(camera, booth, plan, writer, on_frame=kill_after_second_frame)
            assert "step 2" in str(failure.value)
            assert server.emulator.levels == (0.0,) * N_LEDS  # LEDs off on the failure path
            # Releasing the dead device waits out GVCP retries; a fresh fake answers them at once.
            gv_fake_process(serial="MSFLOSS2")
    finally:
        server.close()
    sequence = read_sequence(tmp_path / "seq")
    assert not sequence.complete
    assert [frame.role for frame in sequence.frames] == ["ambient", "led"]
    assert all(sequence.load_frame(i).shape[:2] == (32, 32) for i in range(2))
