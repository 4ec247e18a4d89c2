"""ReplayCamera and the ``replay:DIR`` rig on a small recorded sim sequence (tests/data/sequences)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.devices.replay_camera import ReplayCamera
from msflash.acquisition.errors import ReplayMismatchError
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import write_sequence

RECORDED = Path(__file__).resolve().parents[2] / "data" / "sequences" / "sim-macbeth-fluorescent"


def _recorded_plan(**timing) -> CapturePlan:
    return CapturePlan.ambient_then_each_led(7, 10_000.0, **timing)


def test_recording_is_small_and_complete() -> None:
    sequence = read_sequence(RECORDED)
    assert sequence.complete and [f.role for f in sequence.frames] == ["ambient"] + ["led"] * 7 + ["flash"]
    assert sum(p.stat().st_size for p in RECORDED.rglob("*") if p.is_file()) < 300_000


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            lambda s: s[3].__class__(3, "led", (0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0), 10_000.0),
            "step 3 (led:3): led_levels",
        ),
        (lambda s: dataclasses.replace(s[2], exposure_us=12_000.0), "step 2 (led:2): exposure_us 12000"),
        (lambda s: dataclasses.replace(s[5], gain=2.0), "step 5 (led:5): gain 2"),
        (lambda s: dataclasses.replace(s[0], role="dark"), "step 0 (dark): role 'dark'"),
    ],
)
def test_prepare_names_the_first_differing_step_and_field(change, message: str) -> None:
    plan = _recorded_plan()
    steps = list(plan.steps)
    changed = change(steps)
    steps[changed.index] = changed
    camera = ReplayCamera.open(RECORDED)
    with pytest.raises(ReplayMismatchError) as caught:
        camera.prepare(dataclasses.replace(plan, steps=tuple(steps)))
    assert message in str(caught.value)
    assert "frames[" in str(caught.value) and "sequence.json" in str(caught.value)


def test_prepare_refuses_steps_beyond_the_recording() -> None:
    camera = ReplayCamera.open(RECORDED)
    camera.prepare(_recorded_plan())
    camera.start()
    for _ in range(8):
        camera.trigger()
        camera.next_frame(1.0)
    flash = CapturePlan.single(camera.sequence.frames[8].led_levels, 10_000.0).steps[0]
    with pytest.raises(ReplayMismatchError, match=r"step 1 \(flash\): the recording has no frame 9"):
        camera.prepare(CapturePlan((flash, dataclasses.replace(flash, index=1))))


def test_frames_are_served_in_order_with_the_recorded_pixels() -> None:
    camera = ReplayCamera.open(RECORDED)
    camera.prepare(_recorded_plan())
    camera.start()
    for index in range(8):
        camera.trigger()
        frame = camera.next_frame(1.0)
        np.testing.assert_array_equal(frame.pixels, camera.sequence.load_frame(index))
        assert frame.frame_id == index + 1


def test_replayed_run_reproduces_the_estimate(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["estimate", str(RECORDED), "--json"]) == 0
    expected = json.loads(capsys.readouterr().out)
    out = tmp_path / "replayed"
    assert main(["run", "--rig", f"replay:{RECORDED}", "--out", str(out)]) == 0
    replayed = json.loads((out / "estimate.json").read_text())
    # `estimate` (method auto, global chosen) sums per-tile statistics, `run` the whole frame at once:
    # the same numbers in another summation order, so agreement is to rounding, not bit for bit.
    assert expected["method"] == "global"
    np.testing.assert_allclose(replayed["spectrum"], expected["spectrum"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(replayed["ambient_weights"], expected["ambient_weights"], rtol=1e-9, atol=0)
    # The recording's flash was chosen by an earlier estimator (re-estimated since: the global model is
    # solved on noise-corrected statistics), so it is not this run's flash: synthesised, not replayed.
    sequence = read_sequence(out / "sequence")
    assert sequence.complete and [f.role for f in sequence.frames] == ["ambient"] + ["led"] * 7
    assert "the flash is synthesised from the frames, not replayed" in capsys.readouterr().err
    assert (out / "complementary.exr").exists()


def test_a_recorded_flash_with_this_runs_levels_is_replayed(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A recording whose flash frame has the levels this run asks for: the flash frame is replayed as recorded."""
    assert main(["flash", str(RECORDED), "--mode", "complementary", "--json"]) == 0
    weights = np.clip(json.loads(capsys.readouterr().out)["flash_weights"], 0.0, 1.0)
    # The recording written again with its flash frame taken at those levels (a file says what it was
    # taken under, so editing sequence.json alone would be refused as a frame bound to another entry).
    recorded = read_sequence(RECORDED)
    flash = dataclasses.replace(recorded.frames[8], led_levels=tuple(round(float(w), 6) for w in weights))
    copy = tmp_path / "recording"
    write_sequence(
        copy,
        dataclasses.replace(recorded, frames=(*recorded.frames[:8], flash)),
        [recorded.load_frame(i) for i in range(len(recorded.frames))],
    )
    out = tmp_path / "replayed"
    assert main(["run", "--rig", f"replay:{copy}", "--out", str(out)]) == 0
    sequence = read_sequence(out / "sequence")
    assert sequence.complete and len(sequence.frames) == 9  # the flash matched the recorded flash
    np.testing.assert_array_equal(sequence.load_frame(8), read_sequence(RECORDED).load_frame(8))
    assert "not replayed" not in capsys.readouterr().err


@pytest.mark.parametrize("sync", ["booth", "camera"])
def test_replay_in_table_paced_sync(tmp_path: Path, sync: str) -> None:
    out = tmp_path / sync
    assert main(["capture", "--rig", f"replay:{RECORDED}", "--sync", sync, "--out", str(out)]) == 0
    sequence = read_sequence(out / "sequence")
    assert sequence.complete and [f.extra["trigger"] for f in sequence.frames] == list(range(1, 9))


