"""The ``aravis-fake`` rig: AravisCamera on the GigE Vision fake at 127.0.0.1 + booth emulator on a pty.

The fake streams test patterns, so these tests check plumbing (a complete format-v1 sequence,
frame ids, the trigger wires, releasing the fake), never spectra.
"""

from __future__ import annotations

import socket
from types import ModuleType

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.session.rig import open_rig
from msflash.acquisition.sequence.format import read_sequence

pytestmark = pytest.mark.aravis


def _gvcp_port_free() -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind(("127.0.0.1", 3956))
        except OSError:
            return False
    return True


def _assert_released(aravis: ModuleType) -> None:
    """The rig let go of the fake: the port lock can be taken (a lock this process still held would
    time out — flock conflicts across file descriptions) and, holding it, nobody listens on 3956.

    Another xdist worker may hold the lock for its own test meanwhile, hence the wait.
    """
    with aravis.gvcp_port_lock(timeout_s=120.0):
        assert _gvcp_port_free()


@pytest.mark.parametrize("sync", ["booth", "camera"])  # host-paced: the run test below
def test_capture_writes_a_complete_sequence(aravis: ModuleType, tmp_path, sync: str) -> None:
    out = tmp_path / "c"
    assert main(["capture", "--rig", "aravis-fake", "--sync", sync, "--out", str(out)]) == 0
    sequence = read_sequence(out / "sequence")
    assert sequence.complete
    assert [f.role for f in sequence.frames] == ["ambient"] + ["led"] * 7
    assert sequence.camera.pixel_format == "Mono16" and sequence.camera.cfa is None
    assert "replicated" in sequence.camera.extra["channels"]
    ids = [f.extra["frame_id"] for f in sequence.frames]
    assert all((b - a) % (1 << 16) == 1 for a, b in zip(ids, ids[1:]))
    if sync != "host":
        assert [f.extra["trigger"] for f in sequence.frames] == list(range(1, 9))
    for index, frame in enumerate(sequence.frames):
        assert frame.led_levels == pytest.approx([1.0 if i == index - 1 else 0.0 for i in range(7)])
    pixels = sequence.load_frame(0)
    assert pixels.shape == (48, 64, 3) and pixels.dtype == np.uint16
    assert np.array_equal(pixels[..., 0], pixels[..., 2])
    _assert_released(aravis)


def test_run_completes_the_sequence_and_reports_a_degenerate_estimate(aravis: ModuleType, tmp_path, capsys) -> None:
    """Test patterns do not determine an ambient: run keeps a complete sequence and says why it stops."""
    out = tmp_path / "r"
    status = main(["run", "--rig", "aravis-fake", "--out", str(out)])
    err = capsys.readouterr().err
    sequence = read_sequence(out / "sequence")
    assert sequence.complete
    assert [f.role for f in sequence.frames] == ["ambient"] + ["led"] * 7 + ["flash"]
    if status == 1:  # today's fake patterns: the LED-only images are dependent
        last = err.strip().splitlines()[-1]
        assert last.startswith("msflash: error: rig 'aravis-fake': the ambient estimate is degenerate")
        assert str(out / "sequence") in last
    else:
        assert status == 0 and (out / "report.md").exists()
    _assert_released(aravis)


def test_rig_leds_off_and_fake_released_after_close(aravis: ModuleType) -> None:
    rig = open_rig("aravis-fake")
    try:
        rig.booth.set_levels([0.5] * 7)
        assert rig.emulator is not None and max(rig.emulator.levels) > 0
        header = rig.sequence_header()
        assert len(header[0]) == len(header[2][0].spd) == 31
    finally:
        rig.close()
    assert rig.emulator.levels == (0.0,) * 7
    _assert_released(aravis)


def test_an_exposure_below_the_fakes_range_is_bad_input(aravis: ModuleType, tmp_path, capsys) -> None:
    """The fake's ExposureTime starts at 10 µs: --exposure-us 2 is refused up front, naming the camera's
    own range (it passed the default range and failed later at the camera, exit 1)."""
    status = main(["capture", "--rig", "aravis-fake", "--exposure-us", "2", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2
    assert err[-1].startswith("msflash: error: --exposure 2: outside the camera's range 10–")
