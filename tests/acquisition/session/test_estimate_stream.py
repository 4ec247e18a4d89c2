"""One estimation route: the statistics accumulated as frames arrive are the reported estimate.

A run reports the estimate of the statistics it decided its flash from and reads no frame back from disk
for it or its report; ``msflash estimate SEQ`` feeds the recorded frames, one decoded frame at a time, to
the same accumulator (:class:`acquisition.session.estimate_stream.EstimateStream`) and gives the same
numbers to the last digit; its peak memory is about one frame plus the statistics, whatever the frame
count (tracemalloc here, and an address-space limit smaller than the frame stack in a subprocess).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main as msflash_main
from msflash.acquisition.sequence import image_files
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.acquisition.session import analysis, local_route
from msflash.acquisition.session.estimate_stream import stream_sequence
from msflash.acquisition.session.rig import open_sim_rig

SHAPE = (384, 512, 3)
"""The synthetic sequences' RGB frames: 1.1 MiB each in 16 bits."""
N_LED_FRAMES = 32
"""Multiplexed LED frames (each of 4 LEDs lit 8 times): the stack is 33 frames."""


def write_sequence(path: Path, n_led_frames: int = N_LED_FRAMES, shape: tuple[int, ...] = SHAPE) -> Path:
    """An RGB sequence of one ambient and ``n_led_frames`` LED frames (the sim rig's header), written to ``path``."""
    with open_sim_rig(n_leds=4, seed=3, cfa=None) as rig:
        wavelengths, camera, leds = rig.sequence_header()
        black = int(rig.camera.info.black_level)
    rng = np.random.default_rng(7)
    scene = rng.uniform(0.2, 1.0, size=shape)
    ambient = black + 900 * scene
    with SequenceWriter(path, wavelengths_nm=wavelengths, spectral_unit="energy", camera=camera, leds=leds) as writer:
        writer.add_frame((ambient + rng.normal(0, 3, shape)).astype(np.uint16), "ambient", (0.0,) * 4, 2000.0)
        for j in range(n_led_frames):
            levels = tuple(float(i == j % 4) for i in range(4))
            response = 400 * scene * (0.6 + 0.1 * (j % 4)) * np.array([1.0, 0.8, 0.5])[(j % 4) % 3]
            frame = ambient + response + rng.normal(0, 3, shape)
            writer.add_frame(frame.astype(np.uint16), "led", levels, 2000.0)
        writer.finish()
    return path


def count_frame_reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every image file opened for reading from now on (the one opener every frame reader goes through)."""
    opened: list[str] = []
    real = image_files._open_input

    def counted(path):  # noqa: ANN001, ANN202 — wraps the module's own opener
        opened.append(str(path))
        return real(path)

    monkeypatch.setattr(image_files, "_open_input", counted)
    return opened


def test_a_run_reads_no_frame_back_for_its_estimate_or_report(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``msflash run`` on the sim rig: no frame file is opened for reading; its estimate is ``estimate SEQ``'s."""
    run = tmp_path / "run"
    opened = count_frame_reads(monkeypatch)
    assert msflash_main(["run", "--rig", "sim", "--scene", "macbeth", "--out", str(run)]) == 0
    assert opened == []
    assert (run / "flash-capture.png").is_file() and (run / "ambient.png").is_file()
    reported = json.loads((run / "estimate.json").read_text())
    capsys.readouterr()
    assert msflash_main(["estimate", "--method", "global", "--json", str(run / "sequence")]) == 0
    reread = json.loads(capsys.readouterr().out)
    # The counter counts: estimate SEQ opens the ambient and LED frames (and frame 0's header to check sizes).
    used = {entry.file for entry in read_sequence(run / "sequence").frames if entry.role != "flash"}
    assert {f"frames/{Path(path).name}" for path in opened} == used
    for key in ("ambient_weights", "spectrum", "spectrum_std", "alpha", "relative_residual", "n_samples"):
        np.testing.assert_array_equal(reported[key], reread[key], err_msg=key)


def test_the_estimate_decodes_one_frame_at_a_time(tmp_path: Path) -> None:
    """tracemalloc: estimating a 33-frame sequence peaks at a few frames plus the statistics (the stack is
    33 frames), for the global estimate and for auto's (whose tiles keep block sums of their own)."""
    sequence = read_sequence(write_sequence(tmp_path / "s"))
    frame_bytes = int(np.prod(SHAPE)) * 2
    stack_bytes = (N_LED_FRAMES + 1) * frame_bytes
    local_route.estimate_sequence_local(sequence)  # warm: lazy imports, caches
    for tiles, estimate in ((None, analysis.estimate_sequence), (8, local_route.estimate_sequence_local)):
        statistics = stream_sequence(sequence, 8, tiles).nbytes
        tracemalloc.start()
        try:
            estimate(sequence)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert peak < 3 * frame_bytes + statistics < stack_bytes / 2, (tiles, peak / frame_bytes, statistics)


WORKER = textwrap.dedent(
    """
    import json, resource, sys
    from msflash.acquisition.sequence.reader import read_sequence
    from msflash.acquisition.session import analysis
    from msflash.acquisition.session import local_route

    from msflash.acquisition.sequence.memory_budget import set_memory_budget

    set_memory_budget(1 << 40)  # no budget: this measures the streaming, not the refusal (test_memory_budget.py)
    sequence = read_sequence(sys.argv[1])
    headroom = int(sys.argv[2])
    first = analysis.estimate_sequence(sequence)  # warm: libraries, thread pools and arenas mapped
    with open("/proc/self/status") as status:
        size = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize:"))
    resource.setrlimit(resource.RLIMIT_AS, (size + headroom, resource.getrlimit(resource.RLIMIT_AS)[1]))
    again = analysis.estimate_sequence(sequence)
    try:
        analysis.load_frame_stack(sequence)
        stacked = "loaded"
    except MemoryError:
        stacked = "MemoryError"
    print(json.dumps({"same": bool((first.ambient_weights == again.ambient_weights).all()), "stack": stacked}))
    """
)