def test_replay_mismatch_through_the_cli_is_one_error_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    status = main(["capture", "--rig", f"replay:{RECORDED}", "--exposure-us", "5000", "--out", str(tmp_path / "x")])
    assert status == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("msflash: error: ") and "step 0 (ambient): exposure_us 5000" in err[-1]


def test_a_booth_that_fails_to_open_is_named_and_the_rig_is_closed(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fault injected into the driver's open (the emulator and its pty are real): the error names the
    rig and the pty, and what was already open (camera, pty server) is closed again."""
    import threading

    from msflash.acquisition.errors import RigOpenError
    from msflash.acquisition.session import rig
    from msflash.led_controller import LedBooth

    def refuse(port, **_kwargs):
        raise OSError(f"cannot open {port}")

    monkeypatch.setattr(LedBooth, "open", staticmethod(refuse))
    threads = threading.active_count()
    with pytest.raises(
        RigOpenError, match=r"rig 'replay:.*': booth emulator on /dev/pts/\d+: cannot open /dev/pts/\d+"
    ):
        rig.open_replay_rig(RECORDED)
    assert threading.active_count() <= threads  # the pty server's thread is gone


def test_a_shared_sample_without_a_camera_serial_is_replayed_as_is(tmp_path: Path) -> None:
    """The independent sample has no ``camera.serial``: the replayed capture records none (the writer
    refuses an empty serial, which the replay camera's identity used to pass on) and every frame
    equals the sample's."""
    from tests.helpers import SAMPLES_DIR

    sample = SAMPLES_DIR / "sample-rgb-tungsten"
    if not sample.is_dir():
        pytest.skip(f"shared sample missing: {sample}")
    assert read_sequence(sample).camera.serial is None
    out = tmp_path / "replayed"
    assert main(["capture", "--rig", f"replay:{sample}", "--out", str(out)]) == 0
    replayed, recorded = read_sequence(out / "sequence"), read_sequence(sample)
    assert replayed.complete and replayed.camera.serial is None
    assert [f.role for f in replayed.frames] == [f.role for f in recorded.frames]
    for index in range(len(recorded.frames)):
        np.testing.assert_array_equal(replayed.load_frame(index), recorded.load_frame(index))


@pytest.mark.parametrize("name", ["sample-rgb-tungsten", "sample-bayer-fluorescent-12bit"])
def test_run_replays_a_recording_without_a_flash_frame_and_synthesises_the_flash(
    tmp_path: Path, capsys: pytest.CaptureFixture, name: str
) -> None:
    """The shared samples hold ambient + 7 LED frames (as 'msflash capture' records; the Bayer one
    with gains 1.5 and 1): 'run' replays them at their recorded exposures *and gains*, estimates,
    solves, says that the flash is synthesised only, and writes the whole report."""
    from tests.helpers import SAMPLES_DIR

    sample = SAMPLES_DIR / name
    if not sample.is_dir():
        pytest.skip(f"shared sample missing: {sample}")
    out = tmp_path / "run"
    assert main(["run", "--rig", f"replay:{sample}", "--out", str(out)]) == 0
    assert "the recording has no flash frame" in capsys.readouterr().err
    replayed, recorded = read_sequence(out / "sequence"), read_sequence(sample)
    assert replayed.complete and not replayed.indices("flash")
    assert [(f.role, f.exposure_us, f.gain) for f in replayed.frames] == [
        (f.role, f.exposure_us, f.gain) for f in recorded.frames
    ]
    summary = json.loads((out / "run.json").read_text())
    assert summary["exposure"]["flash_exposure_us"] is None and summary["exposure"]["mode"] == "recorded"
    assert (out / "complementary.exr").is_file() and (out / "matching.exr").is_file()
    assert "flash-capture" not in summary["previews"]


@pytest.mark.parametrize("sync", ["host", "booth", "camera"])
def test_a_damaged_recorded_frame_is_the_error_in_every_sync_mode(
    tmp_path: Path, capsys: pytest.CaptureFixture, sync: str
) -> None:
    """Frame 3 of the recording is truncated: the replay names that file whoever paces the frames. Booth
    master made the frame on the emulator's trigger-line thread, and the capture reported 'no frame for
    trigger 4' instead (the cause only in a log line). The replay camera now reads (and checks) every
    recorded frame when the rig opens, so the damaged file is refused before anything is captured."""

    recording = tmp_path / "recording"
    shutil.copytree(RECORDED, recording)
    damaged = recording / read_sequence(RECORDED).frames[3].file
    damaged.write_bytes(damaged.read_bytes()[:1000])
    out = tmp_path / "replayed"
    status = main(["capture", "--rig", f"replay:{recording}", "--sync", sync, "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2
    assert err[-1].startswith(f"msflash: error: {damaged}: pixels cannot be decoded")
    assert not (out / "sequence" / "sequence.json").exists()


def test_replaying_an_interrupted_recording_says_it_is_incomplete(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A capture interrupted after two frames (complete: false) cannot be replayed as a whole one; the
    mismatch says the recording is incomplete, the likely reason (it read as a role mismatch alone)."""

    recording = tmp_path / "interrupted"
    shutil.copytree(RECORDED, recording)
    document = json.loads((recording / "sequence.json").read_text())
    document.update(complete=False, frames=document["frames"][:2])
    (recording / "sequence.json").write_text(json.dumps(document))
    status = main(["capture", "--rig", f"replay:{recording}", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1
    assert err[-1].startswith(f"msflash: error: {recording / 'sequence.json'}: step ")
    assert err[-1].endswith(
        "(the recording is incomplete: complete: false, 2 frame(s), as a capture that was interrupted leaves it)"
    )
