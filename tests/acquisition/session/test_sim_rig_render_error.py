"""A frame the simulated camera cannot render surfaces as its own error, whoever paces the frames.

Before, the sim camera ended a failed render with ``_end_frame(None)``: on the booth's trigger line
(booth master) the error only reached a log line and the capture reported a lost frame or a
timeout. It now goes through ``TriggeredFrames._fail_frame`` as the replay camera's does.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from msflash.acquisition.devices import sim_rendering
from msflash.acquisition.errors import DroppedFrameError, FrameTimeoutError
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.acquisition.session.capture import run_capture
from msflash.acquisition.session.rig import open_sim_rig
from msflash.processing.errors import SpectralDataError

FAILING_RENDER = 3
"""The render call (1-based) that fails: step 2, the second LED frame."""


class RenderBroke(SpectralDataError):
    """The error the broken renderer raises (a subclass, so it cannot be mistaken for another)."""


@pytest.mark.parametrize("trigger", ["software", "booth", "camera"])
def test_a_render_error_is_raised_in_its_frames_place(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, trigger: str
) -> None:
    real_render = sim_rendering.render_frame
    calls = {"n": 0}

    def render(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == FAILING_RENDER:
            raise RenderBroke("render frame: the world broke at this frame")
        return real_render(*args, **kwargs)

    monkeypatch.setattr(sim_rendering, "render_frame", render)
    path = tmp_path / "sequence"
    with open_sim_rig(n_leds=3, seed=2) as rig:
        wavelengths, camera, leds = rig.sequence_header()
        with SequenceWriter(
            path, wavelengths_nm=wavelengths, spectral_unit="energy", camera=camera, leds=leds
        ) as writer:
            with pytest.raises(SpectralDataError) as caught:
                run_capture(
                    rig.camera, rig.booth, CapturePlan.ambient_then_each_led(3, 10_000.0, trigger=trigger), writer
                )
        assert rig.emulator is not None and rig.emulator.levels == (0.0,) * 3  # LEDs off after the failure
    assert type(caught.value) is RenderBroke, caught.value
    assert not isinstance(caught.value, (FrameTimeoutError, DroppedFrameError))
    # Booth master: the booth paces its table on its own, so it may pulse the next frame before the
    # host has taken the failed one (render call 4 then starts); host- and camera-paced stop at it.
    assert calls["n"] == FAILING_RENDER if trigger != "booth" else calls["n"] >= FAILING_RENDER
    # The frames before the failure were written and stay readable.
    assert [f.role for f in read_sequence(path).frames] == ["ambient", "led"]
