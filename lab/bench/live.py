"""``msflash bench --part live``: the live preview path's frame rate on the sim rig (issue 23: ≥ 10 fps at 640 px).

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
    }
