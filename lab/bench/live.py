"""``msflash bench --part live``: the live preview path's frame rate on the sim rig (issue 23: ≥ 10 fps at 640 px),
and the flash preview's: mixes synthesised per second at 640 px (issue 33 item 2: ≥ 15).

One live frame is what the server's rig thread does per frame: :meth:`LiveStream.grab` (a host-paced
software trigger on the sim rig, the frame rendered under the booth emulator's levels, the booth's levels
read back) and :meth:`PreviewRenderer.render` (debayer, colour, histogram, saturation overlay, 640-px JPEG).
Rounds of ``frames`` grabs alone and ``frames`` grabs + previews run in turn, so load that comes and goes
hits both; the medians are reported with their ratio to the 10 fps target, and ``preview_over_grab`` the median
of each round's preview rate ÷ grab rate (steadier than either rate on a shared machine). The LEDs are at 50 % while it
runs (a lit scene), off at the end.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from msflash.acquisition.app.live.preview import PREVIEW_WIDTH, PreviewRenderer
from msflash.acquisition.session.live import LiveStream
from msflash.acquisition.session.rig import open_rig

TARGET_FPS = 10.0
MIX_TARGET_FPS = 15.0
MIX_SENSOR = (2048, 2448)
"""(height, width) of the mosaic the flash preview is timed on."""


def mix_bench(rounds: int = 7, frames: int = 20, seed: int = 0) -> dict[str, Any]:
    """Mixes per second of the flash preview at 640 px: synthesis alone, synthesis + JPEG; the target ratio."""
    from msflash.acquisition.app.live.mix_preview import MixPreview
    from msflash.acquisition.devices.camera import CameraInfo
    from msflash.acquisition.session.analysis import FrameStack
    from msflash.processing.statistics import FrameStackSpec

    rng = np.random.default_rng(seed)
    n_leds = 7
    frames_raw = [rng.integers(240, 4095, size=MIX_SENSOR, dtype=np.uint16) for _ in range(n_leds + 1)]
    spec = FrameStackSpec(240.0, 4095.0, 1 / 6000.0, tuple(1 / 1500.0 for _ in range(n_leds)), np.eye(n_leds))
    stack = FrameStack(frames_raw[0], tuple(frames_raw[1:]), spec, 0, tuple(range(1, n_leds + 1)))
    info = CameraInfo("bench", "BayerRG12 5 MP", "0", "BayerRG12", "RGGB", 240.0, 4095.0, MIX_SENSOR[1], MIX_SENSOR[0])
    with open_rig("sim") as rig:
        responsivities = rig.camera_responsivities
    renderer = PreviewRenderer(info, responsivities)
    start = time.perf_counter()
    mix = MixPreview(stack, "RGGB", tuple(f"led{i}" for i in range(n_leds)), {}, renderer)
    prepare_s = time.perf_counter() - start
    synth_rates, image_rates = [], []
    mix.image((0.5,) * n_leds)  # the kernels' first call out of the timings
    for _ in range(rounds):
        mixes = [tuple(rng.uniform(0, 1, n_leds)) for _ in range(frames)]
        start = time.perf_counter()
        for levels in mixes:
            mix.synthesize(levels)
        synth_rates.append(frames / (time.perf_counter() - start))
        start = time.perf_counter()
        for levels in mixes:
            image = mix.image(levels)
        image_rates.append(frames / (time.perf_counter() - start))
    fps = float(np.median(image_rates))
    return {
        "sensor": list(MIX_SENSOR),
        "preview_samples": list(mix.ambient.shape),
        "preview_size": [image.preview.width, image.preview.height],
        "prepare_s": round(prepare_s, 3),
        "synthesis_fps": round(float(np.median(synth_rates)), 1),
        "mix_preview_fps": round(fps, 1),
        "target_fps": MIX_TARGET_FPS,
        "mix_preview_fps_over_target": round(fps / MIX_TARGET_FPS, 2),
        "note": f"medians of {rounds} interleaved rounds of {frames} random mixes; 7 LEDs, 12-bit RGGB",
    }


def live_bench(rounds: int = 7, frames: int = 20) -> dict[str, Any]:
    """Frames per second of the live path on the sim rig: grab alone, grab + preview; the target ratio."""
    with open_rig("sim") as rig:
        stream = LiveStream(rig)
        renderer = PreviewRenderer(rig.camera.info, rig.camera_responsivities)
        stream.set_levels((0.5,) * rig.led_spectra.count)
        grab_rates, preview_rates = [], []
        size = (0, 0)
        try:
            stream.grab()  # the first plan and the renderer's first call out of the timings
            for _ in range(rounds):
                start = time.perf_counter()
                for _ in range(frames):
                    stream.grab()
                grab_rates.append(frames / (time.perf_counter() - start))
                start = time.perf_counter()
                for _ in range(frames):
                    preview = renderer.render(stream.grab().pixels)
                preview_rates.append(frames / (time.perf_counter() - start))
                size = (preview.width, preview.height)
            frame_shape = list(stream.grab().pixels.shape)
        finally:
            stream.pause()
            stream.all_off()
    preview_fps = float(np.median(preview_rates))
    flash_preview = mix_bench(rounds, frames)
    return {
        "rig": "sim",
        "frame_shape": frame_shape,
        "preview_size": list(size),
        "preview_width_target": PREVIEW_WIDTH,
        "grab_fps": round(float(np.median(grab_rates)), 1),
        "preview_fps": round(preview_fps, 1),
        "target_fps": TARGET_FPS,
        "preview_fps_over_target": round(preview_fps / TARGET_FPS, 2),
        "preview_over_grab": round(float(np.median(np.divide(preview_rates, grab_rates))), 3),
        "note": f"medians of {rounds} interleaved rounds of {frames} frames; the server caps the stream at 25 fps",
        "flash_preview": flash_preview,
    }