def test_under_an_address_space_limit_smaller_than_the_stack_the_estimate_still_runs(tmp_path: Path) -> None:
    """RLIMIT_AS at the process's size + 8 frames: the 33-frame stack cannot be loaded, the estimate runs."""
    path = write_sequence(tmp_path / "s")
    script = tmp_path / "worker.py"
    script.write_text(WORKER)
    frame_bytes = int(np.prod(SHAPE)) * 2
    done = subprocess.run(
        [sys.executable, str(script), str(path), str(8 * frame_bytes)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout.strip().splitlines()[-1]) == {"same": True, "stack": "MemoryError"}


def test_a_stack_in_memory_and_the_files_give_the_same_estimate(tmp_path: Path) -> None:
    """The frames of a stack in memory fed to the accumulator (``stream_stack``) = the files streamed."""
    sequence = read_sequence(write_sequence(tmp_path / "s", n_led_frames=4))
    stack = analysis.load_frame_stack(sequence)
    from_memory = local_route.estimate_sequence_local(sequence, stream=analysis.stream_stack(sequence, stack, 8, 8))
    from_disk = local_route.estimate_sequence_local(sequence)
    np.testing.assert_array_equal(
        from_memory.global_estimate.ambient_weights, from_disk.global_estimate.ambient_weights
    )
    np.testing.assert_array_equal(from_memory.mean_weights, from_disk.mean_weights)


def test_synthesis_from_disk_streams_the_frames_and_gives_the_stacks_image_bit_for_bit(tmp_path: Path) -> None:
    """``synthesize``/``flash --out``: one frame decoded at a time into a float64 sum; the image is the stack's."""
    sequence = read_sequence(write_sequence(tmp_path / "s"))
    weights = np.array([0.3, 0.6, 0.2, 0.9])
    frame_bytes = int(np.prod(SHAPE)) * 2
    tracemalloc.start()
    try:
        streamed, saturated, layout = analysis.synthesize_sequence(sequence, weights)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # The float64 sum (4 frames' worth), the float32 image (2) and one frame, against a 33-frame stack.
    assert peak < 8 * frame_bytes, peak / frame_bytes
    stacked, stacked_saturated, _ = analysis.synthesize_sequence(sequence, weights, analysis.load_frame_stack(sequence))
    np.testing.assert_array_equal(streamed, stacked)
    np.testing.assert_array_equal(saturated, stacked_saturated)
    assert layout.ambient_index == 0 and len(layout.led_indices) == N_LED_FRAMES


@pytest.mark.parametrize("ambient_last", [False, True])
def test_the_estimate_and_the_channel_statistics_share_one_completeness_rule(
    tmp_path: Path, ambient_last: bool
) -> None:
    """Issue 31: frame by frame, the light models' channel statistics refuse exactly while the estimate's statistics do
    (a missing LED frame, or every LED frame in but the ambient not yet), and both answer once every frame is in; an
    LED frame beyond the planned ones is refused before it counts, so both still answer after it."""
    from msflash.acquisition.errors import RecordingError
    from msflash.acquisition.session.estimate_stream import EstimateStream

    sequence = read_sequence(write_sequence(tmp_path / "s", n_led_frames=4, shape=(64, 80, 3)))
    entries = list(enumerate(sequence.frames))
    if ambient_last:
        entries = entries[1:] + entries[:1]
    stream = EstimateStream.for_sequence(sequence, full_probe=True)

    def refuses(result: object) -> bool:
        try:
            result()  # type: ignore[operator]
        except RecordingError:
            return True
        return False

    answers = []
    for index, entry in entries:
        stream.add(sequence.load_frame(index), entry.role, entry.led_levels, entry.exposure_us * entry.gain)
        answers.append((refuses(stream.statistics), refuses(stream.channel_statistics)))
    assert answers == [(True, True)] * (len(entries) - 1) + [(False, False)]
    index, entry = next((i, e) for i, e in enumerate(sequence.frames) if e.role == "led")
    with pytest.raises(RecordingError, match="LED frame 5 but 4 were planned"):
        stream.add(sequence.load_frame(index), entry.role, entry.led_levels, entry.exposure_us * entry.gain)
    assert stream.statistics().n_leds == stream.channel_statistics().n_leds == 4


@pytest.mark.parametrize("reader", ["load_frame_stack", "synthesize_sequence", "synthesize_checked"])
def test_the_readers_of_a_sequences_frames_take_its_layout_from_one_place(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, reader: str
) -> None:
    """The frame stack and both syntheses take which frames to use and how to linearise them from one
    ``analysis.sequence_layout`` (each built the roles, levels and exposure·gain lists itself before)."""
    sequence = read_sequence(write_sequence(tmp_path / "s", n_led_frames=4, shape=(32, 40, 3)))
    taken = []
    real = analysis.sequence_layout

    def counted(given):  # noqa: ANN001, ANN202 — the module's own layout, counted
        taken.append(given)
        return real(given)

    monkeypatch.setattr(analysis, "sequence_layout", counted)
    weights = np.full(4, 0.5)
    result = (
        analysis.load_frame_stack(sequence)
        if reader == "load_frame_stack"
        else getattr(analysis, reader)(sequence, weights)
    )
    assert taken == [sequence]
    layout = result.spec if reader == "load_frame_stack" else result[2].spec
    assert layout.led_levels.shape == (4, 4)
